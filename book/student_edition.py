"""The student edition: the same book with every exercise's solution left out, for a course that grades exercises.

    python book/student_edition.py config OUT.yml     # write the student edition's _config.yml to OUT.yml
    python book/student_edition.py check STUDENT_HTML BOOK_HTML

``config`` copies ``_config.yml``, adds this file as a Sphinx extension (``setup`` below: every ``solution``
block and everything between ``solution-start`` and ``solution-end`` is dropped from the output), and points the
execution cache at the self-learner's book's (``_build/.jupyter_cache``), so that the notebooks run once for both
editions. sphinx-exercise's own ``hide_solutions`` is not used: it drops the ``solution-start`` marker but keeps
the gated solution's cells and leaves an orphan ``solution-end`` node that the HTML writer rejects (1.2.1).

``check`` reads every chapter's solutions from the notebooks (their code lines and the prose inside the solution
blocks) and fails, naming the page and the line, if any of them is in the student edition's HTML; it also checks
that the self-learner's book does show them, so that the check is seen to be able to fail.
"""

from __future__ import annotations

import html
import json
import re
import sys
from pathlib import Path

import yaml
from sphinx.errors import ExtensionError
from sphinx.transforms import SphinxTransform
from sphinx_exercise.nodes import solution_end_node, solution_node, solution_start_node

ROOT = Path(__file__).resolve().parents[1]
MIN_LENGTH = 30  # lines shorter than this are too generic to identify a solution ("plt.show()")


def write_config(out: Path) -> None:
    config = yaml.safe_load((ROOT / "_config.yml").read_text())
    config.setdefault("sphinx", {}).setdefault("local_extensions", {})["student_edition"] = str(ROOT / "book")
    config.setdefault("execute", {})["cache"] = str(ROOT / "_build" / ".jupyter_cache")
    config["title"] = f"{config.get('title', '')} (student edition)"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(yaml.safe_dump(config, sort_keys=False, allow_unicode=True))


class DropSolutions(SphinxTransform):
    """Remove every solution from the doctree, gated ones (``solution-start`` … ``solution-end``) included.

    Runs before sphinx-exercise merges the gated markers (priority 10), so both forms are still visible.
    """

    default_priority = 5

    def apply(self, **kwargs) -> None:
        for node in list(self.document.findall(solution_node)):
            node.parent.remove(node)
        for start in list(self.document.findall(solution_start_node)):
            parent = start.parent
            first = parent.index(start)
            ends = [i for i, child in enumerate(parent.children)
                    if i > first and isinstance(child, solution_end_node)]
            if not ends:
                raise ExtensionError(f"{self.env.docname}: a solution-start without its solution-end")
            for child in parent.children[first:ends[0] + 1]:
                parent.remove(child)


def setup(app):
    """Sphinx entry point: the student edition's build loads this file as an extension."""
    app.add_transform(DropSolutions)
    return {"parallel_read_safe": True, "parallel_write_safe": True}


def split_lines(notebook: Path) -> tuple[list[str], set[str]]:
    """The stripped lines of ``notebook``: those inside solution blocks, and the set of those outside them."""
    inside_lines, outside_lines, inside = [], set(), False
    for cell in json.loads(notebook.read_text())["cells"]:
        source = "".join(cell["source"])
        if cell["cell_type"] == "markdown" and "{solution-start}" in source:
            before, source = source.split("{solution-start}", 1)
            outside_lines.update(line.strip() for line in before.splitlines())
            inside, source = True, source.split("\n", 1)[-1]
        body, after = (source.split("{solution-end}", 1) + [""])[:2] if inside else ("", source)
        inside_lines += [line.strip() for line in body.splitlines()]
        outside_lines.update(line.strip() for line in after.splitlines())
        if cell["cell_type"] == "markdown" and "{solution-end}" in source:
            inside = False
    return inside_lines, outside_lines


def solution_lines(notebook: Path) -> list[str]:
    """Distinctive lines found only in the solutions of ``notebook``: code and prose inside solution blocks, not
    found in the rest of the notebook (an exercise's starter code repeats the solution's first lines)."""
    inside, outside = split_lines(notebook)
    rest = " ".join(" ".join(line.split()) for line in outside)
    return [line for line in inside
            if len(line) >= MIN_LENGTH and " ".join(line.split()) not in rest
            and not line.startswith((":", "`", "#", "$", "|")) and "`" not in line]


def page_text(page: Path) -> str:
    """The text of an HTML page, tags removed and entities decoded, whitespace collapsed."""
    raw = re.sub(r"<[^>]+>", "", page.read_text(encoding="utf-8"))
    return " ".join(html.unescape(raw).split())


def check(student: Path, book: Path) -> int:
    leaks, shown, total = [], 0, 0
    for notebook in sorted((ROOT / "notebooks").glob("[0-9][0-9]_*.ipynb")):
        rel = Path("notebooks") / f"{notebook.stem}.html"
        if not (student / rel).is_file() or not (book / rel).is_file():
            print(f"error: {rel} missing in {student} or {book}: build both editions first", file=sys.stderr)
            return 1
        s_text, b_text = page_text(student / rel), page_text(book / rel)
        if 'class="solution' in (student / rel).read_text(encoding="utf-8"):
            leaks.append(f"{rel}: a solution element")
        for line in solution_lines(notebook):
            needle = " ".join(line.split())
            total += 1
            shown += needle in b_text
            if needle in s_text:
                leaks.append(f"{rel}: {line[:80]}")
    print(f"{total} solution lines looked for: {shown} shown in the book, {total - shown} not found there "
          f"(rendered differently); {len(leaks)} in the student edition")
    if leaks:
        print("error: solution text in the student edition:\n  " + "\n  ".join(leaks[:20]), file=sys.stderr)
        return 1
    if total == 0 or shown < total / 2:
        print("error: the book shows too few of the solutions' lines for this check to mean anything", file=sys.stderr)
        return 1
    return 0


def main(argv: list[str]) -> int:
    if len(argv) == 2 and argv[0] == "config":
        write_config(Path(argv[1]))
        return 0
    if len(argv) == 3 and argv[0] == "check":
        return check(Path(argv[1]), Path(argv[2]))
    print(__doc__, file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
