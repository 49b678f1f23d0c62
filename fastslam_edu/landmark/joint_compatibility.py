"""Joint compatibility: the sightings of one instant decided together (Neira and Tardós 2001).

A hypothesis (each sighting a landmark or new, no landmark twice) is scored by the joint Gaussian of its
innovations, correlated by the pose error the sightings share; the most likely one is found by branch and bound, as
in the paper (:func:`best_joint_hypothesis`), without scoring them all. See
:mod:`fastslam_edu.landmark.association`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from fastslam_edu.core.ekf import LOG_2PI
from fastslam_edu.landmark.association_likelihood import (drift_covariance, drift_variances, innovation_with_pose,
                                                          new_landmark_loglik, pose_jacobian)

#: More joint hypotheses than this in one instant (each sighting's candidates and "new", multiplied): the
#: instant is decided one sighting at a time instead (:func:`choose_landmarks`).
JOINT_MAX_HYPOTHESES = 4096

#: The layout of a row of :func:`pair_information` (and of its sum over a hypothesis, :func:`joint_loglik`):
#: :math:`\\nu^\\top D^{-1}\\nu` at ``PAIR_QUAD``; :math:`b = H_x^\\top D^{-1}\\nu` (3) from ``PAIR_B``;
#: :math:`G = H_x^\\top D^{-1} H_x` (3×3, row-major: entry ``(u, v)`` at ``PAIR_G + 3 u + v``);
#: :math:`\\log\\det D` at ``PAIR_LOG_DET``.
PAIR_QUAD, PAIR_B, PAIR_G, PAIR_LOG_DET = 0, 1, 4, 13
N_PAIR_SLOTS = 14


@njit(cache=True, _nrt=False)
def joint_slots(P, m, pose, cloud, instant, rules, work):
    """The jointly most likely association of one instant's sightings (joint compatibility, Neira and Tardós
    2001), written into ``work.slot[:n]``; False (``slot`` untouched) if there are more than
    ``JOINT_MAX_HYPOTHESES`` hypotheses. ``instant = (z (n, 2), R (n, 2, 2), t)``; ``work``: an
    :class:`~fastslam_edu.landmark.association_params.AssociationWorkspace` whose ``ll[:n, :K]`` holds the
    candidates of :func:`~fastslam_edu.landmark.association.choose_landmarks_kernel` (K: the particle's landmarks).

    Sighting :math:`i`'s candidates are the landmarks with ``ll[i, k] > -inf``, and a new landmark
    (:math:`p_0`). The sightings of one instant share the particle's pose error: the part of the drift that
    every candidate has in common, :math:`P_c` (``cloud`` plus the drift over the shortest time any candidate
    was unseen, :func:`drift_covariance`), correlates their innovations,
    :math:`S = \\mathrm{blockdiag}(D_i) + H_x P_c H_x^\\top`, with :math:`D_i` the rest of each innovation's
    covariance (its landmark, :math:`R`, and its own further drift: :func:`pair_information`). Each hypothesis
    (each sighting a free candidate or new, each landmark at most once) is scored by
    :math:`\\log\\mathcal N(\\nu; 0, S) + \\sum_{\\text{new}} \\log p_0` (:func:`best_joint_hypothesis`). A
    rotation of the pose that lines every sighting up with a neighbour of its landmark is then one error, paid
    once, not an independent chance per sighting.
    """
    n, K = instant[0].shape[0], P.n[m]
    ll = work.ll[:n, :K]
    count, unseen = 1, math.inf
    for i in range(n):
        c = 1
        for k in range(K):
            if ll[i, k] > -math.inf:
                c += 1
                unseen = min(unseen, instant[2] - P.last_t[m, k])
        count *= c
        if count > JOINT_MAX_HYPOTHESES:
            return False
    pair_information(P, m, pose, instant, unseen, rules, work)
    p0 = work.p0[:n]
    for i in range(n):
        p0[i] = new_landmark_loglik(instant[1][i], rules.new_chi2)
    drift_covariance(cloud, unseen, rules, work.common)
    best_joint_hypothesis(work.info[:n, :K], ll, p0, work.common, work.slot[:n],
                          (work.choice[:n], work.partial[:n + 1], work.group[:n], work.optimistic[:n + 1]))
    return True


@njit(cache=True, _nrt=False)
def pair_information(P, m, pose, instant, unseen, rules, work):
    """What each candidate pair ``(i, k)`` (``work.ll[i, k] > -inf``) adds to a joint hypothesis
    (:func:`joint_loglik`), written into ``work.info[i, k]`` (:data:`N_PAIR_SLOTS`,) (the other pairs' rows are not
    read, and not written): :math:`\\nu^\\top D^{-1}\\nu`, :math:`H_x^\\top D^{-1}\\nu`
    (3), :math:`H_x^\\top D^{-1} H_x` (3×3, row-major) and :math:`\\log\\det D` at the slots ``PAIR_QUAD``,
    ``PAIR_B``, ``PAIR_G``, ``PAIR_LOG_DET``.

    :math:`D` is the innovation covariance of :func:`innovation_with_pose` with the drift the landmark was
    unseen for beyond the instant's common ``unseen`` seconds (:func:`joint_slots`): with the common part
    :math:`H_x P_c H_x^\\top` added back it is the covariance the landmark is decided by alone
    (:func:`association_loglik`)."""
    z, R, t = instant
    n, K = z.shape[0], P.n[m]
    ll, info = work.ll, work.info
    common_xy, common_theta = drift_variances(unseen, rules)
    excess = work.excess  # the landmark's own drift beyond the common part (only its diagonal is written)
    for i in range(n):
        for k in range(K):
            if ll[i, k] == -math.inf:
                continue
            own_xy, own_theta = drift_variances(t - P.last_t[m, k], rules)
            excess[0, 0] = excess[1, 1] = own_xy - common_xy
            excess[2, 2] = own_theta - common_theta
            nu0, nu1, d00, d01, d11 = innovation_with_pose(pose, z[i], R[i], P.mu[m, k], P.sigma[m, k], excess, rules,
                                                           0.0, 0.0)  # (the drift is in excess)
            j0, j1, j2, k0, k1, k2 = pose_jacobian(pose, P.mu[m, k, 0], P.mu[m, k, 1])
            write_pair_row((nu0, nu1), (d00, d01, d11), (j0, j1, j2), (k0, k1, k2), info[i, k])


@njit(cache=True, _nrt=False)
def write_pair_row(nu, D, hr, hb, row):
    """One row of :func:`pair_information` (:data:`N_PAIR_SLOTS`,), written into ``row``: from the innovation
    ``nu`` :math:`= (\\nu_r, \\nu_\\phi)`, its covariance ``D`` :math:`= (D_{00}, D_{01}, D_{11})` and the rows of
    :math:`H_x` (``hr``: range, ``hb``: bearing; 3 numbers each): :math:`\\nu^\\top D^{-1}\\nu`,
    :math:`H_x^\\top D^{-1}\\nu`, :math:`H_x^\\top D^{-1} H_x` and :math:`\\log\\det D`."""
    nu0, nu1 = nu
    d00, d01, d11 = D
    det = d00 * d11 - d01 * d01
    i00, i01, i11 = d11 / det, -d01 / det, d00 / det  # D⁻¹
    v0, v1 = i00 * nu0 + i01 * nu1, i01 * nu0 + i11 * nu1  # D⁻¹ν
    row[PAIR_QUAD] = nu0 * v0 + nu1 * v1
    for u in range(3):
        row[PAIR_B + u] = hr[u] * v0 + hb[u] * v1
        for v in range(3):
            row[PAIR_G + 3 * u + v] = hr[u] * (i00 * hr[v] + i01 * hb[v]) + hb[u] * (i01 * hr[v] + i11 * hb[v])
    row[PAIR_LOG_DET] = math.log(det)


@njit(cache=True, _nrt=False)
def best_joint_hypothesis(info, ll, p0, Pc, slot, scratch):
    """The most likely joint hypothesis (:func:`joint_slots`), written into ``slot`` (n,) (-1: new).

    The hypotheses are the leaves of a tree searched depth first: depth :math:`i` chooses sighting :math:`i`'s
    landmark, "new" (-1) first, then its candidates (``ll[i, k] > -inf``) in increasing order. A candidate that a
    sighting of the same camera frame above it already took is not a branch, so a hypothesis that gives one landmark
    two sightings of a frame is never built. Each depth keeps the running sum of the rows of
    :func:`pair_information` chosen above it (made in the sightings' order, as the score of the whole hypothesis
    would make them).

    **Branch and bound.** Below a node with sightings :math:`0..i` decided, no leaf scores more than the node's own
    score (:func:`hypothesis_loglik` of the sightings decided) plus, for each sighting still to decide, the larger
    of :math:`\\log p_0` and its best pair's :math:`-\\log 2\\pi - \\tfrac12\\log\\det D_{ik}`
    (:func:`optimistic_rest`). Adding sightings can only raise :math:`\\nu^\\top S^{-1}\\nu` (a quadratic form
    over more variables), and the covariance of the rest given the decided ones is their :math:`D` plus a positive
    semi-definite term, so its log-determinant is at least their :math:`\\sum\\log\\det D`. A subtree whose
    bound is below the best leaf found so far (the greedy one first, :func:`greedy_hypothesis`) is not searched:
    the result is the exhaustive search's.

    ``info`` from :func:`pair_information`, ``p0`` (n,) :math:`\\log p_0`, ``Pc`` (3, 3) the common pose
    covariance; ``scratch = (choice (n,) int, partial (n + 1, N_PAIR_SLOTS), group (n,) int, optimistic (n + 1,))``:
    the choice at each depth, the running sums, the camera frame of each sighting (all 0 for one instant; the frames
    of :mod:`~fastslam_edu.landmark.gap_window` come one after the other, so a frame's sightings are consecutive),
    and the bounds of the sightings still to decide. Returns the number of leaves scored."""
    n, K = ll.shape
    choice, partial, group, optimistic = scratch
    optimistic_rest(info, ll, p0, optimistic)
    for c in range(N_PAIR_SLOTS):
        partial[0, c] = 0.0
    best = greedy_hypothesis(info, ll, p0, Pc, slot, scratch)
    leaves, i = 1, np.int64(0)  # (not 0: a literal would compile next_branch and what it calls a second time)
    choice[0] = -2  # (before "new": the next branch of depth i is choice[i] + 1 onwards)
    while i >= 0:
        k = next_branch(ll, choice, group, i)
        if k == K:  # depth i has no branch left: back up
            i -= 1
            continue
        choice[i] = k
        add_pair_row(info, partial, i, k)
        score = hypothesis_loglik(partial[i + 1], choice[:i + 1], p0, Pc)
        if i + 1 == n:  # a leaf
            leaves += 1
            if score > best:
                best = score
                for c in range(n):
                    slot[c] = choice[c]
        elif score + optimistic[i + 1] > best - BOUND_SLACK:  # (the slack: rounding never prunes a better leaf)
            i += 1
            choice[i] = -2
    return leaves


#: How far below the best leaf a subtree's bound may fall and still be searched (:func:`best_joint_hypothesis`):
#: far above the rounding of a bound, far below any difference of log-likelihood that decides anything.
BOUND_SLACK = 1e-9


@njit(cache=True, _nrt=False)
def add_pair_row(info, partial, i, k):
    """``partial[i + 1] = partial[i]`` plus pair ``(i, k)``'s row of ``info`` (nothing for k = -1, new), number
    by number (see copy_row)."""
    if k < 0:
        for c in range(N_PAIR_SLOTS):
            partial[i + 1, c] = partial[i, c]
    else:
        for c in range(N_PAIR_SLOTS):
            partial[i + 1, c] = partial[i, c] + info[i, k, c]


@njit(cache=True, _nrt=False)
def optimistic_rest(info, ll, p0, optimistic):
    """``optimistic[i]`` (n + 1,): the most that sightings ``i..n-1`` can add to a hypothesis's score
    (:func:`best_joint_hypothesis`), each the larger of :math:`\\log p_0` and its best candidate's
    :math:`-\\log 2\\pi - \\tfrac12\\log\\det D_{ik}`; ``optimistic[n] = 0``."""
    n, K = ll.shape
    optimistic[n] = 0.0
    for i in range(n - 1, -1, -1):
        most = p0[i]
        for k in range(K):
            if ll[i, k] > -math.inf:
                most = max(most, -LOG_2PI - 0.5 * info[i, k, PAIR_LOG_DET])
        optimistic[i] = optimistic[i + 1] + most


@njit(cache=True, _nrt=False)
def greedy_hypothesis(info, ll, p0, Pc, slot, scratch):
    """A first leaf for :func:`best_joint_hypothesis` to beat: each sighting in turn takes its most likely
    candidate alone (``ll``) that its frame has not taken, or is new when :math:`\\log p_0` is larger. Written
    into ``slot``; returns its score (:func:`hypothesis_loglik`)."""
    n, K = ll.shape
    choice, partial, group, _ = scratch
    for i in range(n):
        choice[i], most = -1, p0[i]
        for k in range(K):
            if ll[i, k] > most and not taken_in_frame(choice, group, i, k):
                choice[i], most = k, ll[i, k]
        add_pair_row(info, partial, i, choice[i])
        slot[i] = choice[i]
    return hypothesis_loglik(partial[n], choice, p0, Pc)


@njit(cache=True, _nrt=False)
def next_branch(ll, choice, group, i):
    """The next choice of sighting ``i`` after ``choice[i]`` (-2: none yet): "new" (-1), then its candidates
    (``ll[i, k] > -inf``) that no sighting before it in the same frame (``group``) has taken; K when none is
    left (:func:`best_joint_hypothesis`)."""
    K = ll.shape[1]
    k = choice[i] + 1
    if k < 0:
        return np.int64(-1)
    while k < K:
        if ll[i, k] > -math.inf and not taken_in_frame(choice, group, i, k):
            return k
        k += 1
    return np.int64(K)


@njit(cache=True, _nrt=False)
def taken_in_frame(choice, group, i, k):
    """Whether a sighting before ``i`` of the same camera frame (``group``; a frame's sightings are consecutive)
    chose landmark ``k``."""
    j = i - 1
    while j >= 0 and group[j] == group[i]:
        if choice[j] == k:
            return True
        j -= 1
    return False


@njit(cache=True, _nrt=False)
def hypothesis_loglik(total, choice, p0, Pc):
    """The score of one joint hypothesis ``choice`` (n,) (-1: new): :math:`\\sum_{\\text{new}} \\log p_0` (``p0``
    (n,)) plus :func:`joint_loglik` of ``total``, the sum of its assigned pairs' rows."""
    score, n_assigned = 0.0, np.int64(0)
    for i in range(choice.shape[0]):
        if choice[i] < 0:
            score += p0[i]
        else:
            n_assigned += 1
    return score + joint_loglik(total, n_assigned, Pc)


@njit(cache=True, _nrt=False)
def joint_loglik(total, n_assigned, Pc):
    """:math:`\\log\\mathcal N(\\nu; 0, S)` of ``n_assigned`` stacked sightings, :math:`S = D + H_x P_c H_x^\\top`
    (:math:`D` block-diagonal), from the sums over the sightings of :func:`pair_information`'s rows, ``total``
    (:data:`N_PAIR_SLOTS`,): :math:`a = \\sum \\nu_i^\\top D_i^{-1}\\nu_i`,
    :math:`b = \\sum H_i^\\top D_i^{-1}\\nu_i` (3), :math:`G = \\sum H_i^\\top D_i^{-1} H_i` (3×3) and
    :math:`\\sum\\log\\det D_i`. With :math:`A = I + P_c G`
    (the Woodbury identity and the matrix determinant lemma, so that only 3×3 matrices are solved):
    :math:`\\nu^\\top S^{-1}\\nu = a - b^\\top A^{-1} P_c b` and :math:`\\log\\det S = \\sum\\log\\det D_i + \\log\\det A`."""
    if n_assigned == 0:
        return 0.0
    # A⁻¹ P_c b and det A, as scalars: this runs for every hypothesis, and makes no array
    (x0, x1, x2), det_a = solve_with_prior(Pc, total, (0.0, 0.0, 0.0))
    quad = total[PAIR_QUAD] - (total[PAIR_B] * x0 + total[PAIR_B + 1] * x1 + total[PAIR_B + 2] * x2)
    return -0.5 * quad - n_assigned * LOG_2PI - 0.5 * (total[PAIR_LOG_DET] + math.log(det_a))


@njit(cache=True, _nrt=False)
def solve_with_prior(Pc, total, delta):
    """:math:`x = A^{-1}(P_c b - \\delta)` and :math:`\\det A`, :math:`A = I + P_c G` (3×3), with :math:`b` and
    :math:`G` from the summed rows ``total`` (:data:`N_PAIR_SLOTS`,) of :func:`pair_information` and ``delta`` three
    numbers: ``((x0, x1, x2), det_a)``. With :math:`\\delta = 0` it is :func:`joint_loglik`'s
    :math:`A^{-1} P_c b`; with the current estimate :math:`\\delta_i` it is a Gauss–Newton step under the prior
    :math:`P_c` (:func:`fastslam_edu.landmark.gap_window.window_correction`)."""
    a00, a01, a02 = 1.0 + _pc_g(Pc, total, 0, 0), _pc_g(Pc, total, 0, 1), _pc_g(Pc, total, 0, 2)
    a10, a11, a12 = _pc_g(Pc, total, 1, 0), 1.0 + _pc_g(Pc, total, 1, 1), _pc_g(Pc, total, 1, 2)
    a20, a21, a22 = _pc_g(Pc, total, 2, 0), _pc_g(Pc, total, 2, 1), 1.0 + _pc_g(Pc, total, 2, 2)
    c0, c1, c2 = _pc_b(Pc, total, 0) - delta[0], _pc_b(Pc, total, 1) - delta[1], _pc_b(Pc, total, 2) - delta[2]
    det_a = det3_of((a00, a01, a02), (a10, a11, a12), (a20, a21, a22))
    # Cramer's rule: unknown j is the determinant of A with column j replaced by c, over det A
    x0 = det3_of((c0, a01, a02), (c1, a11, a12), (c2, a21, a22)) / det_a
    x1 = det3_of((a00, c0, a02), (a10, c1, a12), (a20, c2, a22)) / det_a
    x2 = det3_of((a00, a01, c0), (a10, a11, c1), (a20, a21, c2)) / det_a
    return (x0, x1, x2), det_a


@njit(cache=True, inline="always")
def _pc_g(Pc, total, u, v):
    """Entry ``(u, v)`` of :math:`P_c G`, with :math:`G` row-major from ``total[PAIR_G]``."""
    return Pc[u, 0] * total[PAIR_G + v] + Pc[u, 1] * total[PAIR_G + 3 + v] + Pc[u, 2] * total[PAIR_G + 6 + v]


@njit(cache=True, inline="always")
def _pc_b(Pc, total, u):
    """Entry ``u`` of :math:`P_c b`, with :math:`b` from ``total[PAIR_B]``."""
    return Pc[u, 0] * total[PAIR_B] + Pc[u, 1] * total[PAIR_B + 1] + Pc[u, 2] * total[PAIR_B + 2]


@njit(cache=True, inline="always")
def det3_of(r0, r1, r2):
    """The determinant of a 3×3 matrix given by its rows ``r0``, ``r1``, ``r2`` (tuples of 3 numbers, no array),
    by cofactors along the first row."""
    return (r0[0] * (r1[1] * r2[2] - r1[2] * r2[1]) - r0[1] * (r1[0] * r2[2] - r1[2] * r2[0])
            + r0[2] * (r1[0] * r2[1] - r1[1] * r2[0]))


__all__ = ["JOINT_MAX_HYPOTHESES", "PAIR_QUAD", "PAIR_B", "PAIR_G", "PAIR_LOG_DET", "N_PAIR_SLOTS", "joint_slots",
           "pair_information", "write_pair_row", "best_joint_hypothesis", "BOUND_SLACK", "add_pair_row",
           "optimistic_rest", "greedy_hypothesis", "next_branch", "taken_in_frame", "hypothesis_loglik",
           "joint_loglik", "solve_with_prior", "det3_of"]
