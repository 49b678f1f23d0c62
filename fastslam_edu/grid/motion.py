"""The grid filter's motion model: the odometry increment plus noise that grows with it.

Motion noise, scaled to the increment
-------------------------------------
With ``u_k = (Δx, Δy, Δθ)`` in the robot frame and ``d = ‖(Δx, Δy)‖``, the
noise is ``ε ~ N(0, diag(σ_t², σ_t², σ_θ²))`` with (:func:`increment_noise_std`)::

    σ_t = α_tt d + α_tr |Δθ| + σ_t0        [m]
    σ_θ = α_rt d + α_rr |Δθ| + σ_θ0        [rad]

so a robot standing still gets only the floors ``σ_t0, σ_θ0``, and the spread
grows with what odometry measured (the same four-parameter shape as
GMapping's ``srr, srt, str, stt`` and Thrun et al.'s ``α₁…α₄``). Noise is added
to the increment *before* composition, i.e. in the robot frame of ``x_{k−1}``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from fastslam_edu.core.se2 import compose

if TYPE_CHECKING:  # only for the annotations: gridslam imports this module
    from fastslam_edu.grid.gridslam import GridSLAMParams

__all__ = ["increment_noise_std", "sample_odometry_motion"]


def increment_noise_std(u, params: GridSLAMParams) -> np.ndarray:
    """Standard deviations ``(σ_t, σ_t, σ_θ)`` of the noise added to an increment.

    ``σ_t = α_tt d + α_tr |Δθ| + σ_t0``, ``σ_θ = α_rt d + α_rr |Δθ| + σ_θ0`` with
    ``d = ‖(Δx, Δy)‖``.

    Parameters
    ----------
    u : array_like, shape (..., 3)
        Increments ``(Δx, Δy, Δθ)`` [m, m, rad] in the robot frame.
    params : GridSLAMParams

    Returns
    -------
    ndarray, shape (..., 3)
        ``(σ_t, σ_t, σ_θ)`` [m, m, rad].
    """
    u = np.asarray(u, dtype=float)
    if u.shape[-1:] != (3,) or not np.isfinite(u).all():
        raise ValueError(f"increment_noise_std: u must be finite with shape (..., 3), got shape {u.shape}")
    d = np.hypot(u[..., 0], u[..., 1])
    rot = np.abs(u[..., 2])
    st = params.alpha_tt * d + params.alpha_tr * rot + params.sigma_t0
    sr = params.alpha_rt * d + params.alpha_rr * rot + params.sigma_theta0
    return np.stack([st, st, sr], axis=-1)


def sample_odometry_motion(particles, u, params: GridSLAMParams, rng: np.random.Generator) -> np.ndarray:
    """Propagate all particles with one noisy increment: ``x_k^{[i]} = x_{k−1}^{[i]} ⊕ (u_k + ε^{[i]})``.

    ``ε^{[i]} = σ ⊙ n^{[i]}``, ``n^{[i]} ~ N(0, I₃)`` with ``σ`` from
    :func:`increment_noise_std`. Draws exactly ``rng.standard_normal((M, 3))``.

    Parameters
    ----------
    particles : ndarray, shape (M, 3)
    u : array_like, shape (3,)
    params : GridSLAMParams
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (M, 3)
    """
    particles = np.asarray(particles, dtype=float)
    if particles.ndim != 2 or particles.shape[1] != 3:
        raise ValueError(f"sample_odometry_motion: particles must have shape (M, 3), got {particles.shape}")
    sigma = increment_noise_std(u, params)
    noise = rng.standard_normal(particles.shape) * sigma
    return compose(particles, np.asarray(u, dtype=float) + noise)
