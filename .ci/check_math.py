"""Check that a built page's equations render with no network: headless Chromium, MathJax from _static.

    python .ci/check_math.py [--chromium chromium] _build/html/notebooks/04_one_landmark_ekf.html

Chromium runs in a new network namespace (``unshare -n``: no interface but a down loopback), loads the page
from disk, lets MathJax typeset, and dumps the DOM. Every math element of the page (Sphinx writes
``class="math ..."`` spans and divs, with the TeX inside ``\\( \\)`` or ``\\[ \\]``) must come out as a
MathJax ``<mjx-container>``. Exit status 1, with one line saying what is wrong, otherwise.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

CHROMIUM_FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--virtual-time-budget=20000", "--dump-dom",
)


def math_elements(html: str) -> int:
    """Number of math elements Sphinx wrote into the page (inline and display)."""
    return len(re.findall(r'class="math[ "]', html))


def rendered_dom(page: Path, chromium: str) -> str:
    """The page's DOM after scripts ran, from headless Chromium with no network."""
    with tempfile.TemporaryDirectory() as profile:
        cmd = ["unshare", "-n", chromium, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", page.resolve().as_uri()]
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    if done.returncode != 0:
        raise RuntimeError(f"{chromium} exited with {done.returncode}: {done.stderr.strip().splitlines()[-1:]}")
    return done.stdout


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("page", type=Path, help="a built HTML page with equations")
    parser.add_argument("--chromium", default="chromium", help="the Chromium executable")
    args = parser.parse_args(argv)
    if not args.page.is_file():
        print(f"error: {args.page} not found: build the book first (make book)", file=sys.stderr)
        return 1
    if shutil.which(args.chromium) is None:
        print(f"error: {args.chromium} not found (Debian: apt-get install chromium)", file=sys.stderr)
        return 1
    expected = math_elements(args.page.read_text(encoding="utf-8"))
    dom = rendered_dom(args.page, args.chromium)
    rendered = dom.count("<mjx-container")
    print(f"{args.page}: {expected} math elements, {rendered} rendered by MathJax with no network")
    if expected == 0 or rendered < expected:
        print(f"error: {args.page}: {expected - rendered} of {expected} equations not rendered offline", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
