"""Each chapter's first code cell, rendered from one template.

On Colab or Binder a chapter starts without the package or the data. Its first code cell installs
``fastslam_edu`` when it cannot be imported (from the repository named in ``_config.yml``, or from
``$FASTSLAM_EDU_INSTALL``: a folder, a wheel or any pip requirement, for a classroom or CI), then fetches
the datasets the chapter reads with ``fastslam_edu.datasets.fetch_datasets`` (nothing is downloaded when
they are present). On a prepared machine the cell only checks the data.

The cell is rendered here from ONE template, with the repository URL read from ``_config.yml``
(``repository.url``), the only place the URL is written. The datasets of a chapter are found in its code
(:func:`datasets_read`), so a chapter that starts reading another dataset gets it in its first cell at the
next ``--write``.

    python book/setup_cell.py --write   # rewrite (or insert) the first code cell of every notebook in _toc.yml
    python book/setup_cell.py --check   # exit 1 listing the notebooks whose first code cell differs

The notebooks keep their JSON layout (nbformat 4, indent 1, keys in their order, no outputs); the cell id of a
rewritten cell is kept, an inserted cell gets an id derived from the notebook's name.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: The first line of the rendered cell; a first code cell starting with it is a setup cell to rewrite.
MARKER = "# Colab or Binder:"

TEMPLATE = """\
{marker} install the package and fetch this chapter's data when they are missing
# (nothing to install or download on a prepared machine).
import importlib.util
import os

if importlib.util.find_spec("fastslam_edu") is None:
    install = os.environ.get("FASTSLAM_EDU_INSTALL", "git+{url}")
    %pip install -q "{{install}}"

from fastslam_edu.datasets import fetch_datasets

folders = fetch_datasets({names})"""

#: Cell metadata of the setup cell: folded away in the book (a toggle), first in the notebook for Colab and Binder.
METADATA = {"tags": ["hide-cell"]}

#: The laser datasets, in the order the setup cell names them (after the MR.CLAM datasets).
LASER_DATASETS = ("intel", "fr079", "thor")

# What a chapter's code reads, and which dataset that is.
_MRCLAM = re.compile(r"\bmrclam_path\(\s*(\d+)")
_DATASET_PATH = re.compile(r"""\bdataset_path\(\s*["'](\w+)["']""")
_LASER_FILE = re.compile(r"""["'](intel|fr079|thor)/""")  # a path under the data root, e.g. "intel/intel.relations"
_CALLS = {re.compile(r"\breal_thor_joints\("): "thor"}  # library functions that read a dataset file themselves


# --------------------------------------------------------------------------- the book's configuration


def _yaml(path: Path):
    import yaml  # installed with jupyter-book

    with open(path, encoding="utf-8") as f:
        return yaml.safe_load(f)


def repository_url(root: Path = ROOT) -> str:
    """``repository.url`` of ``_config.yml``, without a trailing slash."""
    url = (_yaml(root / "_config.yml").get("repository") or {}).get("url")
    if not url:
        raise SystemExit(f"{root / '_config.yml'}: no repository.url")
    return str(url).rstrip("/")


def toc_notebooks(root: Path = ROOT) -> list[Path]:
    """The notebooks of ``_toc.yml``, in the book's order."""
    files: list[str] = []

    def walk(node) -> None:
        if isinstance(node, dict):
            for key in ("root", "file"):
                if isinstance(node.get(key), str):
                    files.append(node[key])
            for value in node.values():
                if isinstance(value, (dict, list)):
                    walk(value)
        elif isinstance(node, list):
            for item in node:
                walk(item)

    walk(_yaml(root / "_toc.yml"))
    out = []
    for name in files:
        path = root / name
        path = path if path.suffix == ".ipynb" else path.with_suffix(".ipynb")
        if path.is_file() and path not in out:
            out.append(path)
    return out


# --------------------------------------------------------------------------- the cell


def source_text(cell: dict) -> str:
    src = cell.get("source", "")
    return src if isinstance(src, str) else "".join(src)


def is_setup_cell(cell: dict) -> bool:
    return cell.get("cell_type") == "code" and source_text(cell).startswith(MARKER)


def _order(name: str) -> tuple:
    if name.startswith("mrclam") and name[6:].isdigit():
        return (0, int(name[6:]), "")
    if name in LASER_DATASETS:
        return (1, LASER_DATASETS.index(name), "")
    return (2, 0, name)


def datasets_in(code: str) -> set[str]:
    """Names of the datasets that ``code`` reads (``mrclam1``, ``intel``, ...)."""
    found = {f"mrclam{int(n)}" for n in _MRCLAM.findall(code)}
    found |= set(_DATASET_PATH.findall(code))
    found |= set(_LASER_FILE.findall(code))
    found |= {name for pattern, name in _CALLS.items() if pattern.search(code)}
    return found


def datasets_read(nb: dict) -> list[str]:
    """The datasets a notebook's code cells read (its setup cell aside), in the order the cell names them."""
    code = "\n".join(source_text(c) for c in nb["cells"] if c.get("cell_type") == "code" and not is_setup_cell(c))
    return sorted(datasets_in(code), key=_order)


def render(url: str, datasets: list[str]) -> str:
    """The source of the setup cell that installs from ``url`` and fetches ``datasets``."""
    return TEMPLATE.format(marker=MARKER, url=url, names=", ".join(f'"{d}"' for d in datasets))


def _lines(text: str) -> list[str]:
    return text.splitlines(keepends=True)


def _new_id(nb: dict, stem: str) -> str:
    taken = {c.get("id") for c in nb["cells"]}
    for k in range(1000):
        cid = hashlib.sha1(f"setup-cell:{stem}:{k}".encode()).hexdigest()[:8]
        if cid not in taken:
            return cid
    raise RuntimeError("no free cell id")  # pragma: no cover


def expected_cell(nb: dict, url: str) -> dict:
    """The setup cell ``nb`` should start with (without its id)."""
    return {
        "cell_type": "code",
        "execution_count": None,
        "metadata": json.loads(json.dumps(METADATA)),
        "outputs": [],
        "source": _lines(render(url, datasets_read(nb))),
    }


def first_code_index(nb: dict) -> int | None:
    return next((i for i, c in enumerate(nb["cells"]) if c.get("cell_type") == "code"), None)


def differs(nb: dict, url: str) -> bool:
    """True if the first code cell of ``nb`` is not the rendered setup cell."""
    i = first_code_index(nb)
    if i is None:
        return True
    cell = {k: v for k, v in nb["cells"][i].items() if k != "id"}
    want = expected_cell(nb, url)
    cell["source"] = _lines(source_text(cell))
    return cell != want


def apply(nb: dict, url: str, stem: str) -> dict:
    """``nb`` with its first code cell rewritten (a setup cell) or a setup cell inserted before it."""
    cell = expected_cell(nb, url)
    i = first_code_index(nb)
    if i is None:
        i = len(nb["cells"])
    if i < len(nb["cells"]) and is_setup_cell(nb["cells"][i]):
        old = nb["cells"][i]
        if "id" in old:
            cell["id"] = old["id"]
        nb["cells"][i] = _with_key_order(cell)
    else:
        if nb.get("nbformat", 4) > 4 or nb.get("nbformat_minor", 0) >= 5:
            cell["id"] = _new_id(nb, stem)
        nb["cells"].insert(i, _with_key_order(cell))
    return nb


def _with_key_order(cell: dict) -> dict:
    return dict(sorted(cell.items()))


# --------------------------------------------------------------------------- files


def read_notebook(path: Path) -> dict:
    with open(path, encoding="utf-8") as f:
        return json.load(f)


def dumps(nb: dict) -> str:
    """The notebook in nbformat's layout (indent 1, non-ASCII kept, final newline), keys in the order read."""
    return json.dumps(nb, indent=1, ensure_ascii=False) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--write", action="store_true", help="rewrite (or insert) the first code cell of every notebook")
    mode.add_argument("--check", action="store_true", help="exit 1 if a notebook's first code cell differs")
    parser.add_argument("--root", type=Path, default=ROOT, help="the book's folder (default: the repository)")
    args = parser.parse_args(argv)

    root = args.root.resolve()
    url = repository_url(root)
    stale = []
    for path in toc_notebooks(root):
        nb = read_notebook(path)
        if not differs(nb, url):
            continue
        stale.append(path)
        if args.write:
            path.write_text(dumps(apply(nb, url, path.stem)), encoding="utf-8")
    rel = [str(p.relative_to(root)) for p in stale]
    if args.write:
        print(f"setup cell rewritten in {len(rel)} notebook(s)" + "".join(f"\n  {r}" for r in rel))
        return 0
    if rel:
        print("first code cell differs from the rendered setup cell (run `python book/setup_cell.py --write`):")
        print("".join(f"  {r}\n" for r in rel), end="")
        return 1
    print("every notebook starts with the rendered setup cell")
    return 0


if __name__ == "__main__":
    sys.exit(main())
