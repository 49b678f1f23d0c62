"""How long a chapter takes to read, counted from what the book shows.

A reader reads prose at about :data:`WORDS_PER_MINUTE` words a minute and spends about
:data:`SECONDS_PER_CODE_LINE` seconds on each line of code the page shows. What the page does *not* show is not
counted:

- a cell tagged ``remove-input``, ``remove-cell``, ``hide-input`` or ``hide-cell``;
- a code cell stored with its source hidden (``metadata.jupyter.source_hidden``);
- everything between a ``solution-start`` and its ``solution-end`` (the solutions, hidden in the book).

Blank code lines are not counted. Each chapter states its reading time under its title, as the line
``*Reading time: about N min.*`` (:data:`HEADER`); ``python -m fastslam_edu.app.reading_time --write NOTEBOOK ...``
writes it, ``--check`` lists the notebooks whose line is missing or wrong, and with no notebook named both act on
every chapter of :data:`fastslam_edu.app.course.CHAPTERS`.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path
from typing import NamedTuple

__all__ = ["WORDS_PER_MINUTE", "SECONDS_PER_CODE_LINE", "HIDDEN_TAGS", "HEADER", "ReadingTime", "reading_time",
           "reading_time_of_cells", "stated_minutes", "write_header"]

#: prose read per minute
WORDS_PER_MINUTE = 150
#: seconds spent on each shown line of code
SECONDS_PER_CODE_LINE = 6
#: cell tags that keep a cell's source off the page
HIDDEN_TAGS = frozenset({"remove-input", "remove-cell", "hide-input", "hide-cell"})
#: the line under each chapter's title, with the minutes in it
HEADER = "*Reading time: about {minutes} min.*"
_HEADER_RE = re.compile(r"^\*Reading time: about (\d+) min\.\*$", re.M)


class ReadingTime(NamedTuple):
    """Minutes of reading of one chapter: prose, code, and their sum."""

    prose: float
    code: float

    @property
    def total(self) -> float:
        return self.prose + self.code

    @property
    def minutes(self) -> int:
        """The total, rounded up to whole minutes (what the header states)."""
        return int(-(-self.total // 1))


def _source(cell: dict) -> str:
    src = cell.get("source", "")
    return "".join(src) if isinstance(src, list) else src


def _shown(cell: dict) -> bool:
    meta = cell.get("metadata", {})
    if HIDDEN_TAGS & set(meta.get("tags", [])):
        return False
    return not (cell["cell_type"] == "code" and meta.get("jupyter", {}).get("source_hidden"))


def reading_time(notebook: str | Path) -> ReadingTime:
    """The reading time of the notebook at ``notebook``, counted as the module docstring says."""
    return reading_time_of_cells(_cells(notebook))


def reading_time_of_cells(cells: list[dict]) -> ReadingTime:
    """:func:`reading_time` of a notebook's cells (its JSON ``cells`` list)."""
    words = lines = 0
    in_solution = False
    for cell in cells:
        source = _source(cell)
        if cell["cell_type"] == "markdown" and "{solution-start}" in source:
            in_solution = True
        if not in_solution and _shown(cell):
            if cell["cell_type"] == "markdown":
                words += len(source.split())
            elif cell["cell_type"] == "code":
                lines += sum(1 for line in source.splitlines() if line.strip())
        if cell["cell_type"] == "markdown" and "{solution-end}" in source:
            in_solution = False
    return ReadingTime(prose=words / WORDS_PER_MINUTE, code=lines * SECONDS_PER_CODE_LINE / 60)


def _cells(notebook: str | Path) -> list[dict]:
    path = Path(notebook)
    try:
        return json.loads(path.read_text(encoding="utf-8"))["cells"]
    except (OSError, ValueError, KeyError) as exc:
        raise ValueError(f"{path}: not a readable notebook ({exc})") from None


def stated_minutes(notebook: str | Path) -> int | None:
    """The minutes the chapter's header states, or None when it has no header line."""
    for cell in _cells(notebook)[:2]:
        if cell["cell_type"] == "markdown":
            found = _HEADER_RE.search(_source(cell))
            if found:
                return int(found.group(1))
    return None


def write_header(notebook: str | Path) -> bool:
    """Write (or correct) the reading-time line under the title; True when the file changed.

    The notebook keeps its JSON layout (indent 1, keys in order, a trailing newline).
    """
    path = Path(notebook)
    nb = json.loads(path.read_text(encoding="utf-8"))
    first = next(c for c in nb["cells"] if c["cell_type"] == "markdown")
    text = _source(first)
    for _ in range(3):  # the header's own words count: settle on the number it states
        minutes = reading_time_of_cells(nb["cells"]).minutes
        line = HEADER.format(minutes=minutes)
        if _HEADER_RE.search(text):
            new = _HEADER_RE.sub(line.replace("\\", "\\\\"), text, count=1)
        else:
            title, _, rest = text.partition("\n")
            new = f"{title}\n\n{line}\n{rest}" if rest.startswith("\n") else f"{title}\n\n{line}\n\n{rest}"
        first["source"] = new.splitlines(keepends=True)
        text = new
    changed = json.dumps(nb, indent=1, ensure_ascii=False) + "\n" != path.read_text(encoding="utf-8")
    if changed:
        path.write_text(json.dumps(nb, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
    return changed


def main(argv: list[str] | None = None) -> int:
    from fastslam_edu.app.course import CHAPTERS

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("notebooks", nargs="*", type=Path, help="default: every chapter")
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--write", action="store_true", help="write the header line of each notebook")
    group.add_argument("--check", action="store_true", help="exit 1 if a header is missing or wrong")
    args = parser.parse_args(argv)
    root = Path(__file__).resolve().parents[2] / "notebooks"
    paths = args.notebooks or [root / f"{name}.ipynb" for name in CHAPTERS]
    wrong = []
    for path in paths:
        rt = reading_time(path)
        if args.write:
            write_header(path)
        stated = stated_minutes(path)
        print(f"{path.stem:32s} prose {rt.prose:5.1f}  code {rt.code:5.1f}  total {rt.total:5.1f} min"
              f"  (header: {stated if stated is not None else '-'})")
        if stated != rt.minutes:
            wrong.append(path.stem)
    if args.check and wrong:
        print(f"reading-time header missing or wrong: {', '.join(wrong)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
