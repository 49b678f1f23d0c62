"""Rigid motions of the plane, SE(2): composing, inverting and comparing poses.

A pose ``a = (x, y, θ)`` [m, m, rad] is the rigid motion that maps a point
``p`` given in the frame of ``a`` to the world: ``R(θ) p + t`` with
``t = (x, y)`` and ``R(θ)`` the rotation by ``θ``. In homogeneous coordinates
it is the 3×3 matrix ``T(a) = [[R(θ), t], [0, 0, 1]]``, and the three
operations of this module are matrix algebra written out:

* composition ``a ⊕ b`` (:func:`compose`), ``T(a ⊕ b) = T(a) T(b)``: pose ``b``
  given in the frame of ``a``, expressed in the world;
* inverse ``a⁻¹`` (:func:`inverse`), ``T(a⁻¹) = T(a)⁻¹``;
* relative pose ``a⁻¹ ⊕ b`` (:func:`relative`, written ``b ⊖ a`` in the
  graph-SLAM literature): where ``b`` is, seen from ``a``. An odometry
  increment ``u_k = x_{k−1}⁻¹ ⊕ x_k`` is a relative pose in the robot frame, and
  ``x_k = x_{k−1} ⊕ u_k`` rebuilds the path (:func:`compose_increments`).

The rigid motion that best fits one point set onto another (least squares,
:func:`align_se2`, applied by :func:`apply_se2`) is how an estimate is compared
with the truth up to the gauge freedom, and how a start pose is placed on a
surveyed map.

Angles of results are wrapped to (−π, π] with
:func:`fastslam_edu.core.angles.wrap_angle`. Every function is vectorised: poses are
``(..., 3)``, points ``(..., 2)``, and leading dimensions broadcast (e.g. ``M``
particles ``(M, 3)`` composed with one increment ``(3,)``).
"""

from __future__ import annotations

import numpy as np

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.checks import finite_array, float_array, point_rows

__all__ = [
    "interpolate_poses",
    "compose",
    "inverse",
    "relative",
    "transform_points",
    "path_increments",
    "compose_increments",
    "align_se2",
    "apply_se2",
]


def _poses(name: str, a, caller: str, trailing: int = 3) -> np.ndarray:
    """``a`` as a finite float array of shape ``(..., trailing)``, else a ValueError."""
    a = np.asarray(a, dtype=float)
    if a.ndim == 0 or a.shape[-1] != trailing:
        raise ValueError(f"{caller}: {name} must have shape (..., {trailing}), got shape {a.shape}")
    if not np.isfinite(a).all():
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0])
        raise ValueError(f"{caller}: {name} contains a non-finite value ({float(a[bad])}) at index {bad}")
    return a


def _wrapped(theta: np.ndarray) -> np.ndarray:
    return np.asarray(wrap_angle(theta), dtype=float)


def compose(a, b) -> np.ndarray:
    """Composition ``a ⊕ b``: pose ``b``, given in the frame of ``a``, in the world.

    ``x = x_a + cos θ_a x_b − sin θ_a y_b``,
    ``y = y_a + sin θ_a x_b + cos θ_a y_b``,
    ``θ = wrap(θ_a + θ_b)`` — i.e. ``T(a ⊕ b) = T(a) T(b)``.

    Parameters
    ----------
    a, b : array_like, shape (..., 3)
        Poses ``(x, y, θ)`` [m, m, rad]; leading dimensions broadcast.

    Returns
    -------
    ndarray, shape (..., 3)
    """
    a = _poses("a", a, "compose")
    b = _poses("b", b, "compose")
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    th = _wrapped(a[..., 2] + b[..., 2])
    return np.stack(np.broadcast_arrays(x, y, th), axis=-1)


def inverse(a) -> np.ndarray:
    """Inverse pose ``a⁻¹`` with ``a ⊕ a⁻¹ = a⁻¹ ⊕ a = (0, 0, 0)``.

    ``a⁻¹ = (−R(θ)ᵀ t, −θ)``:
    ``x' = −cos θ x − sin θ y``, ``y' = sin θ x − cos θ y``, ``θ' = wrap(−θ)``.

    Parameters
    ----------
    a : array_like, shape (..., 3)

    Returns
    -------
    ndarray, shape (..., 3)
    """
    a = _poses("a", a, "inverse")
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = -c * a[..., 0] - s * a[..., 1]
    y = s * a[..., 0] - c * a[..., 1]
    return np.stack([x, y, _wrapped(-a[..., 2])], axis=-1)


def relative(a, b) -> np.ndarray:
    """Relative pose ``a⁻¹ ⊕ b``: pose ``b`` seen from the frame of pose ``a``.

    ``(R(θ_a)ᵀ (t_b − t_a), wrap(θ_b − θ_a))``. With ``a = x_{k−1}`` and
    ``b = x_k`` this is the odometry increment ``u_k`` in the robot frame, and
    ``compose(a, relative(a, b)) == b``.

    Parameters
    ----------
    a, b : array_like, shape (..., 3)

    Returns
    -------
    ndarray, shape (..., 3)
    """
    a = _poses("a", a, "relative")
    b = _poses("b", b, "relative")
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    x = c * dx + s * dy
    y = -s * dx + c * dy
    th = _wrapped(b[..., 2] - a[..., 2])
    return np.stack(np.broadcast_arrays(x, y, th), axis=-1)


def transform_points(pose, points) -> np.ndarray:
    """Points given in the frame of ``pose``, expressed in the world: ``R(θ) p + t``.

    Parameters
    ----------
    pose : array_like, shape (..., 3)
        ``(x, y, θ)`` [m, m, rad].
    points : array_like, shape (..., 2)
        Points ``p`` [m] in the pose's frame; leading dimensions broadcast with
        those of ``pose`` (e.g. poses ``(M, 1, 3)`` with points ``(B, 2)``).

    Returns
    -------
    ndarray, shape (broadcast(...), 2)
    """
    pose = _poses("pose", pose, "transform_points")
    points = _poses("points", points, "transform_points", trailing=2)
    c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
    x = pose[..., 0] + c * points[..., 0] - s * points[..., 1]
    y = pose[..., 1] + s * points[..., 0] + c * points[..., 1]
    return np.stack(np.broadcast_arrays(x, y), axis=-1)


def path_increments(poses) -> np.ndarray:
    """Increments ``u_k = x_{k−1}⁻¹ ⊕ x_k`` between consecutive poses of a path.

    Parameters
    ----------
    poses : array_like, shape (N, 3)

    Returns
    -------
    ndarray, shape (N − 1, 3)
        Row ``k − 1`` holds ``u_k`` in the frame of ``x_{k−1}``.
    """
    poses = _poses("poses", poses, "path_increments")
    if poses.ndim != 2:
        raise ValueError(f"path_increments: poses must have shape (N, 3), got shape {poses.shape}")
    return relative(poses[:-1], poses[1:])


def compose_increments(x0, increments) -> np.ndarray:
    """The path ``x_k = x_{k−1} ⊕ u_k`` started at ``x0`` (dead reckoning).

    Vectorised closed form of the repeated composition: with
    ``θ_k = θ_0 + Σ_{j≤k} Δθ_j`` (unwrapped),
    ``t_k = t_0 + Σ_{j≤k} R(θ_{j−1}) (Δx_j, Δy_j)``.

    Parameters
    ----------
    x0 : array_like, shape (3,)
        Start pose.
    increments : array_like, shape (n, 3)
        ``u_1 … u_n``, each in the frame of the previous pose.

    Returns
    -------
    ndarray, shape (n + 1, 3)
        ``x_0, x_1, …, x_n`` (so :func:`path_increments` of the result gives back
        ``increments`` up to angle wrapping).
    """
    x0 = _poses("x0", x0, "compose_increments")
    u = _poses("increments", increments, "compose_increments")
    if x0.shape != (3,) or u.ndim != 2:
        raise ValueError(
            f"compose_increments: x0 must have shape (3,) and increments (n, 3), got {x0.shape} and {u.shape}"
        )
    theta = x0[2] + np.concatenate([[0.0], np.cumsum(u[:, 2])])  # θ_0 … θ_n, unwrapped
    c, s = np.cos(theta[:-1]), np.sin(theta[:-1])  # R(θ_{k−1}) for k = 1 … n
    steps = np.stack([c * u[:, 0] - s * u[:, 1], s * u[:, 0] + c * u[:, 1]], axis=-1)
    xy = x0[:2] + np.concatenate([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    return np.column_stack([xy, _wrapped(theta)])


#: Query times this far [s] outside the groundtruth span get its first / last pose (:func:`interpolate_poses`).
DEFAULT_TIME_TOLERANCE = 0.5


def interpolate_poses(t_query, t_gt, poses_gt, *, tolerance: float = DEFAULT_TIME_TOLERANCE) -> np.ndarray:
    """Groundtruth poses at arbitrary times, by linear interpolation.

    ``x`` and ``y`` are interpolated linearly. ``θ`` is first unwrapped (so
    consecutive samples differ by less than π), interpolated, then wrapped to
    (-π, π]: halfway between 3.1 and -3.1 rad is ±π, not 0.

    Parameters
    ----------
    t_query : array_like, shape (n,)
        Times [s] at which poses are wanted.
    t_gt : array_like, shape (T,)
        Groundtruth times [s], strictly increasing.
    poses_gt : array_like, shape (T, 3)
        Groundtruth poses ``(x [m], y [m], θ [rad])``.
    tolerance : float, default 0.5
        Query times up to ``tolerance`` seconds outside ``[t_gt[0], t_gt[-1]]``
        get the first / last pose; further out is an error.

    Returns
    -------
    ndarray, shape (n, 3)
        Interpolated poses, ``θ`` in (-π, π].

    Raises
    ------
    ValueError
        If query times fall outside the groundtruth span by more than
        ``tolerance`` (the message states the span), if ``t_gt`` is not
        strictly increasing, or on shape errors / NaN.
    """
    tq = finite_array("t_query", t_query, "interpolate_poses")
    tg = finite_array("t_gt", t_gt, "interpolate_poses")
    pg = finite_array("poses_gt", poses_gt, "interpolate_poses")
    if tq.ndim != 1:
        raise ValueError(f"t_query must be 1-D, got shape {tq.shape}")
    if tg.ndim != 1 or tg.size == 0 or pg.shape != (tg.size, 3):
        raise ValueError(f"t_gt must have shape (T,) with T ≥ 1 and poses_gt shape (T, 3), got {tg.shape} and {pg.shape}")
    steps = np.diff(tg)
    if np.any(steps <= 0):
        j = int(np.flatnonzero(steps <= 0)[0])
        raise ValueError(
            f"t_gt must be strictly increasing, but t_gt[{j}] = {float(tg[j])!r} "
            f"and t_gt[{j + 1}] = {float(tg[j + 1])!r}"
        )
    outside = (tq < tg[0] - tolerance) | (tq > tg[-1] + tolerance)
    if np.any(outside):
        raise ValueError(
            f"{int(np.count_nonzero(outside))} query time(s) fall outside the groundtruth span "
            f"[{tg[0]:.3f}, {tg[-1]:.3f}] s by more than the tolerance {tolerance} s "
            f"(queries span [{tq.min():.3f}, {tq.max():.3f}] s)"
        )
    theta = np.unwrap(pg[:, 2])
    return np.column_stack(
        [
            np.interp(tq, tg, pg[:, 0]),
            np.interp(tq, tg, pg[:, 1]),
            wrap_angle(np.interp(tq, tg, theta)),
        ]
    )


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
    s = point_rows(source, "source")
    y = point_rows(target, "target")
    if s.shape != y.shape or s.shape[0] == 0:
        raise ValueError(f"source and target must be non-empty with the same shape (n, 2), got {s.shape} and {y.shape}")
    if weights is None:
        w = np.ones(s.shape[0])
    else:
        w = float_array(weights, "weights")
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
    p = float_array(points, "points")
    R = float_array(R, "R")
    t = float_array(t, "t")
    if p.shape[-1:] != (2,) or R.shape != (2, 2) or t.shape != (2,):
        raise ValueError(f"expected points (..., 2), R (2, 2), t (2,); got {p.shape}, {R.shape}, {t.shape}")
    return p @ R.T + t
