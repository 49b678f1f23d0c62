"""The data registry: every file the book reads, where it comes from, and what it must hash to.

Each :class:`DataFile` pins one file: its path under the data root
(``$FASTSLAM_EDU_DATA``, see :func:`fastslam_edu.datasets.data_root`), the URL of
its source in a public GitHub repository at an exact commit, and the sha256
and size [bytes] of the file as it lands. Three Intel files are published
uncompressed and stored gzipped: for them the registry also holds the
download's sha256 and size, and :func:`gzip_file` compresses them the way
``gzip -9 -n`` does, so that the landed bytes are the same on every machine.

:func:`fetch_datasets` downloads (with pooch) what is missing or altered and
verifies what is present without writing anything; :func:`dataset_path` gives
a dataset's folder. With ``$FASTSLAM_EDU_MIRROR`` (or ``mirror=``) set, every
file is taken from ``{mirror}/{path}`` instead: a web folder laid out like the
data folder, holding the files in their final form.

From the command line (one line per dataset)::

    python -m fastslam_edu.datasets.registry [NAME ...] [--check] [--quiet]
    fastslam-edu data [NAME ...] [--check] [--quiet]
"""

from __future__ import annotations

import argparse
import os
import shutil
import struct
import sys
import tempfile
import time
import zlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlparse

from fastslam_edu.datasets.fetch import failure_reason, pooch_download, sha256_of_file

MIRROR_ENV_VAR = "FASTSLAM_EDU_MIRROR"
"""Environment variable: URL of a web folder laid out like the data folder, used instead of the pinned sources."""

CHUNK = 1 << 20
"""Bytes read at a time when hashing or compressing [bytes]."""


@dataclass(frozen=True)
class DataFile:
    """One file of the data folder: where it lands, where it comes from, what it must hash to.

    Attributes
    ----------
    path : str
        Path relative to the data root, ``/``-separated (e.g. ``intel/intel.gfs.log.gz``).
    url : str
        Source, pinned to an exact commit.
    sha256, size : str, int
        SHA-256 (hex) and size [bytes] of the file as it lands in the data folder.
    download_sha256, download_size : str or None, int or None
        SHA-256 and size [bytes] of what ``url`` serves, when it differs from the
        landed file (``gzip=True``).
    gzip : bool
        The download is compressed with :func:`gzip_file` before it lands.
    """

    path: str
    url: str
    sha256: str
    size: int
    download_sha256: str | None = None
    download_size: int | None = None
    gzip: bool = False


@dataclass(frozen=True)
class DatasetEntry:
    """A named group of files under one folder of the data root, with its citation."""

    name: str
    folder: str
    citation: str
    files: tuple[DataFile, ...]

    @property
    def size(self) -> int:
        """Total size of the landed files [bytes]."""
        return sum(f.size for f in self.files)


class DataFetchError(RuntimeError):
    """A file could not be fetched or verified. The message is one line: file, URL, what happened, how to fix by hand."""


def pinned_url(source: tuple[str, str], path: str) -> str:
    """URL of the raw bytes of ``path`` in the GitHub repository ``source = (owner/name, commit)``."""
    repo, commit = source
    return f"https://raw.githubusercontent.com/{repo}/{commit}/{path}"


RAISUL = ("raisul-kibria/localization_and_mapping", "41559172f4e926a4bbe813ec6d984001b9acc2e6")
"""Unmodified copies of the UTIAS MR.CLAM ``.dat`` files (folder ``data/``)."""
ECHEN = ("echen4628/fastslam1", "ec6db6f5e8b2c09ca7ed756da2bea9e97a456f8c")
"""MR.CLAM dataset 1 groundtruth of robots 1 and 2 averaged to 1 Hz."""
XIAOFENG = ("xiaofeng419/ROBOTICS_2DSCAN_SLAM", "d469252f5b33e574bd239ad2625779497ac1d4cc")
"""Intel 910-scan GMapping subset and the Kümmerle et al. relations of Intel and FR079."""
PLE = ("acschaefer/ple", "cfcb5a7f12a793b616357381a688cfcc26eed347")
"""GMapping-corrected CARMEN log of Freiburg building 079."""
THOR = ("abhikandoi2000/particle-filter-slam", "8e3a9f6b8f8a450822c514e5ae0e82b4828589e3")
"""THOR humanoid joint log of training sequence 0 (UCSD ECE 276A re-save)."""


def mrclam_file(n: int, name: str, sha256: str, size: int) -> DataFile:
    """``mrclam/MRCLAM_Dataset{n}/{name}``, from the same path under ``data/`` in :data:`RAISUL`."""
    return DataFile(f"mrclam/MRCLAM_Dataset{n}/{name}", pinned_url(RAISUL, f"data/MRCLAM_Dataset{n}/{name}"), sha256, size)

MRCLAM1_FILES = (
    mrclam_file(1, "Barcodes.dat", "5ec5a195456c1684d664c579400fb175c8657393c9b3ac02c2a95a3471e808dd", 428),
    mrclam_file(1, "Landmark_Groundtruth.dat", "db40f1040957ccadcbf71f64b430658355978fd00b25f810a43990134ab77226", 1117),
    mrclam_file(1, "Robot1_Odometry.dat", "4bc5fcdb5089fc27c65371fa43a2875ca6c0ba0ca6fe87f1d3109f048d1a9a43", 3426379),
    mrclam_file(1, "Robot1_Measurement.dat", "322bfa68614604f40bc193af67d0bc89dc2453c17271982290d46ad6005b8fbe", 234865),
    mrclam_file(1, "Robot2_Odometry.dat", "c880bb6a14e91eece7f492e9d4a70761aa0cce40c55561169a269ce5e26bd19c", 3319139),
    mrclam_file(1, "Robot2_Measurement.dat", "85ba23b1aa4864968612a477adb36a4aa6ab4f97c422c0550307f461c24d2eb1", 274881),
    mrclam_file(1, "Robot3_Odometry.dat", "435cd632056524cf4c3c33f0e4c9ceadbf07fbc3c566e776431d692f0a5d3acb", 3407514),
    mrclam_file(1, "Robot3_Measurement.dat", "c7e599043446aab55fd5ca873a477f9e9bbd34f0e5d492d53d71d10d91b1fdd0", 358644),
    mrclam_file(1, "Robot4_Odometry.dat", "e55dc55f4dff8d9adfae994a1fe2e82b0be9b52daba7fa27b4d2f10a2367e236", 3500649),
    mrclam_file(1, "Robot4_Measurement.dat", "51f0fe2bbec0f70812c1eb805e8cf9dc1adab44a16641049b661769f283a697f", 163853),
    mrclam_file(1, "Robot5_Odometry.dat", "eac7ef3b8386b75b9cb7b672012065f793bd316975f3963a5f50684fe16579e6", 3525639),
    mrclam_file(1, "Robot5_Measurement.dat", "ef36c5e2851efc1727208b48a85c302104881d1a1db7de07a10bbd4f002e8ae5", 360694),
    DataFile("mrclam/MRCLAM_Dataset1/groundtruth_1hz/Robot1_Groundtruth_1hz.csv", pinned_url(ECHEN, "data/Cleaned_Robot1_Groundtruth.csv"),
             "3d2da8ff2136eafb4117a4e4867e21c8a0202aba1a4351b82414826f9e8a63fc", 104052),
    DataFile("mrclam/MRCLAM_Dataset1/groundtruth_1hz/Robot2_Groundtruth_1hz.csv", pinned_url(ECHEN, "data/Cleaned_Robot2_Groundtruth.csv"),
             "22cdfad265139eb1a83201994553622eeafd30325a911d4d76ad5e16d2bdea07", 102288),
)
MRCLAM6_FILES = (
    mrclam_file(6, "Barcodes.dat", "6b418dfacabb6556e0bf3a4e90efeca89775fae1e73521d7baeb8844828186eb", 428),
    mrclam_file(6, "Landmark_Groundtruth.dat", "ca586b164e66caf642895f735c66fe4195ceb963ba7dce303b3aa0307072795d", 1119),
    mrclam_file(6, "Robot1_Groundtruth.dat", "a5922ef6a548ed5a9ca656817f0ac23ab1226a4725e296068abf51df7133906e", 2796155),
    mrclam_file(6, "Robot1_Odometry.dat", "11aff992a8d6825afb4a1fd0ba0f00c49cdd341acabe590dce73545607f1d7d6", 2162704),
    mrclam_file(6, "Robot1_Measurement.dat", "0ad9f9baf5bf45746363c3a7653c2292f75e65ef851933c79b5a22622131a5b3", 79844),
    mrclam_file(6, "Robot2_Groundtruth.dat", "94a6b85947715d1a4d26428ea0eb5244f267b72198b3cf9f62df13b2a3282e24", 3409154),
    mrclam_file(6, "Robot2_Odometry.dat", "a99435568f62a9f371c2287730a1d83d94d75bbf1351bb3d470ed70e60b1cbfe", 2275404),
    mrclam_file(6, "Robot2_Measurement.dat", "658f259bf510a46b20b3f6b011b4ec3fb94abf4cb151e4b70157bcf59976ef9c", 165493),
    mrclam_file(6, "Robot3_Groundtruth.dat", "9de1eceb29374b0e805215e81fa93677ff47db28767f5c9e1f05dceb526904b4", 3254107),
    mrclam_file(6, "Robot3_Odometry.dat", "a08e5b6a5dd208c8c63ab972022b9a609865628a219b04d0addbb939ea77bda3", 2140759),
    mrclam_file(6, "Robot3_Measurement.dat", "7a09702f5f6b9eefc903eb626c55413c606b3c018a85d775d43c551754eeb11d", 230929),
    mrclam_file(6, "Robot4_Groundtruth.dat", "285bc8ce97ed13f8f6096d99ac42c1af6a2a6f598f21e58ca9f7fd51a54b39d4", 3504829),
    mrclam_file(6, "Robot4_Odometry.dat", "c7027d13fdc31ed9686097fcc7fbaf19b95935a7970e7ab433fdc1a1d119e97f", 1852289),
    mrclam_file(6, "Robot4_Measurement.dat", "a9669363963cfdf57e1ad4d2f6af39ea8cec0269c69e3d02260758af5cddad89", 98581),
    mrclam_file(6, "Robot5_Groundtruth.dat", "121bab6a92544864dd39138eaf3f3bc273d0342e3cdd0a745d0d2019c0b5757e", 3274843),
    mrclam_file(6, "Robot5_Odometry.dat", "d6e9fab30a0da8f73917a2fabf71360387a42975d42f552f9042496538cb2efe", 2120074),
    mrclam_file(6, "Robot5_Measurement.dat", "9cfb9b8872395b40bb64b0e194b98e7b480711a379a4005674850f83cdebd151", 220720),
)
INTEL_FILES = (
    DataFile("intel/intel.gfs.log.gz", pinned_url(XIAOFENG, "DataSet/RawData/intel.gfs.log"),
             "6371d58c3b027856f320fca0e6454dda32a71fb52099fffef35ae8e20782d714", 438245,
             download_sha256="b066a0e3c62e69901540895017871835169d13c56a4cbb78f42599cf3563484f",
             download_size=1742833, gzip=True),
    DataFile("intel/intel_gfs.json.gz", pinned_url(XIAOFENG, "DataSet/PreprocessedData/intel_gfs"),
             "9dc28330d84318ab532bc5934b15a88bc14b2f0849dc8c5238bc40297ca03795", 268768,
             download_sha256="b530697cc8f82ff16b9f59f895e3fc7c158968fd6049f5546c01823e854db04e",
             download_size=3738613, gzip=True),
    DataFile("intel/intel_corrected_log.json.gz", pinned_url(XIAOFENG, "DataSet/PreprocessedData/intel_corrected_log"),
             "6bc8a6c567aa4631e1f61a95073b6f6062a6f5e748ed0230850f0b57516ab39e", 271724,
             download_sha256="dcec2826599b067bd272e6231d445476273b3076d869f5a975e94603227b5d4a",
             download_size=3742404, gzip=True),
    DataFile("intel/intel.relations", pinned_url(XIAOFENG, "DataSet/RawData/intel.relations"),
             "330378f153eeae652d6756c1746f335801f66c3e097d90611548e6c4f593c359", 265713),
)
FR079_FILES = (
    DataFile("fr079/freiburg-079-corrected.log.gz", pinned_url(PLE, "data/carmen/freiburg-079-corrected.log.gz"),
             "0631d30baf4b9d1d209af47da9096e876e1b4cb3d5a2d68ef9c39c5a2360a466", 2043193),
    DataFile("fr079/fr079.relations", pinned_url(XIAOFENG, "DataSet/RawData/fr079.relations"),
             "7e7f06b4aca455cb68f1f23d04e7c7316c5e17773e872734c860ed7a274cdfc7", 133044),
)
THOR_FILES = (
    DataFile("thor/train_joint0.mat", pinned_url(THOR, "joint/train_joint0.mat"),
             "81072e9b2957c9cab485df9f438f045afe5bdf4c34a05596f045263efc84075c", 154098),
)

REGISTRY: Mapping[str, DatasetEntry] = {entry.name: entry for entry in (
    DatasetEntry("mrclam1", "mrclam/MRCLAM_Dataset1",
                 "MR.CLAM dataset 1 (Leung, Halpern, Barfoot, Liu, IJRR 30(8), 2011): 5 robots, 15 landmarks, ~1500 s; "
                 "robots 1-2 groundtruth at 1 Hz", MRCLAM1_FILES),
    DatasetEntry("mrclam6", "mrclam/MRCLAM_Dataset6",
                 "MR.CLAM dataset 6 (Leung, Halpern, Barfoot, Liu, IJRR 30(8), 2011): 5 robots, 15 landmarks, ~900 s, "
                 "full-rate Vicon groundtruth", MRCLAM6_FILES),
    DatasetEntry("intel", "intel",
                 "Intel Research Lab, Seattle (D. Hähnel, via Radish): 910 GMapping-selected laser scans, corrected log "
                 "and JSONs, with Kümmerle et al. 2009 relations", INTEL_FILES),
    DatasetEntry("fr079", "fr079",
                 "Freiburg building 079 (C. Stachniss): GMapping-corrected CARMEN log, with Kümmerle et al. 2009 relations",
                 FR079_FILES),
    DatasetEntry("thor", "thor",
                 "THOR humanoid (UPenn/UCLA; UCSD ECE 276A 2020): head/neck joint log of training sequence 0",
                 THOR_FILES),
)}
"""Every dataset, by name. The paths are exactly the files of the shared data folder (README.md files aside)."""


# --- verifying ---------------------------------------------------------------------------------------------------

def file_state(path: Path, entry: DataFile) -> str:
    """``'intact'`` if ``path`` holds the registered size and sha256, else ``'missing'`` or ``'altered'``. Reads only."""
    if not path.is_file():
        return "missing"
    return "intact" if landed_mismatch(path, entry) is None else "altered"


def resolve_root(root: str | Path | None) -> Path:
    """``root`` as an absolute path; the data root (``$FASTSLAM_EDU_DATA`` or ``./data``) when None."""
    if root is None:
        from fastslam_edu.datasets import data_root

        return data_root()
    return Path(root).expanduser().resolve()


def resolve_mirror(mirror: str | None) -> str | None:
    """The mirror URL without a trailing ``/``: ``mirror``, else ``$FASTSLAM_EDU_MIRROR``, else None (pinned sources)."""
    mirror = mirror if mirror is not None else os.environ.get(MIRROR_ENV_VAR)
    return mirror.rstrip("/") if mirror else None


def registered(names: tuple[str, ...], registry: Mapping[str, DatasetEntry]) -> list[DatasetEntry]:
    """The entries called ``names`` (every entry when none is given); ValueError naming the known ones otherwise."""
    unknown = [n for n in names if n not in registry]
    if unknown:
        raise ValueError(f"unknown dataset {', '.join(map(repr, unknown))}; known datasets: {', '.join(registry)}")
    return [registry[n] for n in (names or tuple(registry))]


def dataset_problems(name: str, *, root: str | Path | None = None,
                     registry: Mapping[str, DatasetEntry] = REGISTRY) -> list[str]:
    """Files of dataset ``name`` that are not as registered, as ``'<path> missing'`` / ``'<path> altered'``; reads only."""
    base = resolve_root(root)
    (entry,) = registered((name,), registry)
    states = ((f.path, file_state(base / f.path, f)) for f in entry.files)
    return [f"{path} {state}" for path, state in states if state != "intact"]


# --- fetching ----------------------------------------------------------------------------------------------------

GZIP_HEADER = b"\x1f\x8b\x08\x00\x00\x00\x00\x00\x02\x03"
"""gzip member header of ``gzip -9 -n``: deflate, no flags, mtime 0, extra flags 2 (best compression), OS 3 (Unix)."""


def gzip_file(src: Path, dst: Path) -> Path:
    """Write ``src`` gzip-compressed to ``dst`` exactly as ``gzip -9 -n`` does (no name, no time stamp); return ``dst``.

    Raw deflate at level 9 with a 32 KiB window and memory level 9 between
    :data:`GZIP_HEADER` and the trailer (CRC-32, size mod 2**32, little endian).
    """
    deflate = zlib.compressobj(9, zlib.DEFLATED, -15, 9)
    crc, size = 0, 0
    with open(src, "rb") as fin, open(dst, "wb") as fout:
        fout.write(GZIP_HEADER)
        while chunk := fin.read(CHUNK):
            crc, size = zlib.crc32(chunk, crc), size + len(chunk)
            fout.write(deflate.compress(chunk))
        fout.write(deflate.flush())
        fout.write(struct.pack("<II", crc, size & 0xFFFFFFFF))
    return dst


def source_url(entry: DataFile, mirror: str | None) -> str:
    """Where ``entry`` is downloaded from: ``{mirror}/{path}`` with a mirror, else its pinned URL."""
    return f"{mirror}/{entry.path}" if mirror else entry.url


def source_label(url: str) -> str:
    """Short name of where ``url`` points: ``owner/repo@commit7`` for a raw GitHub URL, else ``scheme://host``."""
    parts = urlparse(url)
    if parts.netloc == "raw.githubusercontent.com":
        owner, repo, commit = parts.path.strip("/").split("/")[:3]
        return f"{owner}/{repo}@{commit[:7]}"
    return f"{parts.scheme}://{parts.netloc}"


def failure_message(entry: DataFile, url: str, target: Path, what: str) -> str:
    """The one-line DataFetchError message: file, URL, what happened, and where the file goes by hand."""
    text = (f"{entry.path}: could not fetch {url}: {what}. To install it by hand, put the file at {target} "
            f"(sha256 {entry.sha256}, {entry.size} bytes)")
    return " ".join(text.split())


def landed_mismatch(path: Path, entry: DataFile) -> str | None:
    """How the file at ``path`` differs from the registered one (size, then sha256), or None if it matches."""
    size = path.stat().st_size
    if size != entry.size:
        return f"size mismatch: expected {entry.size} bytes, got {size}"
    digest = sha256_of_file(path)
    return None if digest == entry.sha256 else f"sha256 mismatch: expected {entry.sha256}, got {digest}"


def fetch_file(entry: DataFile, root: Path, *, mirror: str | None = None, progress: bool = True,
               retries: int = 2, timeout: float = 60) -> bool:
    """Make ``root/entry.path`` hold the registered bytes; True if it was downloaded, False if it was already intact.

    An intact file is only read. Otherwise pooch downloads the file (checking
    the download's sha256, retrying ``retries`` times) into a staging folder
    next to the target; the gzip transform is applied when the registry asks
    for one (not with a mirror, which serves final files), and its result's
    size and sha256 are checked; only then is it moved into place with
    ``os.replace``. The staging folder is always removed.

    Raises
    ------
    DataFetchError
        Download failed, hash or size mismatch, or the folder is not writable.
    """
    target = root / entry.path
    if file_state(target, entry) == "intact":
        return False
    url = source_url(entry, mirror)
    transform = entry.gzip and not mirror
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(dir=target.parent, prefix=f".{target.name}.fetching-"))
    except OSError as exc:
        raise DataFetchError(failure_message(entry, url, target, f"cannot write there ({failure_reason(exc)})")) from None
    try:
        landed = pooch_download(url, staging, sha256=entry.download_sha256 if transform else entry.sha256,
                                retries=retries, timeout=timeout, progress=progress)
        if transform:  # pooch checked what was downloaded; check what it became
            landed = gzip_file(landed, staging / f"{target.name}.landed")
            mismatch = landed_mismatch(landed, entry)
            if mismatch is not None:
                raise DataFetchError(failure_message(entry, url, target, f"after gzip: {mismatch}"))
        os.replace(landed, target)
    except (ValueError, OSError) as exc:  # requests' RequestException is an OSError
        raise DataFetchError(failure_message(entry, url, target, failure_reason(exc))) from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return True


@dataclass(frozen=True)
class FetchReport:
    """What :func:`fetch_dataset` did for one dataset."""

    entry: DatasetEntry
    folder: Path
    fetched: int
    seconds: float
    sources: tuple[str, ...]

    def line(self) -> str:
        """One line: name, file count, size [MB], what happened, folder."""
        n = len(self.entry.files)
        if self.fetched:
            done = f"fetched {self.fetched} of {n} files from {', '.join(self.sources)} in {self.seconds:.1f} s"
        else:
            done = "present and verified"
        return f"{dataset_columns(self.entry)}  {done}  ({self.folder})"


def dataset_columns(entry: DatasetEntry) -> str:
    """The fixed-width start of a report line: name, number of files, total size [MB]."""
    n = len(entry.files)
    return f"{entry.name:<8} {n:>2} {'file ' if n == 1 else 'files'} {entry.size / 1e6:>6.1f} MB"


def fetch_dataset(name: str, *, root: str | Path | None = None, mirror: str | None = None, progress: bool = True,
                  retries: int = 2, timeout: float = 60,
                  registry: Mapping[str, DatasetEntry] = REGISTRY) -> FetchReport:
    """Fetch every missing or altered file of dataset ``name`` (see :func:`fetch_file`); report what was done.

    ``root`` defaults to the data root, ``mirror`` to ``$FASTSLAM_EDU_MIRROR``.
    If all files are intact, nothing is written (the data root may be read-only).
    """
    base, mirror = resolve_root(root), resolve_mirror(mirror)
    (entry,) = registered((name,), registry)
    start = time.perf_counter()
    fetched = [f for f in entry.files
               if fetch_file(f, base, mirror=mirror, progress=progress, retries=retries, timeout=timeout)]
    sources = (mirror,) if mirror and fetched else tuple(dict.fromkeys(source_label(f.url) for f in fetched))
    return FetchReport(entry, base / entry.folder, len(fetched), time.perf_counter() - start, sources)


def fetch_datasets(*names: str, root: str | Path | None = None, mirror: str | None = None, progress: bool = True,
                   retries: int = 2, timeout: float = 60,
                   registry: Mapping[str, DatasetEntry] = REGISTRY) -> dict[str, Path]:
    """Fetch the datasets ``names`` (all when none is given); return each one's folder, by name.

    Parameters
    ----------
    names : str
        Dataset names (keys of ``registry``); unknown names raise ValueError before anything is fetched.
    root : str or Path, optional
        Data root; ``$FASTSLAM_EDU_DATA`` or ``./data`` by default.
    mirror : str, optional
        URL of a web folder laid out like the data folder, holding the files in their
        final form; ``$FASTSLAM_EDU_MIRROR`` by default; ``""`` = the pinned sources.
    progress : bool
        Show pooch's progress bar for each download.
    retries : int
        Further attempts after a failed download (pooch waits 1 s, 2 s, ... in between).
    timeout : float
        Seconds to wait for the server on each network operation [s].
    registry : mapping
        Name -> :class:`DatasetEntry`; :data:`REGISTRY` by default.

    Raises
    ------
    DataFetchError
        On the first file that cannot be fetched or verified (one-line message).
    """
    entries = registered(names, registry)
    return {e.name: fetch_dataset(e.name, root=root, mirror=mirror, progress=progress, retries=retries,
                                  timeout=timeout, registry=registry).folder for e in entries}


def dataset_path(name: str, *, download: bool = False, root: str | Path | None = None,
                 registry: Mapping[str, DatasetEntry] = REGISTRY) -> Path:
    """Folder of dataset ``name`` under the data root.

    With ``download=True`` missing or altered files are fetched first
    (:func:`fetch_datasets`). Otherwise the folder is returned if every
    registered file is there with its registered size (not hashed: cheap), and
    FileNotFoundError says how to get the data if not.
    """
    if download:
        return fetch_datasets(name, root=root, registry=registry)[name]
    base = resolve_root(root)
    (entry,) = registered((name,), registry)
    absent = [f.path for f in entry.files
              if not (base / f.path).is_file() or (base / f.path).stat().st_size != f.size]
    if absent:
        from fastslam_edu.datasets import ENV_VAR

        raise FileNotFoundError(
            f"dataset {name!r} is not complete in {base / entry.folder} ({len(absent)} of {len(entry.files)} files "
            f"missing or of the wrong size, e.g. {absent[0]}): run `make data` or `fastslam-edu data {name}`, "
            f"or set {ENV_VAR} to the folder that holds '{entry.folder}'."
        )
    return base / entry.folder


# --- command line -------------------------------------------------------------------------------------------------

def add_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the options of ``fastslam-edu data`` / ``python -m fastslam_edu.datasets.registry`` to ``parser``."""
    parser.add_argument("names", nargs="*", metavar="NAME", help=f"datasets (default: all of {', '.join(REGISTRY)})")
    parser.add_argument("--check", action="store_true",
                        help="only verify size and sha256 of every file; download nothing (exit 1 if any is missing or altered)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.add_argument("--mirror", default=None,
                        help=f"URL of a web folder laid out like the data folder (default: ${MIRROR_ENV_VAR}, "
                             "else the pinned GitHub sources)")
    parser.add_argument("--retries", type=int, default=2, help="further attempts after a failed download (default 2)")
    parser.add_argument("--timeout", type=float, default=60.0, help="seconds to wait for the server (default 60)")
    return parser


def run_command(args: argparse.Namespace, registry: Mapping[str, DatasetEntry] = REGISTRY) -> int:
    """Run the parsed command: one line per dataset on stdout; 0 done, 1 failure (one ``error:`` line), 2 unknown name."""
    try:
        entries = registered(tuple(args.names), registry)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.check:
        return run_check(entries, registry)
    try:
        for entry in entries:
            report = fetch_dataset(entry.name, mirror=args.mirror, progress=not args.quiet,
                                   retries=max(args.retries, 0), timeout=args.timeout, registry=registry)
            print(report.line(), flush=True)
    except DataFetchError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


def run_check(entries: list[DatasetEntry], registry: Mapping[str, DatasetEntry]) -> int:
    """``--check``: one line per dataset saying whether its files are intact; 1 if any is missing or altered."""
    base = resolve_root(None)
    bad = 0
    for entry in entries:
        problems = dataset_problems(entry.name, root=base, registry=registry)
        bad += len(problems)
        print(f"{dataset_columns(entry)}  {check_status(entry, problems)}  ({base / entry.folder})")
    if bad:
        print(f"error: {bad} file(s) missing or altered under {base}; run `fastslam-edu data` to fetch them",
              file=sys.stderr)
        return 1
    return 0


def check_status(entry: DatasetEntry, problems: list[str]) -> str:
    """What ``--check`` says of a dataset: verified, absent, or which files (relative to its folder) are missing/altered."""
    if not problems:
        return "present and verified"
    if len(problems) == len(entry.files) and all(p.endswith(" missing") for p in problems):
        return f"missing (0 of {len(entry.files)} present)"
    short = [p.removeprefix(entry.folder + "/") for p in problems]
    return f"{len(problems)} of {len(entry.files)} files missing or altered: {', '.join(short)}"


def main(argv: list[str] | None = None, registry: Mapping[str, DatasetEntry] = REGISTRY) -> int:
    """``python -m fastslam_edu.datasets.registry [NAME ...] [--check] [--quiet]``."""
    parser = argparse.ArgumentParser(prog="python -m fastslam_edu.datasets.registry",
                                     description="Fetch (or, with --check, verify) the registered datasets "
                                                 "into $FASTSLAM_EDU_DATA (default ./data).")
    return run_command(add_arguments(parser).parse_args(argv), registry)


__all__ = [
    "DataFetchError",
    "DataFile",
    "DatasetEntry",
    "FetchReport",
    "MIRROR_ENV_VAR",
    "REGISTRY",
    "dataset_path",
    "dataset_problems",
    "fetch_dataset",
    "fetch_datasets",
    "fetch_file",
    "gzip_file",
]

if __name__ == "__main__":
    sys.exit(main())
