"""One FastSLAM 1.0 step, particle by particle, as *Probabilistic Robotics* table 13.1 reads.

This module is both the textbook algorithm and the filter's engine: every
function below is plain Python on one particle's numbers, compiled by numba
(``njit(cache=True)``). With ``NUMBA_DISABLE_JIT=1`` in the environment the very
same lines run as ordinary Python, to step through in a debugger or in class.

Table 13.1 (FastSLAM 1.0, known correspondences), for each particle ``m``, and
where each line is computed::

    line 4      x_t^[m] ~ p(x_t | x_{t-1}^[m], u_t)              sample_pose
    lines 6-9   landmark j never seen: mu = h^-1(x, z),            ekf.ekf_initialise
                Sigma = H^-1 R H^-T, weight unchanged
    lines 11-13 z_hat = h(mu, x), H = dh/dm, Q = H Sigma H^T + R   ekf.ekf_innovation
    lines 14-16 K = Sigma H^T Q^-1, mu += K (z - z_hat),           ekf.ekf_update
                Sigma = (I - K H) Sigma
    line 17     w *= |2 pi Q|^(-1/2) exp(-nu^T Q^-1 nu / 2)        (a log weight)
    lines 5-17  for one particle and one sighting                  update_particle

What real data adds to the table (see :mod:`fastslam_edu.landmark.fastslam`): the outlier
gate (a sighting that *no* particle explains, :func:`explains`, is set aside), its
escape (:func:`gate_escapes`, :func:`gate_record`), and tempered likelihoods (the log
weight grows by :math:`\\beta \\log \\mathcal N`, :func:`tempering_exponents`).

The whole run: :func:`run_segments` chains line 4 over each run of odometry steps
(:func:`sample_segment`) and steps 2–4 at each measurement step (:func:`measure_instant`:
the update, the weights, resampling when :math:`N_\\text{eff}` is low, the combined pose),
so that a run over a log returns to Python once, not once per step.

The particle set is passed as :class:`Particles`, a named tuple of arrays
(:math:`M` particles, :math:`K` landmarks), and changed in place:

=========  ==============  ==========================================
poses      (M, 3)          :math:`x^{[m]} = (x, y, \\theta)` [m, m, rad]
mu         (M, K, 2)       :math:`\\mu_j^{[m]}` [m]
sigma      (M, K, 2, 2)    :math:`\\Sigma_j^{[m]}` [m²]
seen       (M, K) bool     landmark :math:`j` initialised in particle :math:`m`
count      (M, K) int      sightings of :math:`j` used by particle :math:`m`
logw       (M,)            :math:`\\log w^{[m]}` (unnormalised)
=========  ==============  ==========================================

The 2×2 algebra (in :mod:`fastslam_edu.core.ekf`) is written entry by entry (``h00`` is
:math:`H_{00}`): a small array per operation would cost more than the arithmetic.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from fastslam_edu.core.angles import wrap_one
from fastslam_edu.core.ekf import ekf_initialise, ekf_innovation, ekf_update


class Particles(NamedTuple):
    """The particle set's arrays (shapes in the module docstring); the kernels change them in place."""

    poses: np.ndarray
    mu: np.ndarray
    sigma: np.ndarray
    seen: np.ndarray
    count: np.ndarray
    logw: np.ndarray


class Sightings(NamedTuple):
    """The n landmark sightings of one instant.

    z (n, 2) ``(r, φ)`` [m, rad]; j (n,) landmark indices; R (n, 2, 2) noise
    covariances; escape (n,) bool: applied without the gate; beta (n,): exponent
    of the likelihood; loglik (M, n): where not NaN, the log-likelihood to weigh
    particle m with instead of FastSLAM 1.0's (FastSLAM 2.0's proposal).
    """

    z: np.ndarray
    j: np.ndarray
    R: np.ndarray
    escape: np.ndarray
    beta: np.ndarray
    loglik: np.ndarray


# ---------------------------------------------------------------- line 4: the motion model


@njit(cache=True, inline="always")
def sample_pose(x, y, theta, u, dt, noise, eps):
    """Line 4 for one odometry step: the pose ``(x, y, θ)`` moved by the noisy command.

    ``u = (v, ω)`` [m/s, rad/s], ``dt`` [s], ``noise`` = (σ_v, σ_ω, σ_xy, σ_θ)
    (:class:`fastslam_edu.core.motion.MotionNoise`: densities per √s), ``eps`` the
    step's standard normals. Noise on the command (two normals):
    :math:`\\Delta s = v\\Delta t + \\sigma_v\\sqrt{\\Delta t}\\,\\varepsilon_1`,
    :math:`\\Delta\\theta = \\omega\\Delta t + \\sigma_\\omega\\sqrt{\\Delta t}\\,\\varepsilon_2`. Noise on the state (three):
    :math:`\\sigma_{xy}\\sqrt{\\Delta t}\\,(\\varepsilon_1, \\varepsilon_2)` added to the position,
    :math:`\\sigma_\\theta\\sqrt{\\Delta t}\\,\\varepsilon_3` to the turn. The Euler step moves by :math:`\\Delta s`
    along the heading at the start of the step; θ is left unwrapped.
    (:func:`fastslam_edu.core.motion.move` is the same step for arrays of poses.)

    Returns the new ``x, y, θ`` and the cosine and sine of the heading the step
    started from (the caller's weighted mean of the previous step reuses them).
    """
    root_dt = math.sqrt(dt)
    ds = u[0] * dt
    dtheta = u[1] * dt
    kick_x = kick_y = 0.0
    if eps.shape[0] == 2:  # noise on the command
        ds += noise[0] * root_dt * eps[0]
        dtheta += noise[1] * root_dt * eps[1]
    else:  # noise on the state
        kick_x = noise[2] * root_dt * eps[0]
        kick_y = noise[2] * root_dt * eps[1]
        dtheta += noise[3] * root_dt * eps[2]
    cos_theta, sin_theta = math.cos(theta), math.sin(theta)
    return x + ds * cos_theta + kick_x, y + ds * sin_theta + kick_y, theta + dtheta, cos_theta, sin_theta


@njit(cache=True)
def sample_segment(poses, u, dt, noise, eps, w, mean, best):
    """Line 4 for every particle through ``L`` odometry steps, recording the estimates on the way.

    ``poses`` (M, 3) is moved in place (headings wrapped at the end); ``u`` (L, 2), ``dt``
    (L,), ``noise`` as :func:`sample_pose`, ``eps`` (M, L, 2 or 3) the standard
    normals. With the normalised weights ``w`` (M,) — constant along the segment,
    which has no measurement — it writes, for the first ``n = len(mean)`` steps,
    the weighted-mean pose :math:`\\bar x_t = \\sum_m w^{[m]} x_t^{[m]}` (circular mean
    for θ) into ``mean`` (n, 3) and the pose of the highest-weight particle into
    ``best`` (n, 3).
    """
    n = mean.shape[0]
    mean[:] = 0.0
    cos_sum = np.zeros(n)  # Σ_m w cos θ_t, Σ_m w sin θ_t: the circular mean's sums
    sin_sum = np.zeros(n)
    b = np.argmax(w)
    for m in range(poses.shape[0]):
        x, y, theta = poses[m, 0], poses[m, 1], poses[m, 2]
        for t in range(dt.shape[0]):
            x, y, theta, c, s = sample_pose(x, y, theta, u[t], dt[t], noise, eps[m, t])
            if 0 < t <= n:  # c, s: of the heading after step t - 1
                cos_sum[t - 1] += w[m] * c
                sin_sum[t - 1] += w[m] * s
            if t < n:
                mean[t, 0] += w[m] * x
                mean[t, 1] += w[m] * y
                if m == b:
                    best[t, 0], best[t, 1], best[t, 2] = x, y, wrap_one(theta)
        if n == dt.shape[0]:  # the heading after the last step
            cos_sum[n - 1] += w[m] * math.cos(theta)
            sin_sum[n - 1] += w[m] * math.sin(theta)
        poses[m, 0], poses[m, 1], poses[m, 2] = x, y, wrap_one(theta)
    for t in range(n):
        mean[t, 2] = wrap_one(math.atan2(sin_sum[t], cos_sum[t]))


@njit(cache=True)
def standard_normals(rng, out):
    """Fill ``out`` with ``rng``'s standard normals: the numbers of ``rng.standard_normal(out.shape)``.

    Compiled, a normal costs a third of numpy's; the call costs ~10 µs more
    (numba unpacks the Generator), so it pays for large segments only.
    """
    flat = out.reshape(-1)
    for i in range(flat.shape[0]):
        flat[i] = rng.standard_normal()


# ---------------------------------------------------------------- lines 5–17 for one particle, behind the gate


@njit(cache=True, inline="always")
def update_particle(P, m, S, i, gate_chi2, update_map):
    """Lines 5–17 for particle ``m`` and sighting ``i`` of the instant (:class:`Particles`, :class:`Sightings`).

    A first sighting initialises the landmark, weight unchanged. Otherwise the
    particle's log weight grows by :math:`\\beta \\log\\mathcal N(\\nu; 0, Q)` and its
    landmark's EKF is updated — unless :math:`d^2 >` ``gate_chi2``: then the sighting
    is an outlier *for this particle*. It keeps the log-likelihood (a particle
    that disagrees with a sighting others explain should lose weight) but
    leaves its landmark alone, except a landmark seen only once, which is
    re-initialised from the new sighting at no cost in weight (one of its two
    sightings is wrong). With ``update_map`` False (localisation) only weights change.
    """
    j = S.j[i]
    pose, z, R = P.poses[m], S.z[i], S.R[i]
    mu, sigma = P.mu[m, j], P.sigma[m, j]
    if not P.seen[m, j]:
        ekf_initialise(pose, z, R, mu, sigma)
        P.seen[m, j] = True
        P.count[m, j] = 1
        return
    if update_map:
        d2, loglik = ekf_update(pose, z, R, mu, sigma, gate_chi2)
    else:
        d2, loglik = ekf_innovation(pose, z, R, mu, sigma)[9:]
    if not math.isnan(S.loglik[m, i]):
        loglik = S.loglik[m, i]
    outlier = d2 > gate_chi2  # the landmark was left alone
    if outlier and update_map and P.count[m, j] == 1:
        ekf_initialise(pose, z, R, mu, sigma)  # re-initialised, at no cost in weight
        return
    P.logw[m] += S.beta[i] * loglik
    if not outlier:
        P.count[m, j] += 1


@njit(cache=True, inline="always")
def explains(P, S, i, gate_chi2):
    """True unless *every* particle that has seen the landmark of sighting ``i`` puts it beyond the gate.

    Such a sighting fits no hypothesis — a misread barcode, a range off by
    metres — and is set aside (unless it escapes the gate). True when no
    particle has seen the landmark.
    """
    j = S.j[i]
    for m in range(P.poses.shape[0]):
        if P.seen[m, j] and ekf_innovation(P.poses[m], S.z[i], S.R[i], P.mu[m, j], P.sigma[m, j])[9] <= gate_chi2:
            return True
    return not P.seen[:, j].any()


@njit(cache=True)
def update_particles(P, S, gate_chi2, update_map, explained):
    """Lines 5–17 for every sighting of one instant and every particle, in the order given.

    For each sighting: the gate's verdict over all particles (:func:`explains`,
    written to ``explained`` (n,)); a sighting no particle explains is skipped by
    the particles that have seen its landmark (the others initialise it; those
    that have seen it once re-initialise it, as :func:`update_particle` does), one
    with ``S.escape`` set is applied to every particle as if there were no gate.
    ``gate_chi2``: ``inf`` for no gate.
    """
    for i in range(S.j.shape[0]):
        explained[i] = explains(P, S, i, gate_chi2)
        chi2 = math.inf if S.escape[i] else gate_chi2
        apply = explained[i] or S.escape[i]
        j = S.j[i]
        for m in range(P.poses.shape[0]):
            if apply or not P.seen[m, j]:
                update_particle(P, m, S, i, chi2, update_map)
            elif update_map and P.count[m, j] == 1:  # rejected, but one of two sightings is wrong:
                ekf_initialise(P.poses[m], S.z[i], S.R[i], P.mu[m, j], P.sigma[m, j])  # start again


# ---------------------------------------------------------------- step 4: weights and the combined pose


@njit(cache=True)
def normalise_weights(logw, w):
    """:math:`w^{[m]} = \\exp(\\ell^{[m]} - \\max \\ell) / \\sum`, into ``w`` (M,); returns :math:`N_\\text{eff} = 1/\\sum_m (w^{[m]})^2`.

    All log weights :math:`-\\infty` (every particle ruled out): uniform weights,
    as :func:`fastslam_edu.core.weights.weights_from_log` does; NaN or :math:`+\\infty`: ValueError.
    """
    top = np.max(logw)
    if math.isnan(top) or top == math.inf:
        raise ValueError("log weights contain NaN or +inf: a likelihood was not computed right")
    if top == -math.inf:
        w[:] = 1.0 / w.shape[0]
        return float(w.shape[0])
    total = 0.0
    for m in range(w.shape[0]):
        w[m] = math.exp(logw[m] - top)
        total += w[m]
    squares = 0.0
    for m in range(w.shape[0]):
        w[m] /= total
        squares += w[m] * w[m]
    return 1.0 / squares


@njit(cache=True)
def weighted_mean_pose(poses, w, out):
    """:math:`\\bar x = \\sum_m w^{[m]} x^{[m]}` into ``out`` (3,), θ the circular mean (wrapped)."""
    x = y = s = c = 0.0
    for m in range(poses.shape[0]):
        x += w[m] * poses[m, 0]
        y += w[m] * poses[m, 1]
        s += w[m] * math.sin(poses[m, 2])
        c += w[m] * math.cos(poses[m, 2])
    out[0], out[1], out[2] = x, y, wrap_one(math.atan2(s, c))



# ---------------------------------------------------------------- what the run remembers of past sightings


@njit(cache=True)
def gate_escapes(t, j, unexplained_since, escape_s, escape):
    """``escape[i]``: sighting ``i`` (of landmark ``j[i]``, at time ``t``) skips the gate.

    True once the landmark's sightings have been unexplained since
    ``unexplained_since[j]`` for ``escape_s`` seconds or more (``inf`` while explained).
    """
    for i in range(j.shape[0]):
        escape[i] = t - unexplained_since[j[i]] >= escape_s


@njit(cache=True)
def gate_record(t, j, explained, unexplained_since):
    """Note which sightings at ``t`` some particle explained: ``inf`` for those, else the first unexplained time."""
    since = unexplained_since[j]  # read before writing: a landmark may be seen twice in one instant
    for i in range(j.shape[0]):
        unexplained_since[j[i]] = math.inf if explained[i] else min(since[i], t)


@njit(cache=True)
def tempering_exponents(t, j, last_seen, tau, beta):
    """``beta[i] = min(1, (t - last_seen[j[i]]) / tau)``, then ``last_seen[j] = t``; ``tau <= 0``: all 1 (textbook)."""
    if tau <= 0.0:
        beta[:] = 1.0
        return
    for i in range(j.shape[0]):
        beta[i] = min(1.0, (t - last_seen[j[i]]) / tau)
    for i in range(j.shape[0]):
        last_seen[j[i]] = t


# ---------------------------------------------------------------- step 3: resampling, compiled


RESAMPLER_CODES = {"systematic": 0, "stratified": 1, "roulette": 2, "multinomial": 2}


@njit(cache=True)
def resampling_indices(w, rng, code):
    """The particles drawn by resampler ``code`` (:data:`RESAMPLER_CODES`): the numbers of :mod:`fastslam_edu.core.resampling`.

    Positions ``u_j``: systematic ``(j + U) / M``; stratified ``(j + U_j) / M``;
    roulette ``U_j`` sorted; then the inverse CDF, ``min{i : c_i > u_j}``.
    """
    m = w.shape[0]
    if code == 0:
        u = (np.arange(m) + rng.random()) / m
    elif code == 1:
        u = (np.arange(m) + rng.random(m)) / m
    else:
        u = np.sort(rng.random(m))
    c = np.cumsum(w / np.sum(w))
    c = c / c[-1]
    u = np.minimum(np.maximum(u, 0.0), 1.0 - 2.0**-53)
    return np.searchsorted(c, u, side="right")


@njit(cache=True)
def select_in_place(P, idx):
    """The particles ``idx`` replace the set, their maps copied (no two offspring share memory); log weights 0."""
    P.poses[:] = P.poses[idx]
    P.mu[:] = P.mu[idx]
    P.sigma[:] = P.sigma[idx]
    P.seen[:] = P.seen[idx]
    P.count[:] = P.count[idx]
    P.logw[:] = 0.0


# ---------------------------------------------------------------- the run over a chunk of the log


class Log(NamedTuple):
    """The event stream as the compiled run takes it (:class:`fastslam_edu.datasets.log.EventStream`).

    t (N,) [s]; u (N, 2) commands; dt (N,) [s]; offsets (N + 1,): the sightings of
    step k are ``offsets[k]:offsets[k + 1]`` of z (n, 2), j (n,), R (n, 2, 2).
    """

    t: np.ndarray
    u: np.ndarray
    dt: np.ndarray
    offsets: np.ndarray
    z: np.ndarray
    j: np.ndarray
    R: np.ndarray


class Settings(NamedTuple):
    """noise (4,) densities; n_draws 2 or 3; gate_chi2 (inf: none); escape_s; tau (0: no tempering);
    update_map; resample_threshold; resampler (:data:`RESAMPLER_CODES`)."""

    noise: np.ndarray
    n_draws: int
    gate_chi2: float
    escape_s: float
    tau: float
    update_map: bool
    resample_threshold: float
    resampler: int


class Record(NamedTuple):
    """What the run writes: pose_mean, pose_best (N, 3); ess_t, ess (one per measurement step);
    w (M,) the current normalised weights; unexplained_since, last_seen (K,) the gate's and the
    tempering's memory; totals (4,) int: measurement steps, sightings used, rejected, resamples."""

    pose_mean: np.ndarray
    pose_best: np.ndarray
    ess_t: np.ndarray
    ess: np.ndarray
    w: np.ndarray
    unexplained_since: np.ndarray
    last_seen: np.ndarray
    totals: np.ndarray


@njit(cache=True)
def measure_instant(P, L, s, k, rng, out):
    """Steps 2–4 at measurement step ``k``: gate, update, weights, resampling, the combined pose.

    ``P`` :class:`Particles`, ``L`` :class:`Log`, ``s`` :class:`Settings`, ``out`` :class:`Record`.
    """
    a, b = L.offsets[k], L.offsets[k + 1]
    j, t = L.j[a:b], L.t[k]
    n = b - a
    escape, beta, explained = np.empty(n, dtype=np.bool_), np.empty(n), np.ones(n, dtype=np.bool_)
    gate_escapes(t, j, out.unexplained_since, s.escape_s, escape)
    tempering_exponents(t, j, out.last_seen, s.tau, beta)
    S = Sightings(L.z[a:b], j, L.R[a:b], escape, beta, np.full((P.poses.shape[0], n), np.nan))
    update_particles(P, S, s.gate_chi2, s.update_map, explained)
    gate_record(t, j, explained, out.unexplained_since)
    for i in range(n):
        if explained[i] or escape[i]:
            out.totals[1] += 1
        else:
            out.totals[2] += 1
    n_eff = normalise_weights(P.logw, out.w)
    out.ess_t[out.totals[0]], out.ess[out.totals[0]] = t, n_eff
    out.totals[0] += 1
    m = P.poses.shape[0]
    if s.resample_threshold >= 1.0 or n_eff < s.resample_threshold * m:
        select_in_place(P, resampling_indices(out.w, rng, s.resampler))
        out.w[:] = 1.0 / m
        out.totals[3] += 1
    weighted_mean_pose(P.poses, out.w, out.pose_mean[k])
    out.pose_best[k] = P.poses[np.argmax(out.w)]


@njit(cache=True)
def run_segments(P, L, s, segments, rng, out):
    """Steps 1–4 over ``segments`` (S, 2): runs of steps ``start..end``, each ending at a measurement step
    or a cut; for each, line 4 for every particle (:func:`sample_segment`), then :func:`measure_instant`."""
    m = P.poses.shape[0]
    for r in range(segments.shape[0]):
        first, last = segments[r, 0], segments[r, 1]
        measured = L.offsets[last + 1] > L.offsets[last]
        n_record = last - first + (0 if measured else 1)  # a measurement step's estimate comes after the update
        eps = np.empty((m, last - first + 1, s.n_draws))
        standard_normals(rng, eps)
        sample_segment(P.poses, L.u[first:last + 1], L.dt[first:last + 1], s.noise, eps, out.w,
                       out.pose_mean[first:first + n_record], out.pose_best[first:first + n_record])
        if measured:
            measure_instant(P, L, s, last, rng, out)
