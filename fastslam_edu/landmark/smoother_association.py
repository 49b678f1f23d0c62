"""Data association re-decided in the smoother: which landmark each sighting is, with the whole log in view.

FastSLAM without barcodes (:mod:`fastslam_edu.landmark.association`) decides every sighting once, at the instant
it is made, against the map a particle holds then; a wrong decision is never undone. Here the decisions are taken
again, all of them, against a near-final map, by alternating (Olson's "MAP association with the whole graph"; the
EM-like loop of Dellaert et al.'s correspondence-free SfM):

(a) **assignment** (:func:`assign_sightings`): each camera frame's sightings :math:`z_1 \\dots z_s` against the
    current map :math:`l_1 \\dots l_N` at the current path, *jointly per frame*
    (``scipy.optimize.linear_sum_assignment``) over the cost matrix :math:`C` (:func:`frame_costs`), :math:`s`
    rows and :math:`N + 2s` columns,

    .. math::

        C_{ij} = d^2_{ij} = \\nu_{ij}^\\top (R_i + H_{ij} \\Sigma_j H_{ij}^\\top)^{-1} \\nu_{ij}
        \\;(d^2_{ij} \\le g), \\qquad C_{i,\\mathrm{new}_i} = \\lambda, \\qquad C_{i,\\mathrm{out}_i} = g,

    :math:`\\nu_{ij} = z_i \\ominus h(x, l_j)`, :math:`\\Sigma_j` the landmark's covariance given the path
    (:func:`fit_landmark`), and every other entry infeasible: one landmark never takes two sightings of a frame.
    A "new" landmark is opened at the sighting and EKF-updated by the later frames of the pass;
(b) **least squares** (:func:`solve_labelled`): the smoother's problem
    (:func:`fastslam_edu.landmark.smoother.build_problem`, :func:`~fastslam_edu.landmark.smoother.solve_with_gate`,
    ``BEST_ESTIMATE``) with these correspondences; sightings its gate sets aside become outliers;
(c) **split, merge, prune** (:func:`split_moves`, :func:`merge_moves`, :func:`prune_landmarks`) scored by the
    **penalised cost** at the path of (b):

    .. math::

        J = \\sum_{i \\text{ assigned}} \\beta_i\\, d^2_i + g \\sum_{i \\text{ outlier}} \\beta_i + \\lambda N,

    until the assignment stops changing (at most ``max_rounds``). Then **loop closures** between groups of
    landmarks (:func:`loop_closures`), and the same loop again if one was accepted.

**Thresholds from the noise model**, never per robot: :math:`g = \\chi^2_2(p)` (``gate_probability``, the
quantile of :math:`d^2` for a sighting of the landmark it is assigned to, whatever :math:`R`); the per-landmark
penalty :math:`\\lambda = g`: *the cost a sighting pays to start a landmark*. In the frame's assignment a sighting
with no landmark within :math:`g` starts one at cost :math:`\\lambda` (it fits it exactly, :math:`d^2 = 0`) or is an
outlier at cost :math:`g`; the map then keeps a landmark only if its sightings, left out, would cost more than it:
:math:`\\sum_i \\beta_i (g - d^2_i) > \\lambda`, which needs more than one independent sighting's worth of evidence.
:math:`\\beta_i = \\min(1, \\Delta t/\\tau)` is the filter's tempering
(:func:`fastslam_edu.landmark.fastslam.evidence_fractions`): a landmark seen 3 times a second counts about one
sighting every :math:`\\tau` seconds, so another robot in view for a moment is not a landmark. Splitting one landmark
into two pays :math:`\\lambda` and wins when the two fit their sightings better by more; merging two saves it.

**Loop closures** (:func:`loop_closures`): two landmarks never seen in one frame and further apart than their
covariances allow (:math:`d^2 > g`) may still be one landmark mapped twice, after the path drifted between the two
visits; but so may two look-alike neighbours. A pair is a *candidate* within the drift the odometry allows between
the two visits; candidates :math:`(a, b)` and :math:`(c, e)` are *consistent* when the distances agree,
:math:`(\\|l_a - l_c\\| - \\|l_b - l_e\\|)^2 \\le \\chi^2_1(p)\\,\\sigma^2` (a rigid drift keeps distances); a group of
at least ``min_loop_landmarks`` (3) pairwise-consistent candidates — a maximum clique of the consistency graph
(:func:`maximum_clique`, Bron–Kerbosch) — is merged, the problem solved again, and the closure kept only if the
penalised cost falls.

**Restarts** (:func:`smooth_association`): from the filter's best particle (its history gives the first
correspondences, its map and the filter's mean path the start), and from the next-heaviest particles with distinct
maps (their maps, the first correspondences from step (a)); the solution with the lowest final penalised cost is
kept (``restarts``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.stats import chi2

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.measurement import (innovation, jacobian_landmark, jacobian_pose, landmark_from_measurement,
                                           range_bearing)
from fastslam_edu.core.params import Params
from fastslam_edu.core.se2 import compose, relative
from fastslam_edu.datasets.log import EventStream
from fastslam_edu.landmark.association import AssociationParams
from fastslam_edu.landmark.fastslam import FastSLAMParams
from fastslam_edu.landmark.smoother import (BEST_ESTIMATE, PRIOR_STD, SolverSettings, build_problem, dead_reckoning,
                                            keyframe_steps, sighting_weights, solve_with_gate)

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
        Particles of the filter started from (the best, then the heaviest with distinct maps).
    solver : SolverSettings
        The least-squares solve of step (b) (default ``BEST_ESTIMATE``: sightings counted in full).
    window_s : float
        The growing prefixes of :func:`grown_start` [s].
    """

    gate_probability: float = 1.0 - 1e-6
    loop_probability: float = 0.999
    min_loop_landmarks: int = 3
    max_rounds: int = 8
    restarts: int = 3
    solver: SolverSettings = BEST_ESTIMATE
    window_s: float = 60.0

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
        """:math:`g = \\chi^2_2(p)`: the gate, the cost of an outlier."""
        return float(chi2.ppf(self.gate_probability, 2))

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
class _Log:
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


def _prepare(stream: EventStream, params: FastSLAMParams, x0, sensor=None) -> _Log:
    """The :class:`_Log` of ``stream``; ``sensor``: the filter's
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
    return _Log(stream=stream, params=params, keys=keys, path=dead_reckoning(stream, x0, params.odometry_scale),
                x0=np.asarray(x0, dtype=float), frame=frame, key_of=np.searchsorted(keys, frame), R=R,
                Rinv=np.linalg.inv(R), beta=np.ones(len(frame)), camera=camera)


def tempering_of(log: _Log, labels: np.ndarray) -> np.ndarray:
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
        nu = innovation(z, range_bearing(poses, np.broadcast_to(l, (len(z), 2))))
        H = jacobian_landmark(poses, np.broadcast_to(l, (len(z), 2)))
        HtRi = np.swapaxes(H, 1, 2) @ Rinv
        info = np.sum(HtRi @ H, axis=0) + 1e-9 * np.eye(2)
        step = np.linalg.solve(info, np.einsum("nij,nj->i", HtRi, nu))
        l = l + step
        if np.max(np.abs(step)) < 1e-6:
            break
    nu = innovation(z, range_bearing(poses, np.broadcast_to(l, (len(z), 2))))
    d2 = np.einsum("ni,nij,nj->n", nu, Rinv, nu)
    return l, np.linalg.inv(info), d2


def sighting_poses(log: _Log, poses: np.ndarray) -> np.ndarray:
    """The pose (n, 3) of every sighting: its keyframe's (every step with a sighting is a keyframe)."""
    return poses[log.key_of]


def fit_map(log: _Log, poses, labels, n_landmarks: int, start=None):
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


# --------------------------------------------------------------------------- (a) assignment, jointly per frame


def mahalanobis_d2(x, z, R, landmarks, cov, pose_cov=None):
    """:math:`d^2_{ij} = \\nu^\\top (R_i + H \\Sigma_j H^\\top + H_x P_i H_x^\\top)^{-1} \\nu` of sightings ``z`` (s, 2)
    from poses ``x`` (s, 3) (noise ``R`` (s, 2, 2), pose covariance ``pose_cov`` (s, 3, 3) or None: the pose is
    taken as known) against landmarks (N, 2) with covariances (N, 2, 2): shape (s, N)."""
    s, N = len(z), len(landmarks)
    if N == 0:
        return np.zeros((s, 0))
    X = np.broadcast_to(x[:, None, :], (s, N, 3))
    L = np.broadcast_to(landmarks[None], (s, N, 2))
    nu = innovation(z[:, None, :], range_bearing(X, L))
    H = jacobian_landmark(X.reshape(-1, 3), L.reshape(-1, 2)).reshape(s, N, 2, 2)
    Q = R[:, None] + H @ cov[None] @ np.swapaxes(H, 2, 3)
    if pose_cov is not None:
        Hx = jacobian_pose(X.reshape(-1, 3), L.reshape(-1, 2)).reshape(s, N, 2, 3)
        Q = Q + Hx @ pose_cov[:, None] @ np.swapaxes(Hx, 2, 3)
    return np.einsum("sni,snij,snj->sn", nu, np.linalg.inv(Q), nu)


def frame_costs(d2: np.ndarray, gate: float, penalty: float) -> np.ndarray:
    """The cost matrix of one frame, (s, N + 2s): :math:`d^2` where within the gate (else infeasible), then one
    "new landmark" column per sighting at the penalty :math:`\\lambda`, then one "outlier" column per sighting at
    :math:`g` (a tie is taken as new: column order)."""
    s = len(d2)
    C = np.full((s, d2.shape[1] + 2 * s), INFEASIBLE)
    C[:, :d2.shape[1]] = np.where(d2 <= gate, d2, INFEASIBLE)
    C[np.arange(s), d2.shape[1] + np.arange(s)] = penalty
    C[np.arange(s), d2.shape[1] + s + np.arange(s)] = gate + 1e-9
    return C


def assign_frame(d2: np.ndarray, gate: float, penalty: float) -> np.ndarray:
    """``linear_sum_assignment`` of one frame's cost matrix (:func:`frame_costs`): for each of its s sightings the
    landmark (0 … N-1), ``N`` (start a new landmark) or ``OUTLIER``. No landmark is given two sightings."""
    N, s = d2.shape[1], len(d2)
    rows, cols = linear_sum_assignment(frame_costs(d2, gate, penalty))
    out = np.empty(s, dtype=np.int64)
    out[rows] = np.where(cols < N, cols, np.where(cols < N + s, N, OUTLIER))
    return out


def frame_order(log: _Log) -> np.ndarray:
    """The camera frames (steps with sightings), nearest first: by their shortest range, ties in time order. New
    landmarks are then started from the sightings that place them best (the range's σ grows with the range), and a
    far sighting, which cannot tell two landmarks 0.2 m apart, is decided against landmarks already placed by near
    ones, as the oracle decides it against the surveyed map."""
    steps = np.flatnonzero(np.diff(log.stream.offsets))
    nearest = np.minimum.reduceat(log.stream.z[:, 0], log.stream.offsets[steps])
    return steps[np.lexsort((steps, nearest))]


def assign_sightings(log: _Log, poses, landmarks, cov, settings: SmootherAssociationParams, pose_cov=None):
    """Step (a): every frame, nearest first (:func:`frame_order`), against the map ``landmarks`` (N, 2), ``cov`` (N, 2, 2) at the path
    ``poses`` (:func:`assign_frame`). A sighting that starts a landmark puts it at its inverse measurement with
    covariance :math:`G R G^\\top`; later sightings given to it update it by the EKF at their fixed pose.

    ``pose_cov`` (n, 3, 3): the uncertainty of each sighting's pose (:func:`drift_covariance`; None: none).
    Returns ``(labels (n,), landmarks (N', 2), cov (N', 2, 2))``, N' >= N.
    """
    lms, cov = [np.asarray(l, dtype=float) for l in landmarks], [np.asarray(c, dtype=float) for c in cov]
    n_old = len(lms)
    xs = sighting_poses(log, poses)
    z = log.stream.z
    labels = np.full(len(z), OUTLIER, dtype=np.int64)
    d2_old = mahalanobis_d2(xs, z, log.R, np.array(lms).reshape(-1, 2), np.array(cov).reshape(-1, 2, 2), pose_cov)
    gate, penalty = settings.gate, settings.penalty
    for k in frame_order(log):
        a, b = log.stream.offsets[k], log.stream.offsets[k + 1]
        d2 = d2_old[a:b]
        if len(lms) > n_old:
            fresh = mahalanobis_d2(xs[a:b], z[a:b], log.R[a:b], np.array(lms[n_old:]), np.array(cov[n_old:]),
                                   None if pose_cov is None else pose_cov[a:b])
            d2 = np.concatenate([d2, fresh], axis=1)
        chosen = assign_frame(d2, gate, penalty)
        for i, j in zip(range(a, b), chosen.tolist()):
            if j == d2.shape[1]:  # a new landmark, at this sighting
                l = landmark_from_measurement(xs[i], z[i])
                G = np.linalg.inv(jacobian_landmark(xs[i][None], l[None])[0])
                lms.append(l)
                cov.append(G @ log.R[i] @ G.T)
                labels[i] = len(lms) - 1
            elif 0 <= j < len(lms):
                labels[i] = j
                if j >= n_old:  # a landmark of this pass: EKF update at the fixed pose
                    lms[j], cov[j] = _ekf(xs[i], z[i], log.R[i], lms[j], cov[j])
    return labels, np.array(lms).reshape(-1, 2), np.array(cov).reshape(-1, 2, 2)


def _ekf(x, z, R, l, P):
    """One EKF update of landmark ``l`` (2,), covariance ``P`` by sighting ``z`` from the fixed pose ``x``."""
    H = jacobian_landmark(x[None], l[None])[0]
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    nu = innovation(z[None], range_bearing(x[None], l[None]))[0]
    return l + K @ nu, (np.eye(2) - K @ H) @ P


def compact(labels: np.ndarray):
    """Labels renumbered 0 … N-1 in order of first use (outliers stay -1): ``(labels, old index of each new)``."""
    used = np.unique(labels[labels >= 0])
    new = np.full(int(labels.max(initial=-1)) + 1, OUTLIER, dtype=np.int64)
    new[used] = np.arange(len(used))
    return np.where(labels >= 0, new[np.maximum(labels, 0)], OUTLIER), used


# --------------------------------------------------------------------------- (b) least squares


def solve_labelled(log: _Log, labels, poses, landmarks, settings: SmootherAssociationParams):
    """Step (b): the smoother's problem with the correspondences ``labels`` (n,) (outliers left out), from ``poses``
    (N_k, 3) and ``landmarks`` (N, 2). Returns ``(poses, landmarks, labels, motion_d2)``: sightings beyond the gate
    at the solution (``params.gate_chi2``) become outliers; ``motion_d2`` is the whitened squared residual of the
    prior and the odometry factors, :math:`\\sum \\|e\\|^2_C` (what the path costs; a landmark without a sighting
    used is NaN)."""
    keep = labels >= 0
    stream = log.stream
    counts = np.bincount(log.frame[keep], minlength=len(stream))
    sub = dataclasses.replace(stream, z=stream.z[keep], landmark=labels[keep],
                              offsets=np.concatenate([[0], np.cumsum(counts)]),
                              landmark_subjects=np.arange(len(landmarks)))
    problem, seen, use = build_problem(sub, log.params, log.keys, log.path, log.x0, PRIOR_STD,
                                       tempering=settings.solver.tempering)
    poses = np.array(poses, dtype=float)
    poses[:, 2] = log.path[log.keys, 2] + wrap_angle(poses[:, 2] - log.path[log.keys, 2])
    v = np.concatenate([poses.ravel(), np.asarray(landmarks, dtype=float)[seen].ravel()])
    v, active, _, _, _ = solve_with_gate(problem, v, log.params.gate_chi2, settings.solver)
    r, _, rows = problem.evaluate(v, active)
    motion = r[:rows.start]  # the prior's and the odometry's rows come first
    new_poses, lms = problem.split(v)
    landmarks = np.full((len(landmarks), 2), np.nan)
    landmarks[seen] = lms
    labels = labels.copy()
    labels[np.flatnonzero(keep)[use][~active]] = OUTLIER
    return new_poses.copy(), landmarks, labels, float(motion @ motion)


# --------------------------------------------------------------------------- (c) split, merge, prune


def _frames_of(log: _Log, labels, j):
    return set(log.frame[labels == j].tolist())


def two_clusters(poses, z, Rinv, iterations: int = 10) -> np.ndarray:
    """Hard EM of two landmarks for sightings ``z`` (s, 2) from fixed ``poses`` (s, 3): each sighting goes to the
    landmark it fits better (:math:`d^2`, measurement space), each landmark is fitted to its sightings
    (:func:`fit_landmark`); started from the two ends of the principal axis of the inverse measurements.
    Returns a bool (s,): the second cluster."""
    points = landmark_from_measurement(poses, z)
    centred = points - points.mean(axis=0)
    proj = centred @ np.linalg.svd(centred, full_matrices=False)[2][0]
    side = proj > np.median(proj)
    for _ in range(iterations):
        if side.sum() < 2 or (~side).sum() < 2:
            break
        d2 = []
        for part in (~side, side):
            l = fit_landmark(poses[part], z[part], Rinv[part])[0]
            nu = innovation(z, range_bearing(poses, np.broadcast_to(l, (len(z), 2))))
            d2.append(np.einsum("ni,nij,nj->n", nu, Rinv, nu))
        new = d2[1] < d2[0]
        if np.array_equal(new, side):
            break
        side = new
    return side


def split_moves(log: _Log, poses, labels, beta, settings: SmootherAssociationParams) -> tuple[np.ndarray, int]:
    """Split every landmark whose sightings form two clusters (:func:`two_clusters` of their inverse measurements)
    when the two fit them better by more than the penalty :math:`\\lambda` of the second:
    :math:`\\sum \\beta_i d^2_i` (one) :math:`> \\sum \\beta_i d^2_i` (two) :math:`+ \\lambda`, and the two are never
    seen in one frame... by construction, or if they are (a landmark seen twice in one frame), all the more.
    Returns ``(labels, splits)``."""
    labels = labels.copy()
    xs = sighting_poses(log, poses)
    splits = 0
    for j in range(int(labels.max(initial=-1)) + 1):
        i = np.flatnonzero(labels == j)
        if len(i) < 4:
            continue
        _, _, d2_one = fit_landmark(xs[i], log.stream.z[i], log.Rinv[i])
        side = two_clusters(xs[i], log.stream.z[i], log.Rinv[i])
        if side.sum() < 2 or (~side).sum() < 2:
            continue
        _, _, d2_a = fit_landmark(xs[i[~side]], log.stream.z[i[~side]], log.Rinv[i[~side]])
        _, _, d2_b = fit_landmark(xs[i[side]], log.stream.z[i[side]], log.Rinv[i[side]])
        one = np.sum(beta[i] * np.minimum(d2_one, settings.gate))
        two = np.sum(beta[i[~side]] * np.minimum(d2_a, settings.gate)) \
            + np.sum(beta[i[side]] * np.minimum(d2_b, settings.gate))
        if two + settings.penalty < one:
            labels[i[side]] = labels.max() + 1
            splits += 1
    return labels, splits


def merge_moves(log: _Log, poses, labels, landmarks, cov, beta, settings: SmootherAssociationParams):
    """Merge landmarks ``a, b`` never seen in one frame whose positions agree within their covariances
    (:math:`(l_a - l_b)^\\top (\\Sigma_a + \\Sigma_b)^{-1} (l_a - l_b) \\le g`) when one landmark fits the sightings of
    both for less than the penalty :math:`\\lambda` it saves. Nearest pairs first. Returns ``(labels, merges)``."""
    labels = labels.copy()
    xs = sighting_poses(log, poses)
    N = len(landmarks)
    ok = np.isfinite(landmarks).all(axis=1)
    pairs = []
    for a in range(N):
        for b in range(a + 1, N):
            if ok[a] and ok[b]:
                e = landmarks[a] - landmarks[b]
                d2 = e @ np.linalg.solve(cov[a] + cov[b], e)
                if d2 <= settings.gate:
                    pairs.append((d2, a, b))
    merged, gone = 0, set()
    frames = {j: _frames_of(log, labels, j) for j in {a for _, a, _ in pairs} | {b for _, _, b in pairs}}
    for _, a, b in sorted(pairs):
        if a in gone or b in gone or frames[a] & frames[b]:
            continue
        i = np.flatnonzero((labels == a) | (labels == b))
        _, _, d2_one = fit_landmark(xs[i], log.stream.z[i], log.Rinv[i])
        ia, ib = np.flatnonzero(labels == a), np.flatnonzero(labels == b)
        two = sum(np.sum(beta[k] * np.minimum(fit_landmark(xs[k], log.stream.z[k], log.Rinv[k])[2], settings.gate))
                  for k in (ia, ib))
        one = np.sum(beta[i] * np.minimum(d2_one, settings.gate))
        if one < two + settings.penalty:
            labels[ib] = a
            frames[a] |= frames[b]
            gone.add(b)
            merged += 1
    return labels, merged


def existence_log_odds(log: _Log, poses, labels, landmarks) -> np.ndarray:
    """The log odds (N,) that each landmark is real rather than clutter, as the filter's negative evidence
    (:func:`fastslam_edu.landmark.association.existence_log_odds`, over the whole log and unclamped):
    :math:`n_{hit} \\log(p_D/p_F) + n_{miss} \\log((1-p_D)/(1-p_F))`, with :math:`n_{hit}` the camera frames that
    see it and :math:`n_{miss}` those that see something but not it while it is in view (within the field of view and
    the range of the filter's ``AssociationParams``, from the frame's pose). Another robot standing somewhere for a
    while is seen there, and then missed whenever the camera looks there again."""
    fov, r_min, r_max, log_hit, log_miss = log.camera
    steps = np.flatnonzero(np.diff(log.stream.offsets))  # the camera frames (steps with sightings)
    x = poses[np.searchsorted(log.keys, steps)]
    N = len(landmarks)
    placed = np.isfinite(landmarks).all(axis=1)  # a landmark without a sighting used is nowhere: never in view
    landmarks = np.where(placed[:, None], landmarks, 1e6)
    z_hat = range_bearing(np.broadcast_to(x[:, None], (len(x), N, 3)), np.broadcast_to(landmarks[None], (len(x), N, 2)))
    view = placed[None] & (z_hat[..., 0] >= r_min) & (z_hat[..., 0] <= r_max) & (np.abs(z_hat[..., 1]) <= fov)
    seen = np.zeros((len(steps), N), dtype=bool)
    ok = labels >= 0
    seen[np.searchsorted(steps, log.frame[ok]), labels[ok]] = True
    return seen.sum(axis=0) * log_hit + (view & ~seen).sum(axis=0) * log_miss


def prune_landmarks(log: _Log, poses, labels, landmarks, d2, beta, settings: SmootherAssociationParams):
    """Landmarks whose sightings, left out, cost less than the landmark, :math:`\\sum_i \\beta_i (g - d^2_i) \\le
    \\lambda`, or whose existence log odds (:func:`existence_log_odds`) are not positive: their sightings become
    outliers. Returns ``(labels, pruned)``."""
    labels = labels.copy()
    odds = existence_log_odds(log, poses, labels, landmarks)
    pruned = 0
    for j in range(int(labels.max(initial=-1)) + 1):
        i = np.flatnonzero(labels == j)
        support = np.sum(beta[i] * (settings.gate - np.minimum(d2[i], settings.gate)))
        if len(i) and (support <= settings.penalty or not odds[j] > 0):
            labels[i] = OUTLIER
            pruned += 1
    return labels, pruned


# --------------------------------------------------------------------------- loop closures between groups


def maximum_clique(adjacent: np.ndarray) -> list[int]:
    """The largest set of vertices all pairwise adjacent (``adjacent`` (V, V) bool, symmetric): Bron–Kerbosch with
    pivoting. Exponential in the worst case; the candidate graphs here have tens of vertices."""
    V = len(adjacent)
    neighbours = [set(np.flatnonzero(adjacent[v]).tolist()) - {v} for v in range(V)]
    best: list[int] = []

    def expand(clique, candidates, excluded):
        nonlocal best
        if not candidates and not excluded:
            if len(clique) > len(best):
                best = list(clique)
            return
        if len(clique) + len(candidates) <= len(best):
            return
        pivot = max(candidates | excluded, key=lambda u: len(neighbours[u] & candidates))
        for v in sorted(candidates - neighbours[pivot]):
            expand(clique + [v], candidates & neighbours[v], excluded & neighbours[v])
            candidates = candidates - {v}
            excluded = excluded | {v}

    expand([], set(range(V)), set())
    return sorted(best)


def loop_candidates(log: _Log, labels, landmarks, cov, settings: SmootherAssociationParams) -> list[tuple[int, int]]:
    """Pairs ``(a, b)`` of landmarks never seen in one frame, too far apart to be merged by :func:`merge_moves`
    (:math:`d^2 > g`) but within the drift the odometry allows between the two visits: the motion noise's
    :math:`\\sigma_v^2 \\Delta t` on each coordinate, :math:`\\Delta t` [s] the time between the last sighting of the
    older and the first of the newer, plus the landmarks' own covariances, at :math:`\\sqrt g` standard deviations."""
    noise = log.params.motion_noise
    rate = noise.sigma_v ** 2 if noise.mode == "control" else noise.sigma_xy ** 2  # [m²/s]
    t = log.stream.t[log.frame]
    N = len(landmarks)
    first = np.array([t[labels == j].min() if np.any(labels == j) else np.inf for j in range(N)])
    last = np.array([t[labels == j].max() if np.any(labels == j) else -np.inf for j in range(N)])
    frames = [_frames_of(log, labels, j) for j in range(N)]
    out = []
    for a in range(N):
        for b in range(N):
            if a == b or not first[a] <= first[b] or not np.isfinite(landmarks[[a, b]]).all():
                continue
            if first[a] == first[b] and a > b:
                continue
            e = landmarks[a] - landmarks[b]
            C = cov[a] + cov[b]
            if e @ np.linalg.solve(C, e) <= settings.gate or frames[a] & frames[b]:
                continue
            drift = rate * max(first[b] - last[a], 0.0) * 2.0 + np.trace(C)
            if e @ e <= settings.gate * drift:
                out.append((a, b))
    return out


def consistent_pairs(pairs, landmarks, cov, settings: SmootherAssociationParams) -> np.ndarray:
    """The consistency graph (P, P) of candidate pairs: ``(a, b)`` and ``(c, e)`` (four distinct landmarks) agree
    when :math:`(\\|l_a - l_c\\| - \\|l_b - l_e\\|)^2 \\le \\chi^2_1(p)\\,\\sigma^2`, :math:`\\sigma^2` half the trace of the
    four landmarks' covariances summed (the variance of a distance, to first order, for round covariances)."""
    k = float(chi2.ppf(settings.loop_probability, 1))
    P = len(pairs)
    adjacent = np.zeros((P, P), dtype=bool)
    for p in range(P):
        a, b = pairs[p]
        for q in range(p + 1, P):
            c, e = pairs[q]
            if len({a, b, c, e}) < 4:
                continue
            diff = np.linalg.norm(landmarks[a] - landmarks[c]) - np.linalg.norm(landmarks[b] - landmarks[e])
            var = 0.5 * np.trace(cov[a] + cov[b] + cov[c] + cov[e])
            adjacent[p, q] = adjacent[q, p] = diff * diff <= k * var
    return adjacent


def loop_closures(log: _Log, labels, landmarks, cov, settings: SmootherAssociationParams):
    """A group of landmark pairs to merge at once: the maximum clique of the consistency graph of the loop
    candidates (:func:`loop_candidates`, :func:`consistent_pairs`), if it holds at least ``min_loop_landmarks``
    pairs; else none. Returns the merged labels, or None."""
    pairs = loop_candidates(log, labels, landmarks, cov, settings)
    if len(pairs) < settings.min_loop_landmarks:
        return None
    clique = maximum_clique(consistent_pairs(pairs, landmarks, cov, settings))
    if len(clique) < settings.min_loop_landmarks:
        return None
    labels = labels.copy()
    for p in clique:
        a, b = pairs[p]
        labels[labels == b] = a
    return labels


# --------------------------------------------------------------------------- the loop


@dataclass
class _State:
    poses: np.ndarray
    landmarks: np.ndarray
    cov: np.ndarray
    labels: np.ndarray
    cost: float = math.inf
    rounds: int = 0
    loops: int = 0
    motion: float = math.nan  # the path's part of the cost


def _settle(log: _Log, poses, labels, landmarks, settings) -> _State:
    """(b) then (c) once from ``labels``: solve, prune, split, merge, fit; the state and its cost, the path's
    (prior and odometry, :math:`\\sum \\|e\\|^2_C`) plus the penalised cost of the sightings (:func:`penalised_cost`)."""
    labels, used = compact(labels)
    poses, lms, labels, motion = solve_labelled(log, labels, poses, np.asarray(landmarks)[used], settings)
    beta = tempering_of(log, labels)
    lms, cov, d2 = fit_map(log, poses, labels, len(lms), start=lms)
    labels, _ = prune_landmarks(log, poses, labels, lms, d2, beta, settings)
    labels, _ = split_moves(log, poses, labels, beta, settings)
    labels, _ = compact(labels)
    lms, cov, d2 = fit_map(log, poses, labels, int(labels.max(initial=-1)) + 1)
    beta = tempering_of(log, labels)
    labels, _ = merge_moves(log, poses, labels, lms, cov, beta, settings)
    labels, _ = compact(labels)
    N = int(labels.max(initial=-1)) + 1
    lms, cov, d2 = fit_map(log, poses, labels, N)
    beta = tempering_of(log, labels)
    return _State(poses, lms, cov, labels, motion + penalised_cost(d2, beta, labels, N, settings), motion=motion)


def alternate(log: _Log, poses, labels, landmarks, settings: SmootherAssociationParams) -> _State:
    """Rounds of (a) assignment, (b) least squares, (c) split / merge / prune until the labels stop changing or the
    cost stops falling (at most ``max_rounds``); then loop closures (:func:`loop_closures`), kept only if the cost
    falls, and rounds again."""
    state = _settle(log, poses, labels, landmarks, settings)
    rounds = 1
    while True:
        while rounds < settings.max_rounds:
            labels, lms, cov = assign_sightings(log, state.poses, state.landmarks, state.cov, settings)
            if np.array_equal(compact(labels)[0], state.labels):
                break
            new = _settle(log, state.poses, labels, lms, settings)
            rounds += 1
            if not new.cost < state.cost:
                break
            new.loops = state.loops
            state = new
        closed = loop_closures(log, state.labels, state.landmarks, state.cov, settings)
        if closed is None:
            break
        trial = _settle(log, state.poses, closed, state.landmarks, settings)
        rounds += 1
        if not trial.cost < state.cost:
            break
        trial.loops = state.loops + 1
        state = trial
    state.rounds = rounds
    return state


def poses_between(steps, key_steps, key_poses, path) -> np.ndarray:
    """Poses (S, 3) at stream ``steps``: the last of ``key_poses`` (at ``key_steps``) at or before each, moved on by
    the dead-reckoned motion since, :math:`x_k \\oplus (\\hat x_k^{-1} \\oplus \\hat x_s)` (``path``: dead reckoning
    at every step)."""
    at = np.clip(np.searchsorted(key_steps, steps, side="right") - 1, 0, len(key_steps) - 1)
    return compose(key_poses[at], relative(path[key_steps[at]], path[steps]))


def drift_covariance(log: _Log, solved_until: float) -> np.ndarray:
    """The covariance (n, 3, 3) of each sighting's pose when it is dead-reckoned from the last pose solved, at
    ``solved_until`` [s]: :math:`\\mathrm{diag}(\\sigma_v^2, \\sigma_v^2, \\sigma_\\omega^2)\\,\\Delta t`, the motion
    noise's densities over the :math:`\\Delta t` since (zero for the poses solved)."""
    noise = log.params.motion_noise
    density = (np.array([noise.sigma_v ** 2, noise.sigma_v ** 2, noise.sigma_omega ** 2]) if noise.mode == "control"
               else np.array([noise.sigma_xy ** 2, noise.sigma_xy ** 2, noise.sigma_theta ** 2]))
    dt = np.maximum(log.stream.t[log.frame] - solved_until, 0.0)
    return dt[:, None, None] * np.diag(density)[None]


def truncated(stream: EventStream, n_steps: int) -> EventStream:
    """The first ``n_steps`` steps of ``stream`` and their sightings."""
    n = int(stream.offsets[n_steps])
    return dataclasses.replace(stream, t=stream.t[:n_steps], dt=stream.dt[:n_steps], u=stream.u[:n_steps],
                               offsets=stream.offsets[:n_steps + 1], z=stream.z[:n], landmark=stream.landmark[:n])


def grown_start(log: _Log, settings: SmootherAssociationParams, sensor=None):
    """A start that never lets the path drift far: the log solved in growing prefixes, ``window_s`` seconds more
    each time; each prefix's new stretch is dead-reckoned from the last solved pose, every sighting of the prefix
    assigned (:func:`assign_sightings`) to the map so far, and the prefix solved ((b), (c): :func:`_settle`).
    Returns ``(poses (N_k, 3), labels (n,), landmarks (N, 2))`` for the whole log. (A filter that lost its way —
    MR.CLAM Dataset 6 robot 1, seed 0: its path 1.8 m off groundtruth after alignment — gives the smoother nothing
    to start from; this start does not depend on it.)"""
    stream, t = log.stream, log.stream.t
    key_steps, key_poses = log.keys[:1], log.path[log.keys[:1]]
    landmarks, cov = np.zeros((0, 2)), np.zeros((0, 2, 2))
    for end in np.arange(t[0] + settings.window_s, t[-1] + settings.window_s, settings.window_s):
        n_steps = max(int(np.searchsorted(t, end, side="right")), 2)
        sub = _prepare(truncated(stream, n_steps), log.params, log.x0, sensor)
        poses = poses_between(sub.keys, key_steps, key_poses, log.path)
        drift = drift_covariance(sub, stream.t[key_steps[-1]]) if len(key_steps) > 1 else None
        labels, lms, c = assign_sightings(sub, poses, landmarks, cov, settings, drift)
        state = _settle(sub, poses, labels, lms, settings)
        key_steps, key_poses = sub.keys, state.poses
        landmarks, cov = state.landmarks, state.cov
        keep = np.isfinite(landmarks).all(axis=1)
        landmarks, cov = landmarks[keep], cov[keep]
    poses = poses_between(log.keys, key_steps, key_poses, log.path)
    labels, landmarks, _ = assign_sightings(log, poses, landmarks, cov, settings,
                                            drift_covariance(log, stream.t[key_steps[-1]]))
    return poses, labels, landmarks


def starts_from_filter(log: _Log, result, n: int):
    """Up to ``n`` starts ``(poses (N_k, 3), labels (n,) or None, landmarks (N, 2))`` from a run of
    :func:`fastslam_edu.landmark.association.run_unknown`: its best particle (the filter's mean path, its final map,
    and its history as the first correspondences), then the next-heaviest particles whose maps differ (their
    confirmed landmarks; the correspondences from step (a))."""
    poses = np.array(result.pose_mean, dtype=float)[log.keys]
    ident = np.asarray(result.landmark_ident)
    slot = {int(i): k for k, i in enumerate(ident.tolist())}
    labels = np.array([slot.get(int(h), OUTLIER) for h in np.asarray(result.history).tolist()], dtype=np.int64)
    starts = [(poses, labels, np.asarray(result.landmarks, dtype=float)), "grown"]
    P = result.particles
    confirm = result.params.n_confirm
    order = np.argsort(-P.logw, kind="stable")
    maps = []
    for m in order.tolist():
        if len(starts) >= n:
            break
        k = np.arange(P.n[m])
        keep = k[P.evidence[m, k] >= confirm]
        key = tuple(np.round(P.mu[m, keep], 3).ravel().tolist())
        if key in maps or len(keep) == 0:
            continue
        maps.append(key)
        if m == order[0]:
            continue  # the best particle's map: the first start already
        if len(starts) >= n:
            break
        starts.append((poses, None, P.mu[m, keep].copy()))
    return starts


def smooth_association(stream: EventStream, filter_result, params: FastSLAMParams | None = None,
                       settings: SmootherAssociationParams = SmootherAssociationParams(), *, x0=None
                       ) -> SmootherAssociationResult:
    """The associations, path and map re-decided with the whole log (module docstring), from the filter's run
    ``filter_result`` (:class:`~fastslam_edu.landmark.association.AssociationResult`) on the same anonymous
    ``stream`` (``stream.landmark`` is never read). ``params``: the noise model (default: the filter's,
    ``filter_result.params.filter``). Deterministic: no random step."""
    started = time.perf_counter()
    if len(filter_result.t) != len(stream):
        raise ValueError(f"smooth_association: the filter ran {len(filter_result.t)} steps but the stream has "
                         f"{len(stream)}: run the filter on the same stream")
    params = filter_result.params.filter if params is None else params
    log = _prepare(stream, params, x0, filter_result.params)
    best, costs = None, []
    for start in starts_from_filter(log, filter_result, settings.restarts):
        poses, labels, landmarks = grown_start(log, settings, filter_result.params) if start == "grown" else start
        if labels is None:
            cov = np.repeat(np.eye(2)[None] * 0.1, len(landmarks), axis=0)
            labels, landmarks, _ = assign_sightings(log, poses, landmarks, cov, settings)
        state = alternate(log, poses, labels, landmarks, settings)
        costs.append(state.cost)
        if best is None or state.cost < best.cost:
            best = state
    N = len(best.landmarks)
    steps = np.arange(len(stream))
    pose_mean = poses_between(steps, log.keys, best.poses, log.path)
    return SmootherAssociationResult(
        t=stream.t[log.keys], steps=log.keys, poses=best.poses, pose_mean=pose_mean, landmarks=best.landmarks,
        landmarks_cov=best.cov, landmark_ident=np.arange(N), landmark_seen=np.bincount(best.labels[best.labels >= 0],
                                                                                       minlength=N),
        history=best.labels, cost=best.cost, costs=costs, rounds=best.rounds, loop_closures=best.loops,
        outliers=int(np.sum(best.labels < 0)), seconds=time.perf_counter() - started)


__all__ = ["OUTLIER", "SmootherAssociationParams", "SmootherAssociationResult", "fit_landmark", "fit_map",
           "penalised_cost", "tempering_of", "mahalanobis_d2", "frame_costs", "assign_frame", "assign_sightings",
           "compact", "solve_labelled", "two_clusters", "split_moves", "merge_moves", "prune_landmarks",
           "maximum_clique", "loop_candidates", "consistent_pairs", "loop_closures", "alternate",
           "starts_from_filter", "smooth_association"]
