"""FastSLAM with unknown correspondences, steps 1–2 of one particle at one instant: which landmark each sighting is
(:func:`choose_landmarks`), and the update, weight and negative evidence that follow (:func:`apply_associations`).
See :mod:`fastslam_edu.landmark.association`, which runs them over a log.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from fastslam_edu.core.ekf import initialise_landmark_kernel, innovation_statistics_kernel, update_landmark_kernel
from fastslam_edu.landmark.association_likelihood import association_loglik, new_landmark_loglik, outside_gate
from fastslam_edu.landmark.association_params import INDEPENDENT, JOINT, association_workspace
from fastslam_edu.landmark.joint_compatibility import joint_slots
from fastslam_edu.landmark.landmark_existence import add_landmark, existence_log_odds, negative_evidence
from fastslam_edu.landmark.proposal import improved_pose_kernel


def choose_landmarks(P, m, pose, z, R, cloud, t, rules):
    """The association of one instant's sightings ``z`` (n, 2) for particle ``m`` at ``pose`` (3,) (its own pose,
    or FastSLAM 2.0's motion prediction :math:`\\bar x`, with ``cloud`` its covariance): ``(slot, loglik)`` (n,), (n,),
    the slot each goes to (-1: a new landmark) and its log-likelihood :math:`\\ell_{ik}` (-inf for a new one).

    Every pair ``(i, k)`` with :math:`d^2_{ik} \\le d_0^2` is a candidate, scored by its log-likelihood
    :math:`\\ell_{ik}` (:func:`association_loglik`); a sighting with no candidate is new (:math:`p_0` wins).
    ``rules.association`` (:data:`~fastslam_edu.landmark.association_params.ASSOCIATION_RULES`): ``GREEDY``
    takes the pairs greedily, the most likely first, each sighting and each landmark at most once (mutual
    exclusion): an approximation of the most likely joint association of the instant, so that a landmark is not
    taken by the sighting of its neighbour just because that sighting came first in the file. ``INDEPENDENT``:
    each sighting takes its most likely landmark. ``JOINT`` (two sightings or more) decides the instant as a whole
    (:func:`joint_slots`; when it gives up, the greedy pairing), a sighting with candidates may then be new; each
    sighting keeps its own :math:`\\ell_{ik}` as its log-likelihood.
    """
    work = association_workspace(z.shape[0], P.mu.shape[1])
    choose_landmarks_kernel(P, m, pose, (z, R, t), cloud, rules, work)
    return work.slot.copy(), work.chosen.copy()


@njit(cache=True, _nrt=False)
def choose_landmarks_kernel(P, m, pose, instant, cloud, rules, work):
    """:func:`choose_landmarks` of ``instant = (z (n, 2), R (n, 2, 2), t)``, its decision written into
    ``work.slot[:n]`` and ``work.chosen[:n]`` (``work``: an
    :class:`~fastslam_edu.landmark.association_params.AssociationWorkspace`): it makes no array."""
    z, R, t = instant
    n, K = z.shape[0], P.n[m]
    ll, slot, chosen = work.ll[:n, :K], work.slot[:n], work.chosen[:n]
    ll[:, :] = -math.inf
    slot[:] = -1
    chosen[:] = -math.inf
    candidate_logliks(P, m, pose, instant, cloud, rules, ll)
    if rules.association == JOINT and n > 1 and K > 0 and joint_slots(P, m, pose, cloud, instant, rules, work):
        for i in range(n):
            if slot[i] >= 0:
                chosen[i] = ll[i, slot[i]]
        return
    if rules.association == INDEPENDENT:
        for i in range(n):
            for k in range(K):  # the first most likely landmark (np.argmax's), if any is a candidate
                if ll[i, k] > chosen[i]:
                    slot[i], chosen[i] = k, ll[i, k]
        return
    for _ in range(min(n, K)):
        best, bi, bk = -math.inf, -1, -1
        for i in range(n):
            for k in range(K):
                if ll[i, k] > best:
                    best, bi, bk = ll[i, k], i, k
        if bi < 0:
            break
        slot[bi], chosen[bi] = bk, best
        ll[bi, :] = -math.inf  # the sighting is used, and so is the landmark
        ll[:, bk] = -math.inf


@njit(cache=True, _nrt=False)
def candidate_logliks(P, m, pose, instant, cloud, rules, ll):
    """The candidates of :func:`choose_landmarks`: ``ll[i, k]`` (n, N) set to :math:`\\ell_{ik}`
    (:func:`association_loglik`) for every sighting ``i`` of ``instant = (z, R, t)`` and landmark ``k`` of
    particle ``m`` within the gate, :math:`d^2_{ik} \\le d_0^2`; the others are left as they are (-inf).
    (Without reference counts: it only reads the particle set and writes ``ll``.)"""
    z, R, t = instant
    for i in range(z.shape[0]):
        direction = (math.cos(z[i, 1] + pose[2]), math.sin(z[i, 1] + pose[2]))  # the sighting's, world frame
        for k in range(P.n[m]):
            unseen = t - P.last_t[m, k]
            if outside_gate(pose, z[i], direction, R[i], P.mu[m, k], P.sigma[m, k], cloud, unseen, rules):
                continue  # beyond the gate on its range or its bearing alone: no candidate, at a fraction of the cost
            lik, d2 = association_loglik(pose, z[i], R[i], P.mu[m, k], P.sigma[m, k], cloud, t - P.last_t[m, k],
                                         rules)
            if d2 <= rules.new_chi2:
                ll[i, k] = lik


def associate_particle(P, m, instant, rules, next_ident, out, cloud):
    """The sightings of one instant, ``instant = (z (n, 2), R (n, 2, 2), t)``, for particle ``m`` (FastSLAM 1.0):
    association at the particle's pose (:func:`choose_landmarks`, ``cloud`` (3, 3) the pose covariance it adds),
    then :func:`apply_associations`. ``out`` (n,) receives the identity of the landmark each sighting went to
    (-1: none); ``next_ident`` (1,) is the shared counter of new identities."""
    work = association_workspace(instant[0].shape[0], P.mu.shape[1])
    associate_particle_kernel(P, m, instant, rules, cloud, work, (next_ident, out))


@njit(cache=True, _nrt=False)
def associate_particle_kernel(P, m, instant, rules, cloud, work, record):
    """:func:`associate_particle` in the arrays of ``work`` (an
    :class:`~fastslam_edu.landmark.association_params.AssociationWorkspace`), ``record = (next_ident, out)``: the
    filter's step 2, per particle, making no array."""
    choose_landmarks_kernel(P, m, P.poses[m], instant, cloud, rules, work)
    apply_associations(P, m, instant, rules, work, record)


@njit(cache=True)
def associate_particle_improved(P, m, instant, rules, prediction, rng, work, record):
    """The same with FastSLAM 2.0's proposal: the association is decided at the motion prediction
    ``prediction = (x_bar (3,), cov (3, 3))`` with its covariance (:func:`choose_landmarks`); then each sighting
    assigned to a landmark seen at least ``rules.min_count`` times moves the particle's pose by the proposal
    (:func:`fastslam_edu.landmark.proposal.improved_pose_kernel`, in the sightings' order) and weighs it by
    :math:`\\mathcal N(z; \\hat z(\\bar x), S)`; :func:`apply_associations` then updates the map from the new pose.
    ``work``, ``record``: as :func:`associate_particle_kernel`'s."""
    z, R, _ = instant
    x_bar, cov = prediction[0].copy(), prediction[1].copy()
    choose_landmarks_kernel(P, m, x_bar, instant, cov, rules, work)
    slot, lls = work.slot, work.chosen
    e = np.empty(2)
    for i in range(z.shape[0]):
        k = slot[i]
        if k < 0 or P.seen[m, k] < rules.min_count:
            continue
        e[0], e[1] = rng.standard_normal(), rng.standard_normal()
        _, lls[i] = improved_pose_kernel(P.poses[m], x_bar, cov, P.mu[m, k], P.sigma[m, k], z[i], R[i], e)
    apply_associations(P, m, instant, rules, work, record)


@njit(cache=True, _nrt=False)
def apply_associations(P, m, instant, rules, work, record):
    """Update, weight and negative evidence for particle ``m`` once ``work.slot[:n]``, ``work.chosen[:n]`` (the slot
    and log-likelihood of each sighting) are decided (:func:`choose_landmarks_kernel`); ``record = (next_ident,
    out)``: ``out`` (n,) receives the identity of the landmark each sighting went to, ``next_ident`` (1,) is the
    shared counter of new identities.

    An assigned sighting updates its landmark's EKF (lines 12–17 of table 13.1, or a re-initialisation:
    :func:`measure_landmark`) and multiplies the weight by its likelihood (line 18, tempered by the exponent
    :math:`\\beta = \\min(1, \\Delta t/\\tau)`); a provisional landmark's, or a new one's (lines 7–9), by
    :math:`p_0` (line 10). Line numbers: *Probabilistic Robotics*, 2005 printing, table 13.1 (FastSLAM 1.0, known
    correspondences). A new landmark started beyond the confirmation range :math:`r^*` is not committed.
    """
    z, R, t = instant
    next_ident, out = record
    slot, lls, split, taken = work.slot, work.chosen, work.split, work.taken
    taken[:] = False
    splitting_sightings(P, m, instant, rules, work)
    for i in range(z.shape[0]):
        k = slot[i]
        if k < 0:
            continue
        beta = 1.0 if rules.tau <= 0.0 else min(1.0, (t - P.last_t[m, k]) / rules.tau)
        ll = lls[i]  # the likelihood the association was decided by: weight and decision agree
        measure_landmark(P, m, k, z[i], R[i], rules, split[i])
        if P.evidence[m, k] < rules.n_confirm and rules.provisional_as_new:
            ll = new_landmark_loglik(R[i], rules.new_chi2)  # a provisional landmark explains nothing yet
        P.logw[m] += beta * ll
        P.seen[m, k] += 1
        P.evidence[m, k] += beta
        P.log_odds[m, k] = existence_log_odds(P.log_odds[m, k], True, rules)
        P.last_t[m, k] = t
        out[i] = P.ident[m, k]
        taken[k] = True
    for i in range(z.shape[0]):
        if slot[i] >= 0 or not rules.min_range <= z[i, 0] <= rules.new_max_range:
            continue  # assigned, or outside the range where a sighting starts a landmark: not mapped
        P.logw[m] += new_landmark_loglik(R[i], rules.new_chi2)  # p0 wins: a landmark never seen before
        k = add_landmark(P, m, z[i], R[i], next_ident[0], t)
        out[i] = -1 if k < 0 else next_ident[0]
        if k >= 0:
            P.log_odds[m, k] = existence_log_odds(0.0, True, rules)
            P.committed[m, k] = z[i, 0] <= rules.confirm_range
            next_ident[0] += 1
            taken[k] = True
    negative_evidence(P, m, taken, rules)


@njit(cache=True, _nrt=False)
def measure_landmark(P, m, k, z, R, rules, fresh):
    """Landmark ``k`` of particle ``m`` measured by sighting ``z`` (2,): its EKF update (lines 12–17 of table 13.1),
    or, under deferred commitment, its re-initialisation from ``z`` alone (lines 7–9): when ``z`` is its first
    sighting within the confirmation range :math:`r^*` (``rules.confirm_range``; the landmark is then
    committed), or when it splits (``fresh``, :func:`splitting_sightings`). What far sightings made of it,
    possibly two landmarks seen as one, is then forgotten; its identity, counts and evidence stay."""
    near = z[0] <= rules.confirm_range
    if fresh or (near and not P.committed[m, k]):
        initialise_landmark_kernel(P.poses[m], z, R, P.mu[m, k], P.sigma[m, k])
        P.committed[m, k] = near
    else:
        update_landmark_kernel(P.poses[m], z, R, P.mu[m, k], P.sigma[m, k], math.inf)


@njit(cache=True, _nrt=False)
def splitting_sightings(P, m, instant, rules, work):
    """``work.split[:n]`` (bool): sighting ``i`` went to a provisional landmark of particle ``m`` that another sighting of the same
    instant, left without a landmark (``slot`` -1), also fits (:math:`d^2 \\le d_0^2` with the landmark's
    :math:`Q = H\\Sigma H^\\top + R`): two things seen at once where the particle holds one, so the landmark
    splits (``rules.split``; all False without it)."""
    z, R, _ = instant
    n = z.shape[0]
    slot, split = work.slot, work.split
    split[:n] = False
    if not rules.split:
        return
    for i in range(n):
        k = slot[i]
        if k < 0 or P.evidence[m, k] >= rules.n_confirm:
            continue
        for j in range(n):
            if j != i and slot[j] < 0 and innovation_statistics_kernel(P.poses[m], z[j], R[j], P.mu[m, k], P.sigma[m, k]).d2 \
                    <= rules.new_chi2:
                split[i] = True


__all__ = ["choose_landmarks", "choose_landmarks_kernel", "candidate_logliks", "associate_particle",
           "associate_particle_kernel", "associate_particle_improved", "apply_associations", "measure_landmark",
           "splitting_sightings"]
