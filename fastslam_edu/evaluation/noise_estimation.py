"""Estimating the filter's noise parameters from a log with groundtruth.

FastSLAM needs two noise models: the measurement covariance
``R = diag(σ_r², σ_φ²)`` of the range–bearing sensor, and the motion noise
densities ``σ_v`` [m/√s], ``σ_ω`` [rad/√s] of the odometry
(:class:`~fastslam_edu.core.motion.MotionNoise`, control mode). With groundtruth
(Vicon poses and surveyed landmarks) both can be *measured* instead of guessed.
This module writes down how the package's defaults are obtained.

Measurement noise (:func:`measurement_residuals`, :func:`measurement_noise`)
--------------------------------------------------------------------------
1. For every landmark measurement ``z_j = (r_j, φ_j)`` of subject ``s_j`` at
   time ``t_j``, take the groundtruth pose ``x(t_j)`` interpolated linearly
   (heading unwrapped first, :func:`fastslam_edu.core.se2.interpolate_poses`)
   and the surveyed landmark ``m_{s_j}``; predict ``ẑ_j = h(x(t_j), m_{s_j})``
   (:func:`fastslam_edu.core.measurement.range_bearing`).
2. Residual ``e_j = (r_j − r̂_j, wrap(φ_j − φ̂_j))``.
3. Robust spread: ``σ = 1.4826 · median_j |e_j − median e|`` (the MAD,
   scaled by ``1.4826 = 1/Φ⁻¹(3/4)`` so that it equals the standard deviation
   for Gaussian data, :func:`robust_std`; a few
   per cent of gross outliers barely move it, while they would dominate the
   sample standard deviation). Biases: the median of all residuals and the
   mean of the inliers. Outliers: ``|r_j − r̂_j| > 0.5 m``.

Motion noise (:func:`odometry_increment_errors`, :func:`motion_noise`)
----------------------------------------------------------------------
1. Dead-reckon the odometry with the filter's own model (Euler steps, command
   held until the next row, :func:`fastslam_edu.core.motion.move_segment` with zero
   noise): :func:`dead_reckoning`.
2. Cut time into windows ``[a, a + τ]`` starting at whole seconds. In each,
   compute the increment of the dead-reckoned path and of the groundtruth,
   both expressed in the robot frame at ``a`` (:func:`relative_motion`):
   the forward distance ``Δs`` and the turn ``Δθ``.
3. Errors ``δs = Δs_odo − Δs_gt``, ``δθ = wrap(Δθ_odo − Δθ_gt)``.
4. If the odometry error is a random walk with densities ``σ_v, σ_ω`` (the
   filter's model), then ``Var δs = σ_v² τ`` and ``Var δθ = σ_ω² τ``.
   Groundtruth noise and a small command-to-motion delay add a constant that
   does not grow with ``τ``, so the robust variances at several ``τ`` are fitted
   by ``Var(τ) = c + σ² τ`` (:func:`fit_random_walk`); the slope is the density.
   The fit's residuals, and the ratio ``Var/τ`` per window, show whether the
   random-walk model holds.

Groundtruth hygiene (why some data are skipped)
-----------------------------------------------
* Measurements outside the groundtruth time span, or inside a groundtruth gap
  longer than ``max_gap`` seconds (a Vicon dropout), are skipped and counted.
* The 1 Hz groundtruth of Dataset 1 was made by averaging headings
  arithmetically, so a second in which the robot crossed θ = ±π averages
  ``+3.1`` and ``−3.1`` to some value near 0: a *heading glitch*.
  :func:`heading_glitches` finds them and they are removed before
  interpolating (which opens a 2 s gap: the measurements there are skipped).
* :func:`landmark_check` compares where the measurements put each landmark
  with its surveyed position: a subject whose median offset is metres, not
  centimetres, has wrong groundtruth (in the Dataset 1 files, subjects 11 and
  17 are swapped) and would otherwise count as thousands of "outliers".
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.stats import median_abs_deviation

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.datasets.log import Dataset, RobotLog
from fastslam_edu.core.measurement import landmark_from_measurement, range_bearing
from fastslam_edu.core.se2 import interpolate_poses
from fastslam_edu.core.motion import MotionNoise, dead_reckon

#: Default largest groundtruth gap [s] to interpolate over (1 Hz data have 1 s gaps; a removed glitch makes 2 s).
MAX_GAP = 1.5

#: Default heading glitch threshold [rad] (good 1 Hz rows disagree with their neighbours by < 0.2 rad).
GLITCH_THRESHOLD = 0.5

#: Default range-residual threshold [m] above which a measurement is an outlier.
OUTLIER_THRESHOLD = 0.5

#: Default window lengths τ [s] of the random-walk check.
WINDOWS = (1.0, 2.0, 4.0)

__all__ = [
    "MeasurementNoise",
    "RandomWalkFit",
    "dead_reckoning",
    "estimate_noise",
    "fit_random_walk",
    "fit_range_noise",
    "heading_glitches",
    "increment_variances",
    "landmark_check",
    "measurement_noise",
    "measurement_residuals",
    "motion_noise",
    "odometry_increment_errors",
    "range_noise_profile",
    "relative_motion",
    "robust_std",
    "usable_groundtruth",
]


# --------------------------------------------------------------------------- robust statistics


def robust_std(e) -> float:
    """Robust standard deviation ``σ̂ = 1.4826 · median |e − median e|`` (scaled MAD).

    ``scipy.stats.median_abs_deviation(e, scale="normal")`` (the factor is
    ``1/Φ⁻¹(3/4) = 1.482602…``), after checking that ``e`` is non-empty and
    finite, with an error that says which (SciPy returns NaN for an empty
    input or one with a NaN in it).

    For Gaussian data it estimates the standard deviation (relative standard
    error ≈ 0.78/√n, against 0.71/√n for the sample std); each gross outlier
    moves it by about as much as one ordinary point, not by its size.

    Parameters
    ----------
    e : array_like, shape (n,)
        Finite values, n ≥ 1.

    Returns
    -------
    float
    """
    return float(median_abs_deviation(_finite_1d(e, "robust_std"), scale="normal"))


def _finite_1d(e, caller: str) -> np.ndarray:
    e = np.asarray(e, dtype=float).ravel()
    if e.size == 0:
        raise ValueError(f"{caller}: no values (empty input)")
    if not np.isfinite(e).all():
        raise ValueError(f"{caller}: {int(np.count_nonzero(~np.isfinite(e)))} NaN or inf value(s) in the input")
    return e


# --------------------------------------------------------------------------- groundtruth


def heading_glitches(time, theta, odometry: pd.DataFrame | None = None, threshold: float = GLITCH_THRESHOLD,
                     half_window: int = 3) -> np.ndarray:
    """Rows of a groundtruth whose heading jumps away from its neighbours and back.

    Each row's heading is compared with the odometry's: the offset
    ``o_i = θ_i − θ_odo(t_i)`` (θ_odo: the dead-reckoned heading,
    :func:`dead_reckoning`) drifts slowly, because the odometry follows every
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
    offset = th - (dead_reckoning(odometry, t)[:, 2] if odometry is not None else 0.0)
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


def _covered(t_gt: np.ndarray, t: np.ndarray, max_gap: float) -> np.ndarray:
    """Times inside the groundtruth span and not inside a gap longer than ``max_gap``."""
    inside = (t >= t_gt[0]) & (t <= t_gt[-1])
    i = np.clip(np.searchsorted(t_gt, t, side="right") - 1, 0, t_gt.size - 2)
    on_row = t == t_gt[i]
    short = (t_gt[i + 1] - t_gt[i]) <= max_gap
    return inside & (on_row | short)


def _check_max_gap(max_gap: float) -> float:
    if not (isinstance(max_gap, (int, float, np.integer, np.floating)) and np.isfinite(max_gap) and max_gap > 0):
        raise ValueError(f"max_gap must be a positive number of seconds, got {max_gap!r}")
    return float(max_gap)


# --------------------------------------------------------------------------- measurement noise


def _landmark_table(landmarks, subjects) -> pd.DataFrame:
    """Landmarks as a DataFrame indexed by subject with columns ``x, y``."""
    if isinstance(landmarks, Dataset):
        landmarks = landmarks.landmarks
    if isinstance(landmarks, pd.DataFrame):
        if not {"x", "y"} <= set(landmarks.columns):
            raise ValueError(f"landmarks DataFrame needs columns x, y (index subject), got {list(landmarks.columns)}")
        table = landmarks[["x", "y"]].astype(float)
        table.index = pd.Index(np.asarray(landmarks.index, dtype=np.int64), name="subject")
    else:
        pos = np.asarray(landmarks, dtype=float)
        if pos.ndim != 2 or pos.shape[1] != 2:
            raise ValueError(f"landmarks must be a DataFrame (index subject, columns x, y) or an array (K, 2), got shape {pos.shape}")
        if subjects is None:
            raise ValueError("landmarks given as an array (K, 2): pass subjects (K,), the subject number of each row")
        subj = np.asarray(subjects)
        if subj.shape != (pos.shape[0],):
            raise ValueError(f"subjects must have shape ({pos.shape[0]},), got {subj.shape}")
        table = pd.DataFrame(pos, columns=["x", "y"], index=pd.Index(subj.astype(np.int64), name="subject"))
    if table.index.has_duplicates:
        raise ValueError(f"landmarks: repeated subjects {sorted(set(table.index[table.index.duplicated()]))}")
    if not np.isfinite(table.to_numpy()).all():
        raise ValueError("landmarks contain NaN or inf positions")
    return table


def measurement_residuals(log: RobotLog, landmarks, subjects=None, *, max_gap: float = MAX_GAP,
                          glitch_threshold: float = GLITCH_THRESHOLD) -> pd.DataFrame:
    """Range and bearing residuals of every landmark measurement against groundtruth.

    For measurement ``j`` (time ``t_j``, subject ``s_j``, ``z_j = (r_j, φ_j)``)::

        x_j = groundtruth pose interpolated at t_j       (x, y, θ)
        (r̂_j, φ̂_j) = h(x_j, m_{s_j})                    expected measurement
        e_r = r_j − r̂_j,   e_φ = wrap(φ_j − φ̂_j)       residuals

    and the landmark position the measurement implies, ``h⁻¹(x_j, z_j)``.

    Parameters
    ----------
    log : RobotLog
        With groundtruth.
    landmarks : Dataset, DataFrame or array_like (K, 2)
        Surveyed landmarks: a Dataset, ``Dataset.landmarks`` (index
        ``subject``, columns ``x, y``), or an array of positions with ``subjects``.
    subjects : array_like of int, shape (K,), optional
        Subject numbers of the rows of an array ``landmarks``.
    max_gap : float
        Measurements inside a groundtruth gap longer than this [s] are skipped.
    glitch_threshold : float
        Heading glitches (:func:`heading_glitches`) are removed first.

    Returns
    -------
    DataFrame
        One row per kept measurement, in log order, columns ``robot, time,
        subject, range, bearing, x, y, theta`` (groundtruth pose), ``range_expected,
        bearing_expected, range_residual, bearing_residual, x_seen, y_seen``
        (landmark implied by the measurement). ``attrs``: ``robot``,
        ``n_measurements`` (in the log), ``n_outside_span`` and ``n_in_gaps``
        (skipped), ``glitches`` (groundtruth rows removed).

    Raises
    ------
    ValueError
        No groundtruth; NaN/inf in the measurements; a measured subject with
        no landmark position.
    """
    gt = usable_groundtruth(log, glitch_threshold)
    max_gap = _check_max_gap(max_gap)
    table = _landmark_table(landmarks, subjects)
    values, subject = _checked_measurements(log, table)
    t_gt = gt["time"].to_numpy()
    t = values[:, 0]
    inside = (t >= t_gt[0]) & (t <= t_gt[-1])
    keep = _covered(t_gt, t, max_gap)
    pose = interpolate_poses(t[keep], t_gt, gt[["x", "y", "theta"]].to_numpy(), tolerance=0.0)
    lm = table.loc[subject[keep]].to_numpy()
    z = values[keep, 1:3]
    z_hat = range_bearing(pose, lm)
    seen = landmark_from_measurement(pose, np.column_stack([np.maximum(z[:, 0], 0.0), z[:, 1]]))
    out = pd.DataFrame({
        "robot": np.full(int(keep.sum()), int(log.robot)),
        "time": t[keep],
        "subject": subject[keep],
        "range": z[:, 0],
        "bearing": z[:, 1],
        "x": pose[:, 0],
        "y": pose[:, 1],
        "theta": pose[:, 2],
        "range_expected": z_hat[:, 0],
        "bearing_expected": z_hat[:, 1],
        "range_residual": z[:, 0] - z_hat[:, 0],
        "bearing_residual": wrap_angle(z[:, 1] - z_hat[:, 1]),
        "x_seen": seen[:, 0],
        "y_seen": seen[:, 1],
    })
    out.attrs.update(robot=int(log.robot), n_measurements=int(t.size), n_outside_span=int((~inside).sum()),
                     n_in_gaps=int((inside & ~keep).sum()), glitches=gt.attrs["glitches"])
    return out


def _checked_measurements(log: RobotLog, table: pd.DataFrame):
    """``(values (n, 3): time, range, bearing; subject (n,))`` of the log's sightings, checked against ``table``."""
    m = log.measurements
    missing = [c for c in ("time", "subject", "range", "bearing") if c not in m.columns]
    if missing:
        raise ValueError(f"robot {log.robot}: measurements are missing columns {missing}")
    values = m[["time", "range", "bearing"]].to_numpy(dtype=float)
    bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
    if bad.size:
        raise ValueError(f"robot {log.robot}: measurement row {int(bad[0])} has NaN or inf: {values[bad[0]].tolist()}")
    subject = m["subject"].to_numpy(dtype=np.int64)
    unknown = sorted(set(subject.tolist()) - set(table.index.tolist()))
    if unknown:
        raise ValueError(f"robot {log.robot} measures subjects {unknown} that have no landmark position")
    return values, subject


def residual_correlation(residuals: pd.DataFrame, lag: float, column: str, *, tolerance: float = 0.25) -> float:
    """Correlation of a residual between two sightings of one landmark by one robot, ``lag`` seconds apart.

    Every pair of sightings of the same ``(robot, subject)`` whose times differ
    by ``lag ± tolerance`` seconds [s] gives one pair of residuals
    (``column``, e.g. ``"bearing_residual"`` of :func:`measurement_residuals`);
    the result is their Pearson correlation ρ. Independent errors give ρ ≈ 0;
    an AR(1) error with correlation ρ at one step carries about
    ``(1 − ρ)/(1 + ρ)`` of an independent reading's information per reading.
    """
    missing = [c for c in ("robot", "subject", "time", column) if c not in residuals.columns]
    if missing:
        raise ValueError(f"residual_correlation: the residual table has no column(s) {missing}")
    first, second = [], []
    for _, g in residuals.groupby(["robot", "subject"]):
        t, v = g["time"].to_numpy(), g[column].to_numpy()
        i, j = np.nonzero(np.abs(t[None, :] - t[:, None] - lag) < tolerance)
        first.append(v[i])
        second.append(v[j])
    a, b = (np.concatenate(x) if x else np.zeros(0) for x in (first, second))
    if a.size < 3:
        raise ValueError(f"residual_correlation: fewer than 3 pairs of sightings {lag} ± {tolerance} s apart")
    return float(np.corrcoef(a, b)[0, 1])


def _residual_frame(residuals) -> pd.DataFrame:
    if isinstance(residuals, pd.DataFrame):
        frame = residuals
    else:
        frames = list(residuals)
        if not frames or not all(isinstance(f, pd.DataFrame) for f in frames):
            raise ValueError("residuals must be a DataFrame from measurement_residuals, or a non-empty list of them")
        frame = pd.concat(frames, ignore_index=True)
    needed = ["subject", "range", "range_residual", "bearing_residual"]
    missing = [c for c in needed if c not in frame.columns]
    if missing:
        raise ValueError(f"residuals are missing columns {missing} (make them with measurement_residuals)")
    if len(frame) == 0:
        raise ValueError("residuals: no measurements (is every measurement outside the groundtruth span?)")
    return frame


def landmark_check(residuals, landmarks, subjects=None, max_offset: float = OUTLIER_THRESHOLD) -> pd.DataFrame:
    """Where the measurements put each landmark, against its surveyed position.

    For each subject: the median of the implied positions ``h⁻¹(x_j, z_j)``
    (:func:`measurement_residuals` columns ``x_seen, y_seen``), its distance
    ``offset`` to the surveyed position, and the surveyed landmark nearest to it.
    A median over hundreds of measurements is precise to centimetres, so an
    offset of metres means the landmark's groundtruth (or barcode) is wrong.

    Parameters
    ----------
    residuals : DataFrame or list of DataFrames
        From :func:`measurement_residuals` (lists are concatenated).
    landmarks, subjects
        As in :func:`measurement_residuals`.
    max_offset : float
        Offsets above this [m] mark the subject as ``suspect``.

    Returns
    -------
    DataFrame
        Index ``subject``; columns ``n, x, y`` (surveyed), ``x_seen, y_seen``
        (median implied), ``offset`` [m], ``nearest`` (subject nearest to the
        implied position), ``median_range_residual`` [m],
        ``median_bearing_residual`` [rad], ``suspect`` (bool).
    """
    frame = _residual_frame(residuals)
    table = _landmark_table(landmarks, subjects)
    g = frame.groupby("subject")
    seen = g[["x_seen", "y_seen"]].median()
    out = table.loc[seen.index].copy()
    out.insert(0, "n", g.size().astype(int))
    out["x_seen"], out["y_seen"] = seen["x_seen"], seen["y_seen"]
    out["offset"] = np.hypot(out["x_seen"] - out["x"], out["y_seen"] - out["y"])
    d = np.hypot(seen["x_seen"].to_numpy()[:, None] - table["x"].to_numpy()[None, :],
                 seen["y_seen"].to_numpy()[:, None] - table["y"].to_numpy()[None, :])
    out["nearest"] = table.index.to_numpy()[np.argmin(d, axis=1)]
    out["median_range_residual"] = g["range_residual"].median()
    out["median_bearing_residual"] = g["bearing_residual"].median()
    out["suspect"] = out["offset"] > max_offset
    return out


@dataclass(frozen=True)
class MeasurementNoise:
    """Measurement noise estimated from residuals (:func:`measurement_noise`).

    Attributes
    ----------
    sigma_range : float
        Robust std of the range residuals, ``1.4826 · MAD`` [m].
    sigma_bearing : float
        Robust std of the bearing residuals [rad].
    range_bias_median, bearing_bias_median : float
        Median residuals (all measurements) [m], [rad].
    range_bias_mean, bearing_bias_mean : float
        Mean residuals of the inliers [m], [rad].
    range_std_inliers, bearing_std_inliers : float
        Ordinary sample standard deviations of the inliers, for comparison.
    outlier_fraction : float
        Fraction of measurements with ``|range residual| > outlier_threshold``.
    outlier_threshold : float
        [m].
    n : int
        Number of residuals used.
    n_outliers : int
    """

    sigma_range: float
    sigma_bearing: float
    range_bias_median: float
    bearing_bias_median: float
    range_bias_mean: float
    bearing_bias_mean: float
    range_std_inliers: float
    bearing_std_inliers: float
    outlier_fraction: float
    outlier_threshold: float
    n: int
    n_outliers: int

    @property
    def R(self) -> np.ndarray:
        """Measurement covariance ``R = diag(σ_r², σ_φ²)``, shape (2, 2) [m², rad²]."""
        return np.diag([self.sigma_range**2, self.sigma_bearing**2])


def measurement_noise(residuals, outlier_threshold: float = OUTLIER_THRESHOLD) -> MeasurementNoise:
    """Robust measurement noise from residuals against groundtruth.

    ``σ_r = 1.4826 · median|e_r − median e_r|`` and likewise ``σ_φ``
    (:func:`robust_std`); an outlier is ``|e_r| > outlier_threshold``; the
    mean biases and plain standard deviations use the inliers only.

    Parameters
    ----------
    residuals : DataFrame or list of DataFrames
        From :func:`measurement_residuals` (lists are pooled).
    outlier_threshold : float
        [m], > 0.

    Returns
    -------
    MeasurementNoise
    """
    if not (np.isfinite(outlier_threshold) and outlier_threshold > 0):
        raise ValueError(f"outlier_threshold must be > 0 m, got {outlier_threshold!r}")
    frame = _residual_frame(residuals)
    er = _finite_1d(frame["range_residual"], "measurement_noise (range residuals)")
    eb = _finite_1d(frame["bearing_residual"], "measurement_noise (bearing residuals)")
    outlier = np.abs(er) > outlier_threshold
    inl_r, inl_b = er[~outlier], eb[~outlier]
    have = inl_r.size > 1
    return MeasurementNoise(
        sigma_range=robust_std(er),
        sigma_bearing=robust_std(eb),
        range_bias_median=float(np.median(er)),
        bearing_bias_median=float(np.median(eb)),
        range_bias_mean=float(inl_r.mean()) if inl_r.size else float("nan"),
        bearing_bias_mean=float(inl_b.mean()) if inl_b.size else float("nan"),
        range_std_inliers=float(inl_r.std(ddof=1)) if have else float("nan"),
        bearing_std_inliers=float(inl_b.std(ddof=1)) if have else float("nan"),
        outlier_fraction=float(outlier.mean()),
        outlier_threshold=float(outlier_threshold),
        n=int(er.size),
        n_outliers=int(outlier.sum()),
    )


def range_noise_profile(residuals, edges=None, min_count: int = 30) -> pd.DataFrame:
    """Robust range and bearing noise per range bin: does the error grow with range?

    Parameters
    ----------
    residuals : DataFrame or list of DataFrames
        From :func:`measurement_residuals`.
    edges : array_like, optional
        Bin edges of the *expected* range ``r̂`` [m] (from groundtruth: binning
        by the measured range would put the outliers, whose range is too long,
        in the far bins); default 0.5 m bins from 0 to the largest ``r̂``.
    min_count : int
        Bins with fewer measurements are left out.

    Returns
    -------
    DataFrame
        One row per bin of ``r̂``: ``r_low, r_high, r_mid`` [m], ``n``,
        ``sigma_range`` [m] and ``sigma_bearing`` [rad] (robust, :func:`robust_std`),
        ``median_range_residual`` [m], ``outlier_fraction`` (``|e_r| > 0.5 m``).
    """
    frame = _residual_frame(residuals)
    if "range_expected" not in frame.columns:
        raise ValueError("residuals are missing the column range_expected (make them with measurement_residuals)")
    r = frame["range_expected"].to_numpy(dtype=float)
    if edges is None:
        edges = np.arange(0.0, np.ceil(r.max() / 0.5) * 0.5 + 0.5, 0.5)
    edges = np.asarray(edges, dtype=float)
    if edges.ndim != 1 or edges.size < 2 or np.any(np.diff(edges) <= 0):
        raise ValueError(f"edges must be increasing bin edges, got {edges.tolist()}")
    which = np.digitize(r, edges) - 1
    rows = []
    for b in range(edges.size - 1):
        sel = which == b
        if sel.sum() < max(int(min_count), 1):
            continue
        er = frame["range_residual"].to_numpy()[sel]
        rows.append({
            "r_low": edges[b], "r_high": edges[b + 1], "r_mid": (edges[b] + edges[b + 1]) / 2,
            "n": int(sel.sum()), "sigma_range": robust_std(er),
            "sigma_bearing": robust_std(frame["bearing_residual"].to_numpy()[sel]),
            "median_range_residual": float(np.median(er)),
            "outlier_fraction": float(np.mean(np.abs(er) > OUTLIER_THRESHOLD)),
        })
    return pd.DataFrame(rows, columns=["r_low", "r_high", "r_mid", "n", "sigma_range", "sigma_bearing",
                                       "median_range_residual", "outlier_fraction"])


def fit_range_noise(profile: pd.DataFrame) -> tuple[float, float]:
    """Straight-line fit ``σ_r(r) = a + b r`` to a :func:`range_noise_profile`.

    Weighted least squares with weights ``n`` (the MAD's variance falls like 1/n).

    Returns
    -------
    a : float
        Intercept [m].
    b : float
        Growth of σ_r per metre of range [m/m].
    """
    if len(profile) < 2:
        raise ValueError(f"fit_range_noise needs at least 2 range bins, got {len(profile)}")
    w = np.sqrt(profile["n"].to_numpy(dtype=float))
    A = np.column_stack([np.ones(len(profile)), profile["r_mid"].to_numpy(dtype=float)])
    coef, *_ = np.linalg.lstsq(A * w[:, None], profile["sigma_range"].to_numpy(dtype=float) * w, rcond=None)
    return float(coef[0]), float(coef[1])


# --------------------------------------------------------------------------- motion noise


def dead_reckoning(odometry: pd.DataFrame, times, x0=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Integrate the odometry with the filter's motion model, without noise.

    The command ``(v_i, ω_i)`` of row ``i`` is held from ``t_i`` until the
    next row (zero before the first row); the path is a chain of Euler steps
    (:func:`fastslam_edu.core.motion.dead_reckon`) between the
    sorted union of the odometry times and ``times``, starting at ``x0`` at
    ``min(times[0], t_0)``.

    Parameters
    ----------
    odometry : DataFrame
        Columns ``time, v, omega``, time non-decreasing.
    times : array_like, shape (n,)
        Non-decreasing times [s] at which the pose is wanted.
    x0 : array_like, shape (3,)
        Pose at the start.

    Returns
    -------
    ndarray, shape (n, 3)
        Poses ``(x, y, θ)`` at ``times``; θ is **not** wrapped (a continuous
        heading, so that differences count whole turns).
    """
    odo = odometry[["time", "v", "omega"]].to_numpy(dtype=float)
    q = np.asarray(times, dtype=float)
    if odo.shape[0] == 0 or not np.isfinite(odo).all():
        raise ValueError("dead_reckoning: odometry must be non-empty and finite")
    if q.ndim != 1 or q.size == 0 or not np.isfinite(q).all() or np.any(np.diff(q) < 0):
        raise ValueError("dead_reckoning: times must be a non-empty, finite, non-decreasing 1-D array")
    if np.any(np.diff(odo[:, 0]) < 0):
        raise ValueError("dead_reckoning: odometry time goes backwards")
    knots = np.unique(np.concatenate([odo[:, 0], q]))
    knots = knots[knots <= q[-1]]
    row = np.searchsorted(odo[:, 0], knots[:-1], side="right") - 1
    u = np.where(row[:, None] >= 0, odo[np.maximum(row, 0), 1:3], 0.0)
    x0 = np.asarray(x0, dtype=float)
    path = np.vstack([x0, dead_reckon(x0, u, np.diff(knots))])
    return path[np.searchsorted(knots, q)]


def relative_motion(start, end) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Motion from pose ``start`` to pose ``end`` in the robot frame at ``start``.

    ``Δs = cos θ_a (x_b − x_a) + sin θ_a (y_b − y_a)`` (forward),
    ``Δℓ = −sin θ_a (x_b − x_a) + cos θ_a (y_b − y_a)`` (to the left),
    ``Δθ = θ_b − θ_a`` (not wrapped: pass continuous headings to count turns).

    Parameters
    ----------
    start, end : array_like, shape (..., 3)

    Returns
    -------
    ds, dl, dtheta : ndarrays, shape (...)
    """
    a = np.asarray(start, dtype=float)
    b = np.asarray(end, dtype=float)
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return c * dx + s * dy, -s * dx + c * dy, b[..., 2] - a[..., 2]


def odometry_increment_errors(log: RobotLog, window: float = 1.0, *, stride: float | None = None,
                              max_gap: float = MAX_GAP, glitch_threshold: float = GLITCH_THRESHOLD,
                              groundtruth: pd.DataFrame | None = None) -> pd.DataFrame:
    """Errors of the odometry's distance and turn over windows of ``τ`` seconds.

    Windows ``[a, a + τ]`` start at whole seconds ``a = ⌈t_first⌉ + k·stride``
    (a 1 Hz groundtruth row at second ``a`` is the mean pose over
    ``[a − ½, a + ½)``, so it stands for time ``a``), inside both the
    odometry and the groundtruth spans, with no groundtruth gap longer than
    ``max_gap`` inside. For each window::

        Δs_odo, Δθ_odo = relative_motion(DR(a), DR(a + τ))      (dead reckoning)
        Δs_gt,  Δθ_gt  = relative_motion(GT(a), GT(a + τ))      (groundtruth)
        δs = Δs_odo − Δs_gt,     δθ = wrap(Δθ_odo − Δθ_gt)

    Because the increment is expressed in the robot frame at ``a``, it equals
    integrating the odometry from the groundtruth pose at ``a``.

    Parameters
    ----------
    log : RobotLog
        With odometry and groundtruth.
    window : float
        ``τ`` [s], a positive whole number of seconds.
    stride : float, optional
        Seconds between window starts (whole, ≥ 1); default ``τ`` (windows do not overlap).
    max_gap, glitch_threshold : as in :func:`measurement_residuals`.
    groundtruth : ``usable_groundtruth(log, glitch_threshold)``, if already computed.

    Returns
    -------
    DataFrame
        One row per window: ``robot, t_start, window, ds_odometry,
        ds_groundtruth, ds_error, dtheta_odometry, dtheta_groundtruth,
        dtheta_error`` (m, rad). ``attrs``: ``n_skipped`` (windows dropped for a
        gap), ``glitches``.
    """
    tau = _whole_seconds(window, "window")
    stride = tau if stride is None else _whole_seconds(stride, "stride")
    max_gap = _check_max_gap(max_gap)
    gt = usable_groundtruth(log, glitch_threshold) if groundtruth is None else groundtruth
    odo = log.odometry
    if len(odo) == 0:
        raise ValueError(f"robot {log.robot}: no odometry")
    t_gt = gt["time"].to_numpy()
    t_odo = odo["time"].to_numpy(dtype=float)
    first = np.ceil(max(t_gt[0], t_odo[0]))
    last = min(t_gt[-1], t_odo[-1])
    starts = np.arange(first, last - tau + 1e-9, stride)
    if starts.size == 0:
        raise ValueError(f"robot {log.robot}: odometry and groundtruth overlap by less than one window of {tau} s")
    ends = starts + tau
    # windows with a long groundtruth gap inside are dropped
    gap_start = t_gt[:-1][np.diff(t_gt) > max_gap]
    gap_end = t_gt[1:][np.diff(t_gt) > max_gap]
    has_gap = ((gap_start[None, :] < ends[:, None]) & (gap_end[None, :] > starts[:, None])).any(axis=1)
    starts, ends = starts[~has_gap], ends[~has_gap]
    if starts.size == 0:
        raise ValueError(f"robot {log.robot}: every window of {tau} s contains a groundtruth gap > {max_gap} s")
    times = np.unique(np.concatenate([starts, ends]))
    dr = dead_reckoning(odo, times)
    theta_gt = np.unwrap(gt["theta"].to_numpy())
    pose_gt = np.column_stack([np.interp(times, t_gt, gt[c].to_numpy()) for c in ("x", "y")]
                              + [np.interp(times, t_gt, theta_gt)])
    ia, ib = np.searchsorted(times, starts), np.searchsorted(times, ends)
    ds_o, _, dth_o = relative_motion(dr[ia], dr[ib])
    ds_g, _, dth_g = relative_motion(pose_gt[ia], pose_gt[ib])
    out = pd.DataFrame({
        "robot": np.full(starts.size, int(log.robot)),
        "t_start": starts,
        "window": np.full(starts.size, tau),
        "ds_odometry": ds_o,
        "ds_groundtruth": ds_g,
        "ds_error": ds_o - ds_g,
        "dtheta_odometry": dth_o,
        "dtheta_groundtruth": dth_g,
        "dtheta_error": wrap_angle(dth_o - dth_g),
    })
    out.attrs.update(robot=int(log.robot), n_skipped=int(has_gap.sum()), glitches=gt.attrs["glitches"])
    return out


def _whole_seconds(value, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a whole number of seconds, got {value!r}") from None
    if not (np.isfinite(v) and v >= 1 and v == round(v)):
        raise ValueError(f"{name} must be a whole number of seconds ≥ 1 (windows start at whole seconds), got {value!r}")
    return v


def _logs(logs) -> list[RobotLog]:
    if isinstance(logs, RobotLog):
        return [logs]
    if isinstance(logs, Dataset):
        return list(logs.robots.values())
    if isinstance(logs, Mapping):
        logs = list(logs.values())
    out = list(logs)
    if not out or not all(isinstance(g, RobotLog) for g in out):
        raise ValueError("expected a RobotLog, a Dataset, or a non-empty list of RobotLogs")
    return out


def increment_variances(logs, windows: Iterable[float] = WINDOWS, **kwargs) -> pd.DataFrame:
    """Robust variances of the odometry errors for several window lengths ``τ``.

    Parameters
    ----------
    logs : RobotLog, list of RobotLog, or Dataset
        Errors of several robots are pooled per window.
    windows : iterable of float
        Window lengths ``τ`` [s] (whole seconds).
    **kwargs
        Passed to :func:`odometry_increment_errors` (``stride``, ``max_gap``, ...).

    Returns
    -------
    DataFrame
        One row per ``τ``: ``window, n``, ``var_s`` [m²] and ``var_theta``
        [rad²] (squared :func:`robust_std` of ``δs``, ``δθ``), ``var_s_per_s``
        and ``var_theta_per_s`` (divided by ``τ``: constant for a random walk),
        ``bias_s``, ``bias_theta`` (median errors per second, [m/s], [rad/s]).
    """
    logs = _logs(logs)
    truth = [usable_groundtruth(g, kwargs.get("glitch_threshold", GLITCH_THRESHOLD)) for g in logs]  # once per log
    rows = []
    for tau in windows:
        e = pd.concat([odometry_increment_errors(g, tau, groundtruth=gt, **kwargs) for g, gt in zip(logs, truth)],
                      ignore_index=True)
        vs = robust_std(e["ds_error"]) ** 2
        vt = robust_std(e["dtheta_error"]) ** 2
        tau = float(tau)
        rows.append({"window": tau, "n": len(e), "var_s": vs, "var_theta": vt,
                     "var_s_per_s": vs / tau, "var_theta_per_s": vt / tau,
                     "bias_s": float(np.median(e["ds_error"])) / tau,
                     "bias_theta": float(np.median(e["dtheta_error"])) / tau})
    if not rows:
        raise ValueError("increment_variances: give at least one window length")
    return pd.DataFrame(rows)


@dataclass(frozen=True)
class RandomWalkFit:
    """Fit of ``Var δ(τ) = c + σ² τ`` to robust variances (:func:`fit_random_walk`).

    Attributes
    ----------
    sigma_v : float
        Distance noise density ``σ_v`` [m/√s] (√ of the slope, 0 if the slope is negative).
    sigma_omega : float
        Heading noise density ``σ_ω`` [rad/√s].
    intercept_s : float
        ``c`` of the distance errors [m²]: error that does not grow with ``τ``.
    intercept_theta : float
        ``c`` of the heading errors [rad²].
    slope_s, slope_theta : float
        The fitted slopes ``σ²`` (may be negative if the data are not a random walk).
    """

    sigma_v: float
    sigma_omega: float
    intercept_s: float
    intercept_theta: float
    slope_s: float
    slope_theta: float

    def motion_noise(self) -> MotionNoise:
        """The densities as a control-mode :class:`~fastslam_edu.core.motion.MotionNoise`."""
        return MotionNoise(mode="control", sigma_v=self.sigma_v, sigma_omega=self.sigma_omega)


def fit_random_walk(variances: pd.DataFrame) -> RandomWalkFit:
    """Fit ``Var(τ) = c + σ² τ`` to an :func:`increment_variances` table.

    Weighted least squares: the variance estimated from ``n`` windows has a
    standard error ∝ ``Var/√n``, so each row gets weight ``√n / Var``. With a
    single window the intercept is taken as 0 and ``σ² = Var/τ``.

    Returns
    -------
    RandomWalkFit
    """
    if len(variances) == 0:
        raise ValueError("fit_random_walk: empty table")
    tau = variances["window"].to_numpy(dtype=float)
    n = variances["n"].to_numpy(dtype=float)
    out = {}
    for col, key in (("var_s", "s"), ("var_theta", "theta")):
        var = variances[col].to_numpy(dtype=float)
        if len(variances) == 1:
            c, slope = 0.0, float(var[0] / tau[0])
        else:
            w = np.sqrt(n) / np.maximum(var, np.finfo(float).tiny)
            A = np.column_stack([np.ones_like(tau), tau])
            (c, slope), *_ = np.linalg.lstsq(A * w[:, None], var * w, rcond=None)
        out[key] = (float(c), float(slope))
    return RandomWalkFit(
        sigma_v=float(np.sqrt(max(out["s"][1], 0.0))),
        sigma_omega=float(np.sqrt(max(out["theta"][1], 0.0))),
        intercept_s=out["s"][0], intercept_theta=out["theta"][0],
        slope_s=out["s"][1], slope_theta=out["theta"][1],
    )


def motion_noise(logs, windows: Iterable[float] = WINDOWS, **kwargs) -> MotionNoise:
    """Motion noise densities ``σ_v, σ_ω`` estimated from odometry against groundtruth.

    :func:`increment_variances` over ``windows``, then :func:`fit_random_walk`.

    Parameters
    ----------
    logs : RobotLog, list of RobotLog, or Dataset
    windows : iterable of float
        Window lengths [s].
    **kwargs
        Passed to :func:`odometry_increment_errors`.

    Returns
    -------
    MotionNoise
        ``mode="control"``.
    """
    return fit_random_walk(increment_variances(logs, windows, **kwargs)).motion_noise()


# --------------------------------------------------------------------------- everything at once


def estimate_noise(dataset: Dataset, robots: Iterable[int] | None = None, *, windows: Iterable[float] = WINDOWS,
                   outlier_threshold: float = OUTLIER_THRESHOLD, exclude_suspect: bool = True,
                   max_gap: float = MAX_GAP, glitch_threshold: float = GLITCH_THRESHOLD) -> dict:
    """Measurement and motion noise of a dataset, per robot and pooled over robots.

    Parameters
    ----------
    dataset : Dataset
    robots : iterable of int, optional
        Robots to use; default every robot that has groundtruth.
    windows : iterable of float
        Window lengths of the random-walk fit [s].
    outlier_threshold : float
        [m], see :func:`measurement_noise`.
    exclude_suspect : bool
        Leave out the measurements of landmarks whose surveyed position
        disagrees with the measurements (:func:`landmark_check`, pooled over robots).
    max_gap, glitch_threshold
        See :func:`measurement_residuals`.

    Returns
    -------
    dict
        ``measurement`` (:class:`MeasurementNoise`, pooled), ``motion``
        (:class:`~fastslam_edu.core.motion.MotionNoise`, pooled), ``random_walk``
        (:class:`RandomWalkFit`, pooled), ``variances`` (pooled
        :func:`increment_variances` table), ``range_fit`` ``(a, b)`` of
        :func:`fit_range_noise` (None if < 2 bins), ``per_robot``
        ``{robot: {"measurement", "motion", "random_walk"}}``,
        ``landmarks`` (the :func:`landmark_check` table), ``suspect``
        (subjects left out), ``residuals`` (all kept residuals, with a
        ``robot`` column), ``robots`` (used).
    """
    if not isinstance(dataset, Dataset):
        raise ValueError(f"estimate_noise expects a Dataset, got {type(dataset).__name__}")
    if robots is None:
        numbers = [r for r, g in sorted(dataset.robots.items()) if g.groundtruth is not None]
        if not numbers:
            raise ValueError(f"{dataset.path or 'dataset'}: no robot has groundtruth; noise cannot be estimated")
    else:
        numbers = [int(r) for r in robots]
        absent = [r for r in numbers if r not in dataset.robots]
        if absent:
            raise ValueError(f"robots {absent} are not in the dataset (it has {sorted(dataset.robots)})")
        if not numbers:
            raise ValueError("estimate_noise: robots is empty")
    windows = tuple(windows)
    opts = {"max_gap": max_gap, "glitch_threshold": glitch_threshold}
    residuals = {r: measurement_residuals(dataset.robots[r], dataset.landmarks, **opts) for r in numbers}
    check = landmark_check(list(residuals.values()), dataset.landmarks)
    suspect = check.index[check["suspect"]].tolist() if exclude_suspect else []
    kept = {r: e[~e["subject"].isin(suspect)] for r, e in residuals.items()}
    per_robot = {}
    for r in numbers:
        fit = fit_random_walk(increment_variances(dataset.robots[r], windows, **opts))
        per_robot[r] = {"measurement": measurement_noise(kept[r], outlier_threshold),
                        "motion": fit.motion_noise(), "random_walk": fit}
    variances = increment_variances([dataset.robots[r] for r in numbers], windows, **opts)
    fit = fit_random_walk(variances)
    pooled = pd.concat(list(kept.values()), ignore_index=True)
    profile = range_noise_profile(pooled)
    return {
        "measurement": measurement_noise(pooled, outlier_threshold),
        "motion": fit.motion_noise(),
        "random_walk": fit,
        "variances": variances,
        "range_fit": fit_range_noise(profile) if len(profile) >= 2 else None,
        "per_robot": per_robot,
        "landmarks": check,
        "suspect": suspect,
        "residuals": pooled,
        "robots": numbers,
    }
