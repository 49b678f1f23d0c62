"""Errors of a SLAM estimate against groundtruth: landmarks, trajectory, alignment.

Two ways of scoring
-------------------
* **Absolute** errors compare the estimate with groundtruth in the world
  frame. They are what a filter started from the true initial pose should
  achieve.
* **Aligned** errors first move the whole estimate by the rigid motion
  (rotation ``R``, translation ``t``) that fits it best to the truth
  (:func:`align_se2`), then compare. SLAM without absolute references can
  only recover the map and path up to such a motion (the gauge freedom), so
  aligned errors measure the *shape* of the estimate. Aligned errors are never
  larger in the least-squares sense: ``R = I, t = 0`` is one of the candidates.

Landmark error of landmark ``k``: ``e_k = ‖μ̂_k − m_k‖`` [m]. Position error at
time ``t_j``: ``e_j = ‖(x̂_j, ŷ_j) − (x_j, y_j)‖`` [m], with the groundtruth pose
interpolated at ``t_j`` (:func:`interpolate_poses`); heading error
``|wrap(θ̂_j − θ_j)|`` [rad].

Over seeds
----------
A particle filter's figure is a random variable: each seed draws other noise.
:func:`mean_of_medians` summarises runs of several robots over several seeds, with
a bootstrap interval that says how far the seeds alone move the summary.
"""

from __future__ import annotations

import numpy as np

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.checks import float_array, point_rows
from fastslam_edu.core.se2 import DEFAULT_TIME_TOLERANCE, align_se2, apply_se2, interpolate_poses  # noqa: F401 (align_se2, apply_se2: re-exported)

__all__ = [
    "landmark_errors",
    "mean_landmark_error",
    "landmark_errors_aligned",
    "trajectory_errors",
    "align_se2",
    "apply_se2",
    "mean_of_medians",
]


# --------------------------------------------------------------------------- input checks


def _observed_mask(observed, k: int) -> np.ndarray:
    if observed is None:
        return np.ones(k, dtype=bool)
    mask = np.asarray(observed)
    if mask.shape != (k,) or mask.dtype != bool:
        raise ValueError(f"observed must be a boolean array of shape ({k},), got dtype {mask.dtype} and shape {mask.shape}")
    return mask


def _landmark_pair(estimate, truth, observed) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    est = point_rows(estimate, "estimate", allow_nan=True)
    tru = point_rows(truth, "truth", allow_nan=True)
    if est.shape != tru.shape:
        raise ValueError(f"estimate and truth must have the same shape (N, 2), got {est.shape} and {tru.shape}")
    mask = _observed_mask(observed, est.shape[0])
    for name, p in (("estimate", est), ("truth", tru)):
        missing = mask & np.isnan(p).any(axis=1)
        if np.any(missing):
            raise ValueError(
                f"{name} is NaN for landmark(s) {np.flatnonzero(missing).tolist()} marked as observed; "
                f"pass observed=... to exclude landmarks that were never seen"
            )
    return est, tru, mask


# --------------------------------------------------------------------------- landmarks


def landmark_errors(estimate, truth, observed=None) -> np.ndarray:
    """Euclidean error ``e_k = ‖μ̂_k − m_k‖`` of each landmark estimate [m].

    Parameters
    ----------
    estimate : array_like, shape (N, 2)
        Estimated landmark positions ``μ̂_k`` (e.g. the particle-weighted mean);
        rows of landmarks never observed may be NaN.
    truth : array_like, shape (N, 2)
        Groundtruth positions ``m_k`` in the same index order.
    observed : array_like of bool, shape (N,), optional
        Which landmarks have an estimate (default: all).

    Returns
    -------
    ndarray, shape (N,)
        ``e_k`` for observed landmarks, **NaN** for the others.

    Raises
    ------
    ValueError
        On shape mismatch, or NaN / inf in a row marked as observed.
    """
    est, tru, mask = _landmark_pair(estimate, truth, observed)
    out = np.full(est.shape[0], np.nan)
    out[mask] = np.linalg.norm(est[mask] - tru[mask], axis=1)
    return out


def mean_landmark_error(estimate, truth, observed=None) -> float:
    """Mean of :func:`landmark_errors` over the observed landmarks [m].

    Raises
    ------
    ValueError
        If no landmark is observed (the mean is undefined).
    """
    e = landmark_errors(estimate, truth, observed)
    mask = ~np.isnan(e)
    if not np.any(mask):
        raise ValueError("no landmark is observed: the mean landmark error is undefined")
    return float(e[mask].mean())


def landmark_errors_aligned(estimate, truth, observed=None) -> np.ndarray:
    """Landmark errors after aligning the estimated map onto the truth.

    The observed estimates are moved by the rigid motion of :func:`align_se2`
    fitted on the observed landmarks, ``μ̂'_k = R μ̂_k + t``, then
    ``e_k = ‖μ̂'_k − m_k‖``.

    Parameters
    ----------
    estimate, truth, observed
        As in :func:`landmark_errors`.

    Returns
    -------
    ndarray, shape (N,)
        Aligned errors [m], NaN for unobserved landmarks.
    """
    est, tru, mask = _landmark_pair(estimate, truth, observed)
    if not np.any(mask):
        raise ValueError("no landmark is observed: nothing to align")
    R, t, _ = align_se2(est[mask], tru[mask])
    moved = est.copy()
    moved[mask] = apply_se2(est[mask], R, t)
    return landmark_errors(moved, tru, mask)


# --------------------------------------------------------------------------- trajectories


def _stats(e: np.ndarray) -> tuple[float, float, float]:
    return float(e.mean()), float(np.sqrt(np.mean(e * e))), float(e.max())


def _estimated_path(t_est, poses_est) -> tuple[np.ndarray, np.ndarray]:
    """``t_est`` (n,) and ``poses_est`` (n, 3) or (n, 2) as float arrays, n ≥ 1, poses finite."""
    te = float_array(t_est, "t_est")
    pe = float_array(poses_est, "poses_est")
    if pe.ndim != 2 or pe.shape[1] not in (2, 3) or te.shape != (pe.shape[0],) or te.size == 0:
        raise ValueError(
            f"t_est must have shape (n,) and poses_est shape (n, 3) or (n, 2) with n ≥ 1, got {te.shape} and {pe.shape}"
        )
    if not np.all(np.isfinite(pe)):
        raise ValueError(f"poses_est contains {int(np.count_nonzero(~np.isfinite(pe)))} NaN or inf value(s)")
    return te, pe


def trajectory_errors(
    t_est,
    poses_est,
    t_gt,
    poses_gt,
    *,
    align: bool = False,
    tolerance: float = DEFAULT_TIME_TOLERANCE,
) -> dict:
    """Position (and heading) errors of an estimated path against groundtruth.

    For each estimated pose at time ``t_j`` the groundtruth pose is
    interpolated at ``t_j`` (:func:`interpolate_poses`), and

    .. math::

        e_j = \\| (\\hat x_j, \\hat y_j) - (x_j, y_j) \\|, \\quad
        \\text{mean} = \\tfrac1n \\sum_j e_j, \\quad
        \\text{rmse} = \\sqrt{\\tfrac1n \\sum_j e_j^2}, \\quad
        \\text{max} = \\max_j e_j.

    Parameters
    ----------
    t_est : array_like, shape (n,)
        Times [s] of the estimated poses.
    poses_est : array_like, shape (n, 3) or (n, 2)
        Estimated ``(x, y, θ)`` or ``(x, y)``.
    t_gt, poses_gt : array_like, shapes (T,), (T, 3)
        Groundtruth times and poses.
    align : bool, default False
        First move the estimated path by the rigid motion that best fits its
        positions onto the groundtruth ones (:func:`align_se2`):
        ``p ↦ R p + t`` and ``θ ↦ θ + angle``.
    tolerance : float, default 0.5
        See :func:`interpolate_poses`.

    Returns
    -------
    dict
        ``errors`` (n,) [m]; ``mean``, ``rmse``, ``max`` [m];
        ``heading_errors`` (n,) ``|wrap(θ̂ − θ)|`` [rad] and ``heading_mean``,
        ``heading_rmse``, ``heading_max`` [rad] (None when ``poses_est`` has no
        heading column); ``alignment``: None, or ``{"R", "t", "angle"}`` when
        ``align=True``.
    """
    te, pe = _estimated_path(t_est, poses_est)
    truth = interpolate_poses(te, t_gt, poses_gt, tolerance=tolerance)
    xy = pe[:, :2]
    heading = pe[:, 2] if pe.shape[1] == 3 else None
    alignment = None
    if align:
        R, t, angle = align_se2(xy, truth[:, :2])
        xy = apply_se2(xy, R, t)
        if heading is not None:
            heading = heading + angle
        alignment = {"R": R, "t": t, "angle": angle}
    errors = np.linalg.norm(xy - truth[:, :2], axis=1)
    mean, rmse, emax = _stats(errors)
    result = {
        "errors": errors,
        "mean": mean,
        "rmse": rmse,
        "max": emax,
        "heading_errors": None,
        "heading_mean": None,
        "heading_rmse": None,
        "heading_max": None,
        "alignment": alignment,
    }
    if heading is not None:
        h = np.abs(wrap_angle(heading - truth[:, 2]))
        result["heading_errors"] = h
        result["heading_mean"], result["heading_rmse"], result["heading_max"] = _stats(h)
    return result


# --------------------------------------------------------------------------- over seeds


def mean_of_medians(values, rng=0, n_boot: int = 2000) -> tuple[float, float, float]:
    """The mean over robots of the median over seeds, and its 95 % bootstrap interval: ``(mean, low, high)``.

    ``values``: one sequence of per-seed figures per robot (one robot: its median and the interval of that median).
    Each robot's seeds are drawn again with replacement, ``n_boot`` times; each draw gives a mean of medians, and
    ``low``, ``high`` are their 2.5 and 97.5 % quantiles. ``rng``: a seed or a ``numpy.random.Generator``.
    """
    rng = np.random.default_rng(rng)
    per_robot = [np.asarray(v, dtype=float) for v in values]
    if not per_robot or any(v.ndim != 1 or len(v) == 0 or not np.isfinite(v).all() for v in per_robot):
        raise ValueError("mean_of_medians: values must be one non-empty sequence of finite figures per robot")
    mean = float(np.mean([np.median(v) for v in per_robot]))
    draws = np.mean([np.median(rng.choice(v, (n_boot, len(v))), axis=1) for v in per_robot], axis=0)
    low, high = np.quantile(draws, [0.025, 0.975])
    return mean, float(low), float(high)
