"""Download an MR.CLAM dataset from the official UTIAS ASRL page and unpack it.

The nine datasets are published as ``MRCLAM_Dataset{n}.zip`` on
http://asrl.utias.utoronto.ca/datasets/mrclam/ (Leung et al., IJRR 2011).
:func:`fetch_mrclam` downloads one, checks it, and unpacks it to
``<dest>/MRCLAM_Dataset{n}/``, the layout :func:`fastslam_edu.datasets.mrclam_path`
expects under ``$FASTSLAM_EDU_DATA/mrclam``.

From the command line::

    python -m fastslam_edu.datasets.fetch 1 data/mrclam
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import sys
import tempfile
import urllib.error
import urllib.request
import zipfile
from pathlib import Path, PurePosixPath

from tqdm.auto import tqdm

OFFICIAL_URL = "http://asrl.utias.utoronto.ca/datasets/mrclam/"
"""Folder of the official ``MRCLAM_Dataset{n}.zip`` files."""

CHUNK = 1 << 20


class FetchError(RuntimeError):
    """The download itself failed (HTTP error, no connection, time-out)."""


def expected_files(robots: int = 5) -> tuple[str, ...]:
    """Files every MR.CLAM dataset folder must hold (groundtruth is optional)."""
    per_robot = tuple(f"Robot{i}_{kind}.dat" for i in range(1, robots + 1)
                      for kind in ("Odometry", "Measurement"))
    return ("Barcodes.dat", "Landmark_Groundtruth.dat") + per_robot


def dataset_url(n: int, base_url: str = OFFICIAL_URL) -> str:
    """URL of ``MRCLAM_Dataset{n}.zip`` under ``base_url``."""
    return base_url.rstrip("/") + f"/MRCLAM_Dataset{n}.zip"


def missing_files(folder: str | Path) -> list[str]:
    """Expected files absent (or empty) in ``folder``; empty list = a complete dataset."""
    folder = Path(folder)
    return [name for name in expected_files()
            if not (folder / name).is_file() or (folder / name).stat().st_size == 0]


def download(url: str, target: Path, *, timeout: float = 60, progress: bool = True) -> str:
    """Stream ``url`` to the file ``target``; return the SHA-256 hex digest of the bytes.

    Raises
    ------
    FetchError
        On an HTTP error status, a connection failure or a time-out.
    """
    digest = hashlib.sha256()
    try:
        with urllib.request.urlopen(url, timeout=timeout) as response, open(target, "wb") as out:
            total = response.headers.get("Content-Length")
            with tqdm(total=int(total) if total else None, unit="B", unit_scale=True,
                      desc=PurePosixPath(url).name, disable=not progress) as bar:
                while chunk := response.read(CHUNK):
                    out.write(chunk)
                    digest.update(chunk)
                    bar.update(len(chunk))
    except urllib.error.HTTPError as exc:
        raise FetchError(
            f"download of {url} failed: HTTP {exc.code} {exc.reason}. If the UTIAS page has moved, "
            f"pass base_url= (or --base-url) pointing to the folder that holds the zip."
        ) from None
    except (urllib.error.URLError, OSError) as exc:
        reason = getattr(exc, "reason", exc)
        raise FetchError(f"download of {url} failed: {reason}") from None
    return digest.hexdigest()


def _safe_relative(name: str, archive: str) -> PurePosixPath:
    """The member path ``name`` as a relative path, refusing anything that escapes."""
    p = PurePosixPath(name.replace("\\", "/"))
    if p.is_absolute() or ".." in p.parts or (p.parts and ":" in p.parts[0]):
        raise ValueError(f"{archive}: refusing to unpack member {name!r}: it would be written outside the destination")
    return p


def dataset_root_in_zip(names: list[str], archive: str) -> PurePosixPath:
    """Folder inside the zip that holds ``Barcodes.dat`` (``.`` when at the top)."""
    roots = {_safe_relative(n, archive).parent for n in names
             if PurePosixPath(n).name == "Barcodes.dat" and "__MACOSX" not in n}
    if len(roots) != 1:
        raise ValueError(
            f"{archive}: expected exactly one Barcodes.dat in the zip, found {len(roots)} "
            f"({', '.join(sorted(str(r) for r in roots)) or 'none'}); is this an MR.CLAM dataset?"
        )
    return roots.pop()


def unpack_dataset(archive: Path, folder: Path) -> Path:
    """Check the zip ``archive`` and unpack its dataset files into ``folder``.

    The dataset may sit at the top of the zip or inside one folder; only
    members under the folder that holds ``Barcodes.dat`` are unpacked, with
    that folder prefix removed.

    Raises
    ------
    ValueError
        If the file is not a zip, a member's CRC fails, a member path would
        escape ``folder``, or an expected file is missing.
    """
    try:
        zf = zipfile.ZipFile(archive)
    except zipfile.BadZipFile:
        raise ValueError(f"{archive} is not a valid zip archive ({archive.stat().st_size} bytes)") from None
    with zf:
        members = [m for m in zf.infolist() if not m.is_dir()]
        for m in members:
            _safe_relative(m.filename, str(archive))
        bad = zf.testzip()
        if bad is not None:
            raise ValueError(f"{archive}: member {bad!r} is corrupted (CRC check failed)")
        root = dataset_root_in_zip([m.filename for m in members], str(archive))
        selected = {}
        for m in members:
            rel = _safe_relative(m.filename, str(archive))
            if root == PurePosixPath(".") or rel.parts[: len(root.parts)] == root.parts:
                selected[PurePosixPath(*rel.parts[len(root.parts):])] = m
        absent = [f for f in expected_files() if PurePosixPath(f) not in selected]
        if absent:
            raise ValueError(f"{archive}: missing expected files {absent}")
        folder.mkdir(parents=True, exist_ok=True)
        base = folder.resolve()
        for rel, m in selected.items():
            target = (folder / rel).resolve()
            if base not in target.parents:
                raise ValueError(f"{archive}: refusing to unpack member {m.filename!r} outside {folder}")
            target.parent.mkdir(parents=True, exist_ok=True)
            with zf.open(m) as src, open(target, "wb") as dst:
                shutil.copyfileobj(src, dst)
    return folder


def fetch_mrclam(n: int, dest: str | Path, *, base_url: str = OFFICIAL_URL, sha256: str | None = None,
                 timeout: float = 60, progress: bool = True) -> Path:
    """Download MR.CLAM dataset ``n`` and unpack it to ``dest/MRCLAM_Dataset{n}/``.

    Steps: skip everything if that folder already holds the expected files
    (``Barcodes.dat``, ``Landmark_Groundtruth.dat``,
    ``Robot{1..5}_{Odometry,Measurement}.dat``); otherwise stream
    ``{base_url}/MRCLAM_Dataset{n}.zip`` to a temporary file in ``dest``
    (with a tqdm progress bar), compare its SHA-256 with ``sha256`` if
    given, test the zip (CRC of every member, no path escaping the folder,
    expected files present), and unpack it. The temporary file is removed.

    Parameters
    ----------
    n : int
        Dataset number (1–9 on the official page).
    dest : str or Path
        Folder that will contain ``MRCLAM_Dataset{n}/`` (e.g. ``data/mrclam``).
    base_url : str
        Folder URL holding the zips; the official UTIAS page by default.
    sha256 : str, optional
        Expected SHA-256 (hex) of the zip.
    timeout : float
        Seconds to wait for the server on each network operation.
    progress : bool
        Show a progress bar.

    Returns
    -------
    Path
        The dataset folder ``dest/MRCLAM_Dataset{n}``.

    Raises
    ------
    FetchError
        If the download fails (HTTP error such as 404, no connection).
    ValueError
        On a checksum mismatch, a file that is not a valid zip, a corrupted
        or unsafe member, or missing dataset files.
    """
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"dataset number must be a positive int, got {n!r}")
    dest = Path(dest)
    folder = dest / f"MRCLAM_Dataset{n}"
    if not missing_files(folder):
        return folder
    dest.mkdir(parents=True, exist_ok=True)
    url = dataset_url(n, base_url)
    with tempfile.TemporaryDirectory(dir=dest, prefix=f".MRCLAM_Dataset{n}-") as tmp:
        archive = Path(tmp) / f"MRCLAM_Dataset{n}.zip"
        digest = download(url, archive, timeout=timeout, progress=progress)
        if sha256 is not None and digest != sha256.strip().lower():
            raise ValueError(f"checksum mismatch for {url}: expected sha256 {sha256.strip().lower()}, got {digest}")
        staging = unpack_dataset(archive, Path(tmp) / "unpacked")
        for path in sorted(staging.rglob("*")):
            if path.is_file():
                target = folder / path.relative_to(staging)
                target.parent.mkdir(parents=True, exist_ok=True)
                os.replace(path, target)
    return folder


def main(argv: list[str] | None = None) -> int:
    """``python -m fastslam_edu.datasets.fetch N [DEST]``."""
    from . import data_root

    parser = argparse.ArgumentParser(
        prog="python -m fastslam_edu.datasets.fetch",
        description="Download MR.CLAM dataset N from the UTIAS ASRL page into DEST/MRCLAM_Dataset{N}/.",
    )
    parser.add_argument("n", type=int, help="dataset number (1-9)")
    parser.add_argument("dest", nargs="?", type=Path, default=None,
                        help="folder to hold MRCLAM_Dataset{N}/ (default: $FASTSLAM_EDU_DATA/mrclam)")
    parser.add_argument("--base-url", default=OFFICIAL_URL, help=f"folder URL of the zips (default {OFFICIAL_URL})")
    parser.add_argument("--sha256", default=None, help="expected SHA-256 of the zip")
    parser.add_argument("--timeout", type=float, default=60.0)
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    dest = args.dest if args.dest is not None else data_root() / "mrclam"
    try:
        folder = fetch_mrclam(args.n, dest, base_url=args.base_url, sha256=args.sha256,
                              timeout=args.timeout, progress=not args.quiet)
    except (FetchError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(folder)
    return 0


__all__ = [
    "OFFICIAL_URL",
    "FetchError",
    "dataset_url",
    "download",
    "expected_files",
    "fetch_mrclam",
    "missing_files",
    "unpack_dataset",
]

if __name__ == "__main__":
    sys.exit(main())
