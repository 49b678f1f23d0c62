"""The range–bearing sensor's noise ``R = diag(σ_r², σ_φ²)``, measured against groundtruth.

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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.measurement import landmark_from_measurement, range_bearing
from fastslam_edu.core.se2 import interpolate_poses
from fastslam_edu.datasets.log import Dataset, RobotLog
from fastslam_edu.evaluation.noise_estimation.groundtruth import (GLITCH_THRESHOLD, MAX_GAP, checked_max_gap,
                                                                  covered_by_groundtruth, usable_groundtruth)
from fastslam_edu.evaluation.noise_estimation.robust import finite_values, robust_std

__all__ = ["OUTLIER_THRESHOLD", "MeasurementNoise", "measurement_residuals", "residual_correlation", "landmark_check",
           "measurement_noise", "range_noise_profile", "fit_range_noise"]

#: Default range-residual threshold [m] above which a measurement is an outlier.
OUTLIER_THRESHOLD = 0.5


def _landmarks_by_subject(landmarks, subjects) -> pd.DataFrame:
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
            raise ValueError(f"landmarks must be a DataFrame (index subject, columns x, y) or an array (N, 2), got shape {pos.shape}")
        if subjects is None:
            raise ValueError("landmarks given as an array (N, 2): pass subjects (N,), the subject number of each row")
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
    landmarks : Dataset, DataFrame or array_like (N, 2)
        Surveyed landmarks: a Dataset, ``Dataset.landmarks`` (index
        ``subject``, columns ``x, y``), or an array of positions with ``subjects``.
    subjects : array_like of int, shape (N,), optional
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
    max_gap = checked_max_gap(max_gap)
    table = _landmarks_by_subject(landmarks, subjects)
    values, subject = _checked_measurements(log, table)
    t_gt = gt["time"].to_numpy()
    t = values[:, 0]
    inside = (t >= t_gt[0]) & (t <= t_gt[-1])
    keep = covered_by_groundtruth(t_gt, t, max_gap)
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
    table = _landmarks_by_subject(landmarks, subjects)
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
    er = finite_values(frame["range_residual"], "measurement_noise (range residuals)")
    eb = finite_values(frame["bearing_residual"], "measurement_noise (bearing residuals)")
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
