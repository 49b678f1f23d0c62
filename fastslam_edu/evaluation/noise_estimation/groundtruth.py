"""Groundtruth fit to measure noise against: heading glitches removed, gaps not interpolated over.

Groundtruth hygiene (why some data are skipped)
-----------------------------------------------
* Measurements outside the groundtruth time span, or inside a groundtruth gap
  longer than ``max_gap`` seconds (a Vicon dropout), are skipped and counted.
* The 1 Hz groundtruth of Dataset 1 was made by averaging headings
  arithmetically, so a second in which the robot crossed θ = ±π averages
  ``+3.1`` and ``−3.1`` to some value near 0: a *heading glitch*.
  :func:`heading_glitches` finds them and they are removed before
  interpolating (which opens a 2 s gap: the measurements there are skipped).
* :func:`~fastslam_edu.evaluation.noise_estimation.measurement.landmark_check` compares where the
  measurements put each landmark with its surveyed position: a subject whose median offset is metres, not
  centimetres, has wrong groundtruth (in the Dataset 1 files, subjects 11 and
  17 are swapped) and would otherwise count as thousands of "outliers".
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.motion import dead_reckon_at
from fastslam_edu.datasets.log import RobotLog

__all__ = ["MAX_GAP", "GLITCH_THRESHOLD", "heading_glitches", "usable_groundtruth", "covered_by_groundtruth",
           "checked_max_gap"]

#: Default largest groundtruth gap [s] to interpolate over (1 Hz data have 1 s gaps; a removed glitch makes 2 s).
MAX_GAP = 1.5

#: Default heading glitch threshold [rad] (good 1 Hz rows disagree with their neighbours by < 0.2 rad).
GLITCH_THRESHOLD = 0.5


def heading_glitches(time, theta, odometry: pd.DataFrame | None = None, threshold: float = GLITCH_THRESHOLD,
                     half_window: int = 3) -> np.ndarray:
    """Rows of a groundtruth whose heading jumps away from its neighbours and back.

    Each row's heading is compared with the odometry's: the offset
    ``o_i = θ_i − θ_odo(t_i)`` (θ_odo: the dead-reckoned heading,
    :func:`~fastslam_edu.core.motion.dead_reckon_at`) drifts slowly, because the odometry follows every
    turn. Row ``i`` is a glitch if the median, over its ``2·half_window``
    neighbours ``j``, of ``wrap(o_j − o_i)`` exceeds ``threshold``: its
    heading disagrees with most of its neighbours' once the turning is
    accounted for. The median ignores up to ``half_window − 1`` glitches among
    the neighbours, so a glitch does not condemn its good neighbours.

    Parameters
    ----------
    time : array_like, shape (T,)
        Row times [s], non-decreasing.
    theta : array_like, shape (T,)
        Headings [rad].
    odometry : DataFrame, optional
        Columns ``time, v, omega``. Without it ``θ_odo = 0``: only right if the
        heading changes little between neighbouring rows.
    threshold : float
        [rad], > 0. Good rows of MR.CLAM's 1 Hz groundtruth disagree by < 0.2 rad.
    half_window : int
        Neighbours on each side, ≥ 1.

    Returns
    -------
    ndarray of bool, shape (T,)
        True for the glitch rows.
    """
    t = np.asarray(time, dtype=float)
    th = np.asarray(theta, dtype=float)
    if t.ndim != 1 or th.shape != t.shape or t.size < 2:
        raise ValueError(f"heading_glitches: time and theta must be 1-D of the same length ≥ 2, got {t.shape}, {th.shape}")
    if not (np.isfinite(t).all() and np.isfinite(th).all()):
        raise ValueError("heading_glitches: time or theta contains NaN or inf")
    if not (np.isfinite(threshold) and threshold > 0):
        raise ValueError(f"heading_glitches: threshold must be > 0 rad, got {threshold!r}")
    if int(half_window) != half_window or half_window < 1:
        raise ValueError(f"heading_glitches: half_window must be an integer ≥ 1, got {half_window!r}")
    h = int(half_window)
    offset = th - (dead_reckon_at(odometry, t)[:, 2] if odometry is not None else 0.0)
    padded = np.concatenate([np.full(h, np.nan), offset, np.full(h, np.nan)])
    around = np.lib.stride_tricks.sliding_window_view(padded, 2 * h + 1)  # (T, 2h+1), row i centred on i
    neighbours = np.delete(around, h, axis=1)
    rel = wrap_angle(neighbours - offset[:, None])  # NaN stays NaN
    rel = np.where(np.isnan(neighbours), np.nan, rel)
    # every row has ≥ 1 neighbour (T ≥ 2), so no slice is all-NaN
    return np.abs(np.nanmedian(rel, axis=1)) > threshold


def usable_groundtruth(log: RobotLog, glitch_threshold: float = GLITCH_THRESHOLD) -> pd.DataFrame:
    """The robot's groundtruth, checked, with heading glitches removed.

    Parameters
    ----------
    log : RobotLog
        Must have groundtruth (columns ``time, x, y, theta``).
    glitch_threshold : float
        See :func:`heading_glitches` (checked against the log's odometry).

    Returns
    -------
    DataFrame
        Columns ``time, x, y, theta``, times strictly increasing (repeated
        times keep their first row); ``attrs["glitches"]`` = number of rows removed
        as heading glitches, ``attrs["rate"]`` copied from the log.

    Raises
    ------
    ValueError
        If the log has no groundtruth, fewer than 2 rows, NaN/inf, or time going backwards.
    """
    if not isinstance(log, RobotLog):
        raise ValueError(f"expected a RobotLog, got {type(log).__name__}")
    gt = log.groundtruth
    where = f"robot {log.robot} ({log.source or 'no source'})"
    if gt is None:
        raise ValueError(f"{where} has no groundtruth: noise cannot be estimated without it")
    missing = [c for c in ("time", "x", "y", "theta") if c not in gt.columns]
    if missing:
        raise ValueError(f"{where}: groundtruth is missing columns {missing}")
    values = gt[["time", "x", "y", "theta"]].to_numpy(dtype=float)
    if values.shape[0] < 2:
        raise ValueError(f"{where}: groundtruth needs at least 2 rows, has {values.shape[0]}")
    bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
    if bad.size:
        raise ValueError(f"{where}: groundtruth row {int(bad[0])} has NaN or inf: {values[bad[0]].tolist()}")
    step = np.diff(values[:, 0])
    if (step < 0).any():
        raise ValueError(f"{where}: groundtruth time goes backwards at row {int(np.flatnonzero(step < 0)[0]) + 1}")
    values = values[np.concatenate([[True], step > 0])]
    odometry = log.odometry if log.odometry is not None and len(log.odometry) else None
    glitch = heading_glitches(values[:, 0], values[:, 3], odometry, glitch_threshold)
    out = pd.DataFrame(values[~glitch], columns=["time", "x", "y", "theta"])
    out.attrs.update(glitches=int(glitch.sum()), rate=gt.attrs.get("rate", "unknown"))
    return out


def covered_by_groundtruth(t_gt: np.ndarray, t: np.ndarray, max_gap: float) -> np.ndarray:
    """Which of the times ``t`` (bool, shape of ``t``) lie inside the groundtruth span and not inside a gap longer than ``max_gap``."""
    inside = (t >= t_gt[0]) & (t <= t_gt[-1])
    i = np.clip(np.searchsorted(t_gt, t, side="right") - 1, 0, t_gt.size - 2)
    on_row = t == t_gt[i]
    short = (t_gt[i + 1] - t_gt[i]) <= max_gap
    return inside & (on_row | short)


def checked_max_gap(max_gap: float) -> float:
    """``max_gap`` [s] as a float, or a ValueError if it is not a positive number."""
    if not (isinstance(max_gap, (int, float, np.integer, np.floating)) and np.isfinite(max_gap) and max_gap > 0):
        raise ValueError(f"max_gap must be a positive number of seconds, got {max_gap!r}")
    return float(max_gap)
