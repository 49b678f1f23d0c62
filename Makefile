# The two commands of the README:
#   make book   -> venv, install, build the book executing every notebook (_build/html)
#   make test   -> venv, install, run every test (package tests + notebooks)
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
# The data folder ($FASTSLAM_EDU_DATA, default ./data), made absolute here: the notebooks run in notebooks/,
# where a relative path would point somewhere else (a path starting with ~ is left to Python to expand).
DATA := $(or $(FASTSLAM_EDU_DATA),$(CURDIR)/data)
override FASTSLAM_EDU_DATA := $(if $(filter ~%,$(DATA)),$(DATA),$(abspath $(DATA)))
export FASTSLAM_EDU_DATA

.PHONY: venv book book-strict test test-package test-notebooks bench clean

$(BIN)/.installed: pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e ".[test,book]"
	$(BIN)/python -m ipykernel install --sys-prefix --name python3 >/dev/null
	touch $@

venv: $(BIN)/.installed

book: venv
	$(BIN)/jupyter-book build . --path-output .

# what CI runs: warnings are errors, nitpicky cross-references
book-strict: venv
	$(BIN)/jupyter-book build . --path-output . -W -n --keep-going

test: test-package test-notebooks

test-package: venv
	$(BIN)/python -m pytest tests

test-notebooks: venv
	$(BIN)/python -m pytest --nbmake --nbmake-timeout=300 notebooks

bench: venv
	$(BIN)/python benchmarks/fastslam_mrclam.py

clean:
	rm -rf _build .pytest_cache .hypothesis
