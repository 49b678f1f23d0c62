# The two commands of the README:
#   make book   -> venv, install, fetch and verify the data, build the book executing the notebooks (_build/html)
#   make test   -> venv, install, fetch and verify the data, run every test (package tests + notebooks)
# In class:
#   make lab    -> JupyterLab from the project's venv, with the data folder set (extra arguments: LAB_ARGS=...)
#   make labs   -> the graded labs (labs/): otter assign -> _build/labs/{student,autograder}/<lab>/
#   make check-labs -> grade the solutions, the handed-out notebooks and planted mistakes (labs/check_grading.py)
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
# The data folder ($FASTSLAM_EDU_DATA, default ./data), made absolute here: the notebooks run in notebooks/,
# where a relative path would point somewhere else (a path starting with ~ is left to Python to expand).
DATA := $(or $(FASTSLAM_EDU_DATA),$(CURDIR)/data)
override FASTSLAM_EDU_DATA := $(if $(filter ~%,$(DATA)),$(DATA),$(abspath $(DATA)))
export FASTSLAM_EDU_DATA
LAB_ARGS ?=
# a chapter with equations, rendered offline by `make check-math`
MATH_PAGE ?= _build/html/notebooks/04_one_landmark_ekf.html
CHROMIUM ?= chromium

.PHONY: venv lab-venv grading-venv labs check-labs data book book-force book-strict book-student check-student test test-package test-notebooks lab check-math bench clean

$(BIN)/.installed: pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e ".[test,book,graph,sweep]"
	$(BIN)/python -m ipykernel install --sys-prefix --name python3 >/dev/null
	touch $@

$(BIN)/.lab-installed: $(BIN)/.installed
	$(BIN)/python -m pip install --quiet -c constraints.txt -e ".[lab]"
	touch $@

venv: $(BIN)/.installed

lab-venv: $(BIN)/.lab-installed

$(BIN)/.grading-installed: $(BIN)/.installed
	$(BIN)/python -m pip install --quiet -c constraints.txt -e ".[grading]"
	touch $@

grading-venv: $(BIN)/.grading-installed

# every dataset the notebooks, benchmarks and command line read: fetched when missing (from the pinned
# sources, or from $FASTSLAM_EDU_MIRROR), verified by sha256 when present; one line per dataset
data: venv
	$(BIN)/fastslam-edu data

# re-executes only the notebooks whose code changed since the last build (jupyter-cache in _build/.jupyter_cache)
book: data
	$(BIN)/jupyter-book build . --path-output .

# every notebook executed again (after a change in the package, which the cache does not see)
book-force: data
	rm -rf _build/.jupyter_cache
	$(BIN)/jupyter-book build . --path-output . --all

# what CI runs: every notebook executed, warnings are errors, nitpicky cross-references
book-strict: data
	rm -rf _build/.jupyter_cache
	$(BIN)/jupyter-book build . --path-output . --all -W -n --keep-going

# the student edition: the same book with every solution left out (book/student_edition.py as a Sphinx extension), into
# _build/student/html; it reuses the notebooks' executions of `make book` (the same jupyter-cache)
book-student: data
	$(BIN)/python book/student_edition.py config _build/student/_config.yml
	rm -rf _build/student/html _build/student/_build
	$(BIN)/jupyter-book build . --config _build/student/_config.yml --path-output _build/student $(STUDENT_ARGS)
	mv _build/student/_build/html _build/student/html

# no solution text in the student edition, while the self-learner's book shows it
check-student: book-student
	$(BIN)/python book/student_edition.py check _build/student/html _build/html

test: test-package test-notebooks

test-package: venv
	$(BIN)/python -m pytest tests

test-notebooks: data
	$(BIN)/python -m pytest --nbmake --nbmake-timeout=300 notebooks

lab: data lab-venv
	$(BIN)/jupyter lab $(LAB_ARGS)

# the built book's equations rendered by MathJax from _static, in headless Chromium with no network at all
check-math:
	$(BIN)/python .ci/check_math.py --chromium $(CHROMIUM) $(MATH_PAGE)

# the three graded labs (otter-grader): each master labs/<lab>/<lab>.ipynb -> _build/labs/student/<lab>/ (to hand out)
# and _build/labs/autograder/<lab>/ (solutions, tests, the autograder zip)
LABS := lab1_models lab2_landmarks lab3_fastslam
labs: data grading-venv
	@for lab in $(LABS); do \
	  echo "== otter assign labs/$$lab/$$lab.ipynb"; \
	  rm -rf _build/labs/student/$$lab _build/labs/autograder/$$lab _build/labs/assign/$$lab; \
	  $(BIN)/otter assign --no-run-tests labs/$$lab/$$lab.ipynb _build/labs/assign/$$lab || exit 1; \
	  mkdir -p _build/labs/student _build/labs/autograder; \
	  mv _build/labs/assign/$$lab/student _build/labs/student/$$lab; \
	  mv _build/labs/assign/$$lab/autograder _build/labs/autograder/$$lab; \
	done

# every lab graded with otter: the solution scores 100 %, the handed-out notebook 0, each planted mistake
# loses exactly its question's points (table on stdout, JSON in _build/labs/grading.json)
check-labs: labs
	$(BIN)/python labs/check_grading.py

bench: data
	$(BIN)/python benchmarks/fastslam_mrclam.py

# also numba's compiled kernels (__pycache__/*.nbi, *.nbc): a kernel inlined into another file's kernel is not
# recompiled when only its own file changes
clean:
	rm -rf _build .pytest_cache .hypothesis
	find fastslam_edu -name '*.nbi' -delete -o -name '*.nbc' -delete
