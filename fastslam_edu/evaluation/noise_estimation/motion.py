"""The odometry's noise densities ``σ_v`` [m/√s], ``σ_ω`` [rad/√s], measured against groundtruth.

Motion noise (:func:`odometry_increment_errors`, :func:`motion_noise`)
----------------------------------------------------------------------
1. Dead-reckon the odometry with the filter's own model (Euler steps, command
   held until the next row, :func:`fastslam_edu.core.motion.move_segment` with zero
   noise): :func:`~fastslam_edu.core.motion.dead_reckon_at`.
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
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.motion import MotionNoise, dead_reckon_at
from fastslam_edu.datasets.log import Dataset, RobotLog
from fastslam_edu.evaluation.noise_estimation.groundtruth import (GLITCH_THRESHOLD, MAX_GAP, checked_max_gap,
                                                                  usable_groundtruth)
from fastslam_edu.evaluation.noise_estimation.robust import robust_std

__all__ = ["WINDOWS", "relative_motion", "odometry_increment_errors", "increment_variances", "RandomWalkFit",
           "fit_random_walk", "motion_noise"]

#: Default window lengths τ [s] of the random-walk check.
WINDOWS = (1.0, 2.0, 4.0)


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
    max_gap = checked_max_gap(max_gap)
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
    dr = dead_reckon_at(odo, times)
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
