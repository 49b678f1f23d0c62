"""FastSLAM 1.0 with unknown correspondences: each particle decides which landmark a sighting is.

Montemerlo et al. (2003) and *Probabilistic Robotics* §13.8. The filter never
sees a barcode. For every sighting :math:`z` and every particle :math:`m`:

1. **Maximum-likelihood association** (:func:`choose_landmarks`): the likelihood
   :math:`\\mathcal N(z - \\hat z_j; 0, Q_j)` of each landmark :math:`j` the particle
   holds, and the likelihood :math:`p_0` of a landmark never seen before. The
   most likely hypothesis wins: an existing landmark is updated by its EKF
   (:func:`fastslam_edu.core.ekf.ekf_update`) and the weight grows by the
   log-likelihood the decision was made with; if :math:`p_0` wins a new landmark is
   initialised (:func:`fastslam_edu.core.ekf.ekf_initialise`) and the weight grows by
   :math:`\\log p_0`. Sightings from ``min_range`` to ``new_max_range`` start landmarks; negative
   evidence checks them once they are within ``max_range``.
2. **Mutual exclusion**: within one camera frame two sightings are two different
   things. **Joint compatibility** (``joint_compatibility``, the default; :func:`joint_slots`)
   decides the instant as a whole: every hypothesis (each sighting a landmark or new, no
   landmark twice) is scored by the joint Gaussian of its innovations, correlated by the
   pose error the sightings share. Without it, the pairs (sighting, landmark) of the instant
   are taken most likely first, each sighting and each landmark once (``exclusive``, the
   greedy pairing), or each sighting alone.
3. **Negative evidence** (:func:`negative_evidence`): a landmark the particle
   expects to see (inside the camera's field of view and range) at an instant
   when something is seen, but which no sighting of that instant was assigned
   to, counts a miss. Each landmark carries the log odds that it is real rather
   than clutter (:func:`existence_log_odds`), raised by a sighting by
   :math:`\\log(p_D/p_F)` and lowered by a miss by :math:`\\log((1-p_D)/(1-p_F))`:
   :math:`p_D` is the probability that the camera reports a landmark in view (on
   MR.CLAM only 0.1–0.6), :math:`p_F` the probability that clutter (another robot,
   a misread) is seen again at the same place. A landmark whose log odds fall
   below zero is removed. The log odds are clamped at ``log_odds_cap_sightings`` sightings' worth,
   so a copy that a newer landmark has replaced goes after a few dozen misses. A confirmed landmark that
   goes passes its identity to the nearest landmark made after it, within ``inherit_radius``
   (:func:`retire_landmarks`): usually the copy that replaced it, started when the pose had drifted, so that
   the particle's association history reads one landmark, not two.
4. **Confirmation**: sightings of one landmark a fraction of a second apart are not
   independent (``measurement_correlation_s``, :math:`\\tau`): a landmark counts the
   evidence :math:`\\sum\\beta`, :math:`\\beta = \\min(1, \\Delta t/\\tau)`, and is *provisional*
   (not in the map) until it reaches ``n_confirm``: another robot tracked for a few
   seconds is never confirmed.

The new-landmark likelihood is the Gaussian of a fresh landmark,
:math:`Q = H\\Sigma H^\\top + R = 2R`, evaluated :math:`d_0` standard deviations away
(``new_landmark_chi2`` is :math:`d_0^2`)::

    log p0 = -d0²/2 - log 2π - ½ log det(2R)

and it wins when the most likely landmark is further than :math:`d_0` in
Mahalanobis distance. What real data adds (:func:`association_loglik`): the
association's :math:`Q` includes the drift the particle's own pose has made,
relative to a landmark, since the landmark was last seen: the motion model's
noise densities (``drift_xy`` :math:`=\\sigma_v`, ``drift_theta`` :math:`=\\sigma_\\omega`,
per √s) over at most ``drift_cap_s`` seconds (beyond that the other landmarks
have kept the particle's pose in check). The same likelihood weighs the particle,
so that deciding and weighing agree.

Each particle therefore carries its own *association history*: resampling keeps
the particles whose associations explained the sightings well.

Particles hold a variable number of landmarks: arrays sized to ``max_landmarks``
with a count per particle (:class:`MapParticles`). Every landmark has an
identity (``ident``) that copies share after resampling, so the association
history of the final best particle can be read back through its ancestors
(:func:`best_history`) and scored (:mod:`fastslam_edu.evaluation.association`).

The kernels are numba ``njit(cache=True)`` and run as plain Python with
``NUMBA_DISABLE_JIT=1``; the motion model, weights and resampling are the
kernels of :mod:`fastslam_edu.landmark.fastslam_step`.

With FastSLAM 2.0's proposal (``filter.proposal = "fastslam2"``,
:func:`associate_particle_improved`), the association is decided at the motion
prediction :math:`\\bar x` with its covariance added to :math:`Q`, and the sightings
of landmarks seen before then move the pose by the proposal
(:func:`fastslam_edu.landmark.proposal.improved_pose_into`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit

from fastslam_edu.core.angles import wrap_one
from fastslam_edu.core.ekf import LOG_2PI, ekf_initialise, ekf_innovation, ekf_update, expected_measurement
from fastslam_edu.core.params import Params
from fastslam_edu.core.timing import RunTimer
from fastslam_edu.datasets.log import EventStream
from fastslam_edu.landmark.fastslam import (RESAMPLER_CODES, FastSLAMParams, _segments, stream_commands)
from fastslam_edu.landmark.fastslam_step import (Log, Settings, copy_row, motion_prediction_of, normalise_weights,
                                                 pose_covariance, resampling_indices, sample_segment,
                                                 standard_normals, weighted_mean_pose)
from fastslam_edu.landmark.proposal import improved_pose_into


@dataclass(frozen=True, eq=False)
class AssociationParams(Params):
    """Settings of FastSLAM with unknown correspondences.

    Attributes
    ----------
    filter : FastSLAMParams
        Particles, motion and measurement noise, tempering (``measurement_correlation_s``),
        resampling: as with known correspondences (its gate is not used: a sighting
        no landmark explains becomes a new landmark).
    new_landmark_chi2 : float
        :math:`d_0^2` of the new-landmark likelihood :math:`p_0` (module docstring).
    exclusive : bool
        Mutual exclusion: one landmark per sighting within one instant.
    max_landmarks : int
        Landmarks a particle can hold (a sighting that would exceed it is not mapped).
    fov : float
        Half the camera's field of view [rad]: where negative evidence is counted.
    min_range, max_range : float
        Ranges [m] at which a landmark is expected to be seen, and at which a sighting may start one.
    n_confirm : int
        Independent sightings (:math:`\\sum\\beta`) after which a landmark is no longer provisional (and is
        in the map); also the cap of the existence log odds, in sightings.
    detection_probability : float
        :math:`p_D`: the probability that a landmark inside the field of view and range is seen at an
        instant when the camera sees something (MR.CLAM: 0.1–0.6, by range and bearing; the low end).
    clutter_probability : float
        :math:`p_F`: the probability that a "landmark" made from clutter (a passing robot, a misread) is
        seen again at such an instant. With :math:`p_D` they set the existence log odds (module docstring).
    pose_uncertainty : float
        Scale of the particle set's pose covariance added to the association's likelihoods
        (0: each particle trusts its own pose, as table 13.1; 1: the set's spread).
    provisional_as_new : bool
        A sighting assigned to a provisional landmark weighs the particle with :math:`p_0`, as a
        new landmark does (default True: another robot followed for a few seconds does not select the
        particles that follow it; False: every landmark the particle holds weighs it, as table 13.1).
    drift_xy, drift_theta : float
        Drift of the pose relative to a landmark per √s since it was last seen [m/√s, rad/√s], added
        to the association's innovation covariance (0, 0: table 13.1's :math:`Q`). Default: the motion
        model's :math:`\\sigma_v` and :math:`\\sigma_\\omega` (:class:`FastSLAMParams`).
    drift_cap_s : float
        The drift counts at most this long [s].
    association_range_scale : float
        Scale of the range standard deviation in the association's :math:`Q` (1: the filter's :math:`R`).
    proposal_min_count : int
        With FastSLAM 2.0's proposal (``filter.proposal = "fastslam2"``): a sighting moves the particle's pose only
        if its landmark was seen this many times (a landmark made from one sighting knows nothing of the pose).
    new_max_range : float
        Sightings up to this range [m] may start a landmark (at least ``min_range``). It may exceed ``max_range``:
        such a landmark is not checked by negative evidence until the robot comes within ``max_range`` of it.
    log_odds_cap_sightings : float
        The existence log odds are clamped at this many sightings' worth (:func:`existence_log_odds`).
    inherit_radius : float
        A confirmed landmark retired by negative evidence passes its identity to the nearest landmark made
        after it, within this distance [m] (:func:`retire_landmarks`; 0: no heir).
    merge_radius : float
        In the final map, a landmark within this distance [m] of an older one never sighted in the same instant
        is merged into it (:func:`merge_copies`; 0: none).
    joint_compatibility : bool
        The sightings of one instant are associated jointly, their innovations correlated by the pose error they
        share (:func:`joint_slots`; default), instead of one by one (False: ``exclusive``'s greedy pairing, or each
        alone). On MR.CLAM's seven robots with groundtruth it associates more sightings rightly than the greedy
        pairing (over seeds 0–39, by a difference whose 95 % bootstrap interval stays above zero), at 1.0–1.5 times
        its filter time (``benchmarks/association_mrclam.py`` and its ``--greedy``).
    """

    filter: FastSLAMParams = field(default_factory=FastSLAMParams)
    new_landmark_chi2: float = 16.0
    exclusive: bool = True
    max_landmarks: int = 128
    fov: float = 0.45
    min_range: float = 0.5
    max_range: float = 4.0
    n_confirm: int = 5
    detection_probability: float = 0.3
    clutter_probability: float = 0.05
    pose_uncertainty: float = 0.0
    provisional_as_new: bool = True
    drift_xy: float = 0.02
    drift_theta: float = 0.05
    association_range_scale: float = 1.0
    drift_cap_s: float = 5.0
    proposal_min_count: int = 2
    new_max_range: float = 10.0
    log_odds_cap_sightings: float = 5.0
    inherit_radius: float = 1.0
    merge_radius: float = 0.5
    joint_compatibility: bool = True

    def __post_init__(self):
        if not isinstance(self.filter, FastSLAMParams):
            raise ValueError(f"filter must be a FastSLAMParams, got {self.filter!r}")
        if self.filter.mode != "slam":
            raise ValueError("unknown correspondences: mode 'slam' only")
        if self.filter.resampler not in RESAMPLER_CODES:
            raise ValueError(f"resampler must be one of {sorted(RESAMPLER_CODES)}, got {self.filter.resampler!r}")
        if not (math.isfinite(self.new_landmark_chi2) and self.new_landmark_chi2 > 0):
            raise ValueError(f"new_landmark_chi2 must be > 0, got {self.new_landmark_chi2!r}")
        if int(self.max_landmarks) < 1 or int(self.n_confirm) < 1:
            raise ValueError("max_landmarks and n_confirm must be >= 1")
        if not (self.drift_cap_s >= 0 and self.drift_xy >= 0 and self.drift_theta >= 0):
            raise ValueError("drift_xy, drift_theta and drift_cap_s must be >= 0")
        if not 0.0 < self.clutter_probability < self.detection_probability < 1.0:
            raise ValueError(f"need 0 < clutter_probability < detection_probability < 1, got "
                             f"{self.clutter_probability!r}, {self.detection_probability!r}")
        if not (0 < self.fov <= math.pi and 0 <= self.min_range < self.max_range):
            raise ValueError(f"need 0 < fov <= pi and 0 <= min_range < max_range, got {self.fov}, "
                             f"{self.min_range}, {self.max_range}")


    def rules(self) -> "Rules":
        """The settings as the compiled kernels take them (:class:`Rules`)."""
        tau = self.filter.measurement_correlation_s
        return Rules(float(self.new_landmark_chi2), bool(self.exclusive), float(self.fov), float(self.min_range),
                     float(self.max_range), int(self.n_confirm),
                     math.log(self.detection_probability / self.clutter_probability),
                     math.log((1.0 - self.detection_probability) / (1.0 - self.clutter_probability)),
                     0.0 if tau is None else float(tau), float(self.pose_uncertainty), bool(self.provisional_as_new),
                     float(self.drift_xy), float(self.drift_theta), float(self.association_range_scale),
                     float(self.drift_cap_s), int(self.proposal_min_count), float(self.new_max_range),
                     float(self.log_odds_cap_sightings) * math.log(self.detection_probability
                                                                   / self.clutter_probability),
                     float(self.inherit_radius), bool(self.joint_compatibility))


class MapParticles(NamedTuple):
    """The particle set with variable-size maps (M particles, up to Kmax landmarks each), changed in place.

    poses (M, 3); mu (M, Kmax, 2); sigma (M, Kmax, 2, 2); n (M,) landmarks held;
    ident (M, Kmax) identity of each landmark; seen, missed (M, Kmax) counts; evidence (M, Kmax): the
    sightings counted as independent, :math:`\\sum\\beta` (:func:`associate_particle`);
    last_t, first_t (M, Kmax) times of the last and the first sighting [s]; logw (M,).
    """

    poses: np.ndarray
    mu: np.ndarray
    sigma: np.ndarray
    n: np.ndarray
    ident: np.ndarray
    seen: np.ndarray
    missed: np.ndarray
    evidence: np.ndarray
    log_odds: np.ndarray
    last_t: np.ndarray
    first_t: np.ndarray
    logw: np.ndarray


def initial_particles(n_particles: int, max_landmarks: int, x0) -> MapParticles:
    """All particles at ``x0`` (3,), with empty maps and equal weights."""
    M, K = int(n_particles), int(max_landmarks)
    x0 = np.asarray(x0, dtype=float)
    if x0.shape != (3,) or not np.isfinite(x0).all():
        raise ValueError(f"initial pose must be 3 finite numbers, got {x0!r}")
    return MapParticles(np.tile(x0, (M, 1)), np.zeros((M, K, 2)), np.tile(np.eye(2), (M, K, 1, 1)),
                        np.zeros(M, dtype=np.int64), np.full((M, K), -1, dtype=np.int64),
                        np.zeros((M, K), dtype=np.int64), np.zeros((M, K), dtype=np.int64),
                        np.zeros((M, K)), np.zeros((M, K)), np.zeros((M, K)), np.zeros((M, K)), np.zeros(M))


class Rules(NamedTuple):
    """The association settings as the kernels take them (:class:`AssociationParams`)."""

    new_chi2: float
    exclusive: bool
    fov: float
    min_range: float
    max_range: float
    n_confirm: int
    log_odds_seen: float
    log_odds_missed: float
    tau: float
    pose_scale: float
    provisional_as_new: bool
    drift_xy: float
    drift_theta: float
    range_scale: float
    drift_cap_s: float
    min_count: int
    new_max_range: float
    log_odds_cap: float
    inherit_radius: float
    joint: bool


# ---------------------------------------------------------------- one particle, one sighting


@njit(cache=True)
def new_landmark_loglik(R, d0_sq):
    """:math:`\\log p_0`: a fresh landmark's Gaussian (:math:`Q = 2R`) at squared Mahalanobis distance ``d0_sq``."""
    det_2r = 4.0 * (R[0, 0] * R[1, 1] - 0.25 * (R[0, 1] + R[1, 0]) ** 2)
    return -0.5 * d0_sq - LOG_2PI - 0.5 * math.log(det_2r)


@njit(cache=True)
def pose_jacobian(pose, mx, my):
    """:math:`H_x = \\partial h/\\partial x` (2, 3) of the range and bearing of a landmark at ``(mx, my)``, as
    ``(j0, j1, j2, k0, k1, k2)``: the range row, then the bearing row. A landmark moving by :math:`\\delta` and the
    robot moving by :math:`-\\delta` look the same, so the position columns are :math:`-H` of
    :func:`fastslam_edu.core.ekf.expected_measurement`; turning the robot by :math:`\\delta\\theta` turns the
    bearing by :math:`-\\delta\\theta`."""
    _, _, h00, h01, h10, h11 = expected_measurement(pose, (mx, my))
    return -h00, -h01, 0.0, -h10, -h11, -1.0


@njit(cache=True)
def pose_term(pose, mx, my, cloud):
    """:math:`H_x P H_x^\\top` (``a, b, d``: entries 00, 01, 11) for a landmark at ``(mx, my)``: the pose
    covariance ``cloud`` (3, 3) of the particle set carried into measurement space."""
    j0, j1, j2, k0, k1, k2 = pose_jacobian(pose, mx, my)
    a = b = d = 0.0
    for u, cu, ku in ((0, j0, k0), (1, j1, k1), (2, j2, k2)):
        for v, cv, kv in ((0, j0, k0), (1, j1, k1), (2, j2, k2)):
            a += cu * cloud[u, v] * cv
            b += cu * cloud[u, v] * kv
            d += ku * cloud[u, v] * kv
    return a, b, d


@njit(cache=True, inline="always")
def drift_variances(unseen_s, rules):
    """The variances the pose drifts by over ``unseen_s`` seconds, at most ``rules.drift_cap_s``:
    :math:`(\\sigma_{xy}^2, \\sigma_\\theta^2)\\,\\min(\\Delta t, T)` [m² per axis, rad²]."""
    unseen_s = min(unseen_s, rules.drift_cap_s)
    return rules.drift_xy ** 2 * unseen_s, rules.drift_theta ** 2 * unseen_s


@njit(cache=True)
def drift_covariance(cloud, unseen_s, rules):
    """:math:`P`: ``cloud`` (3, 3) plus the drift of the pose over ``unseen_s`` seconds,
    :math:`\\mathrm{diag}(\\sigma_{xy}^2, \\sigma_{xy}^2, \\sigma_\\theta^2)\\,\\min(\\Delta t, T)`
    (:func:`drift_variances`)."""
    P = cloud.copy()
    v_xy, v_theta = drift_variances(unseen_s, rules)
    P[0, 0] += v_xy
    P[1, 1] += v_xy
    P[2, 2] += v_theta
    return P


@njit(cache=True)
def innovation_with_pose(pose, z, R, mu, sigma, P, rules):
    """The innovation of one sighting and landmark with the pose covariance ``P`` (3, 3) added:
    ``(nu0, nu1, q00, q01, q11)``, :math:`\\nu` and :math:`Q + H_x P H_x^\\top` (its range variance scaled by
    ``rules.range_scale`` squared)."""
    nu0, nu1, h00, h01, h10, h11, q00, q01, q11, d2, ll = ekf_innovation(pose, z, R, mu, sigma)
    a, b, d = pose_term(pose, mu[0], mu[1], P)
    return nu0, nu1, q00 + a - (1.0 - rules.range_scale ** 2) * R[0, 0], q01 + b, q11 + d


@njit(cache=True)
def association_loglik(pose, z, R, mu, sigma, cloud, unseen_s, rules):
    """What the association decides by, for one landmark: ``(loglik, d2)`` of the sighting with
    :math:`Q + H_x P H_x^\\top`, the pose uncertainty added to the innovation covariance.

    :math:`P` is ``cloud`` (the particle set's covariance, scaled; zeros: table 13.1's) plus the drift
    the particle's pose may have made relative to the landmark since it was last seen, ``unseen_s``
    seconds ago (:func:`drift_covariance`: ``rules.drift_xy``, ``rules.drift_theta`` per √s, for at most
    ``rules.drift_cap_s``).
    """
    nu0, nu1, q00, q01, q11 = innovation_with_pose(pose, z, R, mu, sigma, drift_covariance(cloud, unseen_s, rules),
                                                   rules)
    det_q = q00 * q11 - q01 * q01
    d2 = (q11 * nu0 * nu0 - 2.0 * q01 * nu0 * nu1 + q00 * nu1 * nu1) / det_q
    return -0.5 * d2 - LOG_2PI - 0.5 * math.log(det_q), d2


@njit(cache=True)
def best_landmark(P, m, z, R, taken, cloud, t, rules):
    """The most likely landmark of particle ``m`` for sighting ``z`` at time ``t``: ``(k, loglik, d2)``
    (:func:`association_loglik`); ``(-1, -inf, inf)`` if it holds none. Landmarks with ``taken[k]`` set
    (mutual exclusion) are skipped.
    """
    best, best_ll, best_d2 = -1, -math.inf, math.inf
    for k in range(P.n[m]):
        if taken[k]:
            continue
        ll, d2 = association_loglik(P.poses[m], z, R, P.mu[m, k], P.sigma[m, k], cloud, t - P.last_t[m, k], rules)
        if ll > best_ll:
            best, best_ll, best_d2 = k, ll, d2
    return best, best_ll, best_d2


@njit(cache=True)
def choose_landmarks(P, m, pose, z, R, cloud, t, rules):
    """The association of one instant's sightings ``z`` (n, 2) for particle ``m`` at ``pose`` (3,) (its own pose,
    or FastSLAM 2.0's motion prediction :math:`\\bar x`, with ``cloud`` its covariance): ``(slot, loglik)`` (n,), (n,),
    the slot each goes to (-1: a new landmark) and its log-likelihood :math:`\\ell_{ik}` (-inf for a new one).

    Every pair ``(i, k)`` with :math:`d^2_{ik} \\le d_0^2` is a candidate, scored by its log-likelihood
    :math:`\\ell_{ik}` (:func:`association_loglik`); a sighting with no candidate is new (:math:`p_0` wins).
    With mutual exclusion (``rules.exclusive``) the pairs are taken greedily, the most likely first, each
    sighting and each landmark at most once: an approximation of the most likely joint association of
    the instant, so that a landmark is not taken by the sighting of its neighbour just because that
    sighting came first in the file. Without, each sighting takes its most likely landmark. With joint
    compatibility (``rules.joint``, two sightings or more) the instant is decided as a whole
    (:func:`joint_slots`), a sighting with candidates may then be new; each sighting keeps its own
    :math:`\\ell_{ik}` as its log-likelihood.
    """
    n, K = z.shape[0], P.n[m]
    ll = np.full((n, K), -math.inf)
    for i in range(n):
        for k in range(K):
            lik, d2 = association_loglik(pose, z[i], R[i], P.mu[m, k], P.sigma[m, k], cloud, t - P.last_t[m, k],
                                         rules)
            if d2 <= rules.new_chi2:
                ll[i, k] = lik
    slot = np.full(n, -1, dtype=np.int64)
    chosen = np.full(n, -math.inf)
    if rules.joint and n > 1 and K > 0 and joint_slots(P, m, pose, cloud, (z, R, t), rules, ll, slot):
        for i in range(n):
            if slot[i] >= 0:
                chosen[i] = ll[i, slot[i]]
        return slot, chosen
    if not rules.exclusive:
        for i in range(n):
            if K > 0 and ll[i].max() > -math.inf:
                slot[i] = np.argmax(ll[i])
                chosen[i] = ll[i, slot[i]]
        return slot, chosen
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
    return slot, chosen


#: More joint hypotheses than this in one instant (each sighting's candidates and "new", multiplied): the
#: instant is decided one sighting at a time instead (:func:`choose_landmarks`).
JOINT_MAX_HYPOTHESES = 4096


@njit(cache=True)
def joint_slots(P, m, pose, cloud, instant, rules, ll, slot):
    """The jointly most likely association of one instant's sightings (joint compatibility, Neira and Tardós
    2001), written into ``slot`` (n,); False (``slot`` untouched) if there are more than ``JOINT_MAX_HYPOTHESES``
    hypotheses. ``instant = (z (n, 2), R (n, 2, 2), t)``; ``ll`` (n, K) from :func:`choose_landmarks`.

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
    n, K = ll.shape
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
    info = pair_information(P, m, pose, instant, unseen, rules, ll)
    p0 = np.empty(n)
    for i in range(n):
        p0[i] = new_landmark_loglik(instant[1][i], rules.new_chi2)
    best_joint_hypothesis(info, ll, p0, drift_covariance(cloud, unseen, rules), slot)
    return True


@njit(cache=True)
def pair_information(P, m, pose, instant, unseen, rules, ll):
    """What each candidate pair ``(i, k)`` (``ll[i, k] > -inf``) adds to a joint hypothesis
    (:func:`joint_loglik`): (n, K, 14), :math:`\\nu^\\top D^{-1}\\nu`, :math:`H_x^\\top D^{-1}\\nu` (3),
    :math:`H_x^\\top D^{-1} H_x` (3×3, row-major) and :math:`\\log\\det D`.

    :math:`D` is the innovation covariance of :func:`innovation_with_pose` with the drift the landmark was
    unseen for beyond the instant's common ``unseen`` seconds (:func:`joint_slots`): with the common part
    :math:`H_x P_c H_x^\\top` added back it is the covariance the landmark is decided by alone
    (:func:`association_loglik`)."""
    z, R, t = instant
    n, K = ll.shape
    info = np.zeros((n, K, 14))
    common_xy, common_theta = drift_variances(unseen, rules)
    excess = np.zeros((3, 3))  # the landmark's own drift beyond the common part
    for i in range(n):
        for k in range(K):
            if ll[i, k] == -math.inf:
                continue
            own_xy, own_theta = drift_variances(t - P.last_t[m, k], rules)
            excess[0, 0] = excess[1, 1] = own_xy - common_xy
            excess[2, 2] = own_theta - common_theta
            nu0, nu1, d00, d01, d11 = innovation_with_pose(pose, z[i], R[i], P.mu[m, k], P.sigma[m, k], excess, rules)
            det = d00 * d11 - d01 * d01
            i00, i01, i11 = d11 / det, -d01 / det, d00 / det  # D⁻¹
            j0, j1, j2, k0, k1, k2 = pose_jacobian(pose, P.mu[m, k, 0], P.mu[m, k, 1])
            hr, hb = (j0, j1, j2), (k0, k1, k2)  # the rows of H_x: range, bearing
            v0, v1 = i00 * nu0 + i01 * nu1, i01 * nu0 + i11 * nu1  # D⁻¹ν
            info[i, k, 0] = nu0 * v0 + nu1 * v1
            for u in range(3):
                info[i, k, 1 + u] = hr[u] * v0 + hb[u] * v1
                for v in range(3):
                    info[i, k, 4 + 3 * u + v] = (hr[u] * (i00 * hr[v] + i01 * hb[v])
                                                 + hb[u] * (i01 * hr[v] + i11 * hb[v]))
            info[i, k, 13] = math.log(det)
    return info


@njit(cache=True)
def best_joint_hypothesis(info, ll, p0, Pc, slot):
    """Every joint hypothesis, scored (:func:`joint_slots`); the best is written into ``slot`` (n,) (-1: new).

    The hypotheses are counted like an odometer: sighting 0's choice turns fastest, through its candidates
    (``ll[i, k] > -inf``) and "new" (-1); a hypothesis that gives one landmark two sightings is skipped.
    ``info`` from :func:`pair_information`, ``p0`` (n,) :math:`\\log p_0`, ``Pc`` (3, 3) the common pose
    covariance."""
    n, K = ll.shape
    choice = np.full(n, -1, dtype=np.int64)
    used = np.zeros(K, dtype=np.bool_)
    total = np.zeros(14)
    best = -math.inf
    while True:
        # (np.int64(0), not 0: a literal 0 would make numba compile joint_loglik a second time, for the constant)
        ok, score, n_assigned = True, 0.0, np.int64(0)
        used[:] = False
        total[:] = 0.0
        for i in range(n):
            k = choice[i]
            if k < 0:
                score += p0[i]
            elif used[k]:
                ok = False
                break
            else:
                used[k] = True
                for c in range(total.shape[0]):  # (number by number: see copy_row)
                    total[c] += info[i, k, c]
                n_assigned += 1
        if ok:
            score += joint_loglik(total, n_assigned, Pc)
            if score > best:
                best = score
                for c in range(n):
                    slot[c] = choice[c]
        i = 0  # the next hypothesis: turn the odometer
        while i < n:
            k = choice[i] + 1
            while k < K and ll[i, k] == -math.inf:
                k += 1
            if k < K:
                choice[i] = k
                break
            choice[i] = -1
            i += 1
        if i == n:
            return


@njit(cache=True)
def joint_loglik(total, n_assigned, Pc):
    """:math:`\\log\\mathcal N(\\nu; 0, S)` of ``n_assigned`` stacked sightings, :math:`S = D + H_x P_c H_x^\\top`
    (:math:`D` block-diagonal), from the sums over the sightings of :func:`pair_information`'s rows, ``total``
    (14,): :math:`a = \\sum \\nu_i^\\top D_i^{-1}\\nu_i`, :math:`b = \\sum H_i^\\top D_i^{-1}\\nu_i` (3),
    :math:`G = \\sum H_i^\\top D_i^{-1} H_i` (3×3) and :math:`\\sum\\log\\det D_i`. With :math:`A = I + P_c G`
    (the Woodbury identity and the matrix determinant lemma, so that only 3×3 matrices are solved):
    :math:`\\nu^\\top S^{-1}\\nu = a - b^\\top A^{-1} P_c b` and :math:`\\log\\det S = \\sum\\log\\det D_i + \\log\\det A`."""
    if n_assigned == 0:
        return 0.0
    # A = I + P_c G and c = P_c b, as scalars: this runs for every hypothesis, and makes no array
    a00, a01, a02 = 1.0 + _pc_g(Pc, total, 0, 0), _pc_g(Pc, total, 0, 1), _pc_g(Pc, total, 0, 2)
    a10, a11, a12 = _pc_g(Pc, total, 1, 0), 1.0 + _pc_g(Pc, total, 1, 1), _pc_g(Pc, total, 1, 2)
    a20, a21, a22 = _pc_g(Pc, total, 2, 0), _pc_g(Pc, total, 2, 1), 1.0 + _pc_g(Pc, total, 2, 2)
    c0, c1, c2 = _pc_b(Pc, total, 0), _pc_b(Pc, total, 1), _pc_b(Pc, total, 2)
    det_a = det3_of(a00, a01, a02, a10, a11, a12, a20, a21, a22)
    # A⁻¹ P_c b by Cramer's rule: unknown j is the determinant of A with column j replaced by c, over det A
    x0 = det3_of(c0, a01, a02, c1, a11, a12, c2, a21, a22) / det_a
    x1 = det3_of(a00, c0, a02, a10, c1, a12, a20, c2, a22) / det_a
    x2 = det3_of(a00, a01, c0, a10, a11, c1, a20, a21, c2) / det_a
    quad = total[0] - (total[1] * x0 + total[2] * x1 + total[3] * x2)
    return -0.5 * quad - n_assigned * LOG_2PI - 0.5 * (total[13] + math.log(det_a))


@njit(cache=True, inline="always")
def _pc_g(Pc, total, u, v):
    """Entry ``(u, v)`` of :math:`P_c G`, with :math:`G` row-major in ``total[4:13]``."""
    return Pc[u, 0] * total[4 + v] + Pc[u, 1] * total[7 + v] + Pc[u, 2] * total[10 + v]


@njit(cache=True, inline="always")
def _pc_b(Pc, total, u):
    """Entry ``u`` of :math:`P_c b`, with :math:`b` in ``total[1:4]``."""
    return Pc[u, 0] * total[1] + Pc[u, 1] * total[2] + Pc[u, 2] * total[3]


@njit(cache=True, inline="always")
def det3_of(a00, a01, a02, a10, a11, a12, a20, a21, a22):
    """The determinant of a 3×3 matrix given by its entries, row by row (cofactors along the first row)."""
    return a00 * (a11 * a22 - a12 * a21) - a01 * (a10 * a22 - a12 * a20) + a02 * (a10 * a21 - a11 * a20)


@njit(cache=True)
def add_landmark(P, m, z, R, ident, t):
    """A new landmark in particle ``m`` from sighting ``z`` (lines 6–8 of table 13.1); its slot, or -1 if full."""
    k = P.n[m]
    if k >= P.mu.shape[1]:
        return -1
    ekf_initialise(P.poses[m], z, R, P.mu[m, k], P.sigma[m, k])
    P.ident[m, k] = ident
    P.seen[m, k] = 1
    P.missed[m, k] = 0
    P.evidence[m, k] = 1.0
    P.last_t[m, k] = t
    P.first_t[m, k] = t
    P.n[m] = k + 1
    return k


@njit(cache=True)
def remove_landmark(P, m, k):
    """Remove landmark ``k`` of particle ``m``: the last landmark takes its slot."""
    last = P.n[m] - 1
    if k != last:
        for a in range(2):  # (number by number: an array assignment compiles numba's shape check, see copy_row)
            P.mu[m, k, a] = P.mu[m, last, a]
            for b in range(2):
                P.sigma[m, k, a, b] = P.sigma[m, last, a, b]
        P.ident[m, k] = P.ident[m, last]
        P.seen[m, k] = P.seen[m, last]
        P.missed[m, k] = P.missed[m, last]
        P.evidence[m, k] = P.evidence[m, last]
        P.log_odds[m, k] = P.log_odds[m, last]
        P.last_t[m, k] = P.last_t[m, last]
        P.first_t[m, k] = P.first_t[m, last]
    P.ident[m, last] = -1
    P.n[m] = last


@njit(cache=True)
def in_view(pose, mu, rules):
    """Whether a landmark at ``mu`` is inside the camera's field of view and range from ``pose``."""
    r, phi, _, _, _, _ = expected_measurement(pose, mu)
    return rules.min_range <= r <= rules.max_range and abs(phi) <= rules.fov


@njit(cache=True)
def existence_log_odds(log_odds, seen, rules):
    """The existence log odds of a landmark after one instant in view: seen (``True``) or missed.

    :math:`L \\mathrel{+}= \\log\\frac{p_D}{p_F}` for a sighting, :math:`\\log\\frac{1-p_D}{1-p_F}` (< 0) for a miss,
    from :math:`L = 0` (even odds) before the first sighting; clamped above at ``log_odds_cap_sightings``' worth,
    so that a landmark seen for a long time is still removed after a few dozen misses once it has gone (a
    copy that a newer landmark has replaced): :math:`p_D` = 0.3, :math:`p_F` = 0.05 give +1.79 and -0.31.
    """
    if seen:
        return min(log_odds + rules.log_odds_seen, rules.log_odds_cap)
    return log_odds + rules.log_odds_missed


@njit(cache=True)
def negative_evidence(P, m, taken, rules):
    """Count a miss for every landmark of particle ``m`` in view but not taken at this instant; remove the
    provisional ones whose existence log odds (:func:`existence_log_odds`) fall below zero: more likely clutter than
    real. A confirmed landmark whose log odds fall below zero is retired by :func:`retire_landmarks`."""
    k = np.int64(0)  # (not 0: see retire_landmarks)
    while k < P.n[m]:
        if not taken[k] and in_view(P.poses[m], P.mu[m, k], rules):
            P.missed[m, k] += 1
            P.log_odds[m, k] = existence_log_odds(P.log_odds[m, k], False, rules)
            if P.log_odds[m, k] < 0.0 and P.evidence[m, k] < rules.n_confirm:
                taken[k] = taken[P.n[m] - 1]  # the last landmark moves into slot k
                remove_landmark(P, m, k)
                continue
        k += 1


@njit(cache=True)
def heir_of(P, m, a, rules):
    """The landmark of particle ``m`` that continues the identity of landmark ``a``: the nearest one made after
    ``a``, within ``rules.inherit_radius`` metres; -1 if there is none."""
    best, best_d = -1, rules.inherit_radius
    for b in range(P.n[m]):
        if b == a or P.first_t[m, b] <= P.first_t[m, a]:
            continue  # older than a: another landmark
        d = math.hypot(P.mu[m, a, 0] - P.mu[m, b, 0], P.mu[m, a, 1] - P.mu[m, b, 1])
        if d <= best_d:
            best, best_d = b, d
    return best


@njit(cache=True)
def retire_landmarks(P, m, rules, renames, q):
    """Remove the confirmed landmarks of particle ``m`` whose existence log odds fell below zero; each passes
    its identity to its heir (:func:`heir_of`), if it has one.

    A landmark stops being seen where the particle expects it when its pose drifted while the landmark was out of
    view: the sightings, further than :math:`d_0` from it, start a copy nearby, which takes them, and the
    original collects misses. The copy is the same landmark seen again: it continues the original's identity
    (and counts its sightings), so that the particle's association history reads one landmark, not two. It keeps
    its own evidence: a copy still provisional stays out of the map until its own sightings confirm it. Each
    hand-over is written to ``renames`` (C, 4) as ``(q, m, the heir's old identity, the identity it takes)``;
    ``renames[0, 0]`` counts the rows, from row 1 (:func:`best_history` reads them).
    """
    k = np.int64(0)  # (not 0: a literal would make numba compile heir_of and remove_landmark twice)
    while k < P.n[m]:
        if P.log_odds[m, k] >= 0.0:
            k += 1
            continue
        b = heir_of(P, m, k, rules)
        if b >= 0:
            row = renames[0, 0] + 1
            renames[row, 0], renames[row, 1], renames[row, 2], renames[row, 3] = q, m, P.ident[m, b], P.ident[m, k]
            renames[0, 0] = row
            P.ident[m, b] = P.ident[m, k]
            P.seen[m, b] += P.seen[m, k]
        remove_landmark(P, m, k)


@njit(cache=True)
def associate_particle(P, m, instant, rules, next_ident, out, cloud):
    """The sightings of one instant, ``instant = (z (n, 2), R (n, 2, 2), t)``, for particle ``m`` (FastSLAM 1.0):
    association at the particle's pose (:func:`choose_landmarks`, ``cloud`` (3, 3) the pose covariance it adds),
    then :func:`apply_associations`. ``out`` (n,) receives the identity of the landmark each sighting went to
    (-1: none); ``next_ident`` (1,) is the shared counter of new identities."""
    z, R, t = instant
    slot, lls = choose_landmarks(P, m, P.poses[m], z, R, cloud, t, rules)
    apply_associations(P, m, instant, (slot, lls), rules, next_ident, out)


@njit(cache=True)
def associate_particle_improved(P, m, instant, rules, next_ident, out, prediction, rng):
    """The same with FastSLAM 2.0's proposal: the association is decided at the motion prediction
    ``prediction = (x_bar (3,), cov (3, 3))`` with its covariance (:func:`choose_landmarks`); then each sighting
    assigned to a landmark seen at least ``rules.min_count`` times moves the particle's pose by the proposal
    (:func:`fastslam_edu.landmark.proposal.improved_pose_into`, in the sightings' order) and weighs it by
    :math:`\\mathcal N(z; \\hat z(\\bar x), S)`; :func:`apply_associations` then updates the map from the new pose."""
    z, R, t = instant
    x_bar, cov = prediction[0].copy(), prediction[1].copy()
    slot, lls = choose_landmarks(P, m, x_bar, z, R, cov, t, rules)
    e = np.empty(2)
    for i in range(z.shape[0]):
        k = slot[i]
        if k < 0 or P.seen[m, k] < rules.min_count:
            continue
        e[0], e[1] = rng.standard_normal(), rng.standard_normal()
        _, lls[i] = improved_pose_into(P.poses[m], x_bar, cov, P.mu[m, k], P.sigma[m, k], z[i], R[i], e)
    apply_associations(P, m, instant, (slot, lls), rules, next_ident, out)


@njit(cache=True)
def apply_associations(P, m, instant, chosen, rules, next_ident, out):
    """Update, weight and negative evidence for particle ``m`` once ``chosen = (slot (n,), loglik (n,))`` is decided
    (:func:`choose_landmarks`); ``out`` (n,) receives the identity of the landmark each sighting went to.

    An assigned sighting updates its landmark's EKF and multiplies the weight by its likelihood (tempered
    by :math:`\\beta = \\min(1, \\Delta t/\\tau)`); a provisional landmark's, or a new one's, by :math:`p_0`.
    """
    z, R, t = instant
    slot, lls = chosen
    taken = np.zeros(P.mu.shape[1], dtype=np.bool_)
    for i in range(z.shape[0]):
        k = slot[i]
        if k < 0:
            continue
        beta = 1.0 if rules.tau <= 0.0 else min(1.0, (t - P.last_t[m, k]) / rules.tau)
        ll = lls[i]  # the likelihood the association was decided by: weight and decision agree
        ekf_update(P.poses[m], z[i], R[i], P.mu[m, k], P.sigma[m, k], math.inf)
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
            next_ident[0] += 1
            taken[k] = True
    negative_evidence(P, m, taken, rules)


@njit(cache=True)
def select_maps(P, idx):
    """Resampling: particles ``idx`` replace the set (maps copied), log weights 0."""
    take_particles(P.poses, idx)
    take_particles(P.mu, idx)
    take_particles(P.sigma, idx)
    take_particles(P.n, idx)
    take_particles(P.ident, idx)
    take_particles(P.seen, idx)
    take_particles(P.missed, idx)
    take_particles(P.evidence, idx)
    take_particles(P.log_odds, idx)
    take_particles(P.last_t, idx)
    take_particles(P.first_t, idx)
    P.logw[:] = 0.0


@njit(cache=True)
def take_particles(a, idx):
    """``a[:] = a[idx]`` for ``a`` (M, ...) in C order: row ``m`` becomes row ``idx[m]`` of a copy of ``a``, number
    by number (an array assignment compiles numba's shape check and its error message: seconds of compilation)."""
    m_count = a.shape[0]
    before, after = a.copy().reshape(m_count, -1), a.reshape(m_count, -1)
    for m in range(m_count):
        for i in range(after.shape[1]):
            after[m, i] = before[idx[m], i]


# ---------------------------------------------------------------- the run over a log


class AssociationRecord(NamedTuple):
    """What :func:`run_unknown_segments` writes: ``w`` (M,) weights; ``pose_mean``, ``pose_best`` (N, 3);
    ``assoc`` (M, n): the identity each particle gave each sighting; ``parents`` (I, M): after instant ``q``,
    particle ``m`` descends from ``parents[q, m]``; ``instant_of`` (n,): the instant of each sighting;
    ``next_ident`` (1,); ``totals`` (3,): measurement instants, resamples, landmarks created; ``renames`` (C, 4):
    the identities handed over (:func:`retire_landmarks`; ``renames[0, 0]`` rows from row 1)."""

    w: np.ndarray
    pose_mean: np.ndarray
    pose_best: np.ndarray
    assoc: np.ndarray
    parents: np.ndarray
    instant_of: np.ndarray
    next_ident: np.ndarray
    totals: np.ndarray
    renames: np.ndarray


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
    for r in range(segments.shape[0]):
        first, last = segments[r, 0], segments[r, 1]
        a, b = L.offsets[last], L.offsets[last + 1]
        if out.renames[0, 0] + M * P.mu.shape[1] >= out.renames.shape[0]:
            return r  # the record of hand-overs could fill up at this instant: the caller makes it larger, and on
        measured = b > a
        n_record = last - first + (0 if measured else 1)
        if x_start is not None:
            for m in range(M):
                copy_row(P.poses, m, x_start[m])
        eps = np.empty((last - first + 1, s.n_draws, M))
        standard_normals(rng, eps)
        sample_segment(P.poses, L.u[first:last + 1], L.dt[first:last + 1], s.noise, eps, w,
                       out.pose_mean[first:first + n_record], out.pose_best[first:first + n_record])
        if not measured:
            continue
        q = out.totals[0]
        before = out.next_ident[0]
        instant = (L.z[a:b], L.R[a:b], L.t[last])
        if x_start is None:  # (decided when numba compiles)
            cloud = pose_covariance(P.poses, w) * rules.pose_scale
            for m in range(M):
                associate_particle(P, m, instant, rules, out.next_ident, out.assoc[m, a:b], cloud)
        else:
            x_bar, cov = motion_prediction_of(x_start, L.u[first:last + 1], L.dt[first:last + 1], s)
            for m in range(M):
                associate_particle_improved(P, m, instant, rules, out.next_ident, out.assoc[m, a:b],
                                            (x_bar[m], cov[m]), rng)
        for m in range(M):
            retire_landmarks(P, m, rules, out.renames, out.totals[0])
        out.totals[2] += out.next_ident[0] - before
        out.instant_of[a:b] = q
        n_eff = normalise_weights(P.logw, w)
        for m in range(M):
            out.parents[q, m] = m
        if s.resample_threshold >= 1.0 or n_eff < s.resample_threshold * M:
            idx = resampling_indices(w, rng, s.resampler)
            select_maps(P, idx)
            for m in range(M):
                out.parents[q, m] = idx[m]
            w[:] = 1.0 / M
            out.totals[1] += 1
        out.totals[0] += 1
        weighted_mean_pose(P.poses, w, out.pose_mean[last])
        copy_row(P.poses, np.argmax(w), out.pose_best[last])
    return segments.shape[0]


def best_history(assoc: np.ndarray, parents: np.ndarray, instant_of: np.ndarray, m: int,
                 renames: np.ndarray | None = None) -> np.ndarray:
    """The association history of final particle ``m``: the identity its ancestors gave each sighting (n,).

    ``renames`` (C, 4) (:func:`retire_landmarks`): an identity that one of its ancestors handed over is read as the
    identity it took, for the sightings before and after."""
    out = np.full(assoc.shape[1], -1, dtype=np.int64)
    order = np.argsort(instant_of, kind="stable")
    bounds = np.searchsorted(instant_of[order], np.arange(parents.shape[0] + 1))
    ancestor = np.empty(parents.shape[0], dtype=np.int64)
    for q in range(parents.shape[0] - 1, -1, -1):
        m = int(parents[q, m])
        ancestor[q] = m
        rows = order[bounds[q]:bounds[q + 1]]
        out[rows] = assoc[m, rows]
    if renames is None or renames[0, 0] == 0:
        return out
    rows = renames[1:renames[0, 0] + 1]
    ours = rows[ancestor[rows[:, 0]] == rows[:, 1]]
    taken = dict(zip(ours[:, 2].tolist(), ours[:, 3].tolist()))
    for old in list(taken):  # a chain a -> b -> c ends at c (an identity is only ever handed to a newer landmark)
        new = taken[old]
        while new in taken:
            new = taken[new]
        taken[old] = new
    return np.array([taken.get(i, i) for i in out.tolist()], dtype=np.int64)


def seen_together(history: np.ndarray, instant_of: np.ndarray) -> set[tuple[int, int]]:
    """The pairs of identities ``(a, b)``, ``a < b``, that ``history`` (n,) gives sightings of one instant
    (``instant_of`` (n,)): two things the camera saw at once, so two landmarks."""
    pairs: set[tuple[int, int]] = set()
    given = history >= 0
    order = np.argsort(instant_of[given], kind="stable")
    h, q = history[given][order], instant_of[given][order]
    for chunk in np.split(h, np.flatnonzero(np.diff(q)) + 1):
        ids = sorted(set(chunk.tolist()))
        pairs.update((a, b) for i, a in enumerate(ids) for b in ids[i + 1:])
    return pairs


def merge_copies(landmarks, cov, ident, history, instant_of, radius: float):
    """The final map with its copies merged: ``(landmarks (L', 2), cov (L', 2, 2), ident (L',), history (n,))``.

    A map landmark within ``radius`` metres of an older one (a smaller identity) that ``history`` never gives a
    sighting of the same instant (:func:`seen_together`) is a copy of it, kept apart because the pose had
    drifted between the two: the two Gaussians become one (information form,
    :math:`\\Sigma = (\\Sigma_a^{-1} + \\Sigma_b^{-1})^{-1}`), under the older identity, which its sightings take in
    the history. The nearest older landmark is taken first; ``radius`` 0 merges nothing.
    """
    landmarks, cov = np.array(landmarks, dtype=float), np.array(cov, dtype=float)
    ident, history = np.array(ident, dtype=np.int64), np.array(history, dtype=np.int64)
    if radius <= 0 or len(ident) < 2:
        return landmarks, cov, ident, history
    together = seen_together(history, np.asarray(instant_of))
    alive = np.ones(len(ident), dtype=bool)
    for b in np.argsort(ident):
        d = np.linalg.norm(landmarks - landmarks[b], axis=1)
        older = alive & (ident < ident[b]) & (d <= radius)
        older &= np.array([(int(ident[a]), int(ident[b])) not in together for a in range(len(ident))])
        if not older.any():
            continue
        a = int(np.flatnonzero(older)[np.argmin(d[older])])
        info_a, info_b = np.linalg.inv(cov[a]), np.linalg.inv(cov[b])
        cov[a] = np.linalg.inv(info_a + info_b)
        landmarks[a] = cov[a] @ (info_a @ landmarks[a] + info_b @ landmarks[b])
        ia, ib = int(ident[a]), int(ident[b])
        partners = {j if i == ib else i for i, j in together if ib in (i, j)}
        together |= {(min(ia, o), max(ia, o)) for o in partners if o != ia}  # what b was seen with, a now is
        history[history == ident[b]] = ident[a]
        alive[b] = False
    return landmarks[alive], cov[alive], ident[alive], history


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
    log = Log(np.asarray(stream.t, dtype=float), u, dt, offsets, z, np.zeros(n, dtype=np.int64), R)  # no identities
    settings = Settings(fp.motion_noise.densities, fp.motion_noise.n_draws, math.inf, math.inf, 0.0, True,
                        float(fp.resample_threshold), RESAMPLER_CODES[fp.resampler],
                        1 if fp.proposal == "fastslam2" else 0)
    out = AssociationRecord(np.full(M, 1.0 / M), np.empty((N, 3)), np.empty((N, 3)), np.full((M, n), -1, dtype=np.int64),
                            np.empty((n_instants, M), dtype=np.int64), np.zeros(n, dtype=np.int64),
                            np.zeros(1, dtype=np.int64), np.zeros(3, dtype=np.int64),
                            np.zeros((4 * M * params.max_landmarks + 1, 4), dtype=np.int64))
    segments = np.array(list(_segments(stream)), dtype=np.int64).reshape(-1, 2)
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
    history = best_history(assoc, parents, instant_of, best, out.renames)
    landmarks, cov, ident, history = merge_copies(P.mu[best, keep], P.sigma[best, keep], P.ident[best, keep],
                                                  history, instant_of, params.merge_radius)
    seen = np.array([np.sum(history == i) for i in ident.tolist()], dtype=np.int64)
    return AssociationResult(
        t=np.asarray(stream.t, dtype=float), pose_mean=pose_mean, pose_best=pose_best,
        landmarks=landmarks, landmarks_cov=cov, landmark_ident=ident, landmark_seen=seen,
        history=history, n_provisional=int(len(k) - len(keep)),
        landmarks_created=int(totals[2]), n_resamples=int(totals[1]), filter_seconds=timer.filter_seconds, particles=P,
        params=params, compile_seconds=timer.compile_seconds)


__all__ = ["AssociationParams", "AssociationResult", "MapParticles", "Rules", "initial_particles",
           "new_landmark_loglik", "best_landmark", "choose_landmarks", "add_landmark", "remove_landmark",
           "pose_jacobian", "drift_variances", "drift_covariance", "innovation_with_pose", "association_loglik",
           "JOINT_MAX_HYPOTHESES",
           "joint_slots", "pair_information", "best_joint_hypothesis", "joint_loglik",
           "in_view", "existence_log_odds", "negative_evidence", "heir_of", "retire_landmarks", "associate_particle",
           "select_maps",
           "AssociationRecord", "run_unknown_segments", "best_history", "seen_together", "merge_copies", "run_unknown"]
