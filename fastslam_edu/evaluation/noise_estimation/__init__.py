"""Estimating the filter's noise parameters from a log with groundtruth.

FastSLAM needs two noise models: the measurement covariance
``R = diag(σ_r², σ_φ²)`` of the range–bearing sensor, and the motion noise
densities ``σ_v`` [m/√s], ``σ_ω`` [rad/√s] of the odometry
(:class:`~fastslam_edu.core.motion.MotionNoise`, control mode). With groundtruth
(Vicon poses and surveyed landmarks) both can be *measured* instead of guessed.
This package writes down how the package's defaults are obtained.

One module per part, all re-exported here (``from fastslam_edu.evaluation import noise_estimation as ne;
ne.measurement_noise(...)``):

* :mod:`.measurement` — the sensor's noise (residuals, robust spread, range profile);
* :mod:`.motion` — the odometry's noise (windowed increment errors, the random-walk fit);
* :mod:`.groundtruth` — which groundtruth to trust (heading glitches, gaps);
* :mod:`.robust` — the robust standard deviation both use;
* :func:`estimate_noise` (here) — all of it for a dataset, per robot and pooled.
"""

from __future__ import annotations

from collections.abc import Iterable

import pandas as pd

from fastslam_edu.core.motion import dead_reckon_at
from fastslam_edu.datasets.log import Dataset
from fastslam_edu.evaluation.noise_estimation.groundtruth import (GLITCH_THRESHOLD, MAX_GAP, heading_glitches,
                                                                  usable_groundtruth)
from fastslam_edu.evaluation.noise_estimation.measurement import (OUTLIER_THRESHOLD, MeasurementNoise, fit_range_noise,
                                                                  landmark_check, measurement_noise,
                                                                  measurement_residuals, range_noise_profile,
                                                                  residual_correlation)
from fastslam_edu.evaluation.noise_estimation.motion import (WINDOWS, RandomWalkFit, fit_random_walk,
                                                             increment_variances, motion_noise,
                                                             odometry_increment_errors, relative_motion)
from fastslam_edu.evaluation.noise_estimation.robust import robust_std

#: The name the chapters use for :func:`fastslam_edu.core.motion.dead_reckon_at` (the odometry table dead-reckoned).
dead_reckoning = dead_reckon_at

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
    "residual_correlation",
    "MAX_GAP",
    "GLITCH_THRESHOLD",
    "OUTLIER_THRESHOLD",
    "WINDOWS",
]


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
