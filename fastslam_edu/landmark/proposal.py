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
is the paper's; :func:`improved_pose_information_form` computes it that way.) The importance
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

import math

import numpy as np
from numba import njit

from fastslam_edu.core.angles import wrap_angle_kernel
from fastslam_edu.core.ekf import LOG_2PI, expected_measurement, innovation_statistics_kernel
from fastslam_edu.core.measurement import innovation, jacobian_landmark, jacobian_pose, range_bearing
from fastslam_edu.core.motion import MotionNoise
from fastslam_edu.landmark.step_records import Sightings


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
    u = np.ascontiguousarray(np.atleast_2d(np.asarray(u, dtype=float)))
    dt = np.ascontiguousarray(np.atleast_1d(np.asarray(dt, dtype=float)))
    delta, P = np.empty(3), np.empty((3, 3))
    segment_motion_kernel(u, dt, noise.densities, noise.mode == "control", delta, P)
    return delta, P


@njit(cache=True)
def segment_motion_kernel(u, dt, noise, control, delta, P):
    """:func:`segment_motion` into ``delta`` (3,) and ``P`` (3, 3), compiled: ``noise`` = (σ_v, σ_ω, σ_xy, σ_θ)
    (:class:`~fastslam_edu.core.motion.MotionNoise` densities), ``control`` True for noise on the command."""
    n = dt.shape[0]
    heading, px, py = np.empty(n), np.empty(n), np.empty(n)  # during step j; position after it
    x = y = theta = 0.0
    for j in range(n):
        heading[j] = theta
        x += u[j, 0] * dt[j] * math.cos(theta)
        y += u[j, 0] * dt[j] * math.sin(theta)
        theta += u[j, 1] * dt[j]
        px[j], py[j] = x, y
    delta[0], delta[1], delta[2] = x, y, theta
    P[:] = 0.0
    turn_var = noise[1] ** 2 if control else noise[3] ** 2
    for j in range(n):
        turn = (-(y - py[j]), x - px[j], 1.0)  # the rest of the path rotates about the position after step j
        along = (math.cos(heading[j]), math.sin(heading[j]), 0.0)
        for a in range(3):
            for b in range(3):
                P[a, b] += turn_var * dt[j] * turn[a] * turn[b]
                if control:
                    P[a, b] += noise[0] ** 2 * dt[j] * along[a] * along[b]
    if not control:
        total = noise[2] ** 2 * np.sum(dt)
        P[0, 0] += total
        P[1, 1] += total


def motion_prediction(x0, delta, P_rel) -> tuple[np.ndarray, np.ndarray]:
    """:math:`\\bar x` and :math:`P` for particles starting at ``x0`` (M, 3).

    The segment's :func:`segment_motion` rotated into each particle's frame:
    :math:`\\bar x = x_0 \\oplus \\Delta`, :math:`P = T P_\\text{rel} T^\\top` with
    :math:`T = \\operatorname{diag}(R(\\theta_0), 1)`. Returns (M, 3) and (M, 3, 3).
    """
    x0 = np.ascontiguousarray(np.asarray(x0, dtype=float).reshape(-1, 3))
    x_bar, P = np.empty_like(x0), np.empty((len(x0), 3, 3))
    motion_prediction_kernel(x0, np.asarray(delta, dtype=float), np.ascontiguousarray(P_rel, dtype=float),
                             x_bar, P)
    return x_bar, P


@njit(cache=True)
def motion_prediction_kernel(x0, delta, P_rel, x_bar, P):
    """:func:`motion_prediction` into ``x_bar`` (M, 3) and ``P`` (M, 3, 3), compiled."""
    for m in range(x0.shape[0]):
        c, s = math.cos(x0[m, 2]), math.sin(x0[m, 2])
        x_bar[m, 0] = x0[m, 0] + c * delta[0] - s * delta[1]
        x_bar[m, 1] = x0[m, 1] + s * delta[0] + c * delta[1]
        x_bar[m, 2] = x0[m, 2] + delta[2]
        T = ((c, -s, 0.0), (s, c, 0.0), (0.0, 0.0, 1.0))
        for a in range(3):
            for b in range(3):
                total = 0.0
                for i in range(3):
                    for k in range(3):
                        total += T[a][i] * P_rel[i, k] * T[b][k]
                P[m, a, b] = total


@njit(cache=True, inline="always")
def improved_pose_kernel(x_hat, x_bar, P, mu, sigma, z, R, e):
    """The proposal for one particle and one sighting, in place; returns ``(d2, loglik)``.

    At the motion prediction :math:`\\bar x` (3,) with covariance :math:`P` (3, 3): :math:`\\bar\\nu = z - \\hat z(\\bar x)`,
    :math:`H` and :math:`Q = H\\Sigma H^\\top + R` (:func:`fastslam_edu.core.ekf.innovation_statistics_kernel`
    for the landmark ``mu`` (2,), ``sigma`` (2, 2)), :math:`G = \\partial h/\\partial x = (-H \\mid (0, -1)^\\top)`,
    :math:`S = G P G^\\top + Q`, :math:`K = P G^\\top S^{-1}`. Then, in place: the motion sample ``x_hat`` (3,)
    becomes :math:`\\hat x + K\\,(z + L e - \\hat z(\\hat x))` with :math:`L L^\\top = Q` and ``e`` (2,) standard
    normals (heading wrapped), ``x_bar`` becomes :math:`\\mu_x = \\bar x + K\\bar\\nu`, ``P`` becomes
    :math:`\\Sigma_x = (I - K G) P` (kept symmetric). Returns :math:`d^2 = \\bar\\nu^\\top S^{-1}\\bar\\nu` and
    :math:`\\log\\mathcal N(\\bar\\nu; 0, S)`.
    """
    nu0, nu1, h00, h01, h10, h11, q00, q01, q11, _, _ = innovation_statistics_kernel(x_bar, z, R, mu, sigma)
    G = ((-h00, -h01, 0.0), (-h10, -h11, -1.0))
    PG = np.zeros((3, 2))  # P Gᵀ
    for a in range(3):
        for r in range(2):
            for b in range(3):
                PG[a, r] += P[a, b] * G[r][b]
    s00 = G[0][0] * PG[0, 0] + G[0][1] * PG[1, 0] + G[0][2] * PG[2, 0] + q00  # S = G P Gᵀ + Q
    s01 = G[0][0] * PG[0, 1] + G[0][1] * PG[1, 1] + G[0][2] * PG[2, 1] + q01
    s11 = G[1][0] * PG[0, 1] + G[1][1] * PG[1, 1] + G[1][2] * PG[2, 1] + q11
    det_s = s00 * s11 - s01 * s01
    i00, i01, i11 = s11 / det_s, -s01 / det_s, s00 / det_s  # S⁻¹
    K = np.empty((3, 2))
    for a in range(3):
        K[a, 0] = PG[a, 0] * i00 + PG[a, 1] * i01
        K[a, 1] = PG[a, 0] * i01 + PG[a, 1] * i11
    d2 = (s11 * nu0 * nu0 - 2.0 * s01 * nu0 * nu1 + s00 * nu1 * nu1) / det_s
    loglik = -0.5 * d2 - LOG_2PI - 0.5 * math.log(det_s)
    l00 = math.sqrt(q00)  # L Lᵀ = Q
    l10 = q01 / l00
    l11 = math.sqrt(q11 - l10 * l10)
    r, phi = expected_measurement(x_hat, mu)[:2]
    v0 = z[0] + l00 * e[0] - r
    v1 = wrap_angle_kernel(z[1] + l10 * e[0] + l11 * e[1] - phi)
    for a in range(3):
        x_hat[a] += K[a, 0] * v0 + K[a, 1] * v1
        x_bar[a] += K[a, 0] * nu0 + K[a, 1] * nu1
    x_hat[2] = wrap_angle_kernel(x_hat[2])
    for a in range(3):  # Σ_x = P − K G P = P − K (P Gᵀ)ᵀ
        for b in range(3):
            P[a, b] -= K[a, 0] * PG[b, 0] + K[a, 1] * PG[b, 1]
    for a in range(3):
        for b in range(a + 1, 3):
            P[a, b] = P[b, a] = 0.5 * (P[a, b] + P[b, a])
    return d2, loglik


@njit(cache=True)
def _improved_poses(x_hat, x_bar, P, mu, Sigma, z, R, eps):
    d2, loglik = np.empty(x_hat.shape[0]), np.empty(x_hat.shape[0])
    for m in range(x_hat.shape[0]):
        d2[m], loglik[m] = improved_pose_kernel(x_hat[m], x_bar[m], P[m], mu[m], Sigma[m], z, R, eps[m])
    return d2, loglik


def improved_pose(x_hat, x_bar, P, mu, Sigma, *, z, R, eps):
    """The proposal for one sighting, for n particles (:func:`improved_pose_kernel` for each).

    The particles' poses and maps are given by position, the sighting and the draws by name:
    ``improved_pose(x_hat, x_bar, P, mu, Sigma, z=z, R=R, eps=eps)``.

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
    x, x_bar_new, P_new = (np.array(a, dtype=float) for a in (x_hat, x_bar, P))  # private copies, changed in place
    mu, Sigma, eps = (np.ascontiguousarray(a, dtype=float) for a in (mu, Sigma, eps))
    d2, loglik = _improved_poses(x, x_bar_new, P_new, mu, Sigma, np.asarray(z, dtype=float),
                                 np.asarray(R, dtype=float), eps)
    return x, x_bar_new, P_new, loglik, d2


def improved_pose_information_form(x_bar, P, mu, Sigma, z, R):
    """The proposal's Gaussian and weight for one particle, in the paper's information form.

    :math:`\\Sigma_x = (G^\\top Q^{-1} G + P^{-1})^{-1}`,
    :math:`\\mu_x = \\bar x + \\Sigma_x G^\\top Q^{-1} (z - \\hat z(\\bar x))`,
    :math:`\\log w = \\log \\mathcal N(z; \\hat z(\\bar x), G P G^\\top + Q)`.
    Shapes (3,), (3, 3), (2,), (2, 2), (2,), (2, 2); returns ``(mu_x, Sigma_x, log_w)``.
    A plain version for teaching and for testing :func:`improved_pose` (a different
    formula for the same numbers): a job of its own, hence a name of its own, not
    a twin's suffix (:func:`improved_pose` and its compiled twin :func:`improved_pose_kernel`
    draw the sample by the Kalman gain).
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
    :func:`fastslam_edu.landmark.particle_set.update_with_measurements`), with the gate and the
    exponents :math:`\\beta` as for its own.
    """
    z, k, R, escape = sightings
    S = Sightings(np.asarray(z, dtype=float).reshape(-1, 2), np.asarray(k, dtype=np.int64),
                  np.ascontiguousarray(R, dtype=float), np.asarray(escape, dtype=np.bool_), np.ones(len(z)),
                  np.full((len(particles), len(z)), np.nan))
    sample_improved_poses_kernel(particles.arrays(), S, np.array(x_bar, dtype=float), np.array(P, dtype=float),
                                 math.inf if gate_chi2 is None else float(gate_chi2), int(min_count), rng)
    return S.loglik


@njit(cache=True)
def sample_improved_poses_kernel(P, S, x_bar, cov, gate_chi2, min_count, rng):
    """:func:`sample_improved_poses` on the particle arrays ``P`` (:class:`~fastslam_edu.landmark.fastslam_step.Particles`)
    and the sightings ``S`` (:class:`~fastslam_edu.landmark.fastslam_step.Sightings`; the weights go to ``S.loglik``),
    compiled: particle by particle, the proposal of :func:`improved_pose_kernel` where the gate lets it."""
    x, xb, c, e = np.empty(3), np.empty(3), np.empty((3, 3)), np.empty(2)
    for i in range(S.j.shape[0]):
        j = S.j[i]
        if (S.j[:i] == j).any():  # a landmark read twice at one instant: once
            continue
        for m in range(P.poses.shape[0]):
            if not (P.seen[m, j] and P.count[m, j] >= min_count):
                continue
            e[0], e[1] = rng.standard_normal(), rng.standard_normal()
            x[:], xb[:], c[:] = P.poses[m], x_bar[m], cov[m]
            d2, loglik = improved_pose_kernel(x, xb, c, P.mu[m, j], P.sigma[m, j], S.z[i], S.R[i], e)
            if S.escape[i] or d2 <= gate_chi2:
                P.poses[m], x_bar[m], cov[m] = x, xb, c
                S.loglik[m, i] = loglik
