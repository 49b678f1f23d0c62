"""The student edition's check finds solution lines, and only those (book/student_edition.py)."""

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "book"))

import student_edition  # noqa: E402


def notebook(tmp_path, cells):
    path = tmp_path / "nb.ipynb"
    path.write_text(json.dumps({"cells": [{"cell_type": kind, "source": source, "metadata": {}}
                                          for kind, source in cells]}))
    return path


def test_solution_lines_are_the_solutions_own(tmp_path):
    nb = notebook(tmp_path, [
        ("markdown", "Write the sampler.\n"),
        ("code", "def sampler(weights, rng):\n    cumulative = np.cumsum(weights)  # starter code\n"),
        ("markdown", "````{solution-start} ex-1\n:class: dropdown\n````"),
        ("code", "def sampler(weights, rng):\n    cumulative = np.cumsum(weights)\n"
                 "    return np.searchsorted(cumulative, rng.random(len(weights)))\n"),
        ("markdown", "The arcs of the pointers are the weights, so each draw picks particle i with w_i.\n"),
        ("markdown", "````{solution-end}\n````\nThe next section uses the sampler on real weights.\n"),
    ])
    lines = student_edition.solution_lines(nb)
    assert "return np.searchsorted(cumulative, rng.random(len(weights)))" in lines
    assert "The arcs of the pointers are the weights, so each draw picks particle i with w_i." in lines
    assert not any("cumsum" in line for line in lines), "the starter code's lines are not solution lines"
    assert not any("next section" in line for line in lines), "text after solution-end is outside"


def test_an_unclosed_solution_runs_to_the_end_of_the_notebook(tmp_path):
    inside, outside = student_edition.split_lines(notebook(tmp_path, [
        ("markdown", "````{solution-start} ex-1\n:class: dropdown\n````"),
        ("code", "x = 1\n"),
    ]))
    assert "x = 1" in inside
