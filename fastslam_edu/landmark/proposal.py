"""FastSLAM 2.0's proposal: sample the pose from the motion *and* the sighting.

FastSLAM 1.0 samples the new pose from the motion model alone,
:math:`x_t^{[m]} \\sim p(x_t \\mid x_{t-1}^{[m]}, u_t)`, and lets the importance weights
sort the samples out. When the motion noise is wide compared with what a
sighting says about the pose (MR.CLAM: the heading drifts ~0.3 rad a minute
between sightings, a sighting pins it to a few hundredths), most samples land
where the sighting says the robot is not; resampling then copies the few that
fit, and the filter loses the diversity it needs later (*particle
depletion*). FastSLAM 2.0 (Montemerlo et al. 2003) samples from the motion
model *conditioned on the sighting*, linearised around the motion prediction
:math:`\\bar x` (noise-free motion from the particle's previous pose, covariance :math:`P`):

.. math::

    S = G P G^\\top + Q, \\qquad K_x = P G^\\top S^{-1}, \\qquad
    \\mu_x = \\bar x + K_x\\,(z - \\hat z(\\bar x)), \\qquad \\Sigma_x = (I - K_x G)\\,P

with :math:`G = \\partial h/\\partial x` (2×3, :func:`fastslam_edu.core.measurement.jacobian_pose`)
and :math:`Q = H \\Sigma H^\\top + R` the landmark's innovation covariance of FastSLAM 1.0.
(The information form of the same Gaussian, :math:`\\Sigma_x = (G^\\top Q^{-1} G + P^{-1})^{-1}`,
is the paper's; :func:`improved_pose_one` computes it that way.) The importance
weight becomes the likelihood of the sighting with the pose integrated out,

.. math::

    w = \\mathcal N(z;\\ \\hat z(\\bar x),\\ S),

which is how well the particle's *map* predicts the sighting, whatever its
sampled pose. The landmark's EKF is then updated from the new pose, exactly as
in FastSLAM 1.0.

**How the engine samples it.** The engine has already drawn the motion sample
:math:`\\hat x \\sim \\mathcal N(\\bar x, P)` (step 1, :mod:`fastslam_edu.core.motion`). It moves that
sample by a *perturbed observation*,
:math:`x = \\hat x + K_x\\,(z + \\varepsilon - \\hat z(\\hat x))`, :math:`\\varepsilon \\sim \\mathcal N(0, Q)`.
For a linear :math:`h` this is a draw from :math:`\\mathcal N(\\mu_x, \\Sigma_x)` exactly: with
:math:`\\hat x = \\bar x + \\delta`, :math:`x = \\mu_x + (I - K_x G)\\delta + K_x \\varepsilon`, whose covariance
:math:`(I - K_x G)P(I - K_x G)^\\top + K_x Q K_x^\\top` is :math:`(I - K_x G)P` for this gain
(tested against the closed form by simulation). So the motion step keeps its
random numbers, and FastSLAM 1.0 and 2.0 differ only in the update step.

Several sightings at one instant are used one after another, each with the
pose Gaussian the previous one left (:math:`\\bar x \\leftarrow \\mu_x`, :math:`P \\leftarrow \\Sigma_x`); their
log weights add.

Between two sightings the engine moves through many odometry steps; :math:`P` is
the motion noise of all of them carried to the end of the segment
(:func:`segment_motion`).
"""

from __future__ import annotations

import numpy as np

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.ekf import _det2, _inv2, _symmetrise, _transpose
from fastslam_edu.core.measurement import innovation, jacobian_landmark, jacobian_pose, range_bearing
from fastslam_edu.core.motion import MotionNoise, path_from_increments, segment_increments


def segment_motion(u, dt, noise: MotionNoise) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free motion through a segment of odometry steps, and its covariance.

    In the frame of the starting pose (at the origin, heading 0): the end pose
    :math:`\\Delta = (x_L, y_L, \\theta_L)` of the commands with no noise, and the
    covariance :math:`P` of the end pose, linearised around that path. With noise
    on the controls, step :math:`j` (heading :math:`\\theta_j` during the step, position
    :math:`p_{j+1}` after it) contributes

    * its speed noise (variance :math:`\\sigma_v^2 \\Delta t_j`) along :math:`(\\cos\\theta_j, \\sin\\theta_j, 0)`;
    * its turn noise (variance :math:`\\sigma_\\omega^2 \\Delta t_j`), which rotates the rest of the
      path about :math:`p_{j+1}`: along :math:`(-(y_L - y_{j+1}),\\ x_L - x_{j+1},\\ 1)`.

    With noise on the state, each step adds :math:`\\sigma_{xy}^2 \\Delta t_j` to both
    position variances and :math:`\\sigma_\\theta^2 \\Delta t_j` along the same rotation direction.
    :math:`P = \\sum_j J_j \\operatorname{diag}(\\cdot) J_j^\\top`.

    Parameters
    ----------
    u : array_like, shape (L, 2)
        Commands ``(v, ω)`` [m/s, rad/s].
    dt : array_like, shape (L,)
        Step lengths [s].
    noise : MotionNoise

    Returns
    -------
    delta : ndarray, shape (3,)
        End pose in the starting pose's frame [m, m, rad].
    P_rel : ndarray, shape (3, 3)
        Its covariance, in the same frame.
    """
    u = np.atleast_2d(np.asarray(u, dtype=float))
    dt = np.atleast_1d(np.asarray(dt, dtype=float))
    origin = np.zeros((1, 3))
    steps = segment_increments(origin, u, dt, MotionNoise(), np.zeros((1, len(dt), 3)))
    px, py, theta = path_from_increments(origin, *steps, wrap=False)[0].T  # after each step
    heading = theta - u[:, 1] * dt  # during each step
    turn = np.stack([-(py[-1] - py), px[-1] - px, np.ones_like(px)], axis=1)  # (L, 3)
    if noise.mode == "control":
        along = np.stack([np.cos(heading), np.sin(heading), np.zeros_like(px)], axis=1)
        P = (turn.T * noise.sigma_omega**2 * dt) @ turn + (along.T * noise.sigma_v**2 * dt) @ along
    else:
        P = (turn.T * noise.sigma_theta**2 * dt) @ turn
        P[:2, :2] += np.eye(2) * noise.sigma_xy**2 * dt.sum()
    return np.array([px[-1], py[-1], theta[-1]]), P


def motion_prediction(x0, delta, P_rel) -> tuple[np.ndarray, np.ndarray]:
    """:math:`\\bar x` and :math:`P` for particles starting at ``x0`` (M, 3).

    The segment's :func:`segment_motion` rotated into each particle's frame:
    :math:`\\bar x = x_0 \\oplus \\Delta`, :math:`P = T P_\\text{rel} T^\\top` with
    :math:`T = \\operatorname{diag}(R(\\theta_0), 1)`. Returns (M, 3) and (M, 3, 3).
    """
    x0 = np.asarray(x0, dtype=float)
    c, s = np.cos(x0[:, 2]), np.sin(x0[:, 2])
    xbar = np.column_stack([x0[:, 0] + c * delta[0] - s * delta[1],
                            x0[:, 1] + s * delta[0] + c * delta[1],
                            x0[:, 2] + delta[2]])
    T = np.zeros((len(x0), 3, 3))
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1], T[:, 2, 2] = c, -s, s, c, 1.0
    return xbar, T @ P_rel @ _transpose(T)


def _cholesky2(Q):
    """Lower-triangular ``L`` with ``L Lᵀ = Q`` for each 2×2 covariance in (n, 2, 2)."""
    L = np.zeros_like(Q)
    L[:, 0, 0] = np.sqrt(Q[:, 0, 0])
    L[:, 1, 0] = Q[:, 1, 0] / L[:, 0, 0]
    L[:, 1, 1] = np.sqrt(Q[:, 1, 1] - L[:, 1, 0] ** 2)
    return L


def _innovation(z, z_hat):
    nu = z - z_hat
    nu[..., 1] = wrap_angle(nu[..., 1])
    return nu


def improved_pose(x_hat, x_bar, P, mu, Sigma, z, R, eps):
    """The proposal for one sighting, for n particles at once (the engine's form).

    Parameters
    ----------
    x_hat : ndarray (n, 3)
        Motion samples :math:`\\hat x` [m, m, rad].
    x_bar, P : ndarray (n, 3), (n, 3, 3)
        Motion prediction :math:`\\bar x` and its covariance.
    mu, Sigma : ndarray (n, 2), (n, 2, 2)
        The landmark's EKF in each particle.
    z : ndarray (2,)
        The sighting ``(r, φ)``.
    R : ndarray (2, 2)
        Measurement noise.
    eps : ndarray (n, 2)
        Standard normal draws (the perturbation is :math:`L\\varepsilon`, :math:`LL^\\top = Q`).

    Returns
    -------
    x : ndarray (n, 3)
        The new pose samples (heading wrapped).
    x_bar_new, P_new : ndarray (n, 3), (n, 3, 3)
        :math:`\\mu_x` and :math:`\\Sigma_x`, for a further sighting at the same instant.
    loglik : ndarray (n,)
        :math:`\\log \\mathcal N(z; \\hat z(\\bar x), S)`.
    d2 : ndarray (n,)
        :math:`\\nu^\\top S^{-1} \\nu`, for the gate.
    """
    z_bar, H, G = range_bearing(x_bar, mu), jacobian_landmark(x_bar, mu), jacobian_pose(x_bar, mu)
    Q = H @ Sigma @ _transpose(H) + R
    S = G @ P @ _transpose(G) + Q
    det_S = _det2(S)
    S_inv = _inv2(S, det_S)
    K = P @ _transpose(G) @ S_inv  # (n, 3, 2)
    nu_bar = _innovation(z, z_bar)
    d2 = np.einsum("ni,nij,nj->n", nu_bar, S_inv, nu_bar)
    loglik = -0.5 * d2 - np.log(2.0 * np.pi) - 0.5 * np.log(det_S)
    z_hat = range_bearing(x_hat, mu)
    perturbation = np.einsum("nij,nj->ni", _cholesky2(Q), eps)
    x = x_hat + np.einsum("nij,nj->ni", K, _innovation(z + perturbation, z_hat))
    x[:, 2] = wrap_angle(x[:, 2])
    x_bar_new = x_bar + np.einsum("nij,nj->ni", K, nu_bar)
    return x, x_bar_new, _symmetrise(P - K @ G @ P), loglik, d2


def improved_pose_one(x_bar, P, mu, Sigma, z, R):
    """The proposal's Gaussian and weight for one particle, in the paper's information form.

    :math:`\\Sigma_x = (G^\\top Q^{-1} G + P^{-1})^{-1}`,
    :math:`\\mu_x = \\bar x + \\Sigma_x G^\\top Q^{-1} (z - \\hat z(\\bar x))`,
    :math:`\\log w = \\log \\mathcal N(z; \\hat z(\\bar x), G P G^\\top + Q)`.
    Shapes (3,), (3, 3), (2,), (2, 2), (2,), (2, 2); returns ``(mu_x, Sigma_x, log_w)``.
    A plain version for teaching and for testing :func:`improved_pose` (a different
    formula for the same numbers).
    """
    x_bar, P, mu, Sigma, z, R = (np.asarray(a, dtype=float) for a in (x_bar, P, mu, Sigma, z, R))
    H, G = jacobian_landmark(x_bar, mu), jacobian_pose(x_bar, mu)
    Q = H @ Sigma @ H.T + R
    Q_inv = np.linalg.inv(Q)
    Sigma_x = np.linalg.inv(G.T @ Q_inv @ G + np.linalg.inv(P))
    nu = innovation(z, range_bearing(x_bar, mu))
    mu_x = x_bar + Sigma_x @ G.T @ Q_inv @ nu
    S = G @ P @ G.T + Q
    log_w = -0.5 * nu @ np.linalg.solve(S, nu) - np.log(2.0 * np.pi) - 0.5 * np.log(np.linalg.det(S))
    return mu_x, Sigma_x, float(log_w)


def sample_improved_poses(particles, sightings, x_bar, P, *, gate_chi2, rng, min_count: int = 2) -> np.ndarray:
    """Move the particles' poses by the proposal, for the ``sightings`` ``(z, k, R, escape)`` of one instant.

    ``z`` (n, 2) of landmarks ``k`` (n,), with noise ``R`` (n, 2, 2); ``escape`` (n,) bool: those applied without the gate.

    Used for each sighting of a landmark that the particle has used at least
    ``min_count`` times (default 2: a landmark read once is only as good as that
    one reading; 1 for a known map) and, with
    the gate on and no ``escape``, only where :math:`d^2 = \\nu^\\top S^{-1} \\nu` is within
    ``gate_chi2``: an outlier must not drag the pose. A landmark read twice at one
    instant is used once (FastSLAM 1.0's update takes the second reading after
    the first; its weight stays 1.0's).

    Changes ``particles.poses`` and returns the weights, (M, n): :math:`\\log \\mathcal N(z; \\hat z(\\bar x), S)`
    for each particle moved by sighting ``j``, NaN where the proposal was not used
    (FastSLAM 1.0's weight applies there). FastSLAM 1.0's update of the same
    sightings then takes them (``proposal_loglik`` of
    :func:`fastslam_edu.landmark.fastslam.update_with_measurements`), with the gate and the
    exponents :math:`\\beta` as for its own.
    """
    z, k, R, escape = sightings
    loglik = np.full((len(particles), len(z)), np.nan)
    used = set()
    x_bar, P = x_bar.copy(), P.copy()
    for j, landmark in enumerate(np.asarray(k, dtype=int)):
        if landmark in used:
            continue
        used.add(landmark)
        idx = np.flatnonzero(particles.seen[:, landmark] & (particles.count[:, landmark] >= min_count))
        if idx.size == 0:
            continue
        mu, Sigma = particles.mu[idx, landmark], particles.sigma[idx, landmark]
        eps = rng.standard_normal((idx.size, 2))
        x, x_bar_j, P_j, loglik_j, d2 = improved_pose(particles.poses[idx], x_bar[idx], P[idx], mu, Sigma, z[j], R[j],
                                                      eps)
        if gate_chi2 is not None and not escape[j]:
            keep = d2 <= gate_chi2
            idx, x, x_bar_j, P_j, loglik_j = (a[keep] for a in (idx, x, x_bar_j, P_j, loglik_j))
        particles.poses[idx] = x
        x_bar[idx], P[idx] = x_bar_j, P_j
        loglik[idx, j] = loglik_j
    return loglik
