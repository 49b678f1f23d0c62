"""The relation error of Kümmerle et al. (2009): SLAM accuracy from relative poses.

A SLAM estimate lives in a frame of its own choosing, so comparing absolute
poses needs an alignment, and one wrong loop closure far away spoils every
pose after it. Kümmerle et al. ("On measuring the accuracy of SLAM
algorithms", *Autonomous Robots* 27(4), 2009) measure instead the error of
**relations**: for a pair of times ``(t_1, t_2)`` a reference relative pose
``δ*_{12}`` (from manually checked scan alignments) is compared with the
estimate's relative pose ``δ_{12} = x_{t_1}⁻¹ ⊕ x_{t_2}``::

    e_{12} = δ*_{12}⁻¹ ⊕ δ_{12},
    translational error  ‖(e_x, e_y)‖ = ‖t_{12} − t*_{12}‖      [m]
    rotational error     |e_θ| = |wrap(θ_{12} − θ*_{12})|          [rad → deg]

(the translational norm does not depend on the frame the difference is
written in). The paper reports the mean and standard deviation of these
absolute errors over all relations of a dataset (e.g. GMapping on the Intel
lab: 0.070 ± 0.083 m translational).

Matching times
--------------
The relations use the logger time stamps of the original ``.clf`` logs; an
estimate has a pose per *scan*. Each relation time is matched to the scan
with the nearest time stamp, and a relation is **usable** only when both of
its times are within ``tolerance`` of a scan and they match two different
scans. The Intel JSON files carry the original ``intel.clf`` time stamps of
their 910 scans (6 decimals, as the relations), so a tolerance of 1 ms picks
the relations whose both ends are among those scans exactly; a looser
tolerance would pair a relation with a pose taken at another time.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from fastslam_edu.core.se2 import align_se2, apply_se2
from fastslam_edu.core.se2 import relative

__all__ = ["DEFAULT_TOLERANCE", "match_times", "relation_errors", "reference_errors", "score_trajectory"]

#: Default largest gap [s] between a relation's time stamp and the matched scan's.
DEFAULT_TOLERANCE = 1e-3


def match_times(t_query, t_scans, tolerance: float = DEFAULT_TOLERANCE) -> tuple[np.ndarray, np.ndarray]:
    """Index of the scan nearest in time to each query time, and whether it is within ``tolerance``.

    Parameters
    ----------
    t_query : array_like, shape (n,)
        Times to match [s].
    t_scans : array_like, shape (N,)
        Scan times [s], in any order (logs printed with few digits repeat or
        reverse a time stamp now and then).
    tolerance : float
        Largest accepted ``|t_scan − t_query|`` [s].

    Returns
    -------
    index : ndarray of int, shape (n,)
        Nearest scan (on a tie, the one with the earlier time stamp; among equal
        time stamps, the first in the file).
    ok : ndarray of bool, shape (n,)
        ``|t_scans[index] − t_query| ≤ tolerance``.
    """
    tq = np.asarray(t_query, dtype=float)
    ts = np.asarray(t_scans, dtype=float)
    if ts.ndim != 1 or ts.size == 0 or tq.ndim != 1:
        raise ValueError(f"match_times: t_query and t_scans must be 1-D (t_scans non-empty), got {tq.shape}, {ts.shape}")
    if not (np.isfinite(ts).all() and np.isfinite(tq).all()):
        raise ValueError("match_times: times contain NaN or inf")
    if not (np.isfinite(tolerance) and tolerance >= 0):
        raise ValueError(f"match_times: tolerance must be ≥ 0, got {tolerance}")
    order = np.argsort(ts, kind="stable")
    srt = ts[order]
    if srt.size == 1:
        pos = np.zeros(tq.shape, dtype=np.int64)
    else:
        j = np.clip(np.searchsorted(srt, tq), 1, srt.size - 1)
        earlier = np.abs(srt[j - 1] - tq) <= np.abs(srt[j] - tq)
        pos = np.where(earlier, j - 1, j)
        # among equal time stamps, searchsorted may land on a later copy: step back to the first
        pos = np.searchsorted(srt, srt[pos], side="left")
    idx = order[pos].astype(np.int64)
    return idx, np.abs(ts[idx] - tq) <= tolerance


def relation_errors(t, poses, relations: pd.DataFrame, *, tolerance: float = DEFAULT_TOLERANCE) -> dict:
    """Kümmerle et al.'s relation errors of an estimated trajectory.

    Parameters
    ----------
    t : array_like, shape (N,)
        Scan times [s] (same time base as the relations).
    poses : array_like, shape (N, 3)
        Estimated pose ``(x, y, θ)`` of each scan.
    relations : pandas.DataFrame
        Columns ``t1, t2, x, y, yaw`` (as read by
        :func:`fastslam_edu.datasets.laser.read_relations`): pose at ``t2``
        in the frame of the pose at ``t1``.
    tolerance : float
        See :func:`match_times`.

    Returns
    -------
    dict
        ``n_relations`` (rows in the file), ``n_used``; ``used`` (bool per row),
        ``index1``, ``index2`` (matched scans of the used rows);
        ``trans_errors`` [m] and ``rot_errors_deg`` [deg] per used relation;
        ``trans_mean``, ``trans_std`` [m], ``rot_mean_deg``, ``rot_std_deg`` [deg]
        (NaN when no relation is usable); ``tolerance``.
    """
    p = np.asarray(poses, dtype=float)
    ts = np.asarray(t, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or ts.shape != (p.shape[0],):
        raise ValueError(f"relation_errors: t must be (N,) and poses (N, 3), got {ts.shape} and {p.shape}")
    if not np.isfinite(p).all():
        raise ValueError("relation_errors: poses contain NaN or inf")
    missing = [c for c in ("t1", "t2", "x", "y", "yaw") if c not in relations.columns]
    if missing:
        raise ValueError(f"relation_errors: relations lack column(s) {missing} (read them with read_relations)")
    i1, ok1 = match_times(relations["t1"].to_numpy(float), ts, tolerance)
    i2, ok2 = match_times(relations["t2"].to_numpy(float), ts, tolerance)
    used = ok1 & ok2 & (i1 != i2)
    ref = relations[["x", "y", "yaw"]].to_numpy(float)[used]
    est = relative(p[i1[used]], p[i2[used]])
    err = relative(ref, est) if used.any() else np.zeros((0, 3))
    trans = np.hypot(err[:, 0], err[:, 1])
    rot = np.degrees(np.abs(err[:, 2]))

    def stat(f, a):
        return float(f(a)) if a.size else float("nan")

    return {
        "n_relations": int(len(relations)),
        "n_used": int(used.sum()),
        "used": used,
        "index1": i1[used],
        "index2": i2[used],
        "trans_errors": trans,
        "rot_errors_deg": rot,
        "trans_mean": stat(np.mean, trans),
        "trans_std": stat(np.std, trans),
        "rot_mean_deg": stat(np.mean, rot),
        "rot_std_deg": stat(np.std, rot),
        "tolerance": float(tolerance),
    }


def reference_errors(t, poses, t_ref, poses_ref, *, tolerance: float = DEFAULT_TOLERANCE) -> dict:
    """Position errors against a reference trajectory (e.g. GMapping's poses) after SE(2) alignment.

    Each estimated pose is paired with the reference pose of the nearest time
    stamp (within ``tolerance``, :func:`match_times`), or by index when the
    estimate's time stamps are the first ones of the reference (one log
    holding scans and reference poses, possibly cut short); the estimated positions
    are moved by the rigid motion that best fits them onto the reference
    (:func:`fastslam_edu.core.se2.align_se2`, least squares), and

    ``e_j = ‖R p̂_j + t − p_j‖``, ``rmse = √(mean e_j²)``.

    Parameters
    ----------
    t, poses : array_like, shapes (N,), (N, 3)
        The estimate.
    t_ref, poses_ref : array_like, shapes (T,), (T, 3)
        The reference (same time base).
    tolerance : float
        [s].

    Returns
    -------
    dict
        ``n_matched``, ``errors`` (n_matched,) [m], ``rmse``, ``mean``, ``max`` [m],
        ``rotation_deg`` of the alignment, ``matched`` (bool per estimated pose).
    """
    p = np.asarray(poses, dtype=float)
    q = np.asarray(poses_ref, dtype=float)
    ts = np.asarray(t, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or ts.shape != (p.shape[0],):
        raise ValueError(f"reference_errors: t must be (N,) and poses (N, 3), got {ts.shape} and {p.shape}")
    if q.ndim != 2 or q.shape[1] != 3 or np.shape(t_ref) != (q.shape[0],):
        raise ValueError(f"reference_errors: t_ref must be (T,) and poses_ref (T, 3), got {np.shape(t_ref)} and {q.shape}")
    if not (np.isfinite(p).all() and np.isfinite(q).all()):
        raise ValueError("reference_errors: poses contain NaN or inf")
    tr = np.asarray(t_ref, dtype=float)
    if tr.size >= ts.size and np.array_equal(tr[: ts.size], ts):  # the same scans (one log, or its first N): by index
        idx, ok = np.arange(ts.size), np.ones(ts.size, dtype=bool)
    else:
        idx, ok = match_times(ts, tr, tolerance)
    if ok.sum() < 2:
        raise ValueError(
            f"reference_errors: only {int(ok.sum())} of {ts.size} scan times match a reference time within "
            f"{tolerance} s; are both in the same time base?"
        )
    est, ref = p[ok, :2], q[idx[ok], :2]
    R, shift, angle = align_se2(est, ref)
    e = np.linalg.norm(apply_se2(est, R, shift) - ref, axis=1)
    return {
        "n_matched": int(ok.sum()),
        "errors": e,
        "rmse": float(np.sqrt(np.mean(e * e))),
        "mean": float(e.mean()),
        "max": float(e.max()),
        "rotation_deg": float(np.degrees(angle)),
        "matched": ok,
    }


def _number(x):
    """A plain int or float for JSON, NaN as None."""
    return None if isinstance(x, float) and math.isnan(x) else x


def score_trajectory(t, poses, *, relations: pd.DataFrame | None = None, reference=None,
                     tolerance: float = DEFAULT_TOLERANCE) -> dict:
    """The figures of one estimated trajectory: its relation error and its error against a reference path.

    :func:`relation_errors` against ``relations`` and :func:`reference_errors`
    against ``reference``, each summed up in a few plain numbers (what the
    command line writes to its JSON, and the tables of the grid SLAM chapter
    and benchmark show).

    Parameters
    ----------
    t, poses : array_like, shapes (N,), (N, 3)
        The estimate.
    relations : pandas.DataFrame or None
        Relations as read by :func:`fastslam_edu.datasets.laser.read_relations`.
    reference : (t_ref, poses_ref) or None
        A reference trajectory, shapes (T,), (T, 3), in the same time base (e.g. GMapping's poses).
    tolerance : float
        Time matching tolerance [s] of both (:func:`match_times`).

    Returns
    -------
    dict
        ``"reference"``: ``n_matched``, ``rmse_m``, ``mean_m``, ``max_m`` (None without a reference);
        ``"relations"``: ``n_relations``, ``n_used``, ``trans_mean_m``, ``trans_std_m``, ``rot_mean_deg``,
        ``rot_std_deg``, the last four None when no relation is usable (None without relations).
    """
    scores: dict = {"reference": None, "relations": None}
    if reference is not None:
        t_ref, poses_ref = reference
        e = reference_errors(t, poses, t_ref, poses_ref, tolerance=tolerance)
        scores["reference"] = {"n_matched": e["n_matched"], "rmse_m": e["rmse"], "mean_m": e["mean"], "max_m": e["max"]}
    if relations is not None:
        e = relation_errors(t, poses, relations, tolerance=tolerance)
        names = {"n_relations": "n_relations", "n_used": "n_used", "trans_mean": "trans_mean_m",
                 "trans_std": "trans_std_m", "rot_mean_deg": "rot_mean_deg", "rot_std_deg": "rot_std_deg"}
        scores["relations"] = {new: _number(e[old]) for old, new in names.items()}
    return scores
