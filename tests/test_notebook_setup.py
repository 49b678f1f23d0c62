"""Each chapter's first code cell: the one rendered by ``book/setup_cell.py``, fetching what the chapter reads.

The cell installs the package on Colab or Binder from the repository named in ``_config.yml``
(``repository.url``, the only place the URL is written) and fetches the chapter's datasets. These tests
check, without running anything, that every notebook of the book starts with exactly that cell, and that
the datasets it fetches cover what the notebook's code reads (a static look at the code).
"""

from __future__ import annotations

import copy
import importlib.util
import json
import re
from pathlib import Path

import pytest

pytest.importorskip("yaml")

ROOT = Path(__file__).resolve().parents[1]


def _load_setup_cell():
    spec = importlib.util.spec_from_file_location("book_setup_cell", ROOT / "book" / "setup_cell.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


setup_cell = _load_setup_cell()
URL = setup_cell.repository_url(ROOT)
NOTEBOOKS = setup_cell.toc_notebooks(ROOT)


def _code_cells(nb: dict) -> list[dict]:
    return [c for c in nb["cells"] if c["cell_type"] == "code"]


def _source(cell: dict) -> str:
    return "".join(cell["source"]) if isinstance(cell["source"], list) else cell["source"]


def _fetched(cell: dict) -> list[str]:
    """The dataset names of the cell's ``fetch_datasets(...)`` call."""
    calls = re.findall(r"\bfetch_datasets\(([^)]*)\)", _source(cell))
    assert len(calls) == 1, "the setup cell calls fetch_datasets once"
    return re.findall(r"""["'](\w+)["']""", calls[0])


def _read_by(code: str) -> set[str]:
    """What ``code`` reads, seen independently of setup_cell.datasets_in: MR.CLAM datasets by number,
    files under intel/, fr079/, thor/ (by path or dataset_path), THOR's joint log."""
    needed = {f"mrclam{n}" for n in re.findall(r"mrclam_path\((\d+)", code)}
    needed |= set(re.findall(r"""["'](intel|fr079|thor)/""", code))
    needed |= set(re.findall(r"""dataset_path\(["'](intel|fr079|thor|mrclam\d+)["']""", code))
    if "real_thor_joints(" in code:
        needed.add("thor")
    return needed


def test_the_toc_lists_every_notebook():
    assert sorted(NOTEBOOKS) == sorted((ROOT / "notebooks").glob("*.ipynb"))
    assert URL.startswith("https://")


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_first_code_cell_is_the_rendered_setup_cell(path):
    nb = json.loads(path.read_text(encoding="utf-8"))
    first = _code_cells(nb)[0]
    want = setup_cell.expected_cell(nb, URL)
    assert _source(first) == "".join(want["source"]), f"run `python book/setup_cell.py --write` ({path.name})"
    assert first["metadata"] == want["metadata"]
    assert first["outputs"] == [] and first["execution_count"] is None
    assert f'"git+{URL}"' in _source(first)
    assert first.get("id"), "nbformat 4.5 cells have ids"
    # one setup cell, and the URL nowhere else in the notebook: it lives in _config.yml
    assert sum(setup_cell.is_setup_cell(c) for c in nb["cells"]) == 1
    elsewhere = [c for c in nb["cells"] if c is not first and URL.split("//", 1)[1] in _source(c)]
    assert not elsewhere


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_setup_cell_fetches_what_the_notebook_reads(path):
    nb = json.loads(path.read_text(encoding="utf-8"))
    first, *rest = _code_cells(nb)
    fetched = _fetched(first)
    code = "\n".join(_source(c) for c in rest)
    needed = _read_by(code)
    assert needed, f"{path.name} reads no dataset?"
    assert needed <= set(fetched), f"{path.name} reads {sorted(needed)} but fetches {fetched}"
    assert len(set(fetched)) == len(fetched)
    # nothing downloads on its own any more: the first cell fetched the data
    assert "download=True" not in code


def test_fetched_names_are_registry_datasets():
    registry = pytest.importorskip("fastslam_edu.datasets.registry")
    for path in NOTEBOOKS:
        first = _code_cells(json.loads(path.read_text(encoding="utf-8")))[0]
        unknown = set(_fetched(first)) - set(registry.REGISTRY)
        assert not unknown, f"{path.name} fetches datasets the registry does not know: {sorted(unknown)}"


# --------------------------------------------------------------------------- the script itself


def _notebook(*cells) -> dict:
    return {"cells": list(cells), "metadata": {}, "nbformat": 4, "nbformat_minor": 5}


def _cell(kind: str, text: str, cid: str) -> dict:
    cell = {"cell_type": kind, "id": cid, "metadata": {}, "source": text.splitlines(keepends=True)}
    if kind == "code":
        cell.update(execution_count=None, outputs=[])
    return cell


def test_datasets_in_finds_each_kind_of_read():
    found = setup_cell.datasets_in(
        'a = mrclam_path(6)\nb = dataset_path("intel") / "x"\nc = laser_file("fr079/y.gz")\nreal_thor_joints()\n'
        "load_mrclam(mrclam_path( 1 ), 2)"
    )
    assert found == {"mrclam1", "mrclam6", "intel", "fr079", "thor"}
    assert setup_cell.datasets_in("from fastslam_edu import thor\nintel = 3\nthor.body_to_world(p)") == set()
    assert sorted(found, key=setup_cell._order) == ["mrclam1", "mrclam6", "intel", "fr079", "thor"]


def test_apply_inserts_then_rewrites_in_place():
    nb = _notebook(_cell("markdown", "# Title", "t"), _cell("code", "import numpy as np\nx = mrclam_path(1)", "c1"))
    assert setup_cell.differs(nb, "https://example.org/r")
    once = setup_cell.apply(copy.deepcopy(nb), "https://example.org/r", "demo")
    assert [c["id"] for c in once["cells"]][::2] == ["t", "c1"]  # inserted before the first code cell
    setup = once["cells"][1]
    assert setup_cell.is_setup_cell(setup) and setup["id"] not in {"t", "c1"}
    assert 'fetch_datasets("mrclam1")' in _source(setup) and "git+https://example.org/r" in _source(setup)
    assert not setup_cell.differs(once, "https://example.org/r")
    # the chapter starts reading Dataset 6 and the URL moves: the same cell is rewritten, its id kept
    once["cells"][2]["source"].append("\ny = mrclam_path(6)")
    assert setup_cell.differs(once, "https://example.org/r")
    twice = setup_cell.apply(copy.deepcopy(once), "https://example.org/new", "demo")
    assert len(twice["cells"]) == 3 and twice["cells"][1]["id"] == setup["id"]
    assert 'fetch_datasets("mrclam1", "mrclam6")' in _source(twice["cells"][1])
    assert "git+https://example.org/new" in _source(twice["cells"][1])


def test_check_and_write_on_a_small_book(tmp_path, capsys):
    (tmp_path / "notebooks").mkdir()
    (tmp_path / "_config.yml").write_text("repository:\n  url: https://example.org/book/\n")
    (tmp_path / "_toc.yml").write_text("format: jb-book\nroot: intro\nchapters:\n  - file: notebooks/a\n")
    nb = _notebook(_cell("markdown", "# A", "m"), _cell("code", 'p = dataset_path("intel") / "f"', "c"))
    path = tmp_path / "notebooks" / "a.ipynb"
    path.write_text(setup_cell.dumps(nb), encoding="utf-8")

    assert setup_cell.main(["--check", "--root", str(tmp_path)]) == 1
    assert "notebooks/a.ipynb" in capsys.readouterr().out
    assert setup_cell.main(["--write", "--root", str(tmp_path)]) == 0
    assert setup_cell.main(["--check", "--root", str(tmp_path)]) == 0
    written = path.read_text(encoding="utf-8")
    assert written.endswith("}\n") and '\n "cells": [\n  {\n' in written  # nbformat's indent=1 layout
    cells = json.loads(written)["cells"]
    assert 'fetch_datasets("intel")' in _source(cells[1]) and "git+https://example.org/book\"" in _source(cells[1])
    assert cells[1]["metadata"] == {"tags": ["hide-cell"]}
    setup_cell.main(["--write", "--root", str(tmp_path)])
    assert path.read_text(encoding="utf-8") == written  # idempotent
