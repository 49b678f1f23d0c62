"""FastSLAM 1.0 with unknown correspondences: each particle decides which landmark a sighting is.

Montemerlo et al. (2003) and *Probabilistic Robotics* §13.8. The filter never
sees a barcode. For every sighting :math:`z` and every particle :math:`m`:

1. **Maximum-likelihood association** (:func:`choose_landmarks`): the likelihood
   :math:`\\mathcal N(z - \\hat z_j; 0, Q_j)` of each landmark :math:`j` the particle
   holds, and the likelihood :math:`p_0` of a landmark never seen before. The
   most likely hypothesis wins: an existing landmark is updated by its EKF
   (:func:`fastslam_edu.core.ekf.update_landmark_kernel`) and the weight grows by the
   log-likelihood the decision was made with; if :math:`p_0` wins a new landmark is
   initialised (:func:`fastslam_edu.core.ekf.initialise_landmark_kernel`) and the weight grows by
   :math:`\\log p_0`. Sightings from ``min_range`` to ``new_max_range`` start landmarks; negative
   evidence checks them once they are within ``max_range``.
2. **Mutual exclusion**: within one camera frame two sightings are two different
   things. ``association`` chooses one of three rules. ``"joint"`` (joint compatibility, the default;
   :func:`~fastslam_edu.landmark.joint_compatibility.joint_slots`)
   decides the instant as a whole: every hypothesis (each sighting a landmark or new, no
   landmark twice) is scored by the joint Gaussian of its innovations, correlated by the
   pose error the sightings share. ``"greedy"`` takes the pairs (sighting, landmark) of the instant
   most likely first, each sighting and each landmark once; ``"independent"`` decides each sighting alone.
3. **Negative evidence** (:func:`~fastslam_edu.landmark.landmark_existence.negative_evidence`): a landmark the particle
   expects to see (inside the camera's field of view and range) at an instant
   when something is seen, but which no sighting of that instant was assigned
   to, counts a miss. Each landmark carries the log odds that it is real rather
   than clutter (:func:`~fastslam_edu.landmark.landmark_existence.existence_log_odds`), raised by a sighting by
   :math:`\\log(p_D/p_F)` and lowered by a miss by :math:`\\log((1-p_D)/(1-p_F))`:
   :math:`p_D` is the probability that the camera reports a landmark in view (on
   MR.CLAM only 0.1–0.6), :math:`p_F` the probability that clutter (another robot,
   a misread) is seen again at the same place. A landmark whose log odds fall
   below zero is removed. The log odds are clamped at ``log_odds_cap_sightings`` sightings' worth,
   so a copy that a newer landmark has replaced goes after a few dozen misses. A confirmed landmark that
   goes passes its identity to the nearest landmark made after it, within ``inherit_radius``
   (:func:`~fastslam_edu.landmark.landmark_existence.retire_landmarks`): usually the copy that replaced it, started when
   the pose had drifted, so that
   the particle's association history reads one landmark, not two.
4. **Confirmation**: sightings of one landmark a fraction of a second apart are not
   independent (``measurement_correlation_s``, :math:`\\tau`): a landmark counts the
   evidence :math:`\\sum\\beta`, :math:`\\beta = \\min(1, \\Delta t/\\tau)`, and is *provisional*
   (not in the map) until it reaches ``n_confirm``: another robot tracked for a few
   seconds is never confirmed.
5. **Deferred commitment** (``deferred``, ``split_tentative``; both off by default): a sighting from beyond the
   confirmation range :math:`r^*` (:func:`~fastslam_edu.landmark.association_params.confirmation_range`: where one
   sighting tells apart two landmarks ``separation_m`` apart at the gate :math:`d_0^2`) cannot tell two neighbours
   apart, so the landmark it starts is not committed: far sightings update it, and its first sighting within
   :math:`r^*` re-initialises it from that sighting alone (:func:`measure_landmark`). A provisional landmark that
   two sightings of one frame both fit is two things: it is re-initialised from its own sighting and the other
   starts a landmark (:func:`splitting_sightings`).

The new-landmark likelihood is the Gaussian of a fresh landmark,
:math:`Q = H\\Sigma H^\\top + R = 2R`, evaluated :math:`d_0` standard deviations away
(``new_landmark_chi2`` is :math:`d_0^2`)::

    log p0 = -d0²/2 - log 2π - ½ log det(2R)

and it wins when the most likely landmark is further than :math:`d_0` in
Mahalanobis distance. What real data adds
(:func:`~fastslam_edu.landmark.association_likelihood.association_loglik`): the
association's :math:`Q` includes the drift the particle's own pose has made,
relative to a landmark, since the landmark was last seen: the motion model's
noise densities (``drift_xy`` :math:`=\\sigma_v`, ``drift_theta`` :math:`=\\sigma_\\omega`,
per √s) over at most ``drift_cap_s`` seconds (beyond that the other landmarks
have kept the particle's pose in check). The same likelihood weighs the particle,
so that deciding and weighing agree.

Each particle therefore carries its own *association history*: resampling keeps
the particles whose associations explained the sightings well.

Particles hold a variable number of landmarks: arrays sized to ``max_landmarks``
with a count per particle (:class:`~fastslam_edu.landmark.association_params.MapParticles`). Every landmark has an
identity (``ident``) that copies share after resampling, so the association
history of the final best particle can be read back through its ancestors
(:func:`~fastslam_edu.landmark.association_history.best_history`) and scored
(:mod:`fastslam_edu.evaluation.association`).

The modules: settings and particle set (:mod:`fastslam_edu.landmark.association_params`), likelihoods
(:mod:`fastslam_edu.landmark.association_likelihood`), joint compatibility
(:mod:`fastslam_edu.landmark.joint_compatibility`), existence and retirement
(:mod:`fastslam_edu.landmark.landmark_existence`), history and merging
(:mod:`fastslam_edu.landmark.association_history`); this one decides, applies and runs the filter over a log.
The kernels are numba ``njit(cache=True)`` and run as plain Python with
``NUMBA_DISABLE_JIT=1``; the motion model, weights and resampling are the
kernels of :mod:`fastslam_edu.landmark.fastslam_step`.

With FastSLAM 2.0's proposal (``filter.proposal = "fastslam2"``,
:func:`associate_particle_improved`), the association is decided at the motion
prediction :math:`\\bar x` with its covariance added to :math:`Q`, and the sightings
of landmarks seen before then move the pose by the proposal
(:func:`fastslam_edu.landmark.proposal.improved_pose_kernel`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from fastslam_edu.core.ekf import initialise_landmark_kernel, innovation_statistics_kernel, update_landmark_kernel
from fastslam_edu.core.resampling import in_increasing_order
from fastslam_edu.core.timing import RunTimer
from fastslam_edu.datasets.log import EventStream
from fastslam_edu.landmark.association_history import best_history, merge_copies
from fastslam_edu.landmark.association_likelihood import association_loglik, new_landmark_loglik, outside_gate
from fastslam_edu.landmark.association_params import (INDEPENDENT, JOINT, AssociationParams, MapParticles,
                                                      association_workspace, initial_particles)
from fastslam_edu.landmark.fastslam_step import (motion_prediction_through_segment, move_through_segment,
                                                 normalise_weights, pose_covariance, record_poses, segment_normals)
from fastslam_edu.landmark.joint_compatibility import joint_slots
from fastslam_edu.landmark.landmark_existence import (add_landmark, existence_log_odds, negative_evidence,
                                                     retire_landmarks)
from fastslam_edu.landmark.particle_resampling import copy_order, draw_if_degenerate, is_increasing
from fastslam_edu.landmark.proposal import improved_pose_kernel
from fastslam_edu.landmark.segments import measurement_segments, stream_commands
from fastslam_edu.landmark.step_records import RESAMPLER_CODES, Log, Settings


# ---------------------------------------------------------------- the decision of one particle at one instant


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


@njit(cache=True)
def select_maps(P, idx):
    """Resampling: particles ``idx`` replace the set (maps copied), log weights 0, as
    :func:`fastslam_edu.landmark.particle_resampling.select_in_place` does for known correspondences: in place, in
    the order of :func:`~fastslam_edu.landmark.particle_resampling.copy_order`, the indices in increasing order."""
    if not is_increasing(idx):
        idx = in_increasing_order(idx)
    for m in copy_order(idx):
        copy_map_particle(P, idx[m], P, m)
    P.logw[:] = 0.0


@njit(cache=True, _nrt=False)
def copy_map_particle(src, i, dst, m):
    """Particle ``i`` of ``src``: its pose and its map (every slot, held or not) written over particle ``m`` of
    ``dst`` (both :class:`~fastslam_edu.landmark.association_params.MapParticles`), number by number."""
    for a in range(3):
        dst.poses[m, a] = src.poses[i, a]
    dst.n[m] = src.n[i]
    for k in range(src.mu.shape[1]):
        dst.mu[m, k, 0], dst.mu[m, k, 1] = src.mu[i, k, 0], src.mu[i, k, 1]
        dst.sigma[m, k, 0, 0], dst.sigma[m, k, 0, 1] = src.sigma[i, k, 0, 0], src.sigma[i, k, 0, 1]
        dst.sigma[m, k, 1, 0], dst.sigma[m, k, 1, 1] = src.sigma[i, k, 1, 0], src.sigma[i, k, 1, 1]
        dst.ident[m, k], dst.seen[m, k], dst.missed[m, k] = src.ident[i, k], src.seen[i, k], src.missed[i, k]
        dst.evidence[m, k], dst.log_odds[m, k] = src.evidence[i, k], src.log_odds[i, k]
        dst.last_t[m, k], dst.first_t[m, k] = src.last_t[i, k], src.first_t[i, k]
        dst.committed[m, k] = src.committed[i, k]


# ---------------------------------------------------------------- the run over a log


#: The counters of :attr:`AssociationRecord.totals`, by name: measurement instants done, resamplings, landmarks
#: created.
INSTANTS_DONE, MAPS_RESAMPLED, LANDMARKS_CREATED = 0, 1, 2
N_ASSOCIATION_TOTALS = 3


class AssociationRecord(NamedTuple):
    """What :func:`run_unknown_segments` writes: ``w`` (M,) weights; ``pose_mean``, ``pose_best`` (N, 3);
    ``assoc`` (M, n): the identity each particle gave each sighting; ``parents`` (I, M): after instant ``q``,
    particle ``m`` descends from ``parents[q, m]``; ``instant_of`` (n,): the instant of each sighting;
    ``next_ident`` (1,); ``totals`` (:data:`N_ASSOCIATION_TOTALS`,) int, read by name: ``totals[INSTANTS_DONE]``,
    ``totals[MAPS_RESAMPLED]``, ``totals[LANDMARKS_CREATED]``; ``renames`` (C, 4): the identities handed over, in
    its first ``n_renames[0]`` rows
    (:func:`~fastslam_edu.landmark.landmark_existence.retire_landmarks`)."""

    w: np.ndarray
    pose_mean: np.ndarray
    pose_best: np.ndarray
    assoc: np.ndarray
    parents: np.ndarray
    instant_of: np.ndarray
    next_ident: np.ndarray
    totals: np.ndarray
    renames: np.ndarray
    n_renames: np.ndarray


@njit(cache=True, _nrt=False)
def most_sightings(offsets):
    """The most sightings of one instant of a stream whose instant ``q`` holds sightings ``offsets[q]`` to
    ``offsets[q + 1]``."""
    most = 0
    for q in range(offsets.shape[0] - 1):
        most = max(most, offsets[q + 1] - offsets[q])
    return most


@njit(cache=True)
def run_unknown_segments(P, L, s, rules, segments, rng, out, x_start):
    """Steps 1–4 over ``segments`` (S, 2) with unknown correspondences.

    ``L``: the stream (:class:`fastslam_edu.landmark.fastslam_step.Log`; its ``j`` is never read), ``s``: the
    motion noise and resampling settings (:class:`fastslam_edu.landmark.fastslam_step.Settings`), ``rules``
    (:class:`Rules`), ``out``: :class:`AssociationRecord`; ``x_start``: None for FastSLAM 1.0, an (M, 3)
    buffer for FastSLAM 2.0 (as :func:`fastslam_edu.landmark.fastslam_step.run_segments`: the proposal's
    kernels compiled only for a FastSLAM 2.0 run).
    """
    M = P.poses.shape[0]
    w = out.w
    normals = segment_normals(segments, s.n_draws, M)
    work = association_workspace(most_sightings(L.offsets), P.mu.shape[1])
    for r in range(segments.shape[0]):
        first, last = segments[r, 0], segments[r, 1]
        a, b = L.offsets[last], L.offsets[last + 1]
        if out.n_renames[0] + M * P.mu.shape[1] > out.renames.shape[0]:
            return r  # the record of hand-overs could fill up at this instant: the caller makes it larger, and on
        if not move_through_segment(P.poses, L, s, segments[r], rng, out, normals, x_start):
            continue
        q = out.totals[INSTANTS_DONE]
        before = out.next_ident[0]
        instant = (L.z[a:b], L.R[a:b], L.t[last])
        if x_start is None:  # (decided when numba compiles)
            cloud = pose_covariance(P.poses, w) * rules.pose_scale
            for m in range(M):
                associate_particle_kernel(P, m, instant, rules, cloud, work, (out.next_ident, out.assoc[m, a:b]))
        else:
            x_bar, cov = motion_prediction_through_segment(x_start, L.u[first:last + 1], L.dt[first:last + 1], s)
            for m in range(M):
                associate_particle_improved(P, m, instant, rules, (x_bar[m], cov[m]), rng, work,
                                            (out.next_ident, out.assoc[m, a:b]))
        for m in range(M):
            retire_landmarks(P, m, rules, out.renames, out.n_renames, q)
        out.totals[LANDMARKS_CREATED] += out.next_ident[0] - before
        out.instant_of[a:b] = q
        idx = draw_if_degenerate(w, normalise_weights(P.logw, w), s, rng)  # step 3, as with barcodes
        if idx.shape[0] > 0:
            select_maps(P, idx)  # the maps of this filter's particles (variable size) copied
            out.totals[MAPS_RESAMPLED] += 1
        for m in range(M):
            out.parents[q, m] = idx[m] if idx.shape[0] > 0 else m
        out.totals[INSTANTS_DONE] += 1
        record_poses(P.poses, w, out.pose_mean[last], out.pose_best[last])  # step 4
    return segments.shape[0]


@dataclass
class AssociationResult:
    """What a run with unknown correspondences produces.

    t, pose_mean, pose_best (N,), (N, 3): as FastSLAM's result. ``landmarks`` (L, 2), ``landmarks_cov``
    (L, 2, 2), ``landmark_ident`` (L,), ``landmark_seen`` (L,): the map of the highest-weight particle
    at the end, its confirmed landmarks only (evidence :math:`\\sum\\beta` of ``n_confirm`` sightings or
    more), its copies merged (:func:`merge_copies`). ``history`` (n,): the identity that particle (through its
    ancestors) gave each sighting of the stream (-1: none), read through the hand-overs and the merges.
    ``n_provisional``: its landmarks still provisional at the end. ``particles``: the final set.
    ``filter_seconds``: the run's wall time without ``compile_seconds``, numba's compiling (or loading from
    its cache) of the kernels (:class:`fastslam_edu.core.timing.RunTimer`).
    """

    t: np.ndarray
    pose_mean: np.ndarray
    pose_best: np.ndarray
    landmarks: np.ndarray
    landmarks_cov: np.ndarray
    landmark_ident: np.ndarray
    landmark_seen: np.ndarray
    history: np.ndarray
    n_provisional: int
    landmarks_created: int
    n_resamples: int
    filter_seconds: float
    particles: MapParticles
    params: AssociationParams
    compile_seconds: float = 0.0


def run_unknown(stream: EventStream, params: AssociationParams = AssociationParams(), rng=0, *,
                x0=None) -> AssociationResult:
    """Run FastSLAM with unknown correspondences over ``stream`` (1.0, or 2.0's proposal: ``params.filter.proposal``).

    Only the stream's times, commands and sightings ``z`` are used: ``stream.landmark`` (the identities)
    is never read. ``x0``: the initial pose (default ``stream.x0``).
    """
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    x0 = stream.x0 if x0 is None else np.asarray(x0, dtype=float)
    if x0 is None:
        raise ValueError("no initial pose: the stream has no groundtruth; pass x0=(x, y, theta)")
    if len(stream) == 0:
        raise ValueError("the event stream is empty")
    fp = params.filter
    M = fp.n_particles
    P = initial_particles(M, params.max_landmarks, x0)
    u, dt = stream_commands(stream, fp)
    z = np.ascontiguousarray(np.asarray(stream.z, dtype=float).reshape(-1, 2))
    R = np.ascontiguousarray(fp.measurement_covariance(z))
    offsets = np.asarray(stream.offsets, dtype=np.int64)
    n, N = len(z), len(stream)
    n_instants = int(np.count_nonzero(np.diff(offsets)))
    rules = params.rules()
    log = Log(t=np.asarray(stream.t, dtype=float), u=u, dt=dt, offsets=offsets, z=z,
              j=np.zeros(n, dtype=np.int64), R=R)  # no identities
    settings = Settings(noise=fp.motion_noise.densities, n_draws=fp.motion_noise.n_draws, gate_chi2=math.inf,
                        escape_s=math.inf, tau=0.0, update_map=True, resample_threshold=float(fp.resample_threshold),
                        resampler=RESAMPLER_CODES[fp.resampler], proposal=1 if fp.proposal == "fastslam2" else 0)
    out = AssociationRecord(w=np.full(M, 1.0 / M), pose_mean=np.empty((N, 3)), pose_best=np.empty((N, 3)),
                            assoc=np.full((M, n), -1, dtype=np.int64),
                            parents=np.empty((n_instants, M), dtype=np.int64),
                            instant_of=np.zeros(n, dtype=np.int64), next_ident=np.zeros(1, dtype=np.int64),
                            totals=np.zeros(N_ASSOCIATION_TOTALS, dtype=np.int64),
                            renames=np.zeros((4 * M * params.max_landmarks, 4), dtype=np.int64),
                            n_renames=np.zeros(1, dtype=np.int64))
    segments = np.array(list(measurement_segments(stream)), dtype=np.int64).reshape(-1, 2)
    x_start = np.empty((M, 3)) if fp.proposal == "fastslam2" else None
    done = 0
    with RunTimer() as timer:  # filter_seconds without the compilation of the kernels (compile_seconds)
        while done < len(segments):
            done += run_unknown_segments(P, log, settings, rules, segments[done:], rng, out, x_start)
            if done < len(segments):  # the record of hand-overs is full: twice the room, and on
                grown = np.zeros((2 * len(out.renames), 4), dtype=np.int64)
                grown[:len(out.renames)] = out.renames
                out = out._replace(renames=grown)
    w, pose_mean, pose_best, totals = out.w, out.pose_mean, out.pose_best, out.totals
    assoc, parents, instant_of = out.assoc, out.parents, out.instant_of
    best = int(np.argmax(w))
    k = np.arange(P.n[best])
    keep = k[P.evidence[best, k] >= params.n_confirm]
    history = best_history(assoc, parents, instant_of, best, out.renames[:out.n_renames[0]])
    landmarks, cov, ident, history = merge_copies(P.mu[best, keep], P.sigma[best, keep], P.ident[best, keep],
                                                  history, instant_of, params.merge_radius)
    seen = np.array([np.sum(history == i) for i in ident.tolist()], dtype=np.int64)
    return AssociationResult(
        t=np.asarray(stream.t, dtype=float), pose_mean=pose_mean, pose_best=pose_best,
        landmarks=landmarks, landmarks_cov=cov, landmark_ident=ident, landmark_seen=seen,
        history=history, n_provisional=int(len(k) - len(keep)),
        landmarks_created=int(totals[LANDMARKS_CREATED]), n_resamples=int(totals[MAPS_RESAMPLED]),
        filter_seconds=timer.filter_seconds, particles=P, params=params, compile_seconds=timer.compile_seconds)


__all__ = ["INSTANTS_DONE", "MAPS_RESAMPLED", "LANDMARKS_CREATED", "N_ASSOCIATION_TOTALS", "choose_landmarks",
           "choose_landmarks_kernel", "candidate_logliks", "associate_particle", "associate_particle_kernel",
           "associate_particle_improved", "apply_associations", "measure_landmark", "splitting_sightings",
           "select_maps", "copy_map_particle", "most_sightings", "AssociationRecord", "run_unknown_segments",
           "AssociationResult", "run_unknown"]
# Chapter 19 (notebooks/19_hidden_barcodes.ipynb) imports AssociationParams, initial_particles and
# new_landmark_loglik from here: this module uses them, so they stay importable from it.
