"""One 2×2 extended Kalman filter per landmark per particle (FastSLAM 1.0, lines 7–18).

In FastSLAM 1.0 each particle carries its own pose ``x`` and, for every landmark
``j`` it has seen, a Gaussian ``N(μ_j, Σ_j)`` over the landmark position. Given
the particle's pose, the landmark is the only unknown, so each landmark has a
tiny EKF with a 2-D state ``μ`` [m] and the range–bearing measurement
``z = (r, φ) = h(x, μ)`` of :mod:`fastslam_edu.core.measurement`.

Symbols (shapes without the batch dimensions)

=========  =======  ==========================================================
symbol     shape    meaning
=========  =======  ==========================================================
``x``      (3,)     the particle's pose ``(x, y, θ)`` [m, m, rad]
``μ``      (2,)     landmark mean ``(m_x, m_y)`` [m]
``Σ``      (2, 2)   landmark covariance [m²]
``z``      (2,)     measurement ``(r, φ)`` [m, rad]
``ẑ``      (2,)     predicted measurement ``h(x, μ)``
``R``      (2, 2)   measurement noise covariance, typically diag(σ_r², σ_φ²)
``H``      (2, 2)   ``∂h/∂m`` at ``μ``
``Q``      (2, 2)   innovation covariance ``H Σ Hᵀ + R``
``K``      (2, 2)   Kalman gain ``Σ Hᵀ Q⁻¹``
``ν``      (2,)     innovation ``z ⊖ ẑ`` (bearing wrapped to (−π, π])
=========  =======  ==========================================================

(The pseudo-code in the notes calls the measurement noise ``Q_t``; here it is
``R`` as in filterpy, and ``Q`` is the innovation covariance.)

The batched functions accept any leading dimensions ``...`` (particles, or
particles × measurements) that broadcast against each other; the 2×2 inverses
and determinants are written out in closed form.

One concept, two forms, one suffix (the package's rule, :mod:`fastslam_edu`): the teaching
form carries the concept's name, its compiled twin the same name plus ``_kernel``:

==============================  ====================================  ===============
teaching form (numpy, checked)  compiled twin (numba, one landmark)   table 13.1
==============================  ====================================  ===============
:func:`initialise_landmark`     :func:`initialise_landmark_kernel`    lines 7–9
:func:`innovation_statistics`   :func:`innovation_statistics_kernel`  lines 12–14, 18
:func:`update_landmark`         :func:`update_landmark_kernel`        lines 12–18
==============================  ====================================  ===============

The kernels write into the arrays they are given, entry by entry; the filter's
per-particle step calls them directly, and :func:`update_landmark` runs
:func:`update_landmark_kernel` on each landmark of a batch. The update has a third
form with a job of its own: :func:`update_landmark_textbook`, the same numbers
written line by line like the textbook, with numpy's 2×2 matrices and
``np.linalg.inv`` (to read next to the table, and the independent reference
the tests hold the other two to).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from fastslam_edu.core.angles import wrap_angle_kernel
from fastslam_edu.core.checks import finite_array

from fastslam_edu.core.measurement import (
    _at,
    innovation,
    jacobian_inverse,
    jacobian_landmark,
    landmark_from_measurement,
    range_bearing,
)


#: log(2π), the constant of the 2-D Gaussian log-density.
LOG_2PI = math.log(2.0 * math.pi)


def _transpose(A: np.ndarray) -> np.ndarray:
    """``Aᵀ`` of each matrix in a stack ``(..., n, k)``."""
    return np.swapaxes(A, -1, -2)


def _symmetrise(A: np.ndarray) -> np.ndarray:
    """``(A + Aᵀ) / 2``: removes the rounding asymmetry of a covariance."""
    return 0.5 * (A + _transpose(A))


def _det2(A: np.ndarray) -> np.ndarray:
    """Determinant ``a d − b c`` of each 2×2 matrix in ``(..., 2, 2)``."""
    return A[..., 0, 0] * A[..., 1, 1] - A[..., 0, 1] * A[..., 1, 0]


def _inv2(A: np.ndarray, det: np.ndarray) -> np.ndarray:
    """Inverse ``[[d, −b], [−c, a]] / det`` of each 2×2 matrix in ``(..., 2, 2)``."""
    adj = np.stack(
        (
            np.stack((A[..., 1, 1], -A[..., 0, 1]), axis=-1),
            np.stack((-A[..., 1, 0], A[..., 0, 0]), axis=-1),
        ),
        axis=-2,
    )
    return adj / det[..., None, None]


def _check_covariance(name: str, A, caller: str) -> np.ndarray:
    """``A`` as a finite, symmetric, positive-definite stack ``(..., 2, 2)``.

    Cheap 2×2 test: ``A₀₀ > 0`` and ``det A > 0`` (Sylvester's criterion), and
    ``|A₀₁ − A₁₀|`` at rounding level.
    """
    A = finite_array(name, A, caller, (2, 2))
    asym = np.abs(A[..., 0, 1] - A[..., 1, 0])
    scale = np.abs(A[..., 0, 0]) + np.abs(A[..., 1, 1])
    bad = (asym > 1e-9 * scale) | (A[..., 0, 0] <= 0) | (_det2(A) <= 0)
    if bad.any():
        i = tuple(int(k) for k in np.argwhere(bad)[0])
        raise ValueError(
            f"{caller}: {name} must be symmetric positive definite, but{_at(i)} "
            f"it is {A[i].tolist()} (det = {float(_det2(A[i]))})"
        )
    return A


def _check_update_inputs(mu, Sigma, x, z, R, caller: str):
    """The arguments of an EKF update as float arrays, checked (finite, shapes, Σ and R positive definite)."""
    return (finite_array("mu", mu, caller, (2,)), _check_covariance("Sigma", Sigma, caller),
            finite_array("x", x, caller, (3,)), finite_array("z", z, caller, (2,)), _check_covariance("R", R, caller))


def gaussian_log_likelihood(nu, Q) -> np.ndarray:
    """Log-density ``log N(ν; 0, Q)`` of a 2-D innovation: the FastSLAM importance weight.

    ::

        log w = −½ νᵀ Q⁻¹ ν − ½ log|2π Q|
              = −½ νᵀ Q⁻¹ ν − log(2π) − ½ log det Q        (2-D)

    This is line 18 of FastSLAM_1 in logarithms; weights are kept as logs
    because the product over many measurements underflows ``exp``.

    Parameters
    ----------
    nu : array_like, shape (..., 2)
        Innovation ``ν = z ⊖ ẑ`` [m, rad].
    Q : array_like, shape (..., 2, 2)
        Innovation covariance, symmetric positive definite. Broadcasts with ``nu``.

    Returns
    -------
    ndarray, shape (...)
        Log-likelihood (natural log of a density in 1/(m·rad)).
    """
    nu = finite_array("nu", nu, "gaussian_log_likelihood", (2,))
    Q = _check_covariance("Q", Q, "gaussian_log_likelihood")
    det = _det2(Q)
    mahalanobis2 = np.einsum("...i,...ij,...j->...", nu, _inv2(Q, det), nu)
    return -0.5 * mahalanobis2 - np.log(2.0 * np.pi) - 0.5 * np.log(det)


def initialise_landmark(x, z, R) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of a landmark seen for the first time (FastSLAM_1 lines 7–9).

    ::

        μ = h⁻¹(x, z)
        Σ = G R Gᵀ,   G = ∂h⁻¹/∂z = H⁻¹     (the notes' H⁻¹ Q_t H⁻ᵀ)

    i.e. the measurement noise ``R`` in (r, φ) pushed through the linearised
    inverse model into world x–y: ``σ_r²`` along the line of sight and
    ``r² σ_φ²`` across it.

    Parameters
    ----------
    x : array_like, shape (..., 3)
        Particle pose(s) ``(x, y, θ)`` [m, m, rad].
    z : array_like, shape (..., 2)
        Measurement(s) ``(r, φ)`` [m, rad] with ``r > 0``.
    R : array_like, shape (2, 2) or (..., 2, 2)
        Measurement noise covariance [m², rad²], symmetric positive definite.

    Returns
    -------
    mu : ndarray, shape (..., 2)
        Landmark mean [m].
    Sigma : ndarray, shape (..., 2, 2)
        Landmark covariance [m²], symmetric positive definite.
    """
    z = finite_array("z", z, "initialise_landmark", (2,))
    R = _check_covariance("R", R, "initialise_landmark")
    if (z[..., 0] <= 0).any():
        i = tuple(int(k) for k in np.argwhere(z[..., 0] <= 0)[0])
        raise ValueError(
            f"initialise_landmark: range r = {float(z[i][0])} m{_at(i)}; a landmark "
            "needs r > 0 (at r = 0 it would sit on the robot and Σ would be singular)"
        )
    mu = landmark_from_measurement(x, z)
    G = jacobian_inverse(x, z)
    Sigma = _symmetrise(G @ R @ _transpose(G))
    return mu, Sigma


def innovation_statistics(mu, Sigma, x, z, R) -> tuple[np.ndarray, np.ndarray]:
    """Innovation ``ν = z ⊖ h(x, μ)`` and its squared Mahalanobis distance ``d² = νᵀ Q⁻¹ ν``.

    With ``Q = H Σ Hᵀ + R`` as in :func:`update_landmark`. If the models are right,
    ``d²`` follows a χ² distribution with 2 degrees of freedom, so
    ``d² > 13.8`` happens for 0.1 % of good measurements: the outlier gate of
    :mod:`fastslam_edu.landmark.fastslam` rejects measurements beyond such a threshold.

    Shapes as in :func:`update_landmark`; returns ``nu (..., 2)`` and ``d2 (...)``.
    """
    mu, Sigma, x, z, R = _check_update_inputs(mu, Sigma, x, z, R, "innovation_statistics")
    H = jacobian_landmark(x, mu)
    Q = _symmetrise(H @ Sigma @ _transpose(H) + R)
    nu = innovation(z, range_bearing(x, mu))
    Qinv = _inv2(Q, _det2(Q))
    d2 = np.einsum("...i,...ij,...j->...", nu, Qinv, nu)
    return nu, d2


def update_landmark(mu, Sigma, x, z, R) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """EKF update of landmark(s) ``N(μ, Σ)`` with measurement(s) ``z`` (FastSLAM_1 lines 12–18).

    ::

        ẑ  = h(x, μ)                    predicted measurement
        H  = ∂h/∂m at μ                 2×2 Jacobian
        Q  = H Σ Hᵀ + R                 innovation covariance
        K  = Σ Hᵀ Q⁻¹                   Kalman gain
        ν  = z ⊖ ẑ                      innovation, bearing wrapped to (−π, π]
        μ' = μ + K ν
        Σ' = (I − K H) Σ  = Σ − K Q Kᵀ  (symmetric)
        log w = log N(ν; 0, Q) = −½ νᵀ Q⁻¹ ν − ½ log|2π Q|

    The covariance is the textbook ``(I − K H) Σ``, computed entry by entry so
    that the result is exactly symmetric (its off-diagonal entry is computed
    once). filterpy uses the Joseph form ``(I − K H) Σ (I − K H)ᵀ + K R Kᵀ``, which
    equals it in exact arithmetic for the optimal gain and is safer when
    ``K H ≈ I`` (a measurement far more precise than the prior); for the 2×2
    landmark filters here the two agree to ~1e-16 (tested against filterpy),
    and the property test checks that Σ' stays positive definite.

    Parameters
    ----------
    mu : array_like, shape (..., 2)
        Prior landmark mean(s) [m].
    Sigma : array_like, shape (..., 2, 2)
        Prior landmark covariance(s) [m²], symmetric positive definite.
    x : array_like, shape (..., 3)
        Particle pose(s) ``(x, y, θ)`` [m, m, rad].
    z : array_like, shape (..., 2)
        Measurement(s) ``(r, φ)`` [m, rad].
    R : array_like, shape (2, 2) or (..., 2, 2)
        Measurement noise covariance [m², rad²].

    All leading dimensions broadcast, e.g. ``mu (M, n, 2)``, ``x (M, 1, 3)``,
    ``z (n, 2)`` for ``M`` particles and ``n`` measurements.

    Returns
    -------
    mu_new : ndarray, shape (..., 2)
        Posterior mean μ' [m].
    Sigma_new : ndarray, shape (..., 2, 2)
        Posterior covariance Σ' [m²].
    log_likelihood : ndarray, shape (...)
        ``log N(ν; 0, Q)``, the log importance weight of this measurement.

    Raises
    ------
    ValueError
        On NaN/inf inputs, wrong shapes, a non-positive-definite ``Σ`` or ``R``,
        or a landmark mean exactly on the robot (``r = 0``).
    """
    mu, Sigma, x, z, R = _check_update_inputs(mu, Sigma, x, z, R, "update_landmark")

    jacobian_landmark(x, mu)  # raises a clear ValueError if a landmark sits on the robot (r = 0)
    shape = np.broadcast_shapes(mu.shape[:-1], Sigma.shape[:-2], x.shape[:-1], z.shape[:-1], R.shape[:-2])
    mu_new = np.array(np.broadcast_to(mu, shape + (2,)), dtype=float).reshape(-1, 2)
    # the compiled update reads Σ's upper triangle: remove the (tolerated) rounding asymmetry first
    Sigma_new = np.array(np.broadcast_to(_symmetrise(Sigma), shape + (2, 2)), dtype=float).reshape(-1, 2, 2)
    log_likelihood = np.empty(len(mu_new))
    _update_each(np.ascontiguousarray(np.broadcast_to(x, shape + (3,)).reshape(-1, 3)),
                 np.ascontiguousarray(np.broadcast_to(z, shape + (2,)).reshape(-1, 2)),
                 np.ascontiguousarray(np.broadcast_to(R, shape + (2, 2)).reshape(-1, 2, 2)),
                 mu_new, Sigma_new, log_likelihood)
    return mu_new.reshape(shape + (2,)), Sigma_new.reshape(shape + (2, 2)), log_likelihood.reshape(shape)


@njit(cache=True)
def _update_each(x, z, R, mu, Sigma, log_likelihood):
    """:func:`update_landmark_kernel` for each of n landmarks in a row (arrays (n, ...)), in place."""
    for i in range(mu.shape[0]):
        log_likelihood[i] = update_landmark_kernel(x[i], z[i], R[i], mu[i], Sigma[i], math.inf)[1]


# ---------------------------------------------------------------- compiled, one landmark of one particle


@njit(cache=True, inline="always")
def expected_measurement(pose, m):
    """:math:`\\hat z = h(x, m)` and :math:`H = \\partial h / \\partial m` for one pose (3,) and landmark (2,).

    Returns ``r, phi, h00, h01, h10, h11``: range [m], bearing [rad] (wrapped) and
    :math:`H = \\begin{pmatrix} \\delta_x/r & \\delta_y/r \\ -\\delta_y/r^2 & \\delta_x/r^2 \\end{pmatrix}`
    (:func:`range_and_jacobian`, :func:`expected_bearing`).
    """
    r, h00, h01, h10, h11 = range_and_jacobian(pose, m)
    return r, expected_bearing(pose, m), h00, h01, h10, h11


@njit(cache=True, inline="always")
def range_and_jacobian(pose, m):
    """The range :math:`r = \\sqrt{\\delta_x^2 + \\delta_y^2}` [m] of landmark ``m`` (2,) from ``pose`` (3,) and
    :math:`H = \\partial h / \\partial m`: ``r, h00, h01, h10, h11``. No bearing, so no arctangent: what a
    test on the range alone, or :math:`H` alone, needs (:func:`expected_measurement` adds the bearing)."""
    dx = m[0] - pose[0]
    dy = m[1] - pose[1]
    r = math.sqrt(dx * dx + dy * dy)
    inv_r = 1.0 / r  # one division, then products
    inv_q = inv_r * inv_r
    return r, dx * inv_r, dy * inv_r, -dy * inv_q, dx * inv_q


@njit(cache=True, inline="always")
def expected_bearing(pose, m):
    """The bearing :math:`\\phi = \\operatorname{atan2}(\\delta_y, \\delta_x) - \\theta` [rad], wrapped, of landmark
    ``m`` (2,) from ``pose`` (3,)."""
    return wrap_angle_kernel(math.atan2(m[1] - pose[1], m[0] - pose[0]) - pose[2])


@njit(cache=True, inline="always")
def initialise_landmark_kernel(pose, z, R, mu, sigma):
    """Lines 7–9: ``mu`` (2,) and ``sigma`` (2, 2) of a landmark seen for the first time, in place.

    :math:`\\mu = h^{-1}(x, z) = (x + r\\cos(\\phi+\\theta),\\ y + r\\sin(\\phi+\\theta))` and
    :math:`\\Sigma = G R G^\\top` with :math:`G = \\partial h^{-1}/\\partial z = H^{-1}`.
    """
    r, phi = z[0], z[1]
    c, s = math.cos(phi + pose[2]), math.sin(phi + pose[2])
    mu[0] = pose[0] + r * c
    mu[1] = pose[1] + r * s
    g00, g01, g10, g11 = c, -r * s, s, r * c  # G = ∂h⁻¹/∂(r, φ)
    a, b, d = R[0, 0], 0.5 * (R[0, 1] + R[1, 0]), R[1, 1]
    sigma[0, 0] = g00 * (a * g00 + b * g01) + g01 * (b * g00 + d * g01)
    sigma[0, 1] = g00 * (a * g10 + b * g11) + g01 * (b * g10 + d * g11)
    sigma[1, 0] = sigma[0, 1]
    sigma[1, 1] = g10 * (a * g10 + b * g11) + g11 * (b * g10 + d * g11)


class Innovation(NamedTuple):
    """What :func:`innovation_statistics_kernel` computes for one landmark (lines 12–14 and 18), entry by entry.

    ``nu0, nu1``: :math:`\\nu = z - \\hat z` [m, rad] (bearing wrapped); ``h00 … h11``:
    :math:`H = \\partial h/\\partial m`; ``q00, q01, q11``: :math:`Q = H\\Sigma H^\\top + R` (symmetric:
    ``q10 = q01``); ``d2``: :math:`d^2 = \\nu^\\top Q^{-1}\\nu`; ``loglik``: :math:`\\log\\mathcal N(\\nu; 0, Q)`.
    A named tuple: numba passes it as plain numbers, and it unpacks like the tuple it is.
    """

    nu0: float
    nu1: float
    h00: float
    h01: float
    h10: float
    h11: float
    q00: float
    q01: float
    q11: float
    d2: float
    loglik: float


@njit(cache=True, inline="always")
def innovation_statistics_kernel(pose, z, R, mu, sigma):
    """Lines 12–14 and 18: innovation, its covariance and likelihood for one landmark, as an :class:`Innovation`.

    :math:`\\nu = z - \\hat z` (bearing wrapped), :math:`H`, :math:`Q = H\\Sigma H^\\top + R` (symmetric),
    :math:`d^2 = \\nu^\\top Q^{-1}\\nu` and :math:`\\log\\mathcal N(\\nu; 0, Q) = -\\tfrac12 d^2 - \\log 2\\pi - \\tfrac12\\log\\det Q`.
    """
    r, phi, h00, h01, h10, h11 = expected_measurement(pose, mu)
    a, b, d = sigma[0, 0], sigma[0, 1], sigma[1, 1]
    p00, p01 = h00 * a + h01 * b, h00 * b + h01 * d  # P = H Σ
    p10, p11 = h10 * a + h11 * b, h10 * b + h11 * d
    q00 = p00 * h00 + p01 * h01 + R[0, 0]  # Q = H Σ Hᵀ + R
    q01 = p00 * h10 + p01 * h11 + 0.5 * (R[0, 1] + R[1, 0])
    q11 = p10 * h10 + p11 * h11 + R[1, 1]
    det_q = q00 * q11 - q01 * q01
    nu0 = z[0] - r
    nu1 = wrap_angle_kernel(z[1] - phi)
    d2 = (q11 * nu0 * nu0 - 2.0 * q01 * nu0 * nu1 + q00 * nu1 * nu1) / det_q
    loglik = -0.5 * d2 - LOG_2PI - 0.5 * math.log(det_q)
    return Innovation(nu0, nu1, h00, h01, h10, h11, q00, q01, q11, d2, loglik)


@njit(cache=True, inline="always")
def update_landmark_kernel(pose, z, R, mu, sigma, gate_chi2):
    """Lines 12–18: the EKF update of one landmark (``mu`` (2,), ``sigma`` (2, 2), in place).

    :math:`K = \\Sigma H^\\top Q^{-1}`, :math:`\\mu \\mathrel{+}= K\\nu`, :math:`\\Sigma = (I - KH)\\Sigma`
    (kept exactly symmetric), unless :math:`d^2 >` ``gate_chi2`` (``inf``: always).
    Returns ``(d2, loglik)`` of :func:`innovation_statistics_kernel`, computed before the update.
    """
    nu0, nu1, h00, h01, h10, h11, q00, q01, q11, d2, loglik = innovation_statistics_kernel(pose, z, R, mu, sigma)
    if d2 > gate_chi2:
        return d2, loglik
    det_q = q00 * q11 - q01 * q01
    inv_det = 1.0 / det_q
    i00, i01, i11 = q11 * inv_det, -q01 * inv_det, q00 * inv_det  # Q⁻¹
    a, b, d = sigma[0, 0], sigma[0, 1], sigma[1, 1]
    s00, s01 = a * h00 + b * h01, a * h10 + b * h11  # Σ Hᵀ
    s10, s11 = b * h00 + d * h01, b * h10 + d * h11
    k00, k01 = s00 * i00 + s01 * i01, s00 * i01 + s01 * i11  # K = Σ Hᵀ Q⁻¹
    k10, k11 = s10 * i00 + s11 * i01, s10 * i01 + s11 * i11
    mu[0] += k00 * nu0 + k01 * nu1
    mu[1] += k10 * nu0 + k11 * nu1
    # Σ − K H Σ = Σ − K (Σ Hᵀ)ᵀ, the off-diagonal entry computed once (symmetric)
    sigma[0, 0] = a - (k00 * s00 + k01 * s01)
    sigma[0, 1] = sigma[1, 0] = b - (k00 * s10 + k01 * s11)
    sigma[1, 1] = d - (k10 * s10 + k11 * s11)
    return d2, loglik


def update_landmark_textbook(mu, Sigma, x, z, R) -> tuple[np.ndarray, np.ndarray, float]:
    """The same EKF update for ONE landmark, written line by line like FastSLAM_1 lines 12–18.

    :func:`update_landmark` with a different job: to be read next to the table (plain
    2×2 numpy, ``np.linalg.inv`` and the textbook covariance ``(I − K H) Σ``), and to be
    the independent reference that :func:`update_landmark` and :func:`update_landmark_kernel`
    (closed-form inverses, entries written out) are tested against. Hence its own name,
    not a twin's suffix.

    Parameters
    ----------
    mu : array_like, shape (2,)
        Prior landmark mean μ [m].
    Sigma : array_like, shape (2, 2)
        Prior landmark covariance Σ [m²].
    x : array_like, shape (3,)
        Particle pose ``(x, y, θ)`` [m, m, rad].
    z : array_like, shape (2,)
        Measurement ``(r, φ)`` [m, rad].
    R : array_like, shape (2, 2)
        Measurement noise covariance [m², rad²] (``Q_t`` in the notes).

    Returns
    -------
    mu_new : ndarray, shape (2,)
    Sigma_new : ndarray, shape (2, 2)
    log_w : float
        ``log`` of line 18's weight ``w = |2πQ|^(−½) exp(−½ νᵀ Q⁻¹ ν)``.
    """
    caller = "update_landmark_textbook"
    mu = finite_array("mu", mu, caller, (2,))
    Sigma = finite_array("Sigma", Sigma, caller, (2, 2))
    x = finite_array("x", x, caller, (3,))
    z = finite_array("z", z, caller, (2,))
    R = finite_array("R", R, caller, (2, 2))
    if mu.shape != (2,) or Sigma.shape != (2, 2) or x.shape != (3,) or z.shape != (2,):
        raise ValueError(f"{caller}: one landmark only; use update_landmark for batches")

    z_hat = range_bearing(x, mu)                      # line 12: ẑ = h(μ, x)
    H = jacobian_landmark(x, mu)                      # line 13: H = h'(μ, x)
    Q = H @ Sigma @ H.T + R                           # line 14: Q = H Σ Hᵀ + Q_t
    K = Sigma @ H.T @ np.linalg.inv(Q)                # line 15: K = Σ Hᵀ Q⁻¹
    nu = innovation(z, z_hat)                         # z − ẑ, bearing wrapped
    mu_new = mu + K @ nu                              # line 16: μ' = μ + K (z − ẑ)
    Sigma_new = (np.eye(2) - K @ H) @ Sigma           # line 17: Σ' = (I − K H) Σ
    # line 18: w = |2πQ|^(−½) exp(−½ νᵀ Q⁻¹ ν), kept as a logarithm
    log_w = -0.5 * nu @ np.linalg.inv(Q) @ nu - 0.5 * np.log(np.linalg.det(2 * np.pi * Q))
    return mu_new, Sigma_new, float(log_w)
