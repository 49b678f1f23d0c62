"""Re-association after a gap: the first sightings after a stretch of the log without any, decided together per
particle, with the pose error the stretch left, before any of them is committed to the map.
See :mod:`fastslam_edu.landmark.association`, step 6.

While nothing is seen the particle's pose drifts, relative to its map, by the motion noise's densities: over a gap
of :math:`g` seconds the pose error :math:`\\delta` has the prior

.. math:: \\delta \\sim \\mathcal N(0, P_g), \\qquad P_g = P + \\mathrm{diag}(\\sigma_{xy}^2, \\sigma_{xy}^2,
   \\sigma_\\theta^2)\\, g

(:math:`P` the particle set's pose covariance, ``cloud``), which the association's drift, capped at
:math:`T` = ``drift_cap_s`` seconds, leaves out: beyond :math:`T` it assumes that other landmarks have kept the pose
in check, and across a gap none did. A heading 0.3 rad off lays a landmark ahead on a neighbour's place, and one
sighting cannot tell which; MR.CLAM's camera mostly sees one landmark per frame after a gap.

So the filter holds the sightings of the first frames after a gap (a gap: no sighting for more than :math:`T`) in a
window, until it holds ``gap_window_sightings`` of them or ``gap_window_s`` seconds have passed, moving the
particles on but deciding nothing. Then each particle decides the window as a whole
(:func:`decide_window`): every hypothesis (each sighting a landmark or new, no landmark twice in one frame) is
scored by the joint Gaussian of its innovations, correlated by the one pose error :math:`\\delta` they share
(joint compatibility, :func:`~fastslam_edu.landmark.joint_compatibility.best_joint_hypothesis`), so that one rotation
lining up two landmarks at once is paid for once, and a rotation that lines up only one of them does not win. If
the best hypothesis gives sightings to at least two confirmed landmarks, the most likely :math:`\\delta` moves the
particle's path through the window (:func:`window_correction`); the window's frames are then decided and applied
one after the other as usual, from the corrected poses.

The error is taken as a rigid motion of the window's path about its first pose :math:`x_0`: the pose of frame
:math:`j` moves to :math:`p_j + \\delta_{xy} + \\delta_\\theta (p_j - p_0)^\\perp`, :math:`\\theta_j + \\delta_\\theta`
(linearised), so the Jacobian of a sighting from frame :math:`j` is :math:`H_x J_j` with

.. math:: J_j = \\begin{pmatrix} 1 & 0 & -(y_j - y_0) \\\\ 0 & 1 & x_j - x_0 \\\\ 0 & 0 & 1 \\end{pmatrix}.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from fastslam_edu.core.angles import wrap_angle_kernel
from fastslam_edu.core.ekf import innovation_statistics_kernel
from fastslam_edu.landmark.association_decision import associate_particle_kernel, candidate_logliks
from fastslam_edu.landmark.association_likelihood import (drift_covariance, drift_variances, innovation_with_pose,
                                                          new_landmark_loglik, pose_jacobian)
from fastslam_edu.landmark.joint_compatibility import (JOINT_MAX_HYPOTHESES, N_PAIR_SLOTS, best_joint_hypothesis,
                                                      solve_with_prior, write_pair_row)
from fastslam_edu.landmark.landmark_existence import retire_landmarks

#: Gauss–Newton steps of :func:`window_correction` (a heading error of 0.5 rad converges in two or three).
CORRECTION_STEPS = 4
#: A window moves the particle's path only when its best hypothesis gives sightings to this many different confirmed
#: landmarks: one range and bearing fixes two of the pose's three unknowns, two fix all three.
MIN_LANDMARKS_TO_MOVE = 2
#: The candidates a sighting of the window keeps, its most likely (with "new": 3 choices per sighting).
WINDOW_CANDIDATES = 2
#: ``GapWindow.clock``: the time of the last frame with sightings, the time the window opened (nan: no window).
LAST_SEEN, OPENED = 0, 1


class GapWindow(NamedTuple):
    """The frames held after a gap (made once per run by :func:`gap_window`; W frames, S sightings at most).

    poses (M, W, 3): each particle's pose at each held frame; cloud (W, 3, 3): the association's pose covariance
    at each; frames (W, 4) int: the sightings ``a:b`` of each in the stream, its instant number ``q`` and its step;
    count (1,) int: the frames held; clock (2,): :data:`LAST_SEEN`, :data:`OPENED`; gap (1,): the gap [s] before the
    window. The rest is the decision's scratch for S sightings of N landmarks: ll (S, N), info (S, N,
    ``N_PAIR_SLOTS``), p0 (S,), slot, choice, group (S,) int, partial (S + 1, ``N_PAIR_SLOTS``), optimistic (S + 1,),
    prior (3, 3), trial (3,), zero (3, 3) zeros. moves (C, 5): each decision's time [s] (the window's first frame),
    particle and rigid motion :math:`\\delta` (dx, dy [m], dtheta [rad]; zeros: not moved), in its first
    ``n_moves[0]`` rows."""

    poses: np.ndarray
    cloud: np.ndarray
    frames: np.ndarray
    count: np.ndarray
    clock: np.ndarray
    gap: np.ndarray
    ll: np.ndarray
    info: np.ndarray
    p0: np.ndarray
    slot: np.ndarray
    choice: np.ndarray
    group: np.ndarray
    partial: np.ndarray
    optimistic: np.ndarray
    prior: np.ndarray
    trial: np.ndarray
    zero: np.ndarray
    moves: np.ndarray
    n_moves: np.ndarray


def gap_window(n_particles: int, max_landmarks: int, max_sightings: int, most_in_frame: int) -> GapWindow:
    """An empty :class:`GapWindow` for ``n_particles`` particles of ``max_landmarks`` landmarks, held until
    ``max_sightings`` sightings (frames of at most ``most_in_frame`` sightings)."""
    M, N = int(n_particles), int(max_landmarks)
    S = max(1, int(max_sightings) + int(most_in_frame))
    W = S  # (a held frame has at least one sighting)
    return GapWindow(poses=np.zeros((M, W, 3)), cloud=np.zeros((W, 3, 3)), frames=np.zeros((W, 4), dtype=np.int64),
                     count=np.zeros(1, dtype=np.int64), clock=np.array([-math.inf, math.nan]), gap=np.zeros(1),
                     ll=np.full((S, N), -math.inf), info=np.zeros((S, N, N_PAIR_SLOTS)), p0=np.zeros(S),
                     slot=np.full(S, -1, dtype=np.int64), choice=np.full(S, -1, dtype=np.int64),
                     group=np.zeros(S, dtype=np.int64), partial=np.zeros((S + 1, N_PAIR_SLOTS)),
                     optimistic=np.zeros(S + 1), prior=np.zeros((3, 3)), trial=np.zeros(3),
                     zero=np.zeros((3, 3)), moves=np.zeros((200 * M, 5)), n_moves=np.zeros(1, dtype=np.int64))


def frames_held(win: GapWindow | None) -> int:
    """The frames held in ``win`` (0 without a window: ``None``)."""
    return 0 if win is None else int(win.count[0])


# ---------------------------------------------------------------- holding frames


@njit(cache=True, _nrt=False)
def held_sightings(win):
    """The sightings held in the window."""
    count = win.count[0]
    return 0 if count == 0 else win.frames[count - 1, 1] - win.frames[0, 0]


@njit(cache=True, _nrt=False)
def window_is_due(win, t, rules):
    """Whether the window must be decided before the frame at ``t`` [s]: it holds ``rules.window_sightings``
    sightings, or ``rules.window_s`` seconds have passed since it opened."""
    return win.count[0] > 0 and (held_sightings(win) >= rules.window_sightings
                                 or t - win.clock[OPENED] > rules.window_s)


@njit(cache=True, _nrt=False)
def holds_frame(win, t, rules):
    """Whether the frame at ``t`` [s] goes into the window: one is open, or the frame ends a gap (no sighting for
    more than ``rules.drift_cap_s``). Updates the time last seen. (A run without windows has no ``win``.)"""
    gap = t - win.clock[LAST_SEEN]
    win.clock[LAST_SEEN] = t
    if win.count[0] > 0:
        return True
    if not rules.drift_cap_s < gap < math.inf:
        return False
    win.clock[OPENED] = t
    win.gap[0] = gap
    return True


@njit(cache=True, _nrt=False)
def hold_frame(win, poses, cloud, frame):
    """Hold a frame: every particle's pose ``poses`` (M, 3), the pose covariance ``cloud`` (3, 3) and ``frame =
    (a, b, q, step)``."""
    w = win.count[0]
    for m in range(poses.shape[0]):
        for c in range(3):
            win.poses[m, w, c] = poses[m, c]
    for u in range(3):
        for v in range(3):
            win.cloud[w, u, v] = cloud[u, v]
    for c in range(4):
        win.frames[w, c] = frame[c]
    win.count[0] = w + 1


# ---------------------------------------------------------------- the pieces of a particle's decision


@njit(cache=True, _nrt=False)
def moved_pose(win, m, w, e0, e1, e2, out):
    """The pose of frame ``w`` of particle ``m`` after the rigid motion :math:`\\delta` = ``(e0, e1, e2)`` about the
    window's first pose (module docstring; the rotation exact), written into ``out`` (3,)."""
    x0, y0 = win.poses[m, 0, 0], win.poses[m, 0, 1]
    dx, dy = win.poses[m, w, 0] - x0, win.poses[m, w, 1] - y0
    c, s = math.cos(e2), math.sin(e2)
    out[0] = x0 + e0 + c * dx - s * dy
    out[1] = y0 + e1 + s * dx + c * dy
    out[2] = wrap_angle_kernel(win.poses[m, w, 2] + e2)


@njit(cache=True, _nrt=False)
def chained_rows(j, k, px, py):
    """The rows of :math:`H_x J_j` (module docstring): ``j``, ``k`` the range and bearing rows of :math:`H_x`,
    ``(px, py)`` :math:`= p_j - p_0`."""
    return ((j[0], j[1], j[2] - py * j[0] + px * j[1]), (k[0], k[1], k[2] - py * k[0] + px * k[1]))


@njit(cache=True, _nrt=False)
def keep_most_likely(row, keep):
    """Set all but the ``keep`` largest finite entries of ``row`` to -inf (ties: the first)."""
    while True:
        finite, low, k_low = 0, math.inf, -1
        for k in range(row.shape[0]):
            if row[k] > -math.inf:
                finite += 1
                if row[k] < low:
                    low, k_low = row[k], k
        if finite <= keep:
            return
        row[k_low] = -math.inf


@njit(cache=True, _nrt=False)
def window_information(P, m, L, win, rules):
    """``win.info[s, k]``: what each candidate pair adds to a joint hypothesis
    (:func:`~fastslam_edu.landmark.joint_compatibility.write_pair_row`), with the Jacobian :math:`H_x J_j` of the
    rigid motion of the window's path, and each sighting's :math:`\\log p_0` in ``win.p0``. :math:`D`: the
    landmark's and the sighting's covariance and the landmark's own (capped) drift."""
    s0 = win.frames[0, 0]
    x0, y0 = win.poses[m, 0, 0], win.poses[m, 0, 1]
    for w in range(win.count[0]):
        a, b, t = win.frames[w, 0], win.frames[w, 1], L.t[win.frames[w, 3]]
        pose = win.poses[m, w]
        for s in range(a - s0, b - s0):
            z, R = L.z[s0 + s], L.R[s0 + s]
            win.p0[s] = new_landmark_loglik(R, rules.new_chi2)
            for k in range(P.n[m]):
                if win.ll[s, k] == -math.inf:
                    continue
                v_xy, v_theta = drift_variances(t - P.last_t[m, k], rules)
                nu0, nu1, d00, d01, d11 = innovation_with_pose(pose, z, R, P.mu[m, k], P.sigma[m, k], win.zero, rules,
                                                               v_xy, v_theta)
                j0, j1, j2, k0, k1, k2 = pose_jacobian(pose, P.mu[m, k, 0], P.mu[m, k, 1])
                hr, hb = chained_rows((j0, j1, j2), (k0, k1, k2), pose[0] - x0, pose[1] - y0)
                write_pair_row((nu0, nu1), (d00, d01, d11), hr, hb, win.info[s, k])


@njit(cache=True, _nrt=False)
def confirmed_landmarks_taken(P, m, slot, rules):
    """How many different confirmed landmarks of particle ``m`` the sightings' ``slot`` (S,) take."""
    count = 0
    for s in range(slot.shape[0]):
        k = slot[s]
        if k < 0 or P.evidence[m, k] < rules.n_confirm:
            continue
        first = True
        for r in range(s):
            if slot[r] == k:
                first = False
        count += first
    return count


@njit(cache=True, _nrt=False)
def window_correction(P, m, L, win, slot, rules):
    """The most likely rigid motion :math:`\\delta` = ``(dx [m], dy [m], dtheta [rad])`` of particle ``m``'s path
    through the window, given the sightings' landmarks ``slot`` (S,) (confirmed ones only) and the prior
    ``win.prior`` :math:`P_g`: Gauss–Newton on :math:`\\tfrac12\\delta^\\top P_g^{-1}\\delta + \\tfrac12\\sum_s
    \\nu_s^\\top Q_s^{-1}\\nu_s`, :math:`Q_s = H\\Sigma H^\\top + R`. Linearised at :math:`\\delta_i`, the step is
    :math:`\\Delta = A^{-1}(P_g b - \\delta_i)`, :math:`A = I + P_g G`, with :math:`G = \\sum \\tilde H_s^\\top
    Q_s^{-1}\\tilde H_s`, :math:`b = \\sum \\tilde H_s^\\top Q_s^{-1}\\nu_s`, :math:`\\tilde H_s = H_x J_j`."""
    s0, prior, trial = win.frames[0, 0], win.prior, win.trial
    e0 = e1 = e2 = 0.0
    for _ in range(CORRECTION_STEPS):
        total = win.partial[0]  # (the decision's scratch: its first row)
        total[:] = 0.0
        for w in range(win.count[0]):
            moved_pose(win, m, w, e0, e1, e2, trial)
            for s in range(win.frames[w, 0] - s0, win.frames[w, 1] - s0):
                k = slot[s]
                if k < 0 or P.evidence[m, k] < rules.n_confirm:
                    continue
                nu0, nu1, _, _, _, _, q00, q01, q11, _, _ = innovation_statistics_kernel(
                    trial, L.z[s0 + s], L.R[s0 + s], P.mu[m, k], P.sigma[m, k])
                j0, j1, j2, k0, k1, k2 = pose_jacobian(trial, P.mu[m, k, 0], P.mu[m, k, 1])
                hr, hb = chained_rows((j0, j1, j2), (k0, k1, k2), trial[0] - win.poses[m, 0, 0] - e0,
                                      trial[1] - win.poses[m, 0, 1] - e1)
                write_pair_row((nu0, nu1), (q00, q01, q11), hr, hb, win.info[s, k])
                for c in range(N_PAIR_SLOTS):
                    total[c] += win.info[s, k, c]
        (d0, d1, d2), _ = solve_with_prior(prior, total, (e0, e1, e2))  # Δ = A⁻¹(P_g b - δ_i)
        e0, e1, e2 = e0 + d0, e1 + d1, e2 + d2
    return e0, e1, e2


@njit(cache=True, _nrt=False)
def gap_covariance(cloud, gap_s, rules, out):
    """:math:`P_g` less the drift the association adds by itself, written into ``out`` (3, 3): ``cloud`` (3, 3) plus
    the drift of the ``gap_s`` seconds beyond ``rules.drift_cap_s`` (:func:`association_loglik` adds the first
    :math:`T` seconds' worth for every landmark, all unseen for at least the gap)."""
    for u in range(3):
        for v in range(3):
            out[u, v] = cloud[u, v]
    v_xy, v_theta = drift_variances(gap_s, rules)  # (capped at T)
    out[0, 0] += rules.drift_xy ** 2 * gap_s - v_xy
    out[1, 1] += rules.drift_xy ** 2 * gap_s - v_xy
    out[2, 2] += rules.drift_theta ** 2 * gap_s - v_theta



# ---------------------------------------------------------------- one particle's decision of the window


@njit(cache=True, _nrt=False)
def window_candidates(P, m, L, win, rules):
    """``win.ll[s, k]``: the candidates of every sighting ``s`` held in the window ``win``
    (:class:`~fastslam_edu.landmark.gap_window.GapWindow`) among the landmarks ``k`` of particle ``m``
    (:func:`candidate_logliks` at the particle's pose of its frame, with the gap's pose covariance ``win.prior``),
    its :data:`~fastslam_edu.landmark.gap_window.WINDOW_CANDIDATES` most likely kept; ``win.group[s]``: its frame.
    Returns the number of joint hypotheses (at most ``JOINT_MAX_HYPOTHESES`` + 1: too many)."""
    K, s0, count = P.n[m], win.frames[0, 0], 1
    for w in range(win.count[0]):
        a, b = win.frames[w, 0], win.frames[w, 1]
        rows = win.ll[a - s0:b - s0, :K]
        rows[:, :] = -math.inf
        candidate_logliks(P, m, win.poses[m, w], (L.z[a:b], L.R[a:b], L.t[win.frames[w, 3]]), win.prior, rules, rows)
        for s in range(a - s0, b - s0):
            win.group[s] = w
            keep_most_likely(win.ll[s, :K], WINDOW_CANDIDATES)
            c = 1
            for k in range(K):
                if win.ll[s, k] > -math.inf:
                    c += 1
            count = min(count * c, JOINT_MAX_HYPOTHESES + 1)
    return count


@njit(cache=True, _nrt=False)
def decide_window(P, m, L, rules, win, work, out):
    """Step 6 for particle ``m`` (:mod:`~fastslam_edu.landmark.gap_window`): the held sightings decided together
    (the best joint hypothesis of :func:`window_candidates`, with the gap's pose error); if it gives sightings to
    two confirmed landmarks or more, the particle's path through the window moves by the most likely rigid motion
    (:func:`~fastslam_edu.landmark.gap_window.window_correction`). Then the frames are decided and applied one after
    the other from those poses (:func:`associate_particle_kernel`, ``record`` into ``out`` as in the run), and the
    particle ends at its last frame's pose. Returns the rigid motion ``(dx, dy, dtheta)`` (zeros: none)."""
    count, K = win.count[0], P.n[m]
    S = win.frames[count - 1, 1] - win.frames[0, 0]
    gap_covariance(win.cloud[0], win.gap[0], rules, win.prior)
    e0 = e1 = e2 = 0.0
    if K > 0 and window_candidates(P, m, L, win, rules) <= JOINT_MAX_HYPOTHESES:
        window_information(P, m, L, win, rules)
        best_joint_hypothesis(win.info[:S, :K], win.ll[:S, :K], win.p0[:S], win.prior, win.slot[:S],
                              (win.choice[:S], win.partial[:S + 1], win.group[:S], win.optimistic[:S + 1]))
        if confirmed_landmarks_taken(P, m, win.slot[:S], rules) >= MIN_LANDMARKS_TO_MOVE:
            drift_covariance(win.prior, rules.drift_cap_s, rules, win.prior)  # P_g, all of it
            e0, e1, e2 = window_correction(P, m, L, win, win.slot[:S], rules)
    for w in range(count):
        a, b, q, step = win.frames[w, 0], win.frames[w, 1], win.frames[w, 2], win.frames[w, 3]
        moved_pose(win, m, w, e0, e1, e2, P.poses[m])
        associate_particle_kernel(P, m, (L.z[a:b], L.R[a:b], L.t[step]), rules, win.cloud[w], work,
                                  (out.next_ident, out.assoc[m, a:b]))
        retire_landmarks(P, m, rules, out.renames, out.n_renames, q)
    return e0, e1, e2


@njit(cache=True, _nrt=False)
def decide_held_frames(P, L, rules, win, work, out):
    """:func:`decide_window` for every particle (``work``: an
    :class:`~fastslam_edu.landmark.association_params.AssociationWorkspace`, ``out``: the run's
    :class:`~fastslam_edu.landmark.association.AssociationRecord`), and the window emptied; each particle's rigid
    motion recorded in ``win.moves``."""
    for m in range(P.poses.shape[0]):
        e0, e1, e2 = decide_window(P, m, L, rules, win, work, out)
        j = win.n_moves[0]
        if j < win.moves.shape[0]:  # (the first ones, if there are more than it holds)
            win.moves[j, 0], win.moves[j, 1] = L.t[win.frames[0, 3]], m
            win.moves[j, 2], win.moves[j, 3], win.moves[j, 4] = e0, e1, e2
            win.n_moves[0] = j + 1
    win.count[0] = 0

__all__ = ["CORRECTION_STEPS", "MIN_LANDMARKS_TO_MOVE", "WINDOW_CANDIDATES", "LAST_SEEN", "OPENED", "GapWindow", "gap_window",
           "frames_held", "held_sightings", "window_is_due", "holds_frame", "hold_frame", "moved_pose", "chained_rows",
           "keep_most_likely", "window_information", "confirmed_landmarks_taken", "window_correction", "gap_covariance",
           "window_candidates", "decide_window", "decide_held_frames"]
