"""The book as a course: every chapter states goals and prerequisites, ends with a summary, keeps its prose
cells short and about the subject, refers only to chapters before it, and has sphinx-exercise exercises whose
solutions are executed code (hidden in the book, collapsed in JupyterLab).

These tests read the notebooks' JSON; they execute nothing (nbmake does).
"""

import json
import re
from pathlib import Path

import pytest

from fastslam_edu.app.course import CHAPTERS, PARTS, PATHS, PREREQUISITES, WRITEUPS_PART, check_path, chapter_number

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = ROOT / "notebooks"
MAX_WORDS = 450
#: sentences about how the book or the package was made, not about the subject
BANNED = [
    "this project", "while writing", "an earlier design", "re-run by", "the machine this book",
    "the book's targets", "at the time of writing", "in the copy used here", "this book was built",
    "we ran", "when this chapter was written", "the reference folder",
]
GOALS = re.compile(r"after this chapter you can", re.I)
PREREQ = re.compile(r"\*\*Prerequisites?[:.]?\*\*[:.]?(.*)", re.I)
DOC_LINK = re.compile(r"\{doc\}`(?:[^`<]*<)?/?(?:notebooks/)?(\d\d_[a-z0-9_]+)>?`")
CHAPTER_WORD = re.compile(r"(?<![Rr]obotics\*, )(?<![Rr]obotics\* )(?<!ch\. )\b[Cc]hapters? (\d{1,2})\b")


def cells(name):
    return json.loads((NOTEBOOKS / f"{name}.ipynb").read_text())["cells"]


def text(cell):
    return "".join(cell["source"])


def prose_words(source):
    """Words of a markdown cell, display math and code blocks left out."""
    source = re.sub(r"\$\$.*?\$\$", " ", source, flags=re.S)
    source = re.sub(r"(`{3,}|:{3,})\s*\{?math\}?.*?\1", " ", source, flags=re.S)
    source = re.sub(r"```(?:python)?\n.*?```", " ", source, flags=re.S)
    return len(source.split())


def sections(name):
    """(heading, cell) pairs: each cell with the last level-2 heading above it."""
    heading, out = "", []
    for cell in cells(name):
        if cell["cell_type"] == "markdown":
            for line in text(cell).splitlines():
                if line.startswith("## "):
                    heading = line[3:].strip()
        out.append((heading, cell))
    return out


@pytest.mark.parametrize("name", CHAPTERS)
def test_goals_and_prerequisites_open_the_chapter(name):
    opening = "\n".join(text(c) for c in cells(name)[:3] if c["cell_type"] == "markdown")
    assert GOALS.search(opening), f"{name}: no 'After this chapter you can' goals in the opening cells"
    goals = _goal_lines(opening)
    assert 3 <= len(goals) <= 5, f"{name}: {len(goals)} learning goals (want 3-5)"
    match = PREREQ.search(opening)
    assert match, f"{name}: no **Prerequisites:** line in the opening cells"
    named = tuple(DOC_LINK.findall(match.group(1)))
    assert set(named) == set(PREREQUISITES[name]), (
        f"{name}: prerequisites line names {named}, the course map says {PREREQUISITES[name]}")


def _goal_lines(opening):
    """The bullet lines right after 'After this chapter you can'."""
    after = opening[GOALS.search(opening).end():].splitlines()[1:]
    lines = []
    for line in after:
        if re.match(r"^\s*[-*] ", line):
            lines.append(line)
        elif lines and line.strip() and not line.startswith("  "):
            break
    return lines


@pytest.mark.parametrize("name", CHAPTERS)
def test_summary_closes_the_chapter(name):
    headings = [h for h, _ in sections(name)]
    assert "Summary" in headings, f"{name}: no '## Summary' section"


@pytest.mark.parametrize("name", CHAPTERS)
def test_prose_cells_are_short_and_about_the_subject(name):
    for i, cell in enumerate(cells(name)):
        if cell["cell_type"] != "markdown":
            continue
        source = text(cell)
        words = prose_words(source)
        assert words <= MAX_WORDS, f"{name}, cell {i}: {words} words (at most {MAX_WORDS})"
        lower = source.lower()
        for phrase in BANNED:
            assert phrase not in lower, f"{name}, cell {i}: {phrase!r} speaks about the book, not the subject"


@pytest.mark.parametrize("name", CHAPTERS)
def test_no_forward_references(name):
    me = chapter_number(name)
    for heading, cell in sections(name):
        if cell["cell_type"] != "markdown" or heading == "Summary":
            continue  # the summary may point ahead ("next, ...")
        source = text(cell)
        for target in DOC_LINK.findall(source):
            if target in PARTS[WRITEUPS_PART]:
                continue  # a core chapter may point to where the write-ups are examined
            assert target[:2].isdigit() and int(target[:2]) <= me, f"{name}: refers ahead to {target}"
        for number in CHAPTER_WORD.findall(source):
            assert int(number) <= me, f"{name}: refers ahead to chapter {number} ({heading})"


def exercise_blocks(name):
    """The exercises' labels, and per solution: its label, the code cells inside, the directive's options."""
    labels, solutions, current = [], [], None
    for cell in cells(name):
        source = text(cell)
        if cell["cell_type"] == "markdown":
            labels += re.findall(r"\{exercise(?:-start)?\}[^\n]*\n(?:\s*:[a-z-]+:[^\n]*\n)*?\s*:label:\s*(\S+)", source)
            start = re.search(r"\{solution-start\}\s*(\S+)\s*\n((?:\s*:[a-z-]+:[^\n]*\n)*)", source)
            if start:
                current = {"label": start.group(1), "options": start.group(2), "code": []}
            if "{solution-end}" in source:
                assert current is not None, f"{name}: solution-end without solution-start"
                solutions.append(current)
                current = None
        elif current is not None:
            current["code"].append(cell)
    assert current is None, f"{name}: solution-start without solution-end"
    return labels, solutions


@pytest.mark.parametrize("name", CHAPTERS)
def test_exercises_have_executed_hidden_solutions(name):
    old_style = [i for i, c in enumerate(cells(name))
                 if c["cell_type"] == "markdown" and re.search(r"\{admonition\} Solution|\{dropdown\} Solution", text(c))]
    assert not old_style, f"{name}: solutions as markdown dropdowns in cells {old_style} (use solution-start/-end)"
    labels, solutions = exercise_blocks(name)
    assert labels, f"{name}: no sphinx-exercise exercises"
    assert len(set(labels)) == len(labels), f"{name}: duplicate exercise labels"
    solved = {s["label"] for s in solutions}
    assert set(labels) == solved, f"{name}: exercises without a solution {set(labels) - solved}, " \
                                  f"solutions without an exercise {solved - set(labels)}"
    for s in solutions:
        assert ":class: dropdown" in s["options"], f"{name}: solution {s['label']} is not a dropdown"
        assert s["code"], f"{name}: solution {s['label']} has no code cell"
        assert any("assert" in text(c) for c in s["code"]), f"{name}: solution {s['label']} checks nothing"
        for c in s["code"]:
            assert c["metadata"].get("jupyter", {}).get("source_hidden"), (
                f"{name}: a code cell of solution {s['label']} is not stored with hidden source")


def test_toc_lists_the_chapters_in_order():
    listed = re.findall(r"notebooks/(\d\d_[a-z0-9_]+)", (ROOT / "_toc.yml").read_text())
    assert listed == list(CHAPTERS)
    assert sorted(p.stem for p in NOTEBOOKS.glob("[0-9][0-9]_*.ipynb")) == sorted(CHAPTERS)


@pytest.mark.parametrize("path", PATHS)
def test_course_paths_respect_prerequisites(path):
    check_path(PATHS[path])


def test_a_path_out_of_order_is_refused():
    with pytest.raises(ValueError, match="needs"):
        check_path({"one lecture": ("08_putting_it_together",)})


def test_prerequisites_come_earlier():
    for name, before in PREREQUISITES.items():
        assert all(chapter_number(b) < chapter_number(name) for b in before), name


def test_chapter_map_draws_every_chapter_and_dependency():
    import matplotlib.pyplot as plt
    from matplotlib.text import Annotation

    from fastslam_edu.app.course import draw_chapter_map

    fig = draw_chapter_map("three lectures")
    ax = fig.axes[0]
    arrows = [t for t in ax.texts if isinstance(t, Annotation)]
    boxes = [t for t in ax.texts if not isinstance(t, Annotation)]
    assert len(arrows) == sum(len(p) for p in PREREQUISITES.values())
    assert sorted(int(b.get_text().split(".")[0]) for b in boxes) == list(range(1, len(CHAPTERS) + 1))
    outlined = [b for b in boxes if b.get_bbox_patch().get_linewidth() > 2]
    assert len(outlined) == sum(len(c) for c in PATHS["three lectures"].values())
    plt.close(fig)


#: notation that book/notation.md retired, in the landmark chapters' prose: (pattern, what to write instead)
RETIRED_NOTATION = [
    (re.compile(r"h\([^()$]*,\s*m\)"), r"h(x, \mathbf{l}): the landmark position is l, m is the particle index"),
    (re.compile(r"(?<![A-Za-z\\])m_(?:\{?[jkn1K]\b)"), r"\mathbf{l}_k: the landmark position is l"),
    (re.compile(r"\\,?d\s?m\b|\\mathrm\{d\}\s?m\b"), r"d\mathbf{l}"),
    (re.compile(r"\bG_t\b|\bG_x\b|G_\{t\}|G_\{x\}"), "F (motion Jacobian) or H_x (pose Jacobian of h)"),
    (re.compile(r"\bK_t\b"), "K (the gain; the landmark count is N)"),
    (re.compile(r"\$K\$ landmarks|O\(M\s*\\?log\s*K\)|O\(K\^?2\)"), "N for the landmark count"),
]
LANDMARK_CHAPTERS = [c for c in CHAPTERS if c not in ("16_occupancy_grid", "17_grid_slam", "18_thor_humanoid")]


@pytest.mark.parametrize("name", LANDMARK_CHAPTERS)
def test_notation_is_the_notation_page(name):
    for i, cell in enumerate(cells(name)):
        if cell["cell_type"] != "markdown":
            continue
        for pattern, instead in RETIRED_NOTATION:
            hit = pattern.search(text(cell))
            assert not hit, f"{name}, cell {i}: {hit.group(0)!r} (book/notation.md: {instead})"


def test_the_notation_page_defines_the_symbols_the_chapters_use():
    page = (ROOT / "book" / "notation.md").read_text()
    for symbol in (r"\mathbf{l}_k", r"h(x, \mathbf{l})", r"K = \Sigma H^\top Q^{-1}", r"H_x", r"G = \partial h^{-1}",
                   r"F = \partial g", r"k = 1, \dots, N", r"m = 1, \dots, M"):
        assert symbol in page, f"book/notation.md does not define {symbol}"


@pytest.mark.parametrize("name", [c for c in CHAPTERS if c not in PARTS[WRITEUPS_PART]])
def test_the_write_ups_stay_in_their_part(name):
    # the word in the prose ({doc} links to the write-up chapters are links, not the word)
    count = sum(len(re.findall(r"write-ups?", DOC_LINK.sub(" ", text(c)), re.I))
                for c in cells(name) if c["cell_type"] == "markdown")
    assert count <= 1, f"{name}: 'write-up' {count} times in the prose (at most once outside {WRITEUPS_PART!r})"
