"""Download an MR.CLAM dataset from the official UTIAS ASRL page and unpack it.

The nine datasets are published as ``MRCLAM_Dataset{n}.zip`` on
http://asrl.utias.utoronto.ca/datasets/mrclam/ (Leung et al., IJRR 2011).
:func:`fetch_mrclam` downloads one with pooch, checks it, and unpacks it to
``<dest>/MRCLAM_Dataset{n}/``, the layout :func:`fastslam_edu.datasets.mrclam_path`
expects under ``$FASTSLAM_EDU_DATA/mrclam``. (Datasets 1 and 6 also come, file
by file and pinned by sha256, from :mod:`fastslam_edu.datasets.registry`.)

From the command line::

    python -m fastslam_edu.datasets.fetch 1 data/mrclam
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import logging
import os
import re
import shutil
import sys
import tempfile
import zipfile
import zlib
from pathlib import Path, PurePosixPath

OFFICIAL_URL = "http://asrl.utias.utoronto.ca/datasets/mrclam/"
"""Folder of the official ``MRCLAM_Dataset{n}.zip`` files."""


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


@contextlib.contextmanager
def pooch_log_silenced():
    """Within the block, pooch logs only warnings (not its 'Downloading file ...' lines on stderr)."""
    import pooch

    logger = pooch.get_logger()
    level = logger.level
    logger.setLevel(logging.WARNING)
    try:
        yield
    finally:
        logger.setLevel(level)


def pooch_download(url: str, folder: Path, *, sha256: str | None = None, retries: int = 2,
                   timeout: float = 60, progress: bool = True) -> Path:
    """Download ``url`` with pooch into the existing ``folder``; return the path of the file.

    Pooch streams into a temporary name and keeps the file only if its
    SHA-256 equals ``sha256`` (hex; not checked when None). A failed attempt
    is repeated ``retries`` times, waiting 1 s, 2 s, ... in between; each
    network operation waits at most ``timeout`` seconds.

    Raises
    ------
    requests.exceptions.RequestException
        HTTP error status, no connection, time-out (after the last attempt).
    ValueError
        SHA-256 mismatch (pooch's message: ``expected sha256:X but got Y``).
    """
    import pooch

    name = PurePosixPath(url.split("?")[0]).name or "download"
    known = None if sha256 is None else f"sha256:{sha256.strip().lower()}"
    store = pooch.create(path=folder, base_url="", registry={name: known}, urls={name: url},
                         retry_if_failed=retries)
    with pooch_log_silenced():
        return Path(store.fetch(name, downloader=pooch.HTTPDownloader(progressbar=progress, timeout=timeout),
                                progressbar=progress))


def sha256_of_file(path: Path) -> str:
    """SHA-256 (hex) of the bytes of the file ``path``."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()


def failure_reason(exc: BaseException) -> str:
    """What went wrong in a download, in a few words on one line (``HTTP 404 Not Found``, ``connection refused``...)."""
    import requests

    if isinstance(exc, requests.exceptions.HTTPError) and exc.response is not None:
        return f"HTTP {exc.response.status_code} {exc.response.reason}".strip()
    if isinstance(exc, requests.exceptions.Timeout):
        return "the server did not answer in time (time-out)"
    text = " ".join(str(exc).split())
    if isinstance(exc, requests.exceptions.ConnectionError):
        errno = re.search(r"\[Errno -?\d+\] ([^'\")\]]+)", text)
        return f"connection failed: {errno.group(1).strip() if errno else text}"
    mismatch = sha256_mismatch(exc)
    if mismatch is not None:
        return f"sha256 mismatch: expected {mismatch[0]}, got {mismatch[1]}"
    if isinstance(exc, OSError) and exc.strerror:
        return f"{exc.strerror}" + (f": {exc.filename}" if exc.filename else "")
    return text or type(exc).__name__


def sha256_mismatch(exc: BaseException) -> tuple[str, str] | None:
    """(expected, got) hex digests from pooch's hash-mismatch ValueError; None for any other error."""
    found = re.search(r"expected (?:sha256:)?([0-9a-fA-F]{64}) but got ([0-9a-fA-F]{64})", str(exc))
    return None if found is None else (found.group(1).lower(), found.group(2).lower())


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


ZIP_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError, ValueError, OSError)
"""What zipfile raises on a damaged archive: bad headers, a broken deflate stream, a cut-off member,
an unknown compression method, a spurious 'encrypted' flag or a garbled name."""


def open_zip(archive: Path) -> zipfile.ZipFile:
    """The zip ``archive`` opened for reading; ValueError (one line) if it is not a readable zip."""
    try:
        return zipfile.ZipFile(archive)
    except ZIP_ERRORS as exc:
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise ValueError(f"{archive} is not a valid zip archive ({archive.stat().st_size} bytes): {reason}") from None


def corrupted_member(zf: zipfile.ZipFile) -> tuple[str, str] | None:
    """(name, reason) of the first member that cannot be read back intact (CRC, deflate stream, header); else None."""
    for info in zf.infolist():
        try:
            with zf.open(info) as member:
                while member.read(1 << 20):
                    pass
        except ZIP_ERRORS as exc:
            reason = " ".join(str(exc).split()) or type(exc).__name__
            return info.filename, reason
    return None


def unpack_dataset(archive: Path, folder: Path) -> Path:
    """Check the zip ``archive`` and unpack its dataset files into ``folder``.

    The dataset may sit at the top of the zip or inside one folder; only
    members under the folder that holds ``Barcodes.dat`` are unpacked, with
    that folder prefix removed.

    Raises
    ------
    ValueError
        If the file is not a zip (or is cut short), a member is corrupted
        (CRC or deflate stream), a member path would escape ``folder``, or an
        expected file is missing. The message is one line naming the archive.
    """
    with open_zip(archive) as zf:
        members = [m for m in zf.infolist() if not m.is_dir()]
        for m in members:
            _safe_relative(m.filename, str(archive))
        bad = corrupted_member(zf)
        if bad is not None:
            raise ValueError(f"{archive}: member {bad[0]!r} is corrupted (CRC check failed or unreadable: {bad[1]})")
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
                 timeout: float = 60, progress: bool = True, retries: int = 2) -> Path:
    """Download MR.CLAM dataset ``n`` and unpack it to ``dest/MRCLAM_Dataset{n}/``.

    Steps: skip everything if that folder already holds the expected files
    (``Barcodes.dat``, ``Landmark_Groundtruth.dat``,
    ``Robot{1..5}_{Odometry,Measurement}.dat``); otherwise download
    ``{base_url}/MRCLAM_Dataset{n}.zip`` with pooch into a temporary folder in
    ``dest`` (pooch's progress bar; pooch checks ``sha256`` if given), test
    the zip (every member read back and CRC-checked, no path escaping the
    folder, expected files present), and unpack it. The temporary folder is
    always removed.

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
    retries : int
        Further attempts after a failed download (waiting 1 s, 2 s, ... in between).

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
        or unsafe member, or missing dataset files (one line, naming the file).
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
        archive = downloaded_zip(url, Path(tmp), sha256=sha256, timeout=timeout, progress=progress, retries=retries)
        staging = unpack_dataset(archive, Path(tmp) / "unpacked")
        for path in sorted(staging.rglob("*")):
            if path.is_file():
                target = folder / path.relative_to(staging)
                target.parent.mkdir(parents=True, exist_ok=True)
                os.replace(path, target)
    return folder


def downloaded_zip(url: str, folder: Path, *, sha256: str | None, timeout: float, progress: bool,
                   retries: int) -> Path:
    """Path of ``url`` downloaded into ``folder``; FetchError if the transfer fails, ValueError on a checksum mismatch."""
    import requests

    try:
        return pooch_download(url, folder, sha256=sha256, retries=retries, timeout=timeout, progress=progress)
    except ValueError as exc:
        mismatch = sha256_mismatch(exc)
        if mismatch is None:
            raise
        raise ValueError(f"checksum mismatch for {url}: expected sha256 {mismatch[0]}, got {mismatch[1]}") from None
    except (requests.exceptions.RequestException, OSError) as exc:
        hint = (" If the UTIAS page has moved, pass base_url= (or --base-url) pointing to the folder that holds the zip."
                if isinstance(exc, requests.exceptions.HTTPError) else "")
        raise FetchError(f"download of {url} failed: {failure_reason(exc)}.{hint}") from None


def main(argv: list[str] | None = None) -> int:
    """``python -m fastslam_edu.datasets.fetch N [DEST]``."""
    from fastslam_edu.datasets import data_root

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
    parser.add_argument("--retries", type=int, default=2, help="further attempts after a failed download (default 2)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    dest = args.dest if args.dest is not None else data_root() / "mrclam"
    try:
        folder = fetch_mrclam(args.n, dest, base_url=args.base_url, sha256=args.sha256,
                              timeout=args.timeout, progress=not args.quiet, retries=max(args.retries, 0))
    except (FetchError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(folder)
    return 0


__all__ = [
    "OFFICIAL_URL",
    "FetchError",
    "dataset_url",
    "expected_files",
    "failure_reason",
    "fetch_mrclam",
    "missing_files",
    "pooch_download",
    "unpack_dataset",
]

if __name__ == "__main__":
    sys.exit(main())
