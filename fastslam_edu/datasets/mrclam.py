"""Reading and writing the UTIAS MR.CLAM dataset (Leung et al., IJRR 2011).

A dataset folder ``MRCLAM_Dataset{n}/`` holds whitespace-separated text files,
each starting with 4 header lines that begin with ``#``:

=============================  ==============================================
file                           columns
=============================  ==============================================
``Barcodes.dat``               subject #, barcode #
``Landmark_Groundtruth.dat``   subject #, x [m], y [m], x std-dev [m], y std-dev [m]
``RobotN_Odometry.dat``        time [s], v [m/s], ω [rad/s]  (commands, ~67 Hz)
``RobotN_Measurement.dat``     time [s], **barcode #**, range r [m], bearing φ [rad]
``RobotN_Groundtruth.dat``     time [s], x [m], y [m], θ [rad]  (Vicon, ~100 Hz)
=============================  ==============================================

The measurement files say "Subject #" in their header but hold *barcode*
numbers: :func:`landmark_sightings` maps them to subjects with
``Barcodes.dat``. Subjects 1–5 are the robots, 6–20 the landmarks.

Dataset 1 as distributed with this project has no full-rate robot
groundtruth; :func:`read_groundtruth` then falls back to the 1 Hz averages in
``groundtruth_1hz/`` (CSV, header ``Time,X,Y,Orientation``) and records which
one it used in ``groundtruth.attrs["rate"]`` (``"full"`` or ``"1hz"``).

Errors in a file are reported as ``ValueError("<file>, line <n>: ...")`` (:mod:`.numeric_table`);
a missing file as ``FileNotFoundError`` naming the path. In the real data
(Datasets 1 and 6) time never goes backwards within a file (equal consecutive
times do occur, e.g. several sightings in one camera frame), so a backwards
step is treated as corruption and raises.
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from fastslam_edu.datasets.log import Dataset, RobotLog
from fastslam_edu.datasets.numeric_table import line_of_row, read_numeric_table

HEADER_LINES = 4
"""Number of ``#`` header lines at the top of every ``.dat`` file."""

ROBOT_SUBJECTS = (1, 2, 3, 4, 5)
"""Subject numbers of the robots; their sightings are not landmark measurements."""

BARCODE_COLUMNS = ("subject", "barcode")
LANDMARK_COLUMNS = ("subject", "x", "y", "x_std", "y_std")
ODOMETRY_COLUMNS = ("time", "v", "omega")
RAW_MEASUREMENT_COLUMNS = ("time", "barcode", "range", "bearing")
MEASUREMENT_COLUMNS = ("time", "subject", "range", "bearing")
GROUNDTRUTH_COLUMNS = ("time", "x", "y", "theta")

GROUNDTRUTH_1HZ_FOLDER = "groundtruth_1hz"
GROUNDTRUTH_1HZ_NAMES = ("Robot{n}_Groundtruth_1hz.csv", "Cleaned_Robot{n}_Groundtruth.csv")
"""File names tried, in order, inside ``groundtruth_1hz/`` for robot ``n``."""

_HEADERS = {
    "Barcodes": ("Barcode Data Format:", "Subject #    Barcode #"),
    "Landmark_Groundtruth": (
        "Landmark Groundtruth Data Format:",
        "Subject #    x [m]    y [m]    x std-dev [m]    y std-dev [m]",
    ),
    "Odometry": (
        "Odometry Data Format:",
        "Time [s]    forward velocity [m/s]    angular velocity[rad/s]",
    ),
    "Measurement": (
        "Measurement Data Format:",
        "Time [s]    Barcode #    range [m]    bearing [rad]",
    ),
    "Groundtruth": (
        "Robot Groundtruth Data Format:",
        "Time [s]    x [m]    y [m]    orientation [rad]",
    ),
}


# --------------------------------------------------------------------------
# per-file readers
# --------------------------------------------------------------------------


def _check_unique(path: Path, values: np.ndarray, what: str) -> None:
    seen, counts = np.unique(values, return_counts=True)
    dup = seen[counts > 1]
    if dup.size:
        rows = np.flatnonzero(values == dup[0])
        lines = [line_of_row(path, int(r), None, 0) for r in rows[:2]]
        raise ValueError(f"{path}, line {lines[1]}: {what} {int(dup[0])} repeats line {lines[0]}")


def read_barcodes(path: str | Path) -> dict[int, int]:
    """Read ``Barcodes.dat``: the barcode printed on each subject.

    Returns
    -------
    dict[int, int]
        Barcode number -> subject number (1–5 robots, 6–20 landmarks).
    """
    path = Path(path)
    table = read_numeric_table(path, BARCODE_COLUMNS, integer_columns=BARCODE_COLUMNS)
    _check_unique(path, table[:, 0], "subject")
    _check_unique(path, table[:, 1], "barcode")
    return {int(b): int(s) for s, b in table}


def read_landmark_groundtruth(path: str | Path) -> pd.DataFrame:
    """Read ``Landmark_Groundtruth.dat``: the Vicon-surveyed landmark positions.

    Returns
    -------
    DataFrame
        Index ``subject`` (int, sorted), columns ``x, y, x_std, y_std`` [m].
    """
    path = Path(path)
    table = read_numeric_table(path, LANDMARK_COLUMNS, integer_columns=("subject",))
    _check_unique(path, table[:, 0], "subject")
    df = pd.DataFrame(table[:, 1:], columns=list(LANDMARK_COLUMNS[1:]))
    df.index = pd.Index(table[:, 0].astype(np.int64), name="subject")
    return df.sort_index()


def read_odometry(path: str | Path) -> pd.DataFrame:
    """Read ``RobotN_Odometry.dat``: the velocity commands ``u = (v, ω)``.

    Returns
    -------
    DataFrame
        Columns ``time`` [s], ``v`` [m/s], ``omega`` [rad/s], time non-decreasing.
    """
    table = read_numeric_table(path, ODOMETRY_COLUMNS, time_column=True)
    return pd.DataFrame(table, columns=list(ODOMETRY_COLUMNS))


def read_measurements(path: str | Path) -> pd.DataFrame:
    """Read ``RobotN_Measurement.dat`` as recorded: barcodes, not yet subjects.

    Returns
    -------
    DataFrame
        Columns ``time`` [s], ``barcode`` (int), ``range`` r [m], ``bearing`` φ [rad],
        time non-decreasing. Use :func:`landmark_sightings` to map barcodes.
    """
    table = read_numeric_table(path, RAW_MEASUREMENT_COLUMNS, time_column=True,
                               integer_columns=("barcode",))
    df = pd.DataFrame(table, columns=list(RAW_MEASUREMENT_COLUMNS))
    df["barcode"] = df["barcode"].astype(np.int64)
    return df


def read_groundtruth_dat(path: str | Path) -> pd.DataFrame:
    """Read a full-rate ``RobotN_Groundtruth.dat`` (Vicon, ~100 Hz).

    Returns
    -------
    DataFrame
        Columns ``time, x, y, theta`` (s, m, m, rad); ``attrs["rate"] = "full"``.
    """
    table = read_numeric_table(path, GROUNDTRUTH_COLUMNS, time_column=True)
    df = pd.DataFrame(table, columns=list(GROUNDTRUTH_COLUMNS))
    df.attrs.update(rate="full", file=str(path))
    return df


def read_groundtruth_csv(path: str | Path) -> pd.DataFrame:
    """Read a 1 Hz groundtruth CSV (header ``Time,X,Y,Orientation``; blank lines allowed).

    Each row is the mean of the Vicon samples whose times round to that whole
    second, so it stands for the pose at that second.

    Returns
    -------
    DataFrame
        Columns ``time, x, y, theta``; ``attrs["rate"] = "1hz"``.
    """
    path = Path(path)
    if path.is_file():
        with open(path, encoding="utf-8", errors="replace") as f:
            header = f.readline().strip()
        if header.replace(" ", "").lower() != "time,x,y,orientation":
            raise ValueError(f"{path}, line 1: expected the header 'Time,X,Y,Orientation', found {header!r}")
    table = read_numeric_table(path, GROUNDTRUTH_COLUMNS, delimiter=",", skip_header=1, time_column=True)
    df = pd.DataFrame(table, columns=list(GROUNDTRUTH_COLUMNS))
    df.attrs.update(rate="1hz", file=str(path))
    return df


def groundtruth_files(folder: str | Path, robot: int) -> list[Path]:
    """Candidate groundtruth files of ``robot`` in ``folder``, best first."""
    folder = Path(folder)
    return [folder / f"Robot{robot}_Groundtruth.dat"] + [
        folder / GROUNDTRUTH_1HZ_FOLDER / name.format(n=robot) for name in GROUNDTRUTH_1HZ_NAMES
    ]


def read_groundtruth(folder: str | Path, robot: int) -> pd.DataFrame | None:
    """Groundtruth poses of ``robot``: full rate if present, else the 1 Hz CSV, else None.

    Looks for ``RobotN_Groundtruth.dat``, then
    ``groundtruth_1hz/RobotN_Groundtruth_1hz.csv`` (or
    ``groundtruth_1hz/Cleaned_RobotN_Groundtruth.csv``).

    Returns
    -------
    DataFrame or None
        Columns ``time, x, y, theta``; ``attrs["rate"]`` is ``"full"`` or
        ``"1hz"`` and ``attrs["file"]`` the file read.
    """
    for path in groundtruth_files(folder, robot):
        if path.is_file():
            return read_groundtruth_dat(path) if path.suffix == ".dat" else read_groundtruth_csv(path)
    return None


# --------------------------------------------------------------------------
# barcodes -> landmark subjects
# --------------------------------------------------------------------------


def landmark_sightings(raw: pd.DataFrame, barcodes: dict[int, int],
                       landmark_subjects: Iterable[int]) -> tuple[pd.DataFrame, dict]:
    """Keep the sightings of landmarks, with barcodes mapped to subject numbers.

    Parameters
    ----------
    raw : DataFrame
        Columns ``time, barcode, range, bearing`` (:func:`read_measurements`).
    barcodes : dict[int, int]
        Barcode -> subject (:func:`read_barcodes`).
    landmark_subjects : iterable of int
        Subjects that are landmarks (the index of ``Landmark_Groundtruth.dat``).

    Returns
    -------
    measurements : DataFrame
        Columns ``time, subject, range, bearing``, same order as ``raw``.
    dropped : dict
        ``{"robot_sightings": n, "unknown_barcodes": {barcode: count},
        "subjects_without_groundtruth": {subject: count}}``: sightings of the
        robots 1–5, barcodes in no table (misreads, e.g. barcode 43 in
        Dataset 6), and subjects with a barcode but no landmark groundtruth.
    """
    landmarks = np.fromiter((int(s) for s in landmark_subjects), dtype=np.int64)
    code = raw["barcode"].to_numpy(dtype=np.int64)
    known_codes = np.fromiter(barcodes.keys(), dtype=np.int64, count=len(barcodes))
    known_subjects = np.fromiter(barcodes.values(), dtype=np.int64, count=len(barcodes))
    known = np.isin(code, known_codes)
    subject = np.full(code.shape, -1, dtype=np.int64)
    if known_codes.size:
        order = np.argsort(known_codes)
        subject[known] = known_subjects[order][np.searchsorted(known_codes[order], code[known])]
    is_landmark = known & np.isin(subject, landmarks)
    is_robot = known & np.isin(subject, ROBOT_SUBJECTS) & ~is_landmark
    other = known & ~is_landmark & ~is_robot
    dropped = {
        "robot_sightings": int(is_robot.sum()),
        "unknown_barcodes": {int(b): n for b, n in sorted(Counter(code[~known].tolist()).items())},
        "subjects_without_groundtruth": {int(s): n for s, n in sorted(Counter(subject[other].tolist()).items())},
    }
    out = pd.DataFrame({
        "time": raw["time"].to_numpy(dtype=float)[is_landmark],
        "subject": subject[is_landmark],
        "range": raw["range"].to_numpy(dtype=float)[is_landmark],
        "bearing": raw["bearing"].to_numpy(dtype=float)[is_landmark],
    })
    return out, dropped


def robot_sightings(raw: pd.DataFrame, barcodes: dict[int, int], robot: int | None = None,
                    robots: Iterable[int] = ROBOT_SUBJECTS) -> pd.DataFrame:
    """Keep the sightings of the robots (the rows :func:`landmark_sightings` drops), barcodes mapped to subjects.

    A robot's camera reads the barcode on another robot as it reads a landmark's: ``(r, φ)`` of that robot's
    centre in the observer's frame. These tie two robots' poses at one instant (the multi-robot smoother,
    :mod:`fastslam_edu.landmark.multi_robot`).

    Parameters
    ----------
    raw, barcodes : DataFrame, dict[int, int]
        The sightings and the barcode table, as for :func:`landmark_sightings`.
    robot : int, optional
        The observer's subject number: a sighting of itself is an error.
    robots : iterable of int
        The robots' subject numbers (MR.CLAM: 1–5).

    Returns
    -------
    DataFrame
        Columns ``time`` [s], ``subject`` (int, the robot seen), ``range`` [m], ``bearing`` [rad], in the
        order of ``raw``; empty if none.

    Raises
    ------
    ValueError
        If ``raw`` lacks a column, holds a NaN/inf, a negative range or time going backwards, if a robot has
        no barcode in ``barcodes``, or if ``robot`` sees itself (one line naming the row and value).
    """
    missing = [c for c in RAW_MEASUREMENT_COLUMNS if c not in raw.columns]
    if missing:
        raise ValueError(f"robot_sightings: the measurements lack the column(s) {missing}")
    robots = sorted(int(r) for r in robots)
    subject_of = {int(b): int(s) for b, s in barcodes.items()}
    without = [r for r in robots if r not in subject_of.values()]
    if without:
        raise ValueError(f"robot_sightings: robot(s) {without} have no barcode in the barcode table")
    code = raw["barcode"].to_numpy(dtype=np.int64)
    subject = np.array([subject_of.get(int(b), -1) for b in code], dtype=np.int64)
    keep = np.flatnonzero(np.isin(subject, robots))
    values = raw[["time", "range", "bearing"]].to_numpy(dtype=float)[keep]
    bad = np.flatnonzero(~np.isfinite(values).all(axis=1) | (values[:, 1] < 0))
    if bad.size:
        row = int(keep[bad[0]])
        raise ValueError(f"robot_sightings: row {row} (barcode {int(code[row])}) has time, range, bearing "
                         f"{values[bad[0]].tolist()}: not finite, or a negative range")
    back = np.flatnonzero(np.diff(values[:, 0]) < 0)
    if back.size:
        raise ValueError(f"robot_sightings: row {int(keep[back[0] + 1])}: time goes backwards")
    if robot is not None and np.any(subject[keep] == int(robot)):
        row = int(keep[np.flatnonzero(subject[keep] == int(robot))[0]])
        raise ValueError(f"robot_sightings: row {row}: robot {int(robot)} sees its own barcode {int(code[row])}")
    return pd.DataFrame({"time": values[:, 0], "subject": subject[keep], "range": values[:, 1],
                         "bearing": values[:, 2]})


# --------------------------------------------------------------------------
# whole robots and datasets
# --------------------------------------------------------------------------


def read_robot(path: str | Path, robot: int, barcodes: dict[int, int],
               landmark_subjects: Iterable[int]) -> RobotLog:
    """Read one robot's odometry, landmark measurements and groundtruth.

    Parameters
    ----------
    path : str or Path
        The dataset folder.
    robot : int
        Robot subject number ``N`` (files ``RobotN_*.dat``).
    barcodes : dict[int, int]
        Barcode -> subject.
    landmark_subjects : iterable of int
        Subjects kept as landmarks.

    Returns
    -------
    RobotLog
        ``source`` is the folder; ``groundtruth.attrs["rate"]`` says whether
        the groundtruth is full rate or the 1 Hz fallback (None if absent);
        ``robot_sightings`` its sightings of the other robots (:func:`robot_sightings`).
    """
    folder = Path(path)
    odometry = read_odometry(folder / f"Robot{robot}_Odometry.dat")
    raw = read_measurements(folder / f"Robot{robot}_Measurement.dat")
    measurements, dropped = landmark_sightings(raw, barcodes, landmark_subjects)
    robots = [r for r in ROBOT_SUBJECTS if r in barcodes.values()]
    try:
        seen = robot_sightings(raw, barcodes, robot, robots)
    except ValueError as exc:
        raise ValueError(f"{folder / f'Robot{robot}_Measurement.dat'}: {exc}") from None
    groundtruth = read_groundtruth(folder, robot)
    return RobotLog(robot=int(robot), odometry=odometry, measurements=measurements,
                    groundtruth=groundtruth, dropped=dropped, source=str(folder), robot_sightings=seen)


def robots_in(folder: str | Path) -> list[int]:
    """Robot numbers ``N`` for which ``RobotN_Odometry.dat`` exists in ``folder``, sorted."""
    found = (re.fullmatch(r"Robot(\d+)_Odometry\.dat", p.name) for p in Path(folder).iterdir())
    return sorted(int(m.group(1)) for m in found if m)


def read_dataset(path: str | Path, robots: Iterable[int] | None = None) -> Dataset:
    """Read a whole MR.CLAM dataset folder.

    Parameters
    ----------
    path : str or Path
        Folder ``MRCLAM_Dataset{n}`` (see :func:`fastslam_edu.datasets.mrclam_path`).
    robots : iterable of int, optional
        Robots to read; default every ``N`` with a ``RobotN_Odometry.dat``.

    Returns
    -------
    Dataset

    Raises
    ------
    FileNotFoundError
        If the folder or one of the needed files does not exist.
    ValueError
        If a file is malformed (the message names the file and line).
    """
    folder = Path(path)
    if not folder.is_dir():
        raise FileNotFoundError(f"MR.CLAM dataset folder not found: {folder}")
    barcodes = read_barcodes(folder / "Barcodes.dat")
    landmarks = read_landmark_groundtruth(folder / "Landmark_Groundtruth.dat")
    numbers = robots_in(folder) if robots is None else [int(r) for r in robots]
    if not numbers:
        raise FileNotFoundError(f"{folder}: no RobotN_Odometry.dat file found")
    subjects = landmarks.index.to_numpy()
    logs = {n: read_robot(folder, n, barcodes, subjects) for n in numbers}
    return Dataset(path=folder, barcodes=barcodes, landmarks=landmarks, robots=logs)


# --------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------


def _format_table(columns: Sequence[np.ndarray], integer: Sequence[bool]) -> str:
    """Rows of tab-separated numbers; floats in the shortest form that reads back exactly."""
    text = [
        [str(v) for v in np.asarray(c, dtype=np.int64).tolist()] if is_int
        else [repr(v) for v in np.asarray(c, dtype=float).tolist()]
        for c, is_int in zip(columns, integer)
    ]
    return "".join("\t".join(row) + "\n" for row in zip(*text))


def _check_finite_sorted(df: pd.DataFrame, columns: Sequence[str], what: str, time: bool) -> None:
    values = df[list(columns)].to_numpy(dtype=float)
    bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
    if bad.size:
        raise ValueError(f"{what}: row {int(bad[0])} has a NaN or infinite value: {values[bad[0]].tolist()}")
    if time and values.shape[0] > 1:
        back = np.flatnonzero(np.diff(values[:, 0]) < 0)
        if back.size:
            raise ValueError(f"{what}: time goes backwards at row {int(back[0]) + 1}")


def _write_dat(path: Path, kind: str, source: str, columns: Sequence[np.ndarray],
               integer: Sequence[bool]) -> None:
    title, names = _HEADERS[kind]
    header = (
        "# UTIAS Multi-Robot Cooperative Localization and Mapping Dataset (file format)\n"
        f"# written by fastslam_edu.datasets.mrclam.write_dataset; source: {source or 'unknown'}\n"
        f"# {title}\n"
        f"# {names}\n"
    )
    path.write_text(header + _format_table(columns, integer), encoding="utf-8")


def write_dataset(dataset: Dataset, folder: str | Path) -> Path:
    """Write ``dataset`` as MR.CLAM ``.dat`` files (4 header lines, tab separated).

    Writes ``Barcodes.dat``, ``Landmark_Groundtruth.dat`` and, per robot,
    ``RobotN_Odometry.dat``, ``RobotN_Measurement.dat`` (subjects mapped back
    to barcodes) and ``RobotN_Groundtruth.dat`` when the robot has full-rate
    groundtruth (1 Hz groundtruth goes to
    ``groundtruth_1hz/RobotN_Groundtruth_1hz.csv``). Floats are written in
    the shortest form that reads back to the same float, so
    :func:`read_dataset` returns the same numbers. The dropped sightings
    (``RobotLog.dropped``) are not written; the sightings of other robots
    (``RobotLog.robot_sightings``) are, with the landmark sightings, in time order.

    Parameters
    ----------
    dataset : Dataset
    folder : str or Path
        Created if needed; existing files of the same names are overwritten.

    Returns
    -------
    Path
        ``folder``.

    Raises
    ------
    ValueError
        If a value is NaN/inf, time goes backwards, or a measured subject
        has no barcode in ``dataset.barcodes``.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    source = str(dataset.path) if dataset.path is not None else "in-memory dataset"
    pairs = sorted((s, b) for b, s in dataset.barcodes.items())
    _write_dat(folder / "Barcodes.dat", "Barcodes", source,
               [np.array([s for s, _ in pairs]), np.array([b for _, b in pairs])], [True, True])
    lm = dataset.landmarks.sort_index()
    _check_finite_sorted(lm, LANDMARK_COLUMNS[1:], "landmarks", time=False)
    _write_dat(folder / "Landmark_Groundtruth.dat", "Landmark_Groundtruth", source,
               [lm.index.to_numpy()] + [lm[c].to_numpy() for c in LANDMARK_COLUMNS[1:]],
               [True, False, False, False, False])
    barcode_of = {s: b for b, s in dataset.barcodes.items()}
    for n, log in sorted(dataset.robots.items()):
        src = log.source or source
        _check_finite_sorted(log.odometry, ODOMETRY_COLUMNS, f"robot {n} odometry", time=True)
        _write_dat(folder / f"Robot{n}_Odometry.dat", "Odometry", src,
                   [log.odometry[c].to_numpy() for c in ODOMETRY_COLUMNS], [False] * 3)
        m = log.measurements
        _check_finite_sorted(m, MEASUREMENT_COLUMNS, f"robot {n} measurements", time=True)
        if log.robot_sightings is not None and len(log.robot_sightings):  # merged back, in time order
            m = pd.concat([m, log.robot_sightings[list(MEASUREMENT_COLUMNS)]], ignore_index=True)
            m = m.sort_values("time", kind="stable")
        subjects = m["subject"].to_numpy(dtype=np.int64)
        missing = sorted(set(subjects.tolist()) - set(barcode_of))
        if missing:
            raise ValueError(f"robot {n} measurements: subjects {missing} have no barcode in dataset.barcodes")
        codes = np.array([barcode_of[s] for s in subjects.tolist()], dtype=np.int64)
        _write_dat(folder / f"Robot{n}_Measurement.dat", "Measurement", src,
                   [m["time"].to_numpy(), codes, m["range"].to_numpy(), m["bearing"].to_numpy()],
                   [False, True, False, False])
        gt = log.groundtruth
        if gt is None:
            continue
        _check_finite_sorted(gt, GROUNDTRUTH_COLUMNS, f"robot {n} groundtruth", time=True)
        cols = [gt[c].to_numpy() for c in GROUNDTRUTH_COLUMNS]
        if gt.attrs.get("rate") == "1hz":
            sub = folder / GROUNDTRUTH_1HZ_FOLDER
            sub.mkdir(exist_ok=True)
            body = _format_table(cols, [False] * 4).replace("\t", ",")
            (sub / GROUNDTRUTH_1HZ_NAMES[0].format(n=n)).write_text("Time,X,Y,Orientation\n" + body,
                                                                   encoding="utf-8")
        else:
            _write_dat(folder / f"Robot{n}_Groundtruth.dat", "Groundtruth", src, cols, [False] * 4)
    return folder


__all__ = [
    "HEADER_LINES",
    "ROBOT_SUBJECTS",
    "groundtruth_files",
    "landmark_sightings",
    "read_barcodes",
    "read_dataset",
    "read_groundtruth",
    "read_groundtruth_csv",
    "read_groundtruth_dat",
    "read_landmark_groundtruth",
    "read_measurements",
    "read_odometry",
    "read_robot",
    "robot_sightings",
    "robots_in",
    "write_dataset",
]
