"""Readers for 2D laser logs: CARMEN (Intel, FR079), the Intel JSON files, the relation files.

Every reader returns arrays in the package's conventions: times in seconds,
poses ``(x, y, θ)`` [m, m, rad] in the world, beam angles [rad] in the sensor
frame (0 straight ahead, positive to the left), ranges [m].

* :func:`read_carmen` — CARMEN text logs (``PARAM``, ``ODOM``, ``FLASER``), plain
  or gzip, e.g. the GMapping-corrected logs ``intel.gfs.log.gz`` and
  ``freiburg-079-corrected.log.gz``. In those the pose stored with each scan is
  GMapping's *corrected* pose; :func:`odometry_increments` recovers the *raw*
  odometry between scans from the ``ODOM`` lines, and
  :func:`~fastslam_edu.core.se2.compose_increments` rebuilds the raw-odometry path.
* :func:`read_intel_json` — the two JSON versions of the 910 Intel scans
  (raw-odometry poses or corrected poses); :func:`read_relations` — the
  Kümmerle et al. (2009) relation files.
* The THOR humanoid's MATLAB files are read and written by :mod:`fastslam_edu.datasets.thor_lidar`.

"No return" readings (CARMEN writes 81.83 or 81.91 m, beyond the SICK's 80 m)
become ``np.nan`` in :attr:`LaserLog.ranges`; :meth:`LaserLog.beams` gives a
scan's valid beams, ready for :func:`fastslam_edu.grid.occupancy.scan_endpoints`.
"""

from __future__ import annotations

import gzip
import json
import math
import zlib
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.se2 import compose_increments, path_increments, relative

__all__ = [
    "LaserLog",
    "read_carmen",
    "odometry_increments",
    "compose_increments",
    "read_intel_json",
    "read_relations",
    "carmen_angles",
    "DEFAULT_NO_RETURN",
]

#: Ranges at or beyond this [m] are "no return" when a log has no ``robot_front_laser_max``
#: PARAM: SICK LMS scanners reach 80 m and CARMEN logs write 81.83 / 81.91 m for "nothing seen".
DEFAULT_NO_RETURN = 80.0


# --------------------------------------------------------------------------- the log structure


@dataclass
class LaserLog:
    """A 2D laser log: one row per scan.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Scan times [s] (as in the file: relative times for the CARMEN logs,
        Unix times for the Intel JSON files).
    ranges : ndarray, shape (N, B)
        Ranges [m]; ``np.nan`` where the sensor saw nothing ("no return":
        readings ``≥ max_range`` or ``≤ 0``).
    angles : ndarray, shape (B,)
        Beam angles [rad] in the sensor frame, increasing right to left.
    poses : ndarray, shape (N, 3)
        The pose stored with each scan, ``(x, y, θ)`` [m, m, rad]. In the
        GMapping-corrected logs (``*.gfs.log``, ``*-corrected.log``,
        ``intel_corrected_log.json``) this is GMapping's corrected pose; in
        ``intel_gfs.json`` it is the raw odometry.
    odometry : ndarray, shape (N, 3), or None
        The raw odometry pose of each scan where the file holds it (raw CARMEN
        logs; ``intel_gfs.json``), else None — then use
        :func:`odometry_increments`.
    source : str
        Where it came from (used in messages).
    max_range : float
        Readings at or beyond this [m] were turned into ``np.nan``.
    last_odom : ndarray, shape (N, 3), or None
        CARMEN only: the last ``ODOM`` pose before each scan, in file order
        (``np.nan`` rows for scans with no ``ODOM`` before them).
    first_odom : ndarray, shape (3,), or None
        CARMEN only: the first ``ODOM`` pose of the file.
    params : dict[str, str]
        CARMEN ``PARAM`` name → value (as text).
    counts : dict[str, int]
        Messages per type in the file, including those skipped (e.g. ``NEFF``).
    """

    t: np.ndarray
    ranges: np.ndarray
    angles: np.ndarray
    poses: np.ndarray
    odometry: np.ndarray | None
    source: str
    max_range: float
    last_odom: np.ndarray | None = None
    first_odom: np.ndarray | None = None
    params: dict = field(default_factory=dict)
    counts: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        n, b = np.shape(self.ranges) if np.ndim(self.ranges) == 2 else (None, None)
        if n is None:
            raise ValueError(f"LaserLog({self.source}): ranges must be (N, B), got shape {np.shape(self.ranges)}")
        checks = [("t", self.t, (n,)), ("angles", self.angles, (b,)), ("poses", self.poses, (n, 3))]
        if self.odometry is not None:
            checks.append(("odometry", self.odometry, (n, 3)))
        if self.last_odom is not None:
            checks.append(("last_odom", self.last_odom, (n, 3)))
        for name, a, shape in checks:
            if np.shape(a) != shape:
                raise ValueError(f"LaserLog({self.source}): {name} must have shape {shape}, got {np.shape(a)}")

    def __len__(self) -> int:
        return len(self.t)

    def beams(self, k: int, *, min_range: float = 0.0, max_range: float | None = None):
        """Ranges and angles of the valid beams of scan ``k``.

        Drops "no return" beams (NaN) and, optionally, beams shorter than
        ``min_range`` or longer than ``max_range`` [m].

        Returns
        -------
        ranges, angles : ndarray, shape (B_k,) each
        """
        r = self.ranges[k]
        keep = np.isfinite(r)
        keep[keep] &= r[keep] >= min_range
        if max_range is not None:
            keep[keep] &= r[keep] <= max_range
        return r[keep], self.angles[keep]


def carmen_angles(n: int, step: float | None = None) -> np.ndarray:
    """Beam angles of an ``n``-beam CARMEN front laser: ``−π/2 + i·step``, ``i = 0 … n−1``.

    ``step`` defaults to ``π / n`` (``n`` beams over 180°, right to left): 1° for
    the 180-beam Intel log, 0.5° for the 360-beam FR079 log.
    """
    if step is None:
        step = math.pi / n
    return -math.pi / 2 + step * np.arange(n)


# --------------------------------------------------------------------------- text and gzip input


#: What to do about a damaged data file (said at the end of every such error).
REFETCH_HINT = "download it again (for the project's data files: delete it and run `make data`)"

_GZIP_MAGIC = b"\x1f\x8b"


def one_line_message(exc: BaseException) -> str:
    """The text of ``exc`` on one line (for quoting a library's message inside ours)."""
    return " ".join(str(exc).split()) or type(exc).__name__


def _text_lines(path, *, encoding: str = "ascii", errors: str = "replace"):
    """Yield ``(line number, line)`` of a text file, plain or gzip-compressed (name ending ``.gz``).

    The data layer's one way to read text: every reader of a text or ``.gz``
    file goes through it, so that a damaged file gives the same one-line
    ValueError naming it, wherever it is read:

    * a ``.gz`` file that is empty or not gzip at all (e.g. an HTML error page
      saved under the data file's name), or a gzip file whose name lacks ``.gz``;
    * a gzip stream cut short (an interrupted download): "truncated after line N",
      N being the last whole line read;
    * corrupt compressed data or a failed CRC/length check ("after line N");
    * text that is not valid ``encoding`` when ``errors="strict"``.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        For a damaged file, as above.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    gz = path.suffix == ".gz"
    with open(path, "rb") as raw:
        head = raw.read(2)
        if gz and head != _GZIP_MAGIC:
            if not head:
                raise ValueError(f"{path}: empty file (0 bytes), not gzip data; {REFETCH_HINT}")
            raw.seek(0)
            raise ValueError(
                f"{path}: not gzip data although named .gz (it starts with {raw.read(16)!r}); {REFETCH_HINT}, "
                "or, if it is plain text, remove .gz from its name"
            )
        if not gz and head == _GZIP_MAGIC:
            raise ValueError(f"{path}: the file is gzip-compressed but its name does not end in .gz; "
                             f"rename it to {path.name}.gz")
        raw.seek(0)
        with gzip.GzipFile(fileobj=raw) if gz else nullcontext(raw) as f:
            lineno = 0
            try:  # bytes lines, decoded one by one: a decoding error then names its line
                for lineno, line in enumerate(f, start=1):
                    yield lineno, line.decode(encoding, errors)
            except UnicodeDecodeError as exc:
                raise ValueError(
                    f"{path}:{lineno}: not {exc.encoding.upper()} text (byte 0x{exc.object[exc.start]:02x} at "
                    f"column {exc.start + 1}: {exc.reason}); {REFETCH_HINT}"
                ) from None
            except EOFError:
                where = f"after line {lineno}" if lineno else "inside line 1"
                raise ValueError(
                    f"{path}: truncated: the gzip data stops {where}, before the end of the file "
                    f"(an interrupted download?); {REFETCH_HINT}"
                ) from None
            except (zlib.error, gzip.BadGzipFile) as exc:
                raise ValueError(
                    f"{path}: corrupt gzip data after line {lineno} ({one_line_message(exc)}); {REFETCH_HINT}"
                ) from None


# --------------------------------------------------------------------------- CARMEN


def _floats(tokens, path, lineno, what) -> np.ndarray:
    try:
        return np.array([float(v) for v in tokens], dtype=float)
    except ValueError as exc:
        raise ValueError(f"{path}:{lineno}: non-numeric value in {what}: {exc}") from None


def _param_float(params: dict, name: str, path: Path, default):
    """A numeric CARMEN PARAM, or ``default`` if absent; a ValueError naming it if not a number."""
    if name not in params:
        return default
    try:
        return float(params[name])
    except ValueError:
        raise ValueError(f"{path}: PARAM {name} = {params[name]!r} is not a number") from None


def read_carmen(path, *, no_return: float | None = None) -> LaserLog:
    """Read a CARMEN laser log (plain text or ``.gz``).

    Messages read (one per line, fields separated by spaces):

    * ``PARAM name value …`` — kept in :attr:`LaserLog.params`;
    * ``ODOM x y θ tv rv accel ipc_t host logger_t`` — kept as
      :attr:`LaserLog.last_odom` (the last one before each scan);
    * ``FLASER n r_1 … r_n x y θ odom_x odom_y odom_θ ipc_t host logger_t`` — one scan.

    Everything else (``NEFF``, ``SYNC``, ``RLASER``, comments) is skipped and
    counted in :attr:`LaserLog.counts`.

    Conventions: beam ``i`` is at ``−π/2 + i·step`` with ``step`` from the PARAM
    ``laser_front_laser_resolution`` [deg] if present, else ``π/n``
    (:func:`carmen_angles`). Readings ``≥ no_return`` (default: the PARAM
    ``robot_front_laser_max`` if present, else :data:`DEFAULT_NO_RETURN` = 80 m)
    or ``≤ 0`` become ``np.nan``. The scan time is the logger timestamp (last
    field). :attr:`LaserLog.poses` is the ``x y θ`` triple; if the
    ``odom_*`` triple differs from it anywhere (a raw log) it becomes
    :attr:`LaserLog.odometry`, else (a corrected log, where both are GMapping's
    pose) ``odometry`` is None.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        Naming file and line, for a short or non-numeric ``FLASER``/``ODOM``
        line, a non-finite pose, scans of different lengths, or no scan at all;
        for a damaged ``.gz`` (not gzip, truncated after line N, corrupt data).
    """
    path = Path(path)
    params: dict[str, str] = {}
    counts: dict[str, int] = {}
    scans = []  # (t, ranges, pose, odom pose, last ODOM) per FLASER line
    first_odom, current_odom = None, np.full(3, np.nan)
    for lineno, line in _text_lines(path):
        tok = line.split()
        if not tok:
            continue
        kind = tok[0] if not tok[0].startswith("#") else "#"
        counts[kind] = counts.get(kind, 0) + 1
        if kind == "PARAM" and len(tok) >= 3:
            params[tok[1]] = tok[2]
        elif kind == "ODOM":
            current_odom = _odom_pose(tok, path, lineno)
            first_odom = current_odom if first_odom is None else first_odom
        elif kind == "FLASER":
            scans.append(_flaser(tok, path, lineno, len(scans[0][1]) if scans else None) + (current_odom,))
    if not scans:
        raise ValueError(f"{path}: no FLASER line (counted messages: {counts})")
    return _carmen_log(path, scans, params, counts, first_odom, no_return)


def _odom_pose(tok, path: Path, lineno: int) -> np.ndarray:
    """The ``x y θ`` of an ``ODOM`` line, checked."""
    if len(tok) < 4:
        raise ValueError(f"{path}:{lineno}: ODOM line has {len(tok)} fields, expected at least 4 (ODOM x y θ …)")
    pose = _floats(tok[1:4], path, lineno, "ODOM pose")
    if not np.isfinite(pose).all():
        raise ValueError(f"{path}:{lineno}: non-finite ODOM pose {pose.tolist()}")
    return pose


def _flaser(tok, path: Path, lineno: int, n_beams: int | None):
    """``(t, ranges, pose, odom pose)`` of a ``FLASER`` line, checked (``n_beams``: that of the earlier scans)."""
    try:
        n = int(tok[1])
    except (IndexError, ValueError):
        raise ValueError(f"{path}:{lineno}: FLASER line must start with the beam count, got {tok[1:2]}") from None
    if n < 1 or len(tok) < n + 9:
        raise ValueError(
            f"{path}:{lineno}: short FLASER line: {len(tok)} fields for n = {n} beams, expected "
            f"{n + 11} (FLASER n r_1…r_n x y θ odom_x odom_y odom_θ ipc_t host logger_t)"
        )
    if n_beams is not None and n != n_beams:
        raise ValueError(f"{path}:{lineno}: FLASER with {n} beams after scans of {n_beams} beams")
    r = _floats(tok[2 : 2 + n], path, lineno, "FLASER ranges")
    both = _floats(tok[2 + n : 8 + n], path, lineno, "FLASER pose")
    if not np.isfinite(both).all():
        raise ValueError(f"{path}:{lineno}: non-finite FLASER pose {both.tolist()}")
    stamp = tok[-1] if len(tok) >= n + 11 else tok[8 + n]
    return _floats([stamp], path, lineno, "FLASER timestamp")[0], r, both[:3], both[3:]


def _carmen_log(path: Path, scans, params: dict, counts: dict, first_odom, no_return) -> LaserLog:
    """The :class:`LaserLog` of the scans read by :func:`read_carmen` (conventions there)."""
    t, ranges, poses, odoms, last_odom = (np.array(column) for column in zip(*scans))
    if no_return is None:
        no_return = _param_float(params, "robot_front_laser_max", path, DEFAULT_NO_RETURN)
    resolution_deg = _param_float(params, "laser_front_laser_resolution", path, None)
    step = None if resolution_deg is None else math.radians(resolution_deg)
    ranges[~(np.isfinite(ranges) & (ranges > 0) & (ranges < no_return))] = np.nan
    poses[:, 2] = wrap_angle(poses[:, 2])
    odometry = None if np.array_equal(poses[:, :2], odoms[:, :2]) and np.allclose(
        wrap_angle(poses[:, 2] - odoms[:, 2]), 0.0, atol=1e-12
    ) else odoms
    return LaserLog(
        t=t, ranges=ranges, angles=carmen_angles(ranges.shape[1], step), poses=poses, odometry=odometry,
        source=str(path), max_range=float(no_return), last_odom=last_odom,
        first_odom=first_odom, params=params, counts=counts,
    )


def odometry_increments(log: LaserLog) -> np.ndarray:
    """Raw odometry increments ``u_k`` between consecutive scans, in the robot frame.

    * If the log holds raw odometry poses ``o_k`` (:attr:`LaserLog.odometry`):
      ``u_k = o_{k−1}⁻¹ ⊕ o_k``.
    * Else, for a GMapping-corrected CARMEN log: every ``ODOM`` line there is
      the last corrected pose ``x_{k−1}`` composed with the raw odometry since
      that scan, so with ``ō_k`` the last ``ODOM`` before scan ``k``
      (:attr:`LaserLog.last_odom`)::

          u_k = x_{k−1}⁻¹ ⊕ ō_k

    Row 0 holds ``u_0``: the motion from the file's first ``ODOM`` to scan 0
    (``ō_0`` relative to :attr:`LaserLog.first_odom`), or zeros when unknown
    (no ``ODOM`` before the first scan, or a log with odometry poses).

    Returns
    -------
    ndarray, shape (N, 3)
        ``compose_increments(log.poses[0], u[1:])`` is then the raw-odometry
        path started at the first corrected pose.

    Raises
    ------
    ValueError
        If the log has neither odometry poses nor ``ODOM`` lines before a scan ``k ≥ 1``.
    """
    n = len(log)
    u = np.zeros((n, 3))
    if log.odometry is not None:
        if n > 1:
            u[1:] = path_increments(log.odometry)
        return u
    if log.last_odom is None:
        raise ValueError(f"odometry_increments: {log.source} holds neither odometry poses nor ODOM lines")
    missing = ~np.isfinite(log.last_odom[1:]).all(axis=1)
    if missing.any():
        k = int(np.argmax(missing)) + 1
        raise ValueError(f"odometry_increments: {log.source}: no ODOM line before scan {k}")
    if n > 1:
        u[1:] = relative(log.poses[:-1], log.last_odom[1:])
    if log.first_odom is not None and np.isfinite(log.last_odom[0]).all():
        u[0] = relative(log.first_odom, log.last_odom[0])
    return u


# --------------------------------------------------------------------------- Intel JSON, relations


def read_intel_json(path, *, kind: str | None = None, no_return: float = DEFAULT_NO_RETURN) -> LaserLog:
    """Read ``intel_gfs.json.gz`` or ``intel_corrected_log.json.gz`` (910 Intel scans).

    Structure: ``{"map": {"<Unix time>": {"range": [180 floats], "x", "y", "theta"}, …}}``,
    read in key order.

    Parameters
    ----------
    path : str or Path
        ``.json`` or ``.json.gz``.
    kind : {"odometry", "corrected"}, optional
        What the poses are. ``"odometry"`` (``intel_gfs``): raw wheel odometry,
        stored as both :attr:`~LaserLog.poses` and :attr:`~LaserLog.odometry`.
        ``"corrected"`` (``intel_corrected_log``): GMapping's poses, odometry None.
        Default: guessed from the file name (``gfs`` → odometry, ``corrected`` → corrected).
    no_return : float
        Readings ``≥`` this [m] become ``np.nan`` (the file writes 81.83 m).

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        Naming the file: a damaged ``.gz`` (not gzip, truncated, corrupt data),
        text that is not UTF-8 or not JSON, a malformed scan entry.
    """
    path = Path(path)
    if kind is None:
        name = path.name.lower()
        kind = "corrected" if "corrected" in name else "odometry" if "gfs" in name else None
        if kind is None:
            raise ValueError(f"read_intel_json: {path}: cannot tell the pose kind from the name; pass kind=")
    if kind not in ("odometry", "corrected"):
        raise ValueError(f"read_intel_json: kind must be 'odometry' or 'corrected', got {kind!r}")
    text = "".join(line for _, line in _text_lines(path, encoding="utf-8", errors="strict"))  # JSON is UTF-8
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({one_line_message(exc)}); {REFETCH_HINT}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("map"), dict) or not doc["map"]:
        raise ValueError(f"{path}: expected a JSON object {{'map': {{time: scan, …}}}} with at least one scan")
    t, ranges, poses = [], [], []
    for key, scan in doc["map"].items():
        try:
            t.append(float(key))
            ranges.append([float(v) for v in scan["range"]])
            poses.append([float(scan["x"]), float(scan["y"]), float(scan["theta"])])
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{path}: scan {key!r}: malformed entry ({exc!r})") from None
    lengths = {len(r) for r in ranges}
    if len(lengths) != 1:
        raise ValueError(f"{path}: scans have different numbers of beams {sorted(lengths)}")
    poses = np.array(poses)
    if not np.isfinite(poses).all():
        i = int(np.argwhere(~np.isfinite(poses))[0, 0])
        raise ValueError(f"{path}: scan {list(doc['map'])[i]!r}: non-finite pose {poses[i].tolist()}")
    ranges = np.array(ranges)
    ranges[~(np.isfinite(ranges) & (ranges > 0) & (ranges < no_return))] = np.nan
    return LaserLog(
        t=np.array(t), ranges=ranges, angles=carmen_angles(ranges.shape[1]), poses=poses,
        odometry=poses.copy() if kind == "odometry" else None, source=str(path), max_range=float(no_return),
    )


RELATION_COLUMNS = ["t1", "t2", "x", "y", "z", "roll", "pitch", "yaw"]


def read_relations(path) -> pd.DataFrame:
    """Read a Kümmerle et al. (2009) relations file.

    Each line: ``t1 t2 x y z roll pitch yaw`` — the pose of the robot at time
    ``t2`` in the frame of the robot at ``t1`` [s, m, rad].

    Returns
    -------
    pandas.DataFrame
        Columns ``t1, t2, x, y, z, roll, pitch, yaw`` (float), one row per line.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        Naming file and line, for a line without 8 numbers or with a non-finite
        one; naming the file, for a file with no relation or a damaged ``.gz``.
    """
    path = Path(path)
    rows = []
    for lineno, line in _text_lines(path):
        tok = line.split()
        if not tok or tok[0].startswith("#"):
            continue
        if len(tok) != 8:
            raise ValueError(f"{path}:{lineno}: expected 8 fields (t1 t2 x y z roll pitch yaw), got {len(tok)}")
        vals = _floats(tok, path, lineno, "relation")
        if not np.isfinite(vals).all():
            raise ValueError(f"{path}:{lineno}: non-finite value in relation {vals.tolist()}")
        rows.append(vals)
    if not rows:
        raise ValueError(f"{path}: no relation (expected lines 't1 t2 x y z roll pitch yaw')")
    return pd.DataFrame(np.array(rows).reshape(-1, 8), columns=RELATION_COLUMNS)
