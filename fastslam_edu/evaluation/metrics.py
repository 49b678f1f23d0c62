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
from fastslam_edu.core.se2 import DEFAULT_TIME_TOLERANCE, interpolate_poses

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


def _as_float_array(a, name: str) -> np.ndarray:
    try:
        return np.asarray(a, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be an array of real numbers, got {a!r}") from exc


def _points(a, name: str, *, allow_nan: bool = False) -> np.ndarray:
    """An (n, 2) array of finite points (NaN rows allowed on request)."""
    p = _as_float_array(a, name)
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f"{name} must have shape (n, 2) (x, y in metres), got shape {p.shape}")
    bad = ~np.isfinite(p).all(axis=1)
    if allow_nan:
        bad &= ~np.isnan(p).any(axis=1)
    if np.any(bad):
        rows = np.flatnonzero(bad)
        raise ValueError(f"{name} has {rows.size} row(s) with NaN or inf values, e.g. row(s) {rows[:5].tolist()}")
    return p


def _observed_mask(observed, k: int) -> np.ndarray:
    if observed is None:
        return np.ones(k, dtype=bool)
    mask = np.asarray(observed)
    if mask.shape != (k,) or mask.dtype != bool:
        raise ValueError(f"observed must be a boolean array of shape ({k},), got dtype {mask.dtype} and shape {mask.shape}")
    return mask


def _landmark_pair(estimate, truth, observed) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    est = _points(estimate, "estimate", allow_nan=True)
    tru = _points(truth, "truth", allow_nan=True)
    if est.shape != tru.shape:
        raise ValueError(f"estimate and truth must have the same shape (K, 2), got {est.shape} and {tru.shape}")
    mask = _observed_mask(observed, est.shape[0])
    for name, p in (("estimate", est), ("truth", tru)):
        missing = mask & np.isnan(p).any(axis=1)
        if np.any(missing):
            raise ValueError(
                f"{name} is NaN for landmark(s) {np.flatnonzero(missing).tolist()} marked as observed; "
                f"pass observed=... to exclude landmarks that were never seen"
            )
    return est, tru, mask


# --------------------------------------------------------------------------- alignment


def align_se2(source, target, weights=None) -> tuple[np.ndarray, np.ndarray, float]:
    """Rigid motion that best maps ``source`` onto ``target`` (least squares, no scale).

    Solves

    .. math::

        \\min_{R \\in SO(2),\\, t} \\sum_j w_j \\, \\| R s_j + t - y_j \\|^2

    in closed form (Kabsch / Umeyama without scale): with weighted centroids
    ``s̄, ȳ`` and the 2×2 cross-covariance ``H = Σ_j w_j (s_j − s̄)(y_j − ȳ)ᵀ
    = U Σ Vᵀ`` (SVD),

    .. math::

        R = V \\operatorname{diag}(1, \\det(V U^T))\\, U^T, \\qquad t = ȳ - R s̄.

    The ``diag(1, ±1)`` factor enforces ``det R = +1``: without it a mirrored
    point set would be "aligned" by a reflection, which no robot can undergo.

    Parameters
    ----------
    source : array_like, shape (n, 2)
        Points to move (e.g. estimated landmarks or path) [m].
    target : array_like, shape (n, 2)
        Corresponding points to fit (groundtruth) [m].
    weights : array_like, shape (n,), optional
        Non-negative weights ``w_j`` (default all 1), not all zero.

    Returns
    -------
    R : ndarray, shape (2, 2)
        Rotation matrix, ``det R = +1``.
    t : ndarray, shape (2,)
        Translation [m].
    angle : float
        Rotation angle [rad] in (-π, π]: ``R = [[cos, -sin], [sin, cos]]``.

    Notes
    -----
    With one point (or all source points identical) the rotation is not
    determined; ``R = I`` is returned and ``t`` matches the centroids.
    """
    s = _points(source, "source")
    y = _points(target, "target")
    if s.shape != y.shape or s.shape[0] == 0:
        raise ValueError(f"source and target must be non-empty with the same shape (n, 2), got {s.shape} and {y.shape}")
    if weights is None:
        w = np.ones(s.shape[0])
    else:
        w = _as_float_array(weights, "weights")
        if w.shape != (s.shape[0],):
            raise ValueError(f"weights must have shape ({s.shape[0]},), got {w.shape}")
        if not np.all(np.isfinite(w)) or np.any(w < 0) or not np.any(w > 0):
            raise ValueError(f"weights must be finite, non-negative and not all zero, got {w}")
    w = w / w.sum()
    s_bar = w @ s
    y_bar = w @ y
    H = (s - s_bar).T @ (w[:, None] * (y - y_bar))
    scale = (1.0 + np.abs(s).max()) * (1.0 + np.abs(y).max())
    if np.abs(H).max() <= 64 * np.finfo(float).eps * scale:
        R = np.eye(2)  # H = 0 up to round-off: every rotation fits equally well
    else:
        U, _, Vt = np.linalg.svd(H)
        d = 1.0 if np.linalg.det(Vt.T @ U.T) >= 0 else -1.0
        R = Vt.T @ np.diag([1.0, d]) @ U.T
    t = y_bar - R @ s_bar
    angle = float(np.arctan2(R[1, 0], R[0, 0]))
    return R, t, float(wrap_angle(angle))


def apply_se2(points, R, t) -> np.ndarray:
    """Apply the rigid motion ``p ↦ R p + t`` to points.

    Parameters
    ----------
    points : array_like, shape (..., 2)
    R : array_like, shape (2, 2)
    t : array_like, shape (2,)

    Returns
    -------
    ndarray, shape (..., 2)
    """
    p = _as_float_array(points, "points")
    R = _as_float_array(R, "R")
    t = _as_float_array(t, "t")
    if p.shape[-1:] != (2,) or R.shape != (2, 2) or t.shape != (2,):
        raise ValueError(f"expected points (..., 2), R (2, 2), t (2,); got {p.shape}, {R.shape}, {t.shape}")
    return p @ R.T + t


# --------------------------------------------------------------------------- landmarks


def landmark_errors(estimate, truth, observed=None) -> np.ndarray:
    """Euclidean error ``e_k = ‖μ̂_k − m_k‖`` of each landmark estimate [m].

    Parameters
    ----------
    estimate : array_like, shape (K, 2)
        Estimated landmark positions ``μ̂_k`` (e.g. the particle-weighted mean);
        rows of landmarks never observed may be NaN.
    truth : array_like, shape (K, 2)
        Groundtruth positions ``m_k`` in the same index order.
    observed : array_like of bool, shape (K,), optional
        Which landmarks have an estimate (default: all).

    Returns
    -------
    ndarray, shape (K,)
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
    ndarray, shape (K,)
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
    te = _as_float_array(t_est, "t_est")
    pe = _as_float_array(poses_est, "poses_est")
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
