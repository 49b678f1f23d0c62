"""The range–bearing measurement model ``z = h(x, m)``, its inverse and Jacobians.

A robot at pose ``x = (x, y, θ)`` [m, m, rad] sees a landmark at ``m = (m_x, m_y)``
[m] at range ``r`` [m] and bearing ``φ`` [rad], measured in the robot frame
(``φ = 0`` straight ahead, positive to the left)::

    δx = m_x - x,   δy = m_y - y
    r  = √(δx² + δy²)
    φ  = wrap(atan2(δy, δx) - θ)                      z = h(x, m)

and back, from a measurement to the landmark it implies::

    m_x = x + r cos(φ + θ)
    m_y = y + r sin(φ + θ)                              m = h⁻¹(x, z)

FastSLAM 1.0 keeps one 2×2 EKF per landmark, so it needs the Jacobian of ``h``
with respect to the *landmark* (:func:`jacobian_landmark`, the ``H`` of the
landmark update) and the Jacobian of ``h⁻¹`` with respect to the *measurement*
(:func:`jacobian_inverse`, used to initialise a new landmark's covariance).
:func:`jacobian_pose` is for teaching and for FastSLAM 2.0.

Every function is vectorised: ``x`` has shape ``(..., 3)``, ``m`` and ``z`` have
shape ``(..., 2)`` and the leading dimensions broadcast against each other
(e.g. poses ``(M, 1, 3)`` of ``M`` particles against landmarks ``(M, N, 2)``).

Each function checks its input (finite numbers, the right shapes, no landmark on the robot) and names the bad
entry. :func:`range_bearing`, :func:`jacobian_landmark` and :func:`innovation` also come without the checks
(``*_unchecked``: the same arithmetic, which the checked forms call) for loops that call them thousands of times
on arrays the package built itself, such as the smoother's data association.
"""

from __future__ import annotations

import numpy as np

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.checks import finite_array


def _first_where(mask: np.ndarray) -> tuple[int, ...]:
    """Batch index of the first True entry of ``mask`` (for error messages)."""
    return tuple(int(i) for i in np.argwhere(mask)[0])


def _at(index: tuple[int, ...]) -> str:
    """Where in the batch an error is, for messages (empty for unbatched input)."""
    return f" at batch index {index}" if index else ""


def _offsets(x: np.ndarray, m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Landmark position relative to the robot: ``δx = m_x - x``, ``δy = m_y - y``."""
    return m[..., 0] - x[..., 0], m[..., 1] - x[..., 1]


def _nonzero_range(x, m, dx, dy, caller: str) -> np.ndarray:
    """``r² = δx² + δy²``, refusing a landmark exactly on the robot (r = 0)."""
    q = dx**2 + dy**2
    if (q == 0).any():
        i = _first_where(np.broadcast_to(q == 0, q.shape))
        xi = np.broadcast_to(x, q.shape + (3,))[i]
        mi = np.broadcast_to(m, q.shape + (2,))[i]
        raise ValueError(
            f"{caller}: landmark m = {tuple(mi.tolist())} lies on the robot position of pose "
            f"x = {tuple(xi.tolist())} (range r = 0){_at(i)}: the bearing and its "
            "derivatives are undefined there"
        )
    return q


def _offsets_and_range(x, m, caller: str):
    """``δx, δy, r², r`` of landmark(s) ``m`` seen from pose(s) ``x``, checked (finite, r > 0)."""
    x = finite_array("x", x, caller, (3,))
    m = finite_array("m", m, caller, (2,))
    dx, dy = _offsets(x, m)
    q = _nonzero_range(x, m, dx, dy, caller)
    return dx, dy, q, np.sqrt(q)


def _nonnegative_range(z: np.ndarray, caller: str) -> None:
    """Refuse negative ranges (often a sign of swapped (r, φ) columns)."""
    if (z[..., 0] < 0).any():
        i = _first_where(z[..., 0] < 0)
        raise ValueError(
            f"{caller}: negative range r = {float(z[i][0])} m in z{_at(i)}; "
            "z must be (r, φ) with r ≥ 0"
        )


def range_bearing(x, m) -> np.ndarray:
    """Predicted measurement ``ẑ = h(x, m)`` of landmark ``m`` from pose ``x``.

    ``r = √(δx² + δy²)``, ``φ = wrap(atan2(δy, δx) − θ)`` with
    ``δx = m_x − x``, ``δy = m_y − y``.

    Parameters
    ----------
    x : array_like, shape (..., 3)
        Robot pose ``(x, y, θ)`` [m, m, rad].
    m : array_like, shape (..., 2)
        Landmark position ``(m_x, m_y)`` [m]. Broadcasts against ``x``.

    Returns
    -------
    z : ndarray, shape (..., 2)
        ``(r, φ)``: range [m] and bearing [rad] in (−π, π].
    """
    x = finite_array("x", x, "range_bearing", (3,))
    m = finite_array("m", m, "range_bearing", (2,))
    return range_bearing_unchecked(x, m)


def range_bearing_unchecked(x: np.ndarray, m: np.ndarray) -> np.ndarray:
    """:func:`range_bearing` without its checks, for inner loops over arrays the package built itself (float
    ndarrays, finite): the same numbers, a fraction of the time on a few landmarks."""
    dx, dy = _offsets(x, m)
    out = np.empty(np.broadcast_shapes(dx.shape, x.shape[:-1]) + (2,))
    out[..., 0] = np.hypot(dx, dy)
    out[..., 1] = wrap_angle(np.arctan2(dy, dx) - x[..., 2])
    return out


def landmark_from_measurement(x, z) -> np.ndarray:
    """Landmark position ``m = h⁻¹(x, z)`` implied by measurement ``z`` from pose ``x``.

    ``m_x = x + r cos(φ + θ)``, ``m_y = y + r sin(φ + θ)``.

    Parameters
    ----------
    x : array_like, shape (..., 3)
        Robot pose ``(x, y, θ)`` [m, m, rad].
    z : array_like, shape (..., 2)
        Measurement ``(r, φ)`` [m, rad], ``r ≥ 0``. Broadcasts against ``x``.

    Returns
    -------
    m : ndarray, shape (..., 2)
        Landmark position ``(m_x, m_y)`` [m] in the world frame.
    """
    x = finite_array("x", x, "landmark_from_measurement", (3,))
    z = finite_array("z", z, "landmark_from_measurement", (2,))
    _nonnegative_range(z, "landmark_from_measurement")
    r, angle = z[..., 0], z[..., 1] + x[..., 2]
    return np.stack((x[..., 0] + r * np.cos(angle), x[..., 1] + r * np.sin(angle)), axis=-1)


def jacobian_landmark(x, m) -> np.ndarray:
    """Jacobian ``H = ∂h/∂m`` of the measurement with respect to the landmark.

    ::

        H = [[ δx/r,   δy/r  ],        rows: r, φ
             [-δy/r²,  δx/r² ]]        columns: m_x, m_y

    This is the ``H`` of the FastSLAM 1.0 landmark EKF (the pose is given by
    the particle, only the landmark is estimated). ``det H = 1/r``.

    Parameters
    ----------
    x : array_like, shape (..., 3)
        Robot pose ``(x, y, θ)`` [m, m, rad].
    m : array_like, shape (..., 2)
        Landmark position [m], not equal to the robot position.

    Returns
    -------
    H : ndarray, shape (..., 2, 2)
        Units: row r is dimensionless, row φ is rad/m.

    Raises
    ------
    ValueError
        If a landmark lies exactly on the robot (``r = 0``).
    """
    dx, dy, q, r = _offsets_and_range(x, m, "jacobian_landmark")
    return _landmark_jacobian_of(dx, dy, q, r)


def _landmark_jacobian_of(dx, dy, q, r) -> np.ndarray:
    """``H`` (..., 2, 2) from the offsets ``δx, δy``, ``q = r²`` and ``r``."""
    H = np.empty(dx.shape + (2, 2))
    H[..., 0, 0], H[..., 0, 1] = dx / r, dy / r
    H[..., 1, 0], H[..., 1, 1] = -dy / q, dx / q
    return H


def jacobian_landmark_unchecked(x: np.ndarray, m: np.ndarray) -> np.ndarray:
    """:func:`jacobian_landmark` without its checks (finite input, no landmark on the robot), for inner loops."""
    dx, dy = _offsets(x, m)
    q = dx**2 + dy**2
    return _landmark_jacobian_of(dx, dy, q, np.sqrt(q))


def jacobian_pose(x, m) -> np.ndarray:
    """Jacobian ``∂h/∂x`` of the measurement with respect to the robot pose.

    ::

        ∂h/∂x = [[-δx/r,  -δy/r,   0],     rows: r, φ
                 [ δy/r², -δx/r², -1]]     columns: x, y, θ

    Not needed by FastSLAM 1.0 (the pose is sampled, not linearised); used by
    FastSLAM 2.0's proposal and for teaching. ``x``, ``m`` and the error as
    :func:`jacobian_landmark`; returns an ndarray of shape (..., 2, 3).
    """
    dx, dy, q, r = _offsets_and_range(x, m, "jacobian_pose")
    zero, one = np.zeros_like(r), np.ones_like(r)
    row_r = np.stack((-dx / r, -dy / r, zero), axis=-1)
    row_phi = np.stack((dy / q, -dx / q, -one), axis=-1)
    return np.stack((row_r, row_phi), axis=-2)


def jacobian_inverse(x, z) -> np.ndarray:
    """Jacobian ``G = ∂h⁻¹/∂z`` of the inverse model with respect to the measurement.

    ::

        G = [[cos(φ+θ),  −r sin(φ+θ)],     rows: m_x, m_y
             [sin(φ+θ),   r cos(φ+θ)]]     columns: r, φ

    At ``m = h⁻¹(x, z)`` it equals ``H⁻¹`` (inverse function theorem), so a new
    landmark gets the covariance ``Σ = G R Gᵀ = H⁻¹ R H⁻ᵀ``
    (FastSLAM_1 line 9).

    Parameters
    ----------
    x : array_like, shape (..., 3)
        Robot pose ``(x, y, θ)`` [m, m, rad].
    z : array_like, shape (..., 2)
        Measurement ``(r, φ)`` [m, rad], ``r ≥ 0``.

    Returns
    -------
    G : ndarray, shape (..., 2, 2)
        Units: column r is dimensionless, column φ is m/rad.
    """
    x = finite_array("x", x, "jacobian_inverse", (3,))
    z = finite_array("z", z, "jacobian_inverse", (2,))
    _nonnegative_range(z, "jacobian_inverse")
    r, angle = z[..., 0], z[..., 1] + x[..., 2]
    c, s = np.cos(angle), np.sin(angle)
    return np.stack((np.stack((c, -r * s), axis=-1), np.stack((s, r * c), axis=-1)), axis=-2)


def innovation(z, z_hat) -> np.ndarray:
    """Innovation ``ν = z ⊖ ẑ``: the range difference and the *wrapped* bearing difference.

    ``ν = (r − r̂, wrap(φ − φ̂))`` with ``wrap`` to (−π, π], so that measured
    179.5° against predicted −179.5° is a residual of −1°, not 359°.

    Parameters
    ----------
    z, z_hat : array_like, shape (..., 2)
        Measured and predicted ``(r, φ)`` [m, rad]; they broadcast.

    Returns
    -------
    nu : ndarray, shape (..., 2)
        ``(Δr [m], Δφ [rad] in (−π, π])``.
    """
    z = finite_array("z", z, "innovation", (2,))
    z_hat = finite_array("z_hat", z_hat, "innovation", (2,))
    return innovation_unchecked(z, z_hat)


def innovation_unchecked(z: np.ndarray, z_hat: np.ndarray) -> np.ndarray:
    """:func:`innovation` without its checks, for inner loops over arrays the package built itself."""
    out = np.empty(np.broadcast_shapes(z.shape, z_hat.shape))
    out[..., 0] = z[..., 0] - z_hat[..., 0]
    out[..., 1] = wrap_angle(z[..., 1] - z_hat[..., 1])
    return out
