"""Run the first code cells of a notebook, as Colab or Binder would, in this Python's own kernel.

    python .ci/first_cells.py NOTEBOOK [N] [--timeout SECONDS]

Executes the first N code cells of NOTEBOOK with nbclient and prints each cell's output as it finishes.
Default N: the setup cell and the cells after it up to and including the first one that reads data (for
most chapters the imports cell), at least two. Exit status 1, with the error, if a cell fails.

The kernel is the Python running this script (``sys.executable``), whatever kernels are registered for the
user or the system: its kernelspec is written to a temporary folder and only that folder is searched. The
kernel inherits the environment, so in a fresh venv with only ipykernel and nbclient installed

    FASTSLAM_EDU_INSTALL=/path/to/clone PIP_CONSTRAINT=/path/to/clone/constraints.txt \\
    FASTSLAM_EDU_MIRROR=http://127.0.0.1:8765 FASTSLAM_EDU_DATA=/tmp/empty \\
    venv/bin/python .ci/first_cells.py notebooks/02_motion_model.ipynb

shows that the setup cell installs the package and fetches the data the chapter reads. The cells run in
the notebook's folder, as in Jupyter.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
KERNEL_NAME = "first-cells"
_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")


def _datasets_in():
    """``datasets_in(code)`` of book/setup_cell.py: the one definition of what reads data (stdlib only)."""
    sys.path.insert(0, str(ROOT / "book"))
    try:
        from setup_cell import datasets_in, is_setup_cell
    finally:
        sys.path.pop(0)
    return datasets_in, is_setup_cell


def default_count(code_cells) -> int:
    """The setup cell and the cells up to the first that reads data (at least 2, at most all)."""
    datasets_in, is_setup_cell = _datasets_in()
    for k, cell in enumerate(code_cells):
        if not is_setup_cell(cell) and datasets_in(cell.source):
            return max(k + 1, min(2, len(code_cells)))
    return min(2, len(code_cells))


def _print_outputs(cell) -> None:
    for out in cell.get("outputs", []):
        kind = out.get("output_type")
        if kind == "stream":
            print(_ANSI.sub("", out.get("text", "")), end="")
        elif kind in ("execute_result", "display_data"):
            data = out.get("data", {})
            if "text/plain" in data:
                print(data["text/plain"])
            others = sorted(set(data) - {"text/plain"})
            if others:
                print(f"[{', '.join(others)}]")
        elif kind == "error":
            print(_ANSI.sub("", "\n".join(out.get("traceback", [])) or f"{out.get('ename')}: {out.get('evalue')}"))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("notebook", type=Path)
    parser.add_argument("n", type=int, nargs="?", help="number of code cells to run (default: up to the first data read)")
    parser.add_argument("--timeout", type=int, default=1800, help="seconds per cell (default 1800)")
    args = parser.parse_args(argv)

    import nbformat
    from jupyter_client.kernelspec import KernelSpecManager
    from jupyter_client.manager import KernelManager
    from nbclient import NotebookClient
    from nbclient.exceptions import CellExecutionError

    path = args.notebook.resolve()
    nb = nbformat.read(path, as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    n = args.n if args.n is not None else default_count(code)
    if not 1 <= n <= len(code):
        parser.error(f"N must be between 1 and {len(code)} (the code cells of {path.name})")
    run = nbformat.v4.new_notebook(cells=code[:n], metadata=nb.metadata)

    with tempfile.TemporaryDirectory(prefix="first-cells-kernel-") as kernels:
        spec_dir = Path(kernels) / KERNEL_NAME
        spec_dir.mkdir()
        argv_kernel = [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"]
        (spec_dir / "kernel.json").write_text(json.dumps(
            {"argv": argv_kernel, "display_name": f"Python ({sys.executable})", "language": "python"}))
        km = KernelManager(kernel_name=KERNEL_NAME, kernel_spec_manager=KernelSpecManager(kernel_dirs=[kernels]))
        client = NotebookClient(run, km=km, timeout=args.timeout, allow_errors=False,
                                resources={"metadata": {"path": str(path.parent)}})
        print(f"== {path.name}: the first {n} code cell(s), kernel {sys.executable}", flush=True)
        start = time.perf_counter()
        with client.setup_kernel(cleanup_kc=True):  # our kernel manager: shut the kernel down at the end
            for i, cell in enumerate(run.cells):
                t0 = time.perf_counter()
                print(f"-- cell {i + 1}/{n}", flush=True)
                try:
                    client.execute_cell(cell, i)
                except CellExecutionError as exc:
                    _print_outputs(cell)
                    print(f"-- cell {i + 1} failed after {time.perf_counter() - t0:.1f} s:", file=sys.stderr)
                    print(_ANSI.sub("", str(exc)), file=sys.stderr)
                    return 1
                _print_outputs(cell)
                print(f"-- cell {i + 1} done in {time.perf_counter() - t0:.1f} s", flush=True)
    print(f"== {path.name}: {n} code cell(s) ran in {time.perf_counter() - start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
