"""The factors of the smoother's least-squares problem: keyframes, odometry between them, and the sightings.

:mod:`fastslam_edu.landmark.smoother` minimises

.. math::

    \\tfrac12 \\|x_0 - \\bar x_0\\|^2_{P_0}
    + \\tfrac12 \\sum_k \\|(x_{k-1}^{-1} \\oplus x_k) \\ominus \\Delta_k\\|^2_{C_k}
    + \\tfrac12 \\sum_i \\beta_i \\|z_i \\ominus h(x_{k_i}, m_{j_i})\\|^2_{R_i}.

This module builds its pieces: which stream steps get a pose variable (:func:`keyframe_steps`); the path from the
commands alone (:func:`dead_reckon_stream`), about which the odometry factors :math:`(\\Delta_k, C_k)` are
linearised (:func:`odometry_factors`; with the odometry's calibration, :class:`OdometryModel`); the residuals and
Jacobians of both kinds of factor (:func:`odometry_residuals`, :func:`sighting_residuals`); the whitening
:math:`W = L^{-1}` of a covariance (:func:`whitening`) and the filter's tempering :math:`\\beta_i` of every sighting
(:func:`sighting_weights`).
"""

from __future__ import annotations

import numpy as np

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.measurement import innovation, jacobian_landmark, jacobian_pose, range_bearing
from fastslam_edu.core.motion import MotionNoise, dead_reckon
from fastslam_edu.core.se2 import relative
from fastslam_edu.datasets.log import EventStream
from fastslam_edu.landmark.evidence import tempering_exponents
from fastslam_edu.landmark.fastslam import FastSLAMParams, stream_commands

__all__ = ["ODOMETRY_FLOOR_STD", "keyframe_steps", "dead_reckon_stream", "lagged_commands", "OdometryModel",
           "odometry_factors", "odometry_residuals", "sighting_residuals", "whitening", "sighting_weights",
           "wrap_pose_error"]


#: Added to every odometry covariance: a robot that stands still has no sideways noise at all.
ODOMETRY_FLOOR_STD = (1e-4, 1e-4, 1e-5)  # m, m, rad


_CALIBRATION_STEP = (1e-4, 1e-4, 1e-2)


def keyframe_steps(stream: EventStream, max_gap_s: float = 1.0) -> np.ndarray:
    """Stream steps that get a pose variable: the first, the last, every step with
    sightings, and the first step of every ``max_gap_s`` window (so a stretch without
    sightings is still sampled about every ``max_gap_s`` seconds).

    Returns sorted step indices, shape (T,) for T keyframes.
    """
    if not max_gap_s > 0:
        raise ValueError(f"max_gap_s must be > 0 seconds, got {max_gap_s!r}")
    n = len(stream)
    keep = np.diff(stream.offsets) > 0
    keep[0] = keep[-1] = True
    window = np.floor((stream.t - stream.t[0]) / max_gap_s).astype(np.int64)
    keep[np.flatnonzero(np.diff(window, prepend=-1))] = True
    return np.flatnonzero(keep) if n else np.zeros(0, dtype=np.int64)


def dead_reckon_stream(stream: EventStream, x0, odometry_scale=(1.0, 1.0)) -> np.ndarray:
    """The pose after every step from the commands alone: shape (len(stream), 3), θ continuous.

    :func:`fastslam_edu.core.motion.dead_reckon` of the commands times ``odometry_scale``
    (:func:`fastslam_edu.landmark.fastslam.stream_commands`).
    """
    u, dt = stream_commands(stream, FastSLAMParams(odometry_scale=tuple(odometry_scale)))
    return dead_reckon(x0, u, dt)


def lagged_commands(stream: EventStream, tau: float) -> np.ndarray:
    """The commands as a robot executes them ``tau`` seconds late: step ``k`` moves with the mean of the
    recorded commands over :math:`(t_{k-1} - \\tau, t_k - \\tau]` (zero before the log starts). Shape (T, 2).

    Exact for piecewise-constant commands: the integral of the recorded commands, piecewise linear
    in time, read ``tau`` earlier at every step time.
    """
    u = np.array(stream.u, dtype=float)
    if tau == 0 or len(u) < 2:
        return u
    t, dt = np.asarray(stream.t, dtype=float), np.asarray(stream.dt, dtype=float)
    U = np.concatenate([np.zeros((1, 2)), np.cumsum(u[1:] * dt[1:, None], axis=0)])
    shifted = np.stack([np.interp(t - tau, t, U[:, i]) for i in range(2)], axis=1)
    moving = np.flatnonzero(dt > 0)
    moving = moving[moving > 0]
    u[moving] = (shifted[moving] - shifted[moving - 1]) / dt[moving, None]
    return u


class OdometryModel:
    """The relative motions between keyframes as functions of the calibration :math:`c` (``CALIBRATION_NAMES``,
    shape (5,); this model reads :math:`c_{0:4} = (k_v, k_\\omega, \\tau, \\delta)`): the commands, lagged by
    :math:`\\tau` (:func:`lagged_commands`) and scaled by :math:`(k_v, k_\\omega)`, dead-reckoned; then each
    translation turned by the travel offset :math:`\\delta` [rad],
    :math:`\\Delta_{k,xy} \\leftarrow R(\\delta)\\,\\Delta_{k,xy}` — the robot drives along
    :math:`\\theta + \\delta`, not along its heading :math:`\\theta` (the heading that the prior on the first pose
    and the bearings refer to).

    MR.CLAM's odometry is the *commanded* velocity; against groundtruth (100 Hz in Dataset 6), the
    heading change over windows of seconds fits :math:`k_\\omega \\int \\omega(t - \\tau)\\,dt` with a lag τ of a
    fraction of a second and k_ω a few per cent below 1 on every robot (the lag makes the residual clearly smaller),
    the distance :math:`k_v \\int v` with k_v below 1 too: different robot by robot, so estimated with the path.
    The direction of travel differs from the groundtruth heading by about a degree (Dataset 6; the estimates:
    ``benchmarks/smoother_mrclam.py``'s calibration variants). (The covariances
    :math:`C_k` are not turned by δ: at a degree or two, a change of a few per cent in their sideways part.)
    """

    def __init__(self, stream: EventStream, keys: np.ndarray):
        self.stream, self.keys = stream, np.asarray(keys)
        self._cache: tuple | None = None  # (k_v, k_ω, τ) and their relative motions: δ alone needs no dead reckoning

    def _unturned(self, c) -> np.ndarray:
        key = tuple(float(x) for x in c[:3])
        if self._cache is None or self._cache[0] != key:
            u = lagged_commands(self.stream, key[2]) * np.asarray(key[:2])
            path = dead_reckon(np.zeros(3), u, np.asarray(self.stream.dt, dtype=float))
            self._cache = key, relative(path[self.keys[:-1]], path[self.keys[1:]])
        return self._cache[1]

    def deltas(self, c) -> np.ndarray:
        """:math:`\\Delta_k(c)`, shape (T-1, 3)."""
        d = self._unturned(c).copy()
        cd, sd = np.cos(c[3]), np.sin(c[3])
        d[:, 0], d[:, 1] = cd * d[:, 0] - sd * d[:, 1], sd * d[:, 0] + cd * d[:, 1]
        return d

    def jacobian(self, c, free) -> np.ndarray:
        """:math:`\\partial \\Delta_k / \\partial c_i` for the indices ``free`` (all < 4), shape
        (T-1, 3, len(free)): central differences in :math:`(k_v, k_\\omega, \\tau)`, exact in δ
        (:math:`\\partial \\Delta_{xy} / \\partial\\delta = (-\\Delta_y, \\Delta_x)`)."""
        c = np.asarray(c, dtype=float)
        cols = []
        for i in free:
            if i == 3:
                d = self.deltas(c)
                cols.append(np.stack([-d[:, 1], d[:, 0], np.zeros(len(d))], axis=1))
                continue
            h = np.zeros(len(c))
            h[i] = _CALIBRATION_STEP[i]
            cols.append(wrap_pose_error(self.deltas(c + h) - self.deltas(c - h)) / (2 * h[i]))
        return np.stack(cols, axis=-1)


def odometry_factors(stream: EventStream, path: np.ndarray, keys: np.ndarray, noise: MotionNoise):
    """Relative motions :math:`\\Delta_k` between consecutive keyframes and their covariances :math:`C_k`.

    Step ``j`` (between keyframes ``a`` and ``b``) moves by :math:`\\Delta s_j` along the heading
    :math:`\\theta_{j-1}` and turns by :math:`\\Delta\\theta_j`. To first order, noise
    :math:`\\delta s_j, \\delta\\theta_j` moves the pose at ``b`` by

    .. math::

        \\delta x_b = \\sum_j \\delta s_j \\,(\\cos\\theta_{j-1}, \\sin\\theta_{j-1}, 0)
                    + \\delta\\theta_j \\,(-(y_b - y_j),\\; x_b - x_j,\\; 1),

    (a turn at step ``j`` swings everything after it about :math:`(x_j, y_j)`), so
    :math:`\\Sigma_b = \\sum_j \\sigma_v^2 \\Delta t_j\\, u_j u_j^\\top + \\sigma_\\omega^2 \\Delta t_j\\, g_j g_j^\\top`
    (state-mode noise: :math:`\\sigma_{xy}^2 \\Delta t_j` on x and y instead of the first term), then
    rotated into the frame of ``a``. ``path`` from :func:`dead_reckon_stream`. (First order: over an
    interval of ``T`` seconds it misses the sideways variance :math:`\\sigma_v^2 \\sigma_\\omega^2 T^2 / 2` of a
    distance error times a heading error, a few per cent at the filter's noise and 1 s keyframes.)

    Returns ``(delta (T-1, 3), cov (T-1, 3, 3))``.
    """
    keys = np.asarray(keys)
    j = np.arange(keys[0] + 1, keys[-1] + 1)  # every step inside some interval
    f = np.searchsorted(keys, j, side="left") - 1  # its interval: keys[f] < j <= keys[f + 1]
    dt = stream.dt[j]
    end = path[keys[f + 1]]
    g = np.stack([-(end[:, 1] - path[j, 1]), end[:, 0] - path[j, 0], np.ones(len(j))], axis=1)
    if noise.mode == "control":
        heading = path[j - 1, 2]
        along = np.stack([np.cos(heading), np.sin(heading), np.zeros(len(j))], axis=1)
        terms = (noise.sigma_v**2 * dt)[:, None, None] * along[:, :, None] * along[:, None, :]
        turn = noise.sigma_omega**2 * dt
    else:
        terms = np.zeros((len(j), 3, 3))
        terms[:, 0, 0] = terms[:, 1, 1] = noise.sigma_xy**2 * dt
        turn = noise.sigma_theta**2 * dt
    terms = terms + turn[:, None, None] * g[:, :, None] * g[:, None, :]
    starts = np.searchsorted(f, np.arange(len(keys) - 1))  # every interval holds >= 1 step
    cov_world = np.add.reduceat(terms, starts, axis=0)
    a = path[keys[:-1]]
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    T = np.zeros((len(a), 3, 3))  # blockdiag(R(θ_a)ᵀ, 1)
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1], T[:, 2, 2] = c, s, -s, c, 1.0
    cov = T @ cov_world @ np.swapaxes(T, 1, 2) + np.diag(np.square(ODOMETRY_FLOOR_STD))
    return relative(a, path[keys[1:]]), cov


def odometry_residuals(xa: np.ndarray, xb: np.ndarray, delta: np.ndarray):
    """:math:`e = (x_a^{-1} \\oplus x_b) \\ominus \\Delta` and its Jacobians.

    ``xa``, ``xb``, ``delta`` (F, 3). Returns ``(e (F, 3), Ja (F, 3, 3), Jb (F, 3, 3))`` with
    ``Ja = ∂e/∂x_a``, ``Jb = ∂e/∂x_b``.
    """
    rel = relative(xa, xb)  # (R(θ_a)ᵀ (t_b − t_a), θ_b − θ_a)
    e = wrap_pose_error(rel - delta)
    c, s = np.cos(xa[:, 2]), np.sin(xa[:, 2])
    Jb = np.zeros((len(xa), 3, 3))
    Jb[:, 0, 0], Jb[:, 0, 1], Jb[:, 1, 0], Jb[:, 1, 1], Jb[:, 2, 2] = c, s, -s, c, 1.0
    Ja = -Jb
    Ja[:, 0, 2], Ja[:, 1, 2] = rel[:, 1], -rel[:, 0]  # turning x_a swings x_b about it
    return e, Ja, Jb


def sighting_residuals(x: np.ndarray, m: np.ndarray, z: np.ndarray, bearing_bias: float = 0.0):
    """:math:`e = z \\ominus (h(x, m) + (0, b))` and its Jacobians: the camera reads every bearing :math:`b` [rad] too far
    anticlockwise (``bearing_bias``; :math:`\\partial e / \\partial b = (0, -1)`).

    ``x`` (n, 3) poses, ``m`` (n, 2) landmarks, ``z`` (n, 2) sightings. Returns
    ``(e (n, 2), Jx (n, 2, 3), Jm (n, 2, 2))``: ``Jx = −∂h/∂x``, ``Jm = −∂h/∂m = −H``.
    """
    z_hat = range_bearing(x, m)
    if bearing_bias:
        z_hat = z_hat + np.array([0.0, bearing_bias])
    return innovation(z, z_hat), -jacobian_pose(x, m), -jacobian_landmark(x, m)


def whitening(cov: np.ndarray) -> np.ndarray:
    """:math:`W = L^{-1}` with :math:`C = L L^\\top`, so that :math:`\\|W e\\|^2 = e^\\top C^{-1} e`. Shape (..., d, d)."""
    return np.linalg.inv(np.linalg.cholesky(cov))


def sighting_weights(stream: EventStream, tau: float | None) -> np.ndarray:
    """The filter's tempering exponents :math:`\\beta_i` of every sighting, in stream order (n,)."""
    beta = np.ones(stream.n_measurements)
    last_seen = np.full(stream.n_landmarks, -np.inf)
    for k in np.flatnonzero(np.diff(stream.offsets)):
        s, e = stream.offsets[k], stream.offsets[k + 1]
        beta[s:e] = tempering_exponents(stream.t[k], stream.landmark[s:e], last_seen, tau)
    return beta


def wrap_pose_error(e: np.ndarray) -> np.ndarray:
    """A pose difference with its heading wrapped to (−π, π]."""
    e = np.array(e, dtype=float)
    e[..., 2] = wrap_angle(e[..., 2])
    return e
