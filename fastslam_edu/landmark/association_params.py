"""Settings of FastSLAM with unknown correspondences (:class:`AssociationParams`), as the kernels take them
(:class:`Rules`), and the particle set they size (:class:`MapParticles`: variable-size maps).

The algorithm is described in :mod:`fastslam_edu.landmark.association`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from fastslam_edu.core.params import Params
from fastslam_edu.landmark.fastslam import FastSLAMParams
from fastslam_edu.landmark.joint_compatibility import N_PAIR_SLOTS
from fastslam_edu.landmark.step_records import RESAMPLER_CODES

#: The three rules of deciding one instant's sightings (``AssociationParams.association``), as the kernels take them
#: (``Rules.association``): each sighting alone, the greedy pairing (mutual exclusion), jointly.
INDEPENDENT, GREEDY, JOINT = 0, 1, 2
ASSOCIATION_RULES = {"independent": INDEPENDENT, "greedy": GREEDY, "joint": JOINT}


def confirmation_range(R, separation_m: float, gate_chi2: float) -> float:
    """:math:`r^*` [m]: the range within which one sighting tells apart two landmarks ``separation_m`` apart, at the
    gate ``gate_chi2`` (:math:`d_0^2`); ``R`` (2, 2) the filter's :math:`\\mathrm{diag}(\\sigma_r^2, \\sigma_\\phi^2)`.

    A landmark made from one sighting at range :math:`r` has the innovation covariance :math:`Q = H\\Sigma H^\\top
    + R = 2R` (module :mod:`~fastslam_edu.landmark.association`). Its neighbour, :math:`d` away, is seen by the
    next sighting displaced by :math:`d` in the plane: across the line of sight that is a bearing
    :math:`d/r`, with the standard deviation :math:`\\sigma_\\perp(r) = \\sigma_\\phi r` [m]; along it a range
    :math:`d`, with :math:`\\sigma_r(r) = \\sigma_r(0) + s\\,r`. The neighbour's sighting is outside the gate when

    .. math:: \\frac{d^2}{2\\sigma(r)^2} \\ge d_0^2 .

    Along the line of sight this asks :math:`\\sigma_r(r) \\le d/\\sqrt{2 d_0^2}`: with MR.CLAM's
    :math:`\\sigma_r(0)` = 0.07 m, :math:`d` = 0.2 m and :math:`d_0^2` = 16 (0.035 m) at no range at all, so
    a radial pair is told apart only from another direction, as the robot moves. Across it,
    :math:`\\sigma_\\phi r \\le d/\\sqrt{2 d_0^2}`:

    .. math:: r^* = \\frac{d}{\\sigma_\\phi\\sqrt{2 d_0^2}}

    (:math:`\\sigma_\\phi` = 0.02 rad: :math:`r^*` = 1.77 m). The range noise's growth :math:`s` does not enter.
    """
    R = np.asarray(R, dtype=float)
    if R.shape != (2, 2) or not R[1, 1] > 0:
        raise ValueError(f"R must be a 2x2 covariance with a bearing variance > 0, got {R!r}")
    if not (separation_m > 0 and gate_chi2 > 0):
        raise ValueError(f"separation_m and gate_chi2 must be > 0, got {separation_m!r}, {gate_chi2!r}")
    return float(separation_m / (math.sqrt(R[1, 1]) * math.sqrt(2.0 * gate_chi2)))


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
    association : str
        How the sightings of one instant are decided (:data:`ASSOCIATION_RULES`). ``"joint"`` (default): jointly,
        their innovations correlated by the pose error they share (:func:`joint_slots`; above
        ``JOINT_MAX_HYPOTHESES`` hypotheses it falls back to the greedy pairing). ``"greedy"``: the pairs
        (sighting, landmark) most likely first, each sighting and each landmark once (mutual exclusion).
        ``"independent"``: each sighting alone, its most likely landmark. On MR.CLAM's seven robots with
        groundtruth the joint rule associates more sightings rightly than the greedy pairing, at 1.0–1.5 times its
        filter time (``benchmarks/association_mrclam.py`` and its ``--greedy``; figures in ``benchmarks/results/``).
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
    deferred : bool
        Deferred commitment (default False: table 13.1's commitment at the first sighting): a landmark first seen
        beyond the confirmation range :math:`r^*` (:attr:`confirm_range`) is tentative: far sightings that fit it
        update it, but its first sighting within :math:`r^*` re-initialises it from that sighting alone, so that
        two landmarks merged while seen from far are told apart when the robot comes close.
    separation_m : float
        :math:`d` [m]: the distance between two landmarks that a sighting within :math:`r^*` tells apart.
    split_tentative : bool
        A provisional landmark that two sightings of one camera frame both fit splits in two (default False): it is
        re-initialised from the sighting it was given, the other starts a landmark (:func:`splitting_sightings`).
    gap_window_sightings : int
        Re-association after a gap (:mod:`fastslam_edu.landmark.gap_window`; 0, the default: off): the sightings
        after a stretch of more than ``drift_cap_s`` without any are held until there are this many, or
        ``gap_window_s`` seconds have passed, and each particle decides them together, with the gap's pose error.
        FastSLAM 1.0 only.
    gap_window_s : float
        The longest a window of :attr:`gap_window_sightings` stays open [s].
    """

    filter: FastSLAMParams = field(default_factory=FastSLAMParams)
    new_landmark_chi2: float = 16.0
    association: str = "joint"
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
    deferred: bool = False
    separation_m: float = 0.2
    split_tentative: bool = False
    gap_window_sightings: int = 0
    gap_window_s: float = 10.0

    def __post_init__(self):
        if not isinstance(self.filter, FastSLAMParams):
            raise ValueError(f"filter must be a FastSLAMParams, got {self.filter!r}")
        if self.filter.mode != "slam":
            raise ValueError("unknown correspondences: mode 'slam' only")
        if self.filter.resampler not in RESAMPLER_CODES:
            raise ValueError(f"resampler must be one of {sorted(RESAMPLER_CODES)}, got {self.filter.resampler!r}")
        if self.association not in ASSOCIATION_RULES:
            raise ValueError(f"association must be one of {list(ASSOCIATION_RULES)}, got {self.association!r}")
        if not (math.isfinite(self.new_landmark_chi2) and self.new_landmark_chi2 > 0):
            raise ValueError(f"new_landmark_chi2 must be > 0, got {self.new_landmark_chi2!r}")
        if int(self.max_landmarks) < 1 or int(self.n_confirm) < 1:
            raise ValueError("max_landmarks and n_confirm must be >= 1")
        if not (self.drift_cap_s >= 0 and self.drift_xy >= 0 and self.drift_theta >= 0):
            raise ValueError("drift_xy, drift_theta and drift_cap_s must be >= 0")
        if not 0.0 < self.clutter_probability < self.detection_probability < 1.0:
            raise ValueError(f"need 0 < clutter_probability < detection_probability < 1, got "
                             f"{self.clutter_probability!r}, {self.detection_probability!r}")
        if int(self.gap_window_sightings) < 0 or not self.gap_window_s > 0:
            raise ValueError(f"need gap_window_sightings >= 0 (0: off) and gap_window_s > 0, got "
                             f"{self.gap_window_sightings!r}, {self.gap_window_s!r}")
        if self.gap_window_sightings and self.filter.proposal == "fastslam2":
            raise ValueError("gap_window_sightings: FastSLAM 1.0 only (filter.proposal 'fastslam2' moves the pose itself)")
        if not (math.isfinite(self.separation_m) and self.separation_m > 0):
            raise ValueError(f"separation_m must be > 0, got {self.separation_m!r}")
        if not (0 < self.fov <= math.pi and 0 <= self.min_range < self.max_range):
            raise ValueError(f"need 0 < fov <= pi and 0 <= min_range < max_range, got {self.fov}, "
                             f"{self.min_range}, {self.max_range}")

    @property
    def confirm_range(self) -> float:
        """:math:`r^*` [m] of deferred commitment (:func:`confirmation_range` with this filter's :math:`R`,
        ``separation_m`` and the gate :math:`d_0^2` = ``new_landmark_chi2``); ``inf`` when ``deferred`` is off."""
        if not self.deferred:
            return math.inf
        return confirmation_range(self.filter.measurement_cov, self.separation_m, self.new_landmark_chi2)

    def rules(self) -> "Rules":
        """The settings as the compiled kernels take them (:class:`Rules`)."""
        tau = self.filter.measurement_correlation_s
        log_odds_seen = math.log(self.detection_probability / self.clutter_probability)  # log(p_D / p_F)
        return Rules(new_chi2=float(self.new_landmark_chi2), association=ASSOCIATION_RULES[self.association],
                     fov=float(self.fov), min_range=float(self.min_range), max_range=float(self.max_range),
                     n_confirm=int(self.n_confirm), log_odds_seen=log_odds_seen,
                     log_odds_missed=math.log((1.0 - self.detection_probability) / (1.0 - self.clutter_probability)),
                     tau=0.0 if tau is None else float(tau), pose_scale=float(self.pose_uncertainty),
                     provisional_as_new=bool(self.provisional_as_new), drift_xy=float(self.drift_xy),
                     drift_theta=float(self.drift_theta), range_scale=float(self.association_range_scale),
                     drift_cap_s=float(self.drift_cap_s), min_count=int(self.proposal_min_count),
                     new_max_range=float(self.new_max_range),
                     log_odds_cap=float(self.log_odds_cap_sightings) * log_odds_seen,
                     inherit_radius=float(self.inherit_radius), confirm_range=float(self.confirm_range),
                     split=bool(self.split_tentative), window_sightings=int(self.gap_window_sightings),
                     window_s=float(self.gap_window_s))


class MapParticles(NamedTuple):
    """The particle set with variable-size maps (M particles, up to Kmax landmarks each), changed in place.

    poses (M, 3); mu (M, Kmax, 2); sigma (M, Kmax, 2, 2); n (M,) landmarks held;
    ident (M, Kmax) identity of each landmark; seen, missed (M, Kmax) counts; evidence (M, Kmax): the
    sightings counted as independent, :math:`\\sum\\beta` (:func:`associate_particle`);
    last_t, first_t (M, Kmax) times of the last and the first sighting [s]; committed (M, Kmax): seen within
    the confirmation range :math:`r^*` (``AssociationParams.deferred``; always True without it); logw (M,).
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
    committed: np.ndarray
    logw: np.ndarray


class AssociationWorkspace(NamedTuple):
    """The arrays one particle's decision at one instant is written into, made once per run
    (:func:`association_workspace`), so that the kernels run per particle and instant make no array: making one,
    and the reference counts of the arrays handed to a kernel that may make one, cost more than the arithmetic
    of a small map. ``n``: the most sightings of one instant; ``N``: ``max_landmarks``.

    ll (n, N): the candidates' log-likelihoods :math:`\\ell_{ik}`, -inf for a pair outside the gate; slot (n,):
    the slot each sighting goes to (-1: new); chosen (n,): the log-likelihood it was decided by; taken (N,): the
    landmarks a sighting of the instant went to; split (n,): the sightings whose landmark splits
    (:func:`~fastslam_edu.landmark.association.splitting_sightings`); info (n, N, ``N_PAIR_SLOTS``), p0 (n,),
    choice (n,), partial (n + 1, ``N_PAIR_SLOTS``), optimistic (n + 1,), excess and common (3, 3), group (n,):
    joint compatibility's (:mod:`fastslam_edu.landmark.joint_compatibility`).
    """

    ll: np.ndarray
    slot: np.ndarray
    chosen: np.ndarray
    taken: np.ndarray
    split: np.ndarray
    info: np.ndarray
    p0: np.ndarray
    choice: np.ndarray
    partial: np.ndarray
    optimistic: np.ndarray
    excess: np.ndarray
    common: np.ndarray
    group: np.ndarray


def association_workspace(n, N):
    """An :class:`AssociationWorkspace` for instants of at most ``n`` sightings and maps of at most ``N``
    landmarks (made in Python, once per run or decision: compiled, its thirteen arrays of three types cost more
    than a second of compilation on a cold start)."""
    n, N = int(n), int(N)
    return AssociationWorkspace(np.full((n, N), -math.inf), np.full(n, -1, dtype=np.int64), np.full(n, -math.inf),
                                np.zeros(N, dtype=np.bool_), np.zeros(n, dtype=np.bool_),
                                np.zeros((n, N, N_PAIR_SLOTS)), np.zeros(n), np.full(n, -1, dtype=np.int64),
                                np.zeros((n + 1, N_PAIR_SLOTS)), np.zeros(n + 1), np.zeros((3, 3)),
                                np.zeros((3, 3)), np.zeros(n, dtype=np.int64))


def initial_particles(n_particles: int, max_landmarks: int, x0) -> MapParticles:
    """All particles at ``x0`` (3,), with empty maps and equal weights."""
    M, K = int(n_particles), int(max_landmarks)
    x0 = np.asarray(x0, dtype=float)
    if x0.shape != (3,) or not np.isfinite(x0).all():
        raise ValueError(f"initial pose must be 3 finite numbers, got {x0!r}")
    return MapParticles(poses=np.tile(x0, (M, 1)), mu=np.zeros((M, K, 2)), sigma=np.tile(np.eye(2), (M, K, 1, 1)),
                        n=np.zeros(M, dtype=np.int64), ident=np.full((M, K), -1, dtype=np.int64),
                        seen=np.zeros((M, K), dtype=np.int64), missed=np.zeros((M, K), dtype=np.int64),
                        evidence=np.zeros((M, K)), log_odds=np.zeros((M, K)), last_t=np.zeros((M, K)),
                        first_t=np.zeros((M, K)), committed=np.ones((M, K), dtype=np.bool_), logw=np.zeros(M))


class Rules(NamedTuple):
    """The association settings as the kernels take them (:class:`AssociationParams`)."""

    new_chi2: float
    association: int
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
    confirm_range: float
    split: bool
    window_sightings: int
    window_s: float


__all__ = ["ASSOCIATION_RULES", "INDEPENDENT", "GREEDY", "JOINT", "confirmation_range", "AssociationParams",
           "MapParticles", "AssociationWorkspace", "association_workspace", "initial_particles", "Rules"]
