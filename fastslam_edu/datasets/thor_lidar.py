"""Reader and writer of the THOR humanoid's MATLAB files: LiDAR scans and joint angles (both variants that circulate).

Every array is in the package's conventions: times in seconds, poses ``(x, y, θ)`` [m, m, rad], beam angles
[rad] in the sensor frame (0 straight ahead, positive to the left, :func:`thor_angles`), ranges [m] as stored
(:meth:`ThorLidar.valid` keeps 0.1–30 m). The 2D laser logs of wheeled robots (CARMEN, Intel JSON) are read by
:mod:`fastslam_edu.datasets.laser`.

* :func:`read_thor_lidar` — ``train_lidar*.mat`` as a :class:`ThorLidar`;
* :func:`read_thor_joints` — ``train_joint*.mat``, the head and neck angles;
* :func:`write_thor_lidar` — the same files written back (the simulated THOR writes its sequences with it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.io

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.datasets.laser import REFETCH_HINT, one_line_message

__all__ = ["ThorLidar", "read_thor_lidar", "read_thor_joints", "write_thor_lidar", "thor_angles"]


def thor_angles(n: int = 1081) -> np.ndarray:
    """THOR's Hokuyo UTM-30LX beam angles: −135° … +135° in steps of 0.25° (``n`` = 1081)."""
    return np.radians(-135.0 + 0.25 * np.arange(n))


@dataclass
class ThorLidar:
    """A THOR LiDAR log (one row per scan), as read from ``train_lidar*.mat``.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Unix times [s].
    ranges : ndarray, shape (N, 1081)
        Ranges [m] **as stored** (not filtered: keep 0.1–30 m before mapping,
        see :meth:`valid`).
    angles : ndarray, shape (1081,)
        −135° … +135° in 0.25° steps [rad] (:func:`thor_angles`).
    pose : ndarray (N, 3) or None
        Variant 1 (Penn 2018): odometry ``(x, y, yaw)`` [m, m, rad] as stored
        (public loaders subtract the first yaw).
    delta_pose : ndarray (N, 3) or None
        Variant 2 (UCSD 2020), or variant 1 when present: ``(dx, dy, dyaw)``
        since the previous scan, in the world frame.
    rpy : ndarray (N, 3) or None
        Variant 1: body roll, pitch, yaw from the IMU [rad].
    res : float or None
        Variant 1: angular resolution stored in the file [rad].
    variant : int
        1 or 2.
    source : str
    min_range, max_range : float
        Valid range interval of the sensor [m] (0.1, 30).
    """

    t: np.ndarray
    ranges: np.ndarray
    angles: np.ndarray
    pose: np.ndarray | None
    delta_pose: np.ndarray | None
    rpy: np.ndarray | None
    res: float | None
    variant: int
    source: str = ""
    min_range: float = 0.1
    max_range: float = 30.0

    def __len__(self) -> int:
        return len(self.t)

    def valid(self) -> np.ndarray:
        """Mask (N, B) of readings inside ``[min_range, max_range]``."""
        r = self.ranges
        return np.isfinite(r) & (r >= self.min_range) & (r <= self.max_range)

    def odometry_poses(self) -> np.ndarray:
        """Odometry pose per scan ``(x, y, yaw)``, (N, 3).

        Variant 1: :attr:`pose` (yaw wrapped). Variant 2: the running sum of the
        world-frame ``delta_pose`` from ``(0, 0, 0)``: ``x_k = Σ_{j≤k} Δ_j``.
        """
        if self.pose is not None:
            out = self.pose.copy()
        else:
            out = np.cumsum(self.delta_pose, axis=0)
        out[:, 2] = wrap_angle(out[:, 2])
        return out


_THOR_V1_FIELDS = ("t", "pose", "res", "rpy", "scan")


_NOT_NUMERIC = {"c": "complex numbers", "O": "a cell array", "U": "text", "S": "text", "V": "a struct"}


def _numeric(value, what: str, where: str) -> np.ndarray:
    """A MAT variable or struct field as a float array; a ValueError naming it if it holds no real numbers."""
    a = np.asarray(value)
    if a.dtype.kind not in "biuf":
        raise ValueError(f"{where}: {what} must be numeric, got {_NOT_NUMERIC.get(a.dtype.kind, a.dtype)}")
    return a.astype(float)


def _loadmat(path: Path) -> dict:
    """``scipy.io.loadmat(path)``; FileNotFoundError if missing, a one-line ValueError if unreadable."""
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        return scipy.io.loadmat(path)
    except Exception as exc:  # scipy raises ValueError, TypeError, OSError, … for damaged files
        raise ValueError(
            f"{path}: not a readable MATLAB .mat file, truncated or damaged ({one_line_message(exc)}); {REFETCH_HINT}"
        ) from None


def _row(value, n: int | None, what: str, where: str) -> np.ndarray:
    a = _numeric(value, f"field {what!r}", where).ravel()
    if n is not None and a.size != n:
        raise ValueError(f"{where}: field {what!r} has {a.size} values, expected {n}")
    return a


def _thor_struct_fields(cells, i: int, where: str) -> tuple[int, dict]:
    """The variant (1 or 2) of THOR scan struct ``i`` and its fields by name (by position for unnamed variant 1)."""
    try:
        s = cells[0][i][0][0]
        names = s.dtype.names
    except (IndexError, TypeError, AttributeError):
        raise ValueError(f"{where}: not a 1 × 1 struct") from None
    if names is None:
        raise ValueError(f"{where}: not a struct")
    if set(names) == {"t", "scan", "delta_pose"}:
        return 2, {k: s[k] for k in names}
    if set(names) >= set(_THOR_V1_FIELDS):
        return 1, {k: s[k] for k in names}
    if len(names) in (5, 6):  # variant 1 with other field names: by position from the end
        k = len(names)
        get = {"t": s[0], "pose": s[k - 4], "res": s[k - 3], "rpy": s[k - 2], "scan": s[k - 1]}
        if k == 6:
            get["delta_pose"] = s[1]
        return 1, get
    raise ValueError(
        f"{where}: unknown struct fields {names} (expected t, [delta_pose,] pose, res, rpy, scan "
        "or t, scan, delta_pose)"
    )


def read_thor_lidar(path) -> ThorLidar:
    """Read a THOR LiDAR ``.mat`` file (either variant of the THOR README).

    Layout: ``loadmat(path)['lidar']`` is a 1 × N cell array whose element
    ``i`` holds a 1 × 1 struct ``s = d['lidar'][0][i][0][0]``.

    * Variant 1 (Penn ESE 650, 2018): fields ``t``, optionally ``delta_pose``,
      ``pose`` (1×3), ``res``, ``rpy`` (1×3), ``scan`` (1×1081). When the field
      names are not these, the fields are read by position from the end, as
      the public loaders do (``pose`` = n−4, ``res`` = n−3, ``rpy`` = n−2, ``scan`` = n−1).
    * Variant 2 (UCSD ECE 276A, 2020): fields ``t``, ``scan``, ``delta_pose`` (1×3).

    Raises
    ------
    FileNotFoundError, ValueError
        Missing file; a file scipy cannot read (truncated, not a MAT file); no
        ``lidar`` variable; a struct with unexpected or non-numeric fields or
        sizes (naming the scan index); scans of different lengths.
    """
    path = Path(path)
    d = _loadmat(path)
    if "lidar" not in d:
        raise ValueError(f"{path}: no variable 'lidar' (found {sorted(k for k in d if not k.startswith('__'))})")
    cells = d["lidar"]
    if cells.dtype != object or cells.ndim != 2 or cells.shape[0] != 1 or cells.shape[1] == 0:
        raise ValueError(f"{path}: 'lidar' must be a non-empty 1 × N cell array, got {cells.dtype} {cells.shape}")
    t, scans, pose, dpose, rpy, res = [], [], [], [], [], []
    variant = None
    for i in range(cells.shape[1]):
        where = f"{path}: lidar{{{i + 1}}}"
        v, get = _thor_struct_fields(cells, i, where)
        if variant is None:
            variant = v
        elif v != variant:
            raise ValueError(f"{where}: variant-{v} struct in a variant-{variant} file")
        t.append(_row(get["t"], 1, "t", where)[0])
        scan = _row(get["scan"], None, "scan", where)
        if scans and scan.size != scans[0].size:
            raise ValueError(f"{where}: scan has {scan.size} ranges, earlier scans {scans[0].size}")
        scans.append(scan)
        if v == 1:
            pose.append(_row(get["pose"], 3, "pose", where))
            res.append(_row(get["res"], 1, "res", where)[0])
            rpy.append(_row(get["rpy"], 3, "rpy", where))
        if "delta_pose" in get:
            dpose.append(_row(get["delta_pose"], 3, "delta_pose", where))
    t = np.array(t)
    for name, arr in [("t", t), ("pose", pose), ("delta_pose", dpose)]:
        if len(arr) and not np.isfinite(np.asarray(arr)).all():
            i = int(np.argwhere(~np.isfinite(np.asarray(arr)))[0, 0])
            raise ValueError(f"{path}: lidar{{{i + 1}}}: non-finite {name}")
    if dpose and len(dpose) != len(t):
        raise ValueError(f"{path}: delta_pose present in only {len(dpose)} of {len(t)} scans")
    ranges = np.array(scans)
    return ThorLidar(
        t=t, ranges=ranges, angles=thor_angles(ranges.shape[1]),
        pose=np.array(pose) if pose else None, delta_pose=np.array(dpose) if dpose else None,
        rpy=np.array(rpy) if rpy else None, res=float(res[0]) if res else None, variant=variant, source=str(path),
    )


def read_thor_joints(path):
    """Read a THOR joint file: times and the two head joints.

    Keys used: ``ts`` (1, n) Unix time [s] and ``head_angles`` (2, n) [rad],
    row 0 = neck (yaw), row 1 = head (pitch). Angles are returned as stored
    (some public code negates them; the THOR README's geometry uses them as stored).

    Returns
    -------
    t, neck, head : ndarray, shape (n,) each

    Raises
    ------
    FileNotFoundError, ValueError
        Missing file; a file scipy cannot read (truncated, not a MAT file); a
        missing, empty, non-numeric or mis-shaped ``ts`` / ``head_angles``.
    """
    path = Path(path)
    d = _loadmat(path)
    for key in ("ts", "head_angles"):
        if key not in d:
            raise ValueError(f"{path}: no variable {key!r} (found {sorted(k for k in d if not k.startswith('__'))})")
    t = _numeric(d["ts"], "'ts'", str(path)).ravel()
    h = _numeric(d["head_angles"], "'head_angles'", str(path))
    if t.size == 0:
        raise ValueError(f"{path}: 'ts' is empty (no joint sample)")
    if h.ndim != 2 or h.shape != (2, t.size):
        raise ValueError(f"{path}: head_angles must be (2, {t.size}) like ts, got {h.shape}")
    if not (np.isfinite(t).all() and np.isfinite(h).all()):
        raise ValueError(f"{path}: non-finite values in ts or head_angles")
    return t, h[0].copy(), h[1].copy()


def write_thor_lidar(
    path, t, scans, pose=None, delta_pose=None, rpy=None, *, variant: int = 1, res: float | None = None
) -> None:
    """Write a THOR LiDAR ``.mat`` file in the exact layout of :func:`read_thor_lidar`.

    ``lidar`` is saved as a 1 × N cell array (an object array of dicts: scipy
    writes each dict as a 1 × 1 struct, fields in insertion order), so that
    ``loadmat(path)['lidar'][0][i][0][0]`` is the struct of scan ``i``.

    Variant 1 fields: ``t``, [``delta_pose`` if given], ``pose``, ``res``,
    ``rpy``, ``scan`` (``pose`` required; ``rpy`` zeros and ``res`` 0.25° if not
    given). Variant 2 fields: ``t``, ``scan``, ``delta_pose`` (required).

    Parameters
    ----------
    path : str or Path
    t : array_like, shape (N,)
    scans : array_like, shape (N, B)
    pose, delta_pose, rpy : array_like, shape (N, 3), optional
    variant : {1, 2}
    res : float, optional
        Angular resolution [rad] for variant 1.
    """
    t = np.asarray(t, dtype=float).ravel()
    scans = np.asarray(scans, dtype=float)
    n = t.size
    if scans.ndim != 2 or scans.shape[0] != n:
        raise ValueError(f"write_thor_lidar: scans must be (N, B) with N = len(t) = {n}, got {scans.shape}")

    def triple(name, a, required):
        if a is None:
            if required:
                raise ValueError(f"write_thor_lidar: variant {variant} needs {name}")
            return None
        a = np.asarray(a, dtype=float)
        if a.shape != (n, 3):
            raise ValueError(f"write_thor_lidar: {name} must be ({n}, 3), got {a.shape}")
        return a

    if variant == 1:
        pose = triple("pose", pose, True)
        delta_pose = triple("delta_pose", delta_pose, False)
        rpy = triple("rpy", rpy, False)
        rpy = np.zeros((n, 3)) if rpy is None else rpy
        res = math.radians(0.25) if res is None else float(res)
    elif variant == 2:
        delta_pose = triple("delta_pose", delta_pose, True)
    else:
        raise ValueError(f"write_thor_lidar: variant must be 1 or 2, got {variant}")
    cells = np.empty((1, n), dtype=object)
    for i in range(n):
        s = {"t": np.array([[t[i]]])}
        if variant == 1:
            if delta_pose is not None:
                s["delta_pose"] = delta_pose[i][None, :]
            s["pose"] = pose[i][None, :]
            s["res"] = np.array([[res]])
            s["rpy"] = rpy[i][None, :]
            s["scan"] = scans[i][None, :]
        else:
            s["scan"] = scans[i][None, :]
            s["delta_pose"] = delta_pose[i][None, :]
        cells[0, i] = s
    scipy.io.savemat(Path(path), {"lidar": cells})
