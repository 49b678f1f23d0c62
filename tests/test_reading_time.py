"""The course's reading budget, counted from the notebooks as the book shows them (fastslam_edu.app.reading_time):
each chapter of the three-lecture path at most 35 min, each lecture's reading at most 90 min, every other chapter
at most 50 min, and each chapter's header states its own time. The counting itself is checked on made-up cells.

These tests read the notebooks' JSON; they execute nothing.
"""

from pathlib import Path

import pytest

from fastslam_edu.app.course import CHAPTERS, PATHS
from fastslam_edu.app.reading_time import reading_time, reading_time_of_cells, stated_minutes

ROOT = Path(__file__).resolve().parents[1]
CORE_LIMIT, LECTURE_LIMIT, CHAPTER_LIMIT = 35.0, 90.0, 50.0
LECTURES = PATHS["three lectures"]
CORE = {name for chapters in LECTURES.values() for name in chapters}


def minutes(name):
    return reading_time(ROOT / "notebooks" / f"{name}.ipynb")


def test_reading_times_are_printed():
    for name in CHAPTERS:
        rt = minutes(name)
        print(f"{name:28s} prose {rt.prose:5.1f}  code {rt.code:5.1f}  total {rt.total:5.1f} min")
    for session, chapters in LECTURES.items():
        print(f"{session}: {sum(minutes(c).total for c in chapters):.1f} min")


@pytest.mark.parametrize("name", CHAPTERS)
def test_chapter_within_its_budget(name):
    limit = CORE_LIMIT if name in CORE else CHAPTER_LIMIT
    assert minutes(name).total <= limit, f"{name}: {minutes(name).total:.1f} min of reading (at most {limit})"


@pytest.mark.parametrize("session", LECTURES)
def test_lecture_reading_within_budget(session):
    total = sum(minutes(c).total for c in LECTURES[session])
    assert total <= LECTURE_LIMIT, f"{session}: {total:.1f} min of reading (at most {LECTURE_LIMIT})"


@pytest.mark.parametrize("name", CHAPTERS)
def test_header_states_the_reading_time(name):
    stated = stated_minutes(ROOT / "notebooks" / f"{name}.ipynb")
    assert stated == minutes(name).minutes, (
        f"{name}: header says {stated} min, the count gives {minutes(name).minutes} "
        "(python -m fastslam_edu.app.reading_time --write notebooks/...)")


def _md(text, **meta):
    return {"cell_type": "markdown", "metadata": meta, "source": text}


def _code(text, tags=(), hidden=False):
    meta = {"tags": list(tags)}
    if hidden:
        meta["jupyter"] = {"source_hidden": True}
    return {"cell_type": "code", "metadata": meta, "source": text, "outputs": []}


def test_counting_words_lines_and_what_is_not_shown():
    cells = [
        _md("one two three " * 50),                         # 150 words: 1 min
        _code("a = 1\n\nb = 2\n"),                           # 2 lines (the blank one not counted): 12 s
        _code("assert a\n" * 5, tags=["remove-input"]),      # not shown
        _code("plot()\n" * 5, tags=["hide-input"]),          # folded away
        _code("x = 1\n", hidden=True),                       # stored hidden
        _md("````{solution-start} ex\n:class: dropdown\n````"),
        _code("answer = 42\n" * 10),                         # inside a solution
        _md("words " * 300 + "\n````{solution-end}\n````"),  # inside a solution
    ]
    rt = reading_time_of_cells(cells)
    assert rt.prose == pytest.approx(1.0)                    # the solution directives are not prose
    assert rt.code == pytest.approx(12 / 60)
    assert rt.minutes == 2  # 1.2 min, rounded up


def test_a_missing_notebook_is_named(tmp_path):
    with pytest.raises(ValueError, match="nowhere.ipynb"):
        reading_time(tmp_path / "nowhere.ipynb")
