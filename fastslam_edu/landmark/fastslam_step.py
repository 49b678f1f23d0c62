"""One FastSLAM 1.0 step, particle by particle, as *Probabilistic Robotics* table 13.1 reads.

This module is both the textbook algorithm and the filter's engine: every
function below is plain Python on one particle's numbers, compiled by numba
(``njit(cache=True)``). With ``NUMBA_DISABLE_JIT=1`` in the environment the very
same lines run as ordinary Python, to step through in a debugger or in class.

Table 13.1 (FastSLAM 1.0, known correspondences), for each particle ``m``, and
where each line is computed::

    line 4      x_t^[m] ~ p(x_t | x_{t-1}^[m], u_t)              sample_pose
    line 5      j = c_t, the landmark the sighting is of
    lines 7-9   landmark j never seen: mu = h^-1(x, z),            ekf.initialise_landmark_kernel
                Sigma = H^-1 R H^-T
    line 10     w = p0 (the particle's weight is left unchanged)
    lines 12-14 z_hat = h(mu, x), H = dh/dm, Q = H Sigma H^T + R   ekf.innovation_statistics_kernel
    lines 15-17 K = Sigma H^T Q^-1, mu += K (z - z_hat),           ekf.update_landmark_kernel
                Sigma = (I - K H) Sigma
    line 18     w *= |2 pi Q|^(-1/2) exp(-nu^T Q^-1 nu / 2)        (a log weight)
    lines 5-18  for one particle and one sighting                  update_particle

What real data adds to the table (see :mod:`fastslam_edu.landmark.fastslam`): the outlier
gate (a sighting that *no* particle explains, :func:`explains`, is set aside), its
escape (:func:`fastslam_edu.landmark.gate.gate_escapes`, :func:`fastslam_edu.landmark.gate.gate_record`), and
tempered likelihoods (the log weight grows by :math:`\\beta \\log \\mathcal N`,
:func:`fastslam_edu.landmark.evidence.tempering_exponents_kernel`).

The whole run: :func:`run_segments` chains line 4 over each run of odometry steps
(:func:`propagate_segment_kernel`) and steps 2–4 at each measurement step (:func:`measure_instant`:
the update, the weights, resampling when :math:`N_\\text{eff}` is low, the combined pose),
so that a run over a log returns to Python once, not once per step.

The particle set is passed as :class:`~fastslam_edu.landmark.step_records.Particles`, a named tuple of arrays
(:math:`M` particles, :math:`N` landmarks), and changed in place:

=========  ==============  ==========================================
poses      (M, 3)          :math:`x^{[m]} = (x, y, \\theta)` [m, m, rad]
mu         (M, N, 2)       :math:`\\mu_j^{[m]}` [m]
sigma      (M, N, 2, 2)    :math:`\\Sigma_j^{[m]}` [m²]
seen       (M, N) bool     landmark :math:`j` initialised in particle :math:`m`
count      (M, N) int      sightings of :math:`j` used by particle :math:`m`
logw       (M,)            :math:`\\log w^{[m]}` (unnormalised)
=========  ==============  ==========================================

The 2×2 algebra (in :mod:`fastslam_edu.core.ekf`) is written entry by entry (``h00`` is
:math:`H_{00}`): a small array per operation would cost more than the arithmetic.

Reference counts: numba counts the references to every array a compiled function holds. Each field read
from a named tuple (``P.mu``), each view (``P.mu[m, j]``) and each argument of an inlined function
(``update_particle(P, m, s, ...)`` holds ``P``'s six arrays and ``s``'s three) adds one: an atomic
increment, and a call to decrement it later. Lines 5–18 are a few dozen multiplications per particle,
so these counts took three quarters of their time (on D1 R2, 145 of 190 ns per particle and sighting).
Every kernel of the package that creates no array (:func:`update_particles`,
:func:`~fastslam_edu.landmark.particle_resampling.copy_particle`, the landmark bookkeeping of the run without
barcodes, ...) only reads and writes the arrays its caller holds, and is compiled without the counts
(``_nrt=False``; an allocation there, such as ``np.empty``, would not compile): faster to run, and to compile.
The numbers are the same to the bit.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from fastslam_edu.core.angles import wrap_angle_kernel
from fastslam_edu.core.ekf import initialise_landmark_kernel, innovation_statistics_kernel, update_landmark_kernel
from fastslam_edu.landmark.evidence import tempering_exponents_kernel
from fastslam_edu.landmark.gate import gate_escapes, gate_record
from fastslam_edu.landmark.particle_resampling import draw_if_degenerate, select_in_place
from fastslam_edu.landmark.proposal import (motion_prediction_kernel, sample_improved_poses_kernel,
                                           segment_motion_kernel)
from fastslam_edu.landmark.step_records import RESAMPLES, SIGHTINGS_REJECTED, SIGHTINGS_USED, STEPS_DONE, Sightings


# ---------------------------------------------------------------- line 4: the motion model

#: Up to this turn per step [rad] :func:`turn` is exact to 3e-14; after a larger one the heading's
#: cosine and sine are computed directly (:func:`exact_large_turns`).
SMALL_TURN = 0.2

#: Taylor coefficients of :math:`\\cos x = 1 - x^2/2! + x^4/4! - \\dots` and :math:`\\sin x / x = 1 - x^2/3! + \\dots`
#: after the leading 1 (multiplications: a division by a constant would be computed at every step).
COS_SERIES = (-1.0 / 2, 1.0 / 24, -1.0 / 720, 1.0 / 40320)
SIN_SERIES = (-1.0 / 6, 1.0 / 120, -1.0 / 5040, 1.0 / 362880)


@njit(cache=True, inline="always")
def noisy_increments(v, omega, dt, noise, e, m):
    """The noisy increments ``Δs, Δθ, kick_x, kick_y`` of particle ``m`` over one odometry step.

    ``(v, ω)`` [m/s, rad/s], ``dt`` [s], ``noise`` = (σ_v, σ_ω, σ_xy, σ_θ)
    (:class:`fastslam_edu.core.motion.MotionNoise`: densities per √s), ``e`` (2 or 3, M) the
    step's standard normals. Noise on the command (two normals):
    :math:`\\Delta s = v\\Delta t + \\sigma_v\\sqrt{\\Delta t}\\,\\varepsilon_1`,
    :math:`\\Delta\\theta = \\omega\\Delta t + \\sigma_\\omega\\sqrt{\\Delta t}\\,\\varepsilon_2`, no kick.
    Noise on the state (three): the kick :math:`\\sigma_{xy}\\sqrt{\\Delta t}\\,(\\varepsilon_1, \\varepsilon_2)`
    added to the position, :math:`\\sigma_\\theta\\sqrt{\\Delta t}\\,\\varepsilon_3` to the turn.
    """
    root_dt = math.sqrt(dt)
    if e.shape[0] == 2:  # noise on the command
        return v * dt + noise[0] * root_dt * e[0, m], omega * dt + noise[1] * root_dt * e[1, m], 0.0, 0.0
    kick = noise[2] * root_dt
    return v * dt, omega * dt + noise[3] * root_dt * e[2, m], kick * e[0, m], kick * e[1, m]


@njit(cache=True, inline="always")
def turn(c, s, dtheta):
    """The heading :math:`(c, s) = (\\cos\\theta, \\sin\\theta)` turned by :math:`\\Delta\\theta` (angle addition):
    :math:`(c\\cos\\Delta\\theta - s\\sin\\Delta\\theta,\\ s\\cos\\Delta\\theta + c\\sin\\Delta\\theta)`.

    :math:`\\cos\\Delta\\theta` and :math:`\\sin\\Delta\\theta` are their Taylor series to
    :math:`\\Delta\\theta^8` and :math:`\\Delta\\theta^9`, exact to 3e-14 for :math:`|\\Delta\\theta| \\le` :data:`SMALL_TURN`
    (an odometry step turns by hundredths of a radian). Unlike ``math.cos`` this is plain
    arithmetic, which the compiler runs on several particles at once.
    """
    d2 = dtheta * dtheta
    cos_d = 1.0 + d2 * (COS_SERIES[0] + d2 * (COS_SERIES[1] + d2 * (COS_SERIES[2] + d2 * COS_SERIES[3])))
    sin_d = dtheta * (1.0 + d2 * (SIN_SERIES[0] + d2 * (SIN_SERIES[1] + d2 * (SIN_SERIES[2] + d2 * SIN_SERIES[3]))))
    return c * cos_d - s * sin_d, s * cos_d + c * sin_d


@njit(cache=True, inline="always")
def sample_pose(x, y, c, s, ds, dtheta, kick_x, kick_y):
    """Line 4 for one particle and one step: the Euler step of the unicycle.

    The particle moves by :math:`\\Delta s` along the heading it starts from,
    :math:`(c, s) = (\\cos\\theta, \\sin\\theta)`, plus the kick (noise on the state), and turns
    by :math:`\\Delta\\theta` (:func:`turn`); the increments come from :func:`noisy_increments`.
    Returns the new ``x, y, c, s``. (:func:`fastslam_edu.core.motion.move` is the same step for
    arrays of poses.)
    """
    c_new, s_new = turn(c, s, dtheta)
    return x + ds * c + kick_x, y + ds * s + kick_y, c_new, s_new


@njit(cache=True, _nrt=False)
def exact_large_turns(theta, dtheta, c, s):
    """``c, s = cos θ, sin θ`` for the particles that just turned by more than :data:`SMALL_TURN` (long steps)."""
    for m in range(theta.shape[0]):
        if abs(dtheta[m]) > SMALL_TURN:
            c[m], s[m] = math.cos(theta[m]), math.sin(theta[m])


@njit(cache=True, fastmath={"reassoc"}, _nrt=False)
def weighted_mean_xy_heading(x, y, c, s, w, out):
    """:math:`\\bar x = \\sum_m w^{[m]} x^{[m]}` into ``out`` (3,), θ the circular mean from the headings ``c, s``.

    ``fastmath={"reassoc"}`` lets the compiler add the sums in any order (four particles at a time):
    the estimate may differ in the last bits from a sum in order; the particles are not touched.
    """
    mx = my = mc = ms = 0.0
    for m in range(x.shape[0]):
        mx += w[m] * x[m]
        my += w[m] * y[m]
        mc += w[m] * c[m]
        ms += w[m] * s[m]
    out[0], out[1], out[2] = mx, my, wrap_angle_kernel(math.atan2(ms, mc))


@njit(cache=True)
def propagate_segment_kernel(poses, u, dt, noise, eps, w, mean, best):
    """Line 4 for every particle through ``L`` odometry steps, recording the estimates on the way.

    ``poses`` (M, 3) is moved in place (headings wrapped at the end); ``u`` (L, 2), ``dt``
    (L,), ``noise`` as :func:`noisy_increments`, ``eps`` (L, 2 or 3, M) the standard normals
    (``eps[t, :, m]``: particle m's at step t). Each step moves every particle, as table 13.1
    reads, before the next. With the normalised weights ``w`` (M,) — constant along the
    segment, which has no measurement — it writes, for the first ``n = len(mean)`` steps,
    the weighted-mean pose :math:`\\bar x_t = \\sum_m w^{[m]} x_t^{[m]}` (circular mean for θ)
    into ``mean`` (n, 3) and the pose of the highest-weight particle into ``best`` (n, 3).
    """
    x, y, theta = poses[:, 0].copy(), poses[:, 1].copy(), poses[:, 2].copy()
    c, s = np.cos(theta), np.sin(theta)  # each particle's heading as a unit vector
    dtheta = np.empty(theta.shape[0])
    b = np.argmax(w)
    for t in range(dt.shape[0]):
        v, omega, e = u[t, 0], u[t, 1], eps[t]
        for m in range(theta.shape[0]):
            ds, dtheta[m], kick_x, kick_y = noisy_increments(v, omega, dt[t], noise, e, m)
            x[m], y[m], c[m], s[m] = sample_pose(x[m], y[m], c[m], s[m], ds, dtheta[m], kick_x, kick_y)
            theta[m] += dtheta[m]
        exact_large_turns(theta, dtheta, c, s)
        if t < mean.shape[0]:
            weighted_mean_xy_heading(x, y, c, s, w, mean[t])
            best[t, 0], best[t, 1], best[t, 2] = x[b], y[b], wrap_angle_kernel(theta[b])
    for m in range(theta.shape[0]):
        poses[m, 0], poses[m, 1], poses[m, 2] = x[m], y[m], wrap_angle_kernel(theta[m])


@njit(cache=True)
def standard_normals(rng, out):
    """Fill ``out`` (L, k, M) with ``rng``'s standard normals, particle by particle: ``out[t, :, m]``
    holds the numbers of ``rng.standard_normal((M, L, k))[m, t]``.

    Each particle's normals are consecutive in the random stream (its whole segment, step by
    step), and stored by step, the order in which :func:`propagate_segment_kernel` reads them. Each call
    unpacks the Generator (a fixed cost), so small segments are left to numpy
    (:func:`fastslam_edu.landmark.particle_set.draw_normals`).
    """
    n_steps, k, m_count = out.shape
    for m in range(m_count):
        for t in range(n_steps):  # step by step, draw by draw
            for d in range(k):
                out[t, d, m] = rng.standard_normal()


# ---------------------------------------------------------------- lines 5–18 for one particle, behind the gate


class Sighting(NamedTuple):
    """One sighting of the instant as lines 5–18 take it (:func:`sighting_of`): z (2,) ``(r, φ)``;
    R (2, 2); j the landmark; beta the exponent of its likelihood; loglik (M,) FastSLAM 2.0's
    log-likelihood per particle (NaN: FastSLAM 1.0's)."""

    z: np.ndarray
    R: np.ndarray
    j: int
    beta: float
    loglik: np.ndarray


@njit(cache=True, inline="always")
def sighting_of(S, i):
    """Sighting ``i`` of the instant's :class:`Sightings`, taken out once for all the particles."""
    return Sighting(S.z[i], S.R[i], S.j[i], S.beta[i], S.loglik[:, i])


@njit(cache=True, inline="always")
def update_particle(P, m, s, gate_chi2, update_map):
    """Lines 5–18 for particle ``m`` (:class:`~fastslam_edu.landmark.step_records.Particles`) and one sighting ``s`` (:class:`Sighting`).

    A first sighting initialises the landmark, weight unchanged. Otherwise the
    particle's log weight grows by :math:`\\beta \\log\\mathcal N(\\nu; 0, Q)` and its
    landmark's EKF is updated — unless :math:`d^2 >` ``gate_chi2``: then the sighting
    is an outlier *for this particle*. It keeps the log-likelihood (a particle
    that disagrees with a sighting others explain should lose weight) but
    leaves its landmark alone, except a landmark seen only once, which is
    re-initialised from the new sighting at no cost in weight (one of its two
    sightings is wrong). With ``update_map`` False (localisation) only weights change.
    """
    j = s.j
    if not P.seen[m, j]:
        initialise_particle_landmark(P, m, s)
        return
    # without update_map, a gate at -inf: the innovation's (d2, loglik), the landmark left alone (one compiled
    # copy of the innovation instead of two)
    d2, loglik = update_landmark_kernel(P.poses[m], s.z, s.R, P.mu[m, j], P.sigma[m, j],
                                        gate_chi2 if update_map else -math.inf)
    if not math.isnan(s.loglik[m]):
        loglik = s.loglik[m]
    outlier = d2 > gate_chi2  # the landmark was left alone
    if outlier and update_map and P.count[m, j] == 1:
        initialise_particle_landmark(P, m, s)  # re-initialised, at no cost in weight
        return
    P.logw[m] += s.beta * loglik
    if not outlier:
        P.count[m, j] += 1


@njit(cache=True, _nrt=False)
def initialise_particle_landmark(P, m, s):
    """Lines 7–9: landmark ``s.j`` of particle ``m`` from the inverse model
    (:func:`fastslam_edu.core.ekf.initialise_landmark_kernel`), seen once. (Not inlined: it runs once per landmark
    and particle, and the update's loop is faster without it.)"""
    initialise_landmark_kernel(P.poses[m], s.z, s.R, P.mu[m, s.j], P.sigma[m, s.j])
    P.seen[m, s.j] = True
    P.count[m, s.j] = 1


@njit(cache=True, inline="always")
def explains(P, s, gate_chi2):
    """True unless *every* particle that has seen the landmark of sighting ``s`` puts it beyond the gate.

    Such a sighting fits no hypothesis — a misread barcode, a range off by
    metres — and is set aside (unless it escapes the gate). True when no
    particle has seen the landmark.
    """
    j = s.j
    for m in range(P.poses.shape[0]):
        if P.seen[m, j] and \
                innovation_statistics_kernel(P.poses[m], s.z, s.R, P.mu[m, j], P.sigma[m, j]).d2 <= gate_chi2:
            return True
    return not P.seen[:, j].any()


@njit(cache=True, _nrt=False)
def update_particles(P, S, gate_chi2, update_map, explained):
    """Lines 5–18 for every sighting of one instant and every particle, in the order given.

    For each sighting: the gate's verdict over all particles (:func:`explains`,
    written to ``explained`` (n,)); a sighting no particle explains is skipped by
    the particles that have seen its landmark (the others initialise it; those
    that have seen it once re-initialise it, as :func:`update_particle` does), one
    with ``S.escape`` set is applied to every particle as if there were no gate.
    ``gate_chi2``: ``inf`` for no gate.

    Compiled without numba's reference counts (``_nrt=False``: see the module docstring).
    """
    for i in range(S.j.shape[0]):
        s = sighting_of(S, i)
        explained[i] = explains(P, s, gate_chi2)
        chi2 = math.inf if S.escape[i] else gate_chi2
        apply = explained[i] or S.escape[i]
        for m in range(P.poses.shape[0]):
            if apply or not P.seen[m, s.j]:
                update_particle(P, m, s, chi2, update_map)
            elif update_map and P.count[m, s.j] == 1:  # rejected, but one of two sightings is wrong:
                initialise_particle_landmark(P, m, s)  # start again


# ---------------------------------------------------------------- step 4: weights and the combined pose


@njit(cache=True)
def normalise_weights(logw, w):
    """:math:`w^{[m]} = \\exp(\\ell^{[m]} - \\max \\ell) / \\sum`, into ``w`` (M,); returns :math:`N_\\text{eff} = 1/\\sum_m (w^{[m]})^2`.

    All log weights :math:`-\\infty` (every particle ruled out): uniform weights,
    as :func:`fastslam_edu.core.weights.weights_from_log` does; NaN or :math:`+\\infty`: ValueError.
    """
    top = -math.inf
    for m in range(logw.shape[0]):  # (a loop: numba's np.max compiles a generic reduction)
        if math.isnan(logw[m]) or logw[m] == math.inf:
            raise ValueError("log weights contain NaN or +inf: a likelihood was not computed right")
        top = max(top, logw[m])
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
def combined_pose_kernel(poses, w, out):
    """:math:`\\bar x = \\sum_m w^{[m]} x^{[m]}` into ``out`` (3,), θ the circular mean (wrapped)."""
    x = y = s = c = 0.0
    for m in range(poses.shape[0]):
        x += w[m] * poses[m, 0]
        y += w[m] * poses[m, 1]
        s += w[m] * math.sin(poses[m, 2])
        c += w[m] * math.cos(poses[m, 2])
    out[0], out[1], out[2] = x, y, wrap_angle_kernel(math.atan2(s, c))


@njit(cache=True)
def pose_covariance(poses, w):
    """The weighted covariance (3, 3) of the particles' poses ``poses`` (M, 3), ``w`` (M,) normalised:
    :math:`P = \\sum_m w^{[m]} \\delta^{[m]} \\delta^{[m]\\top}`, :math:`\\delta^{[m]} = x^{[m]} - \\bar x` about the mean
    of :func:`combined_pose_kernel`, the heading difference wrapped (a cloud that straddles θ = ±π has a small
    variance, not one of π²)."""
    mean = np.zeros(3)
    combined_pose_kernel(poses, w, mean)
    cov = np.zeros((3, 3))
    e = np.empty(3)
    for m in range(poses.shape[0]):
        e[0], e[1] = poses[m, 0] - mean[0], poses[m, 1] - mean[1]
        e[2] = wrap_angle_kernel(poses[m, 2] - mean[2])
        for u in range(3):
            for v in range(3):
                cov[u, v] += w[m] * e[u] * e[v]
    return cov


# ---------------------------------------------------------------- the run over a chunk of the log


@njit(cache=True)
def measure_instant(P, L, s, k, rng, out, prediction):
    """Steps 2–4 at measurement step ``k``: gate, update, weights (:func:`weigh_instant`), then resampling and the
    combined pose (:func:`resample_and_combine`).

    ``P`` :class:`Particles`, ``L`` :class:`Log`, ``s`` :class:`Settings`, ``out`` :class:`Record`;
    ``prediction``: FastSLAM 2.0's :math:`(\\bar x, P)` ((M, 3), (M, 3, 3),
    :func:`motion_prediction_through_segment`), or None for FastSLAM 1.0 — then numba drops the proposal's branch
    before compiling (it prunes a test ``is None`` on an argument), and a FastSLAM 1.0 run never compiles FastSLAM
    2.0's kernels.
    """
    n_eff = weigh_instant(P, L, s, k, rng, out, prediction)
    resample_and_combine(P, s, k, rng, out, n_eff)


@njit(cache=True)
def weigh_instant(P, L, s, k, rng, out, prediction):
    """Step 2 and the weights at measurement step ``k`` (arguments as :func:`measure_instant`): the gate's escapes
    and the exponents β, FastSLAM 2.0's poses (with a ``prediction``), lines 5–18 for every particle, the gate's
    memory, the counts of sightings used and rejected, the normalised weights ``out.w`` and :math:`N_\\text{eff}`
    (recorded, and returned). The Python loop of :func:`fastslam_edu.landmark.fastslam.run_fastslam` calls it
    too, then resamples itself, so that its hooks see the parents drawn.
    """
    a, b = L.offsets[k], L.offsets[k + 1]
    j, t = L.j[a:b], L.t[k]
    n = b - a
    escape, beta, explained = np.empty(n, dtype=np.bool_), np.empty(n), np.ones(n, dtype=np.bool_)
    gate_escapes(t, j, out.unexplained_since, s.escape_s, escape)
    tempering_exponents_kernel(t, j, out.last_seen, s.tau, beta)
    S = Sightings(L.z[a:b], j, L.R[a:b], escape, beta, np.full((P.poses.shape[0], n), np.nan))
    if prediction is not None:  # FastSLAM 2.0: the poses drawn given the sightings too, S.loglik their weights
        sample_improved_poses_kernel(P, S, prediction[0], prediction[1], s.gate_chi2, s.min_count, rng)
    update_particles(P, S, s.gate_chi2, s.update_map, explained)
    gate_record(t, j, explained, out.unexplained_since)
    for i in range(n):
        if explained[i] or escape[i]:
            out.totals[SIGHTINGS_USED] += 1
        else:
            out.totals[SIGHTINGS_REJECTED] += 1
    n_eff = normalise_weights(P.logw, out.w)
    q = out.totals[STEPS_DONE]
    out.ess_t[q], out.ess[q] = t, n_eff
    out.totals[STEPS_DONE] += 1
    return n_eff


@njit(cache=True)
def resample_and_combine(P, s, k, rng, out, n_eff):
    """Steps 3 and 4 at measurement step ``k``: the particles drawn when the set has degenerated
    (:func:`draw_if_degenerate`, ``n_eff`` from :func:`weigh_instant`) replace it, maps copied
    (:func:`select_in_place`); then the combined pose and the best particle's (:func:`record_poses`). The run with
    unknown correspondences takes the same two steps around its own map copy."""
    idx = draw_if_degenerate(out.w, n_eff, s, rng)
    if idx.shape[0] > 0:
        select_in_place(P, idx)
        out.totals[RESAMPLES] += 1
    record_poses(P.poses, out.w, out.pose_mean[k], out.pose_best[k])


@njit(cache=True)
def record_poses(poses, w, mean, best):
    """Step 4: the combined pose, the weighted mean of ``poses`` (M, 3) with weights ``w`` (M,)
    (:func:`combined_pose_kernel`), into ``mean`` (3,), and the pose of the particle of the highest weight into
    ``best`` (3,)."""
    combined_pose_kernel(poses, w, mean)
    copy_row(poses, np.argmax(w), best)


@njit(cache=True)
def motion_prediction_through_segment(x_start, u, dt, s):
    """FastSLAM 2.0's motion prediction :math:`(\\bar x, P)` through the steps ``u`` (L, 2), ``dt`` (L,) for the
    particles that started at ``x_start`` (M, 3) (:mod:`fastslam_edu.landmark.proposal`)."""
    x_bar, cov = np.empty((x_start.shape[0], 3)), np.empty((x_start.shape[0], 3, 3))
    delta, P_rel = np.empty(3), np.empty((3, 3))
    segment_motion_kernel(u, dt, s.noise, s.n_draws == 2, delta, P_rel)
    motion_prediction_kernel(x_start, delta, P_rel, x_bar, cov)
    return x_bar, cov


@njit(cache=True)
def copy_row(a, i, out):
    """``out[:] = a[i]`` for ``a`` (n, 3) written entry by entry (an array assignment would compile numba's
    shape check and its error message, seconds of compilation for three numbers)."""
    out[0], out[1], out[2] = a[i, 0], a[i, 1], a[i, 2]


@njit(cache=True)
def segment_normals(segments, n_draws, m):
    """One buffer (L, ``n_draws``, ``m``) for the standard normals of every segment of ``segments`` (S, 2), L steps
    the longest, allocated once for a run."""
    longest = 0
    for r in range(segments.shape[0]):
        longest = max(longest, segments[r, 1] - segments[r, 0] + 1)
    return np.empty((longest, n_draws, m))


@njit(cache=True)
def move_through_segment(poses, L, s, segment, rng, out, normals, x_start):
    """Line 4 for every particle (``poses`` (M, 3)) through the steps ``segment = (first, last)`` of the stream
    ``L``, recording the estimates of its steps in ``pose_mean``, ``pose_best`` (weights ``w``) of
    ``out = (w (M,), pose_mean (N, 3), pose_best (N, 3))`` — its last step's too unless it has sightings (a
    measurement step's estimate comes after the update). (Three arrays, not the run's record: the runs with and
    without known correspondences, whose records differ, then share one compiled form.) ``normals``
    from :func:`segment_normals`; ``x_start`` (M, 3): FastSLAM 2.0 keeps there the poses the segment starts from
    (None for FastSLAM 1.0). Returns whether the last step has sightings. The segment loop of both runs, with
    known correspondences (:func:`run_segments`) and without
    (:func:`fastslam_edu.landmark.association.run_unknown_segments`)."""
    first, last = segment[0], segment[1]
    measured = L.offsets[last + 1] > L.offsets[last]
    n_record = last - first + (0 if measured else 1)
    if x_start is not None:
        for i in range(poses.shape[0]):
            copy_row(poses, i, x_start[i])
    eps = normals[:last - first + 1]
    standard_normals(rng, eps)
    w, pose_mean, pose_best = out
    propagate_segment_kernel(poses, L.u[first:last + 1], L.dt[first:last + 1], s.noise, eps, w,
                             pose_mean[first:first + n_record], pose_best[first:first + n_record])
    return measured


@njit(cache=True)
def run_segments(P, L, s, segments, rng, out, x_start):
    """Steps 1–4 over ``segments`` (S, 2): runs of steps ``start..end``, each ending at a measurement step
    or a cut; for each, line 4 for every particle (:func:`propagate_segment_kernel`), then :func:`measure_instant`.

    ``x_start``: None for FastSLAM 1.0; for FastSLAM 2.0 an (M, 3) buffer for the poses each segment
    starts from, which its proposal conditions on (:func:`motion_prediction_through_segment`). The test ``x_start is
    None`` is decided when numba compiles (one compiled run per proposal, FastSLAM 2.0's kernels only
    when asked for). With no segments (S = 0) nothing runs: the call compiles the run, or loads it from
    numba's cache (:meth:`fastslam_edu.landmark.fastslam.FilterRun.run_compiled` times that apart).
    """
    normals = segment_normals(segments, s.n_draws, P.poses.shape[0])
    for r in range(segments.shape[0]):
        first, last = segments[r, 0], segments[r, 1]
        if not move_through_segment(P.poses, L, s, segments[r], rng, (out.w, out.pose_mean, out.pose_best), normals,
                                    x_start):
            continue
        if x_start is None:  # (numba prunes a test on an argument only when it stands alone)
            measure_instant(P, L, s, last, rng, out, None)
        else:
            prediction = motion_prediction_through_segment(x_start, L.u[first:last + 1], L.dt[first:last + 1],
                                                           s)
            measure_instant(P, L, s, last, rng, out, prediction)
