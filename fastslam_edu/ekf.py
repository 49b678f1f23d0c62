"""One 2×2 extended Kalman filter per landmark per particle (FastSLAM 1.0, lines 7–18).

In FastSLAM 1.0 each particle carries its own pose ``x`` and, for every landmark
``j`` it has seen, a Gaussian ``N(μ_j, Σ_j)`` over the landmark position. Given
the particle's pose, the landmark is the only unknown, so each landmark has a
tiny EKF with a 2-D state ``μ`` [m] and the range–bearing measurement
``z = (r, φ) = h(x, μ)`` of :mod:`fastslam_edu.measurement`.

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
and determinants are written out in closed form so that everything is a few
vectorised numpy operations. :func:`update_landmark_one` is the same update
for a single landmark, written line by line like the textbook.
"""

from __future__ import annotations

import numpy as np

from fastslam_edu.angles import wrap_angle

from fastslam_edu.measurement import (
    _as_finite,
    _at,
    innovation,
    jacobian_inverse,
    jacobian_landmark,
    landmark_from_measurement,
    range_bearing,
)


#: log(2π), the constant of the 2-D Gaussian log-density.
LOG_2PI = float(np.log(2.0 * np.pi))


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
    A = _as_finite(name, A, (2, 2), caller)
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
    nu = _as_finite("nu", nu, (2,), "gaussian_log_likelihood")
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
    z = _as_finite("z", z, (2,), "initialise_landmark")
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
    :mod:`fastslam_edu.fastslam` rejects measurements beyond such a threshold.

    Shapes as in :func:`update_landmark`; returns ``nu (..., 2)`` and ``d2 (...)``.
    """
    caller = "innovation_statistics"
    mu = _as_finite("mu", mu, (2,), caller)
    Sigma = _check_covariance("Sigma", Sigma, caller)
    x = _as_finite("x", x, (3,), caller)
    z = _as_finite("z", z, (2,), caller)
    R = _check_covariance("R", R, caller)
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
    caller = "update_landmark"
    mu = _as_finite("mu", mu, (2,), caller)
    Sigma = _check_covariance("Sigma", Sigma, caller)
    x = _as_finite("x", x, (3,), caller)
    z = _as_finite("z", z, (2,), caller)
    R = _check_covariance("R", R, caller)

    jacobian_landmark(x, mu)  # raises a clear ValueError if a landmark sits on the robot (r = 0)
    # the unchecked update reads Σ's upper triangle: remove the (tolerated) rounding asymmetry first
    mu_new, Sigma_new, log_likelihood, _ = update_landmark_unchecked(mu, _symmetrise(Sigma), x, z, R)
    return mu_new, Sigma_new, log_likelihood


def update_landmark_unchecked(mu, Sigma, x, z, R):
    """:func:`update_landmark` without the input checks, also returning ``d² = νᵀQ⁻¹ν``.

    The filter's inner loop calls this with arrays it has built itself (already
    checked once); it computes exactly what :func:`update_landmark` documents,
    plus the squared Mahalanobis distance of the innovation used by the outlier
    gate. Returns ``(mu_new, Sigma_new, log_likelihood, d2)``.

    It is the two halves below in a row: :func:`innovation_unchecked` (predict
    the measurement, compare, weigh) and :func:`kalman_correction_unchecked` (move
    the landmark). The filter calls them separately so that the outlier gate can
    look at ``d²`` before the landmark moves.
    """
    terms, d2, log_likelihood = innovation_unchecked(mu, Sigma, x, z, R)
    mu_new, Sigma_new = kalman_correction_unchecked(mu, terms)
    return mu_new, Sigma_new, log_likelihood, d2


def innovation_unchecked(mu, Sigma, x, z, R):
    """First half of the EKF update: ``ẑ``, ``H``, ``Q``, ``ν``, ``d²`` and ``log N(ν; 0, Q)``.

    Shapes as in :func:`update_landmark` (unchecked inputs; ``Σ`` must be exactly
    symmetric, as every covariance the filter stores is).

    Returns
    -------
    terms : tuple
        What :func:`kalman_correction_unchecked` needs, entry by entry:
        ``ν = (ν_r, ν_φ)``, ``P = H Σ`` (4 entries), ``Q⁻¹`` (3 entries) and ``Σ`` (3 entries).
    d2 : ndarray, shape (...)
        ``νᵀ Q⁻¹ ν``, the squared Mahalanobis distance (for the gate).
    log_likelihood : ndarray, shape (...)
        ``log N(ν; 0, Q) = −½ d² − log 2π − ½ log det Q``.
    """
    # The algebra of update_landmark written out entry by entry for 2×2
    # matrices: ~70 elementwise operations on (M,) arrays beat a dozen stacked
    # matmuls when M is in the hundreds.
    dx = mu[..., 0] - x[..., 0]
    dy = mu[..., 1] - x[..., 1]
    q = dx * dx + dy * dy
    r = np.sqrt(q)
    h00, h01, h10, h11 = dx / r, dy / r, -dy / q, dx / q  # H = ∂h/∂m
    a, b, d = Sigma[..., 0, 0], Sigma[..., 0, 1], Sigma[..., 1, 1]
    R = np.asarray(R, dtype=float)
    p00, p01 = h00 * a + h01 * b, h00 * b + h01 * d  # P = H Σ
    p10, p11 = h10 * a + h11 * b, h10 * b + h11 * d
    q00 = p00 * h00 + p01 * h01 + R[..., 0, 0]  # Q = H Σ Hᵀ + R
    q01 = p00 * h10 + p01 * h11 + 0.5 * (R[..., 0, 1] + R[..., 1, 0])
    q11 = p10 * h10 + p11 * h11 + R[..., 1, 1]
    det_Q = q00 * q11 - q01 * q01
    i00, i01, i11 = q11 / det_Q, -q01 / det_Q, q00 / det_Q  # Q⁻¹
    n0 = z[..., 0] - r  # ν = z ⊖ ẑ
    n1 = wrap_angle(z[..., 1] - (np.arctan2(dy, dx) - x[..., 2]))
    d2 = n0 * (i00 * n0 + i01 * n1) + n1 * (i01 * n0 + i11 * n1)
    log_likelihood = -0.5 * d2 - LOG_2PI - 0.5 * np.log(det_Q)
    return (n0, n1, p00, p01, p10, p11, i00, i01, i11, a, b, d), d2, log_likelihood


def kalman_correction_unchecked(mu, terms, apply=None):
    """Second half of the EKF update: ``K = Σ Hᵀ Q⁻¹``, ``μ' = μ + K ν``, ``Σ' = Σ − K H Σ``.

    ``terms`` from :func:`innovation_unchecked`. ``apply`` (bool, broadcasting with
    the batch shape): where False the gain is zero, so ``μ' = μ`` and ``Σ' = Σ``
    exactly — how the outlier gate leaves a landmark alone. Returns
    ``(mu_new (..., 2), Sigma_new (..., 2, 2))``; ``Σ'`` is exactly symmetric.
    """
    n0, n1, p00, p01, p10, p11, i00, i01, i11, a, b, d = terms
    if apply is not None:  # Q⁻¹ = 0 where not applied: then K = 0 exactly
        apply = np.asarray(apply, dtype=float)
        i00, i01, i11 = i00 * apply, i01 * apply, i11 * apply
    k00, k01 = p00 * i00 + p10 * i01, p00 * i01 + p10 * i11  # K = Σ Hᵀ Q⁻¹ = Pᵀ Q⁻¹
    k10, k11 = p01 * i00 + p11 * i01, p01 * i01 + p11 * i11
    mu_new = np.empty(np.shape(k00) + (2,))
    mu_new[..., 0] = mu[..., 0] + k00 * n0 + k01 * n1
    mu_new[..., 1] = mu[..., 1] + k10 * n0 + k11 * n1
    # Σ' = (I − K H) Σ = Σ − K P, whose symmetric part is Σ − K Q Kᵀ (c01 below is
    # computed once, so the result is exactly symmetric)
    c00 = a - (k00 * p00 + k01 * p10)
    c01 = b - (k00 * p01 + k01 * p11)
    c11 = d - (k10 * p01 + k11 * p11)
    Sigma_new = np.empty(np.shape(c00) + (2, 2))
    Sigma_new[..., 0, 0], Sigma_new[..., 1, 1] = c00, c11
    Sigma_new[..., 0, 1] = Sigma_new[..., 1, 0] = c01
    return mu_new, Sigma_new


def update_landmark_one(mu, Sigma, x, z, R) -> tuple[np.ndarray, np.ndarray, float]:
    """The same EKF update for ONE landmark, written like FastSLAM_1 lines 12–18.

    The teaching version of :func:`update_landmark`: plain 2×2 numpy,
    ``np.linalg.inv`` and the textbook covariance ``(I − K H) Σ``.

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
    caller = "update_landmark_one"
    mu = _as_finite("mu", mu, (2,), caller)
    Sigma = _as_finite("Sigma", Sigma, (2, 2), caller)
    x = _as_finite("x", x, (3,), caller)
    z = _as_finite("z", z, (2,), caller)
    R = _as_finite("R", R, (2, 2), caller)
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
