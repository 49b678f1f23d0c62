"""The pieces the smoother's data association reads (:mod:`fastslam_edu.landmark.smoother_association`): its
settings and result, the log of sightings computed once (:class:`SightingLog`), one landmark fitted to its sightings
at a fixed path (:func:`fit_landmark`, :func:`fit_map`), and the penalised cost :math:`J` that scores a labelling."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from fastslam_edu.core.measurement import (innovation_unchecked, jacobian_landmark_unchecked, landmark_from_measurement,
                                           range_bearing_unchecked)
from fastslam_edu.core.params import Params
from fastslam_edu.datasets.log import EventStream
from fastslam_edu.landmark.association import AssociationParams
from fastslam_edu.landmark.fastslam import FastSLAMParams
from fastslam_edu.landmark.smoother import SolverSettings
from fastslam_edu.landmark.smoother_factors import dead_reckon_stream, keyframe_steps, sighting_weights

#: Step (b)'s solve inside the association: sightings counted in full (as ``BEST_ESTIMATE``), but stopped at a
#: relative cost change of 1e-6 and after 3 gating rounds: the decisions need the path to millimetres, not the cost
#: to 1e-10, and the association solves the problem in every round of every start.
ASSOCIATION_SOLVER = SolverSettings(tempering=False, tol=1e-6, max_rounds=3, max_iterations=30)

#: The label of a sighting assigned to no landmark.
OUTLIER = -1
#: Infeasible entries of the assignment's cost matrix (never chosen while a feasible column is left).
INFEASIBLE = 1e9


@dataclass(frozen=True, eq=False)
class SmootherAssociationParams(Params):
    """Settings of the association in the smoother (module docstring).

    Attributes
    ----------
    gate_probability : float
        :math:`p` of :math:`g = \\chi^2_2(p)`: a sighting of a landmark has :math:`d^2 \\le g` with probability p.
        :math:`g` is the gate of the assignment, the cost of an outlier and the per-landmark penalty :math:`\\lambda`.
    loop_probability : float
        :math:`p` of :math:`\\chi^2_1(p)`, the test of two distances agreeing (loop closures).
    min_loop_landmarks : int
        Landmarks that must agree pairwise before a loop closure is accepted (>= 3).
    max_rounds : int
        Rounds of (a)–(c) at most per restart.
    restarts : int
        Starts from the filter's run (:func:`~fastslam_edu.landmark.smoother_association.starts_from_filter`): 1, its
        best particle; 2, and the same path with every sighting assigned again; more, and the next-heaviest
        particles with distinct maps.
    incremental_start : bool
        Also start, once, from the log walked in time order, each frame localised against the map so far
        (:func:`~.smoother_association.incremental_start`). Off by default: it helps where the filter's path went
        astray, costs time on every log, and one wrong match early can derail it (figures:
        ``benchmarks/association_mrclam.py --smoother``).
    grown_start : bool
        Also start from the log solved in growing prefixes (:func:`~.smoother_association.grown_start`): one solve per
        ``window_s`` of log, too slow for the time target on long logs (MR.CLAM Dataset 1: minutes).
    solver : SolverSettings
        The least-squares solve of step (b) (default ``ASSOCIATION_SOLVER``: sightings counted in full, as
        ``BEST_ESTIMATE``, stopped sooner).
    window_s : float
        The growing prefixes of :func:`grown_start` [s].
    transient_objects : bool
        At the end, drop from the map every landmark more likely *transient* (there only between its first and last
        sighting: another robot standing still, then gone) than static
        (:func:`~fastslam_edu.landmark.smoother_association_moves.static_against_transient`), its sightings made
        outliers, and solve once more. Off by default: it removes the other robots from the map (at the path solved
        with the true correspondences, MR.CLAM's seven robots: 0–8 spurious landmarks down to 0, accuracy 0.92–1.07
        of the oracle against 0.97–1.13), but from the filter's path a landmark mapped twice, because the path
        drifted, looks transient too and goes with its sightings (accuracy 0.19–0.67 of the oracle against
        0.37–0.81 without; medians of seeds 0–3; pruning along the search, not at the end, likewise).
        ``benchmarks/association_mrclam.py --smoother --transient-objects`` measures it.
    """

    gate_probability: float = 1.0 - 1e-6
    loop_probability: float = 0.999
    min_loop_landmarks: int = 3
    max_rounds: int = 8
    restarts: int = 2
    incremental_start: bool = False
    grown_start: bool = False
    solver: SolverSettings = ASSOCIATION_SOLVER
    window_s: float = 60.0
    transient_objects: bool = False

    def __post_init__(self):
        for name in ("gate_probability", "loop_probability"):
            p = getattr(self, name)
            if not 0.0 < p < 1.0:
                raise ValueError(f"SmootherAssociationParams.{name} must be in (0, 1), got {p!r}")
        if int(self.min_loop_landmarks) < 3:
            raise ValueError(f"min_loop_landmarks must be >= 3 (pairwise consistency needs 3), "
                             f"got {self.min_loop_landmarks!r}")
        if int(self.max_rounds) < 1 or int(self.restarts) < 1:
            raise ValueError(f"max_rounds and restarts must be >= 1, got {self.max_rounds!r}, {self.restarts!r}")
        if not (math.isfinite(self.window_s) and self.window_s > 0):
            raise ValueError(f"window_s must be > 0 seconds, got {self.window_s!r}")
        if not isinstance(self.solver, SolverSettings):
            raise ValueError(f"solver must be a SolverSettings, got {self.solver!r}")

    @property
    def gate(self) -> float:
        """:math:`g = \\chi^2_2(p) = -2 \\ln(1 - p)`: the gate, the cost of an outlier (the :math:`\\chi^2` with two
        degrees of freedom is the exponential distribution of mean 2)."""
        return -2.0 * math.log1p(-self.gate_probability)

    @property
    def penalty(self) -> float:
        """:math:`\\lambda = g`: what a sighting pays to start a landmark (it then fits it exactly)."""
        return self.gate


@dataclass
class SmootherAssociationResult:
    """The smoother's path, map and associations.

    t, steps, poses : keyframe times (N_k,) [s], stream steps, poses (N_k, 3) [m, m, rad]
    pose_mean : (T, 3) the path at every step of the stream (each step at its last keyframe, moved by dead
        reckoning), for the scorers of a filter run
    landmarks : (N, 2) the map [m]; landmarks_cov (N, 2, 2) each landmark's covariance given the path [m²]
    landmark_ident : (N,) identities 0 … N-1; landmark_seen (N,) sightings assigned to each
    history : (n,) the landmark each sighting is assigned to (-1: outlier)
    cost : the penalised cost J of the solution kept (module docstring); costs: of every restart
    rounds : rounds of (a)–(c) of the solution kept; loop_closures: groups merged
    outliers : sightings assigned to no landmark
    seconds : wall time (all restarts)
    """

    t: np.ndarray
    steps: np.ndarray
    poses: np.ndarray
    pose_mean: np.ndarray
    landmarks: np.ndarray
    landmarks_cov: np.ndarray
    landmark_ident: np.ndarray
    landmark_seen: np.ndarray
    history: np.ndarray
    cost: float
    costs: list
    rounds: int
    loop_closures: int
    outliers: int
    seconds: float


# --------------------------------------------------------------------------- the pieces of the data


@dataclass
class SightingLog:
    """What every step reads, computed once: the stream, its keyframes, dead reckoning, the sightings' frames,
    noise and tempering."""

    stream: EventStream
    params: FastSLAMParams
    keys: np.ndarray  # (N_k,) keyframe steps
    path: np.ndarray  # (T, 3) dead reckoning
    x0: np.ndarray
    frame: np.ndarray  # (n,) the step of each sighting
    key_of: np.ndarray  # (n,) the keyframe of each sighting
    R: np.ndarray  # (n, 2, 2)
    Rinv: np.ndarray  # (n, 2, 2)
    beta: np.ndarray  # (n,) tempering of each sighting (as if its label were its true landmark: see _beta_of)
    camera: tuple  # (fov [rad], min_range [m], max_range [m], log(p_D/p_F), log((1-p_D)/(1-p_F))): negative evidence


def prepare_log(stream: EventStream, params: FastSLAMParams, x0, sensor=None) -> SightingLog:
    """The :class:`SightingLog` of ``stream``; ``sensor``: the filter's
    :class:`~fastslam_edu.landmark.association.AssociationParams` (its camera's field of view and range, :math:`p_D`,
    :math:`p_F`; default its defaults)."""
    sensor = AssociationParams() if sensor is None else sensor
    pd_, pf = sensor.detection_probability, sensor.clutter_probability
    camera = (float(sensor.fov), float(sensor.min_range), float(sensor.max_range), math.log(pd_ / pf),
              math.log((1 - pd_) / (1 - pf)))
    if len(stream) < 2:
        raise ValueError(f"smooth_association: the stream has {len(stream)} step(s); at least 2 are needed")
    x0 = stream.x0 if x0 is None else np.asarray(x0, dtype=float).reshape(3)
    if x0 is None:
        raise ValueError("smooth_association: the stream has no initial pose (x0 is None): pass x0=(x, y, theta)")
    keys = keyframe_steps(stream)
    frame = stream.sighting_steps
    R = params.measurement_covariance(stream.z)
    return SightingLog(stream=stream, params=params, keys=keys,
                       path=dead_reckon_stream(stream, x0, params.odometry_scale), x0=np.asarray(x0, dtype=float),
                       frame=frame, key_of=np.searchsorted(keys, frame), R=R, Rinv=np.linalg.inv(R),
                       beta=np.ones(len(frame)), camera=camera)


def tempering_of(log: SightingLog, labels: np.ndarray) -> np.ndarray:
    """:math:`\\beta_i = \\min(1, \\Delta t / \\tau)` of each sighting for ``labels`` (n,): :math:`\\Delta t` since the
    previous sighting given the same label (the filter's tempering, ``measurement_correlation_s`` :math:`\\tau`).
    The outliers share one label: another robot in view for a few seconds is one piece of evidence per
    :math:`\\tau`, as a landmark is."""
    tau = log.params.measurement_correlation_s
    if tau is None:
        return np.ones(len(labels))
    relabelled = dataclasses.replace(log.stream, landmark=np.where(labels >= 0, labels + 1, 0),
                                     landmark_subjects=np.arange(int(labels.max(initial=-1)) + 2))
    return sighting_weights(relabelled, tau)


# --------------------------------------------------------------------------- one landmark from its sightings


def fit_landmark(poses, z, Rinv, start=None, iterations: int = 5):
    """The landmark that best explains sightings ``z`` (s, 2) from fixed ``poses`` (s, 3), by Gauss–Newton:

    .. math::

        \\hat l = \\arg\\min_l \\sum_i \\nu_i^\\top R_i^{-1} \\nu_i, \\quad \\nu_i = z_i \\ominus h(x_i, l), \\qquad
        \\Sigma = \\Big(\\sum_i H_i^\\top R_i^{-1} H_i\\Big)^{-1},

    started from the mean of the sightings' inverse measurements (or ``start``). ``Rinv`` (s, 2, 2).
    Returns ``(l (2,), Sigma (2, 2), d2 (s,))``: the position [m], its covariance given the path [m²], and each
    sighting's :math:`d^2 = \\nu_i^\\top R_i^{-1} \\nu_i` at it.
    """
    l = np.mean(landmark_from_measurement(poses, z), axis=0) if start is None else np.asarray(start, dtype=float)
    info = np.eye(2)
    for _ in range(iterations):
        nu = innovation_unchecked(z, range_bearing_unchecked(poses, l))
        H = jacobian_landmark_unchecked(poses, l)
        HtRi = np.swapaxes(H, 1, 2) @ Rinv
        info = np.sum(HtRi @ H, axis=0) + 1e-9 * np.eye(2)
        step = np.linalg.solve(info, np.einsum("nij,nj->i", HtRi, nu))
        l = l + step
        if np.max(np.abs(step)) < 1e-6:
            break
    nu = innovation_unchecked(z, range_bearing_unchecked(poses, l))
    d2 = np.einsum("ni,nij,nj->n", nu, Rinv, nu)
    return l, np.linalg.inv(info), d2


def sighting_poses(log: SightingLog, poses: np.ndarray) -> np.ndarray:
    """The pose (n, 3) of every sighting: its keyframe's (every step with a sighting is a keyframe)."""
    return poses[log.key_of]


def fit_map(log: SightingLog, poses, labels, n_landmarks: int, start=None):
    """Every landmark fitted to its sightings at the path ``poses`` (:func:`fit_landmark`):
    ``(landmarks (N, 2), cov (N, 2, 2), d2 (n,))``; ``d2`` is :math:`g`-free, NaN for outliers, and a landmark
    without sightings is NaN."""
    xs = sighting_poses(log, poses)
    lms, cov = np.full((n_landmarks, 2), np.nan), np.full((n_landmarks, 2, 2), np.nan)
    d2 = np.full(len(labels), np.nan)
    for j in range(n_landmarks):
        i = np.flatnonzero(labels == j)
        if len(i):
            guess = None if start is None or not np.isfinite(start[j]).all() else start[j]
            lms[j], cov[j], d2[i] = fit_landmark(xs[i], log.stream.z[i], log.Rinv[i], guess)
    return lms, cov, d2


def penalised_cost(d2, beta, labels, n_landmarks: int, settings: SmootherAssociationParams) -> float:
    """:math:`J = \\sum_{assigned} \\beta_i d^2_i + g \\sum_{outliers} \\beta_i + \\lambda N` (module docstring)."""
    out = labels < 0
    return float(np.sum(beta[~out] * d2[~out]) + settings.gate * np.sum(beta[out]) + settings.penalty * n_landmarks)



def compact(labels: np.ndarray):
    """Labels renumbered 0 … N-1 in order of first use (outliers stay -1): ``(labels, old index of each new)``."""
    used = np.unique(labels[labels >= 0])
    new = np.full(int(labels.max(initial=-1)) + 1, OUTLIER, dtype=np.int64)
    new[used] = np.arange(len(used))
    return np.where(labels >= 0, new[np.maximum(labels, 0)], OUTLIER), used



def frames_of(log: SightingLog, labels, j) -> set:
    """The camera frames (stream steps) in which landmark ``j`` is given a sighting."""
    return set(log.frame[labels == j].tolist())



__all__ = ["ASSOCIATION_SOLVER", "OUTLIER", "INFEASIBLE", "SmootherAssociationParams", "SmootherAssociationResult",
           "SightingLog", "prepare_log", "tempering_of", "fit_landmark", "sighting_poses", "fit_map", "penalised_cost",
           "compact", "frames_of"]
