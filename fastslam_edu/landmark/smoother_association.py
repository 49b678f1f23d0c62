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
    ``ASSOCIATION_SOLVER``) with these correspondences; sightings its gate sets aside become outliers;
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
(:func:`fastslam_edu.landmark.evidence.tempering_exponents`): a landmark seen 3 times a second counts about one
sighting every :math:`\\tau` seconds, so another robot in view for a moment is not a landmark. Another robot that stood
somewhere for a while, then left, can be dropped from the final map (:func:`without_transients`,
``transient_objects``, off by default): it is seen only between its first and last sighting and missed whenever in
view before or after, which a static landmark explains worse than a *transient* object
(:func:`~fastslam_edu.landmark.smoother_association_moves.static_against_transient`, a likelihood ratio with the
BIC's charge for the transient's two extra parameters). Splitting one landmark into
two pays :math:`\\lambda` and wins when the two fit their sightings better by more; merging two saves it.

**Loop closures** (:func:`loop_closures`): two landmarks never seen in one frame and further apart than their
covariances allow (:math:`d^2 > g`) may still be one landmark mapped twice, after the path drifted between the two
visits; but so may two look-alike neighbours. A pair is a *candidate* within the drift the odometry allows between
the two visits; candidates :math:`(a, b)` and :math:`(c, e)` are *consistent* when the distances agree,
:math:`(\\|l_a - l_c\\| - \\|l_b - l_e\\|)^2 \\le \\chi^2_1(p)\\,\\sigma^2` (a rigid drift keeps distances); a group of
at least ``min_loop_landmarks`` (3) pairwise-consistent candidates — a maximum clique of the consistency graph
(:func:`maximum_clique`, Bron–Kerbosch) — is merged, the problem solved again, and the closure kept only if the
penalised cost falls.

**Restarts** (:func:`smooth_association`, :func:`starts_from_filter`): from the filter's best particle (its history
gives the first correspondences, its map and the filter's mean path the start); from the same path solved and every
sighting assigned again from an empty map, nearest frames first (:func:`reassigned_start`); and optionally from the
next-heaviest particles with distinct maps, from the log solved in growing prefixes (:func:`grown_start`), and,
once, from the log walked in time order with the map held fixed while each frame localises against it
(:func:`incremental_start`, ``incremental_start``: no filter's path to inherit). The solution with the lowest final
penalised cost is kept (``restarts``, ``grown_start``, ``incremental_start``).

**Step (b) is most of the time**: its linear steps eliminate the map first
(:mod:`fastslam_edu.landmark.smoother_association_solve`, the same solution as the smoother's sparse LU).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.measurement import (innovation, innovation_unchecked, jacobian_landmark,
                                           jacobian_landmark_unchecked, jacobian_pose, landmark_from_measurement,
                                           range_bearing, range_bearing_unchecked)
from fastslam_edu.core.se2 import compose, relative
from fastslam_edu.datasets.log import EventStream
from fastslam_edu.landmark.fastslam import FastSLAMParams
from fastslam_edu.landmark.smoother import PRIOR_STD, build_problem, solve_with_gate
from fastslam_edu.landmark.smoother_association_model import (INFEASIBLE, OUTLIER, SightingLog,
                                                              SmootherAssociationParams, SmootherAssociationResult,
                                                              compact, fit_landmark, fit_map, penalised_cost,
                                                              prepare_log, sighting_poses, tempering_of)
from fastslam_edu.landmark.smoother_association_solve import levenberg_marquardt_schur
from fastslam_edu.landmark.smoother_association_moves import (consistent_pairs, loop_candidates,
                                                              loop_closures, maximum_clique, merge_moves,
                                                              prune_landmarks, split_moves, transient_outliers,
                                                              two_clusters)


# --------------------------------------------------------------------------- (a) assignment, jointly per frame


def mahalanobis_d2(x, z, R, landmarks, cov, pose_cov=None):
    """:math:`d^2_{ij} = \\nu^\\top (R_i + H \\Sigma_j H^\\top + H_x P_i H_x^\\top)^{-1} \\nu` of sightings ``z`` (s, 2)
    from poses ``x`` (s, 3) (noise ``R`` (s, 2, 2), pose covariance ``pose_cov`` (s, 3, 3) or None: the pose is
    taken as known) against landmarks (N, 2) with covariances (N, 2, 2): shape (s, N)."""
    s, N = len(z), len(landmarks)
    if N == 0:
        return np.zeros((s, 0))
    X, L = x[:, None, :], landmarks[None]  # (s, 1, 3) against (1, N, 2)
    nu = innovation_unchecked(z[:, None, :], range_bearing_unchecked(X, L))
    H = jacobian_landmark_unchecked(X, L)
    Q = R[:, None] + H @ cov[None] @ np.swapaxes(H, 2, 3)
    if pose_cov is not None:
        Hx = jacobian_pose(np.broadcast_to(X, (s, N, 3)), np.broadcast_to(L, (s, N, 2)))
        Q = Q + Hx @ pose_cov[:, None] @ np.swapaxes(Hx, 2, 3)
    a, b = nu[..., 0], nu[..., 1]  # nu^T Q^-1 nu with the 2 x 2 inverse in closed form
    det = Q[..., 0, 0] * Q[..., 1, 1] - Q[..., 0, 1] * Q[..., 1, 0]
    return (Q[..., 1, 1] * a * a - (Q[..., 0, 1] + Q[..., 1, 0]) * a * b + Q[..., 0, 0] * b * b) / det


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


def frame_order(log: SightingLog) -> np.ndarray:
    """The camera frames (steps with sightings), nearest first: by their shortest range, ties in time order. New
    landmarks are then started from the sightings that place them best (the range's σ grows with the range), and a
    far sighting, which cannot tell two landmarks 0.2 m apart, is decided against landmarks already placed by near
    ones, as the oracle decides it against the surveyed map."""
    steps = np.flatnonzero(np.diff(log.stream.offsets))
    nearest = np.minimum.reduceat(log.stream.z[:, 0], log.stream.offsets[steps])
    return steps[np.lexsort((steps, nearest))]


def assign_sightings(log: SightingLog, poses, landmarks, cov, settings: SmootherAssociationParams, pose_cov=None):
    """Step (a): every frame, nearest first (:func:`frame_order`), against the map ``landmarks`` (N, 2), ``cov``
    (N, 2, 2) at the path ``poses`` (:func:`assign_frame`). A sighting that starts a landmark puts it at its inverse
    measurement with covariance :math:`G R G^\\top`; later sightings given to it update it by the EKF at their fixed
    pose.

    ``pose_cov`` (n, 3, 3): the uncertainty of each sighting's pose (:func:`dead_reckoned_pose_covariance`; None:
    none).
    Returns ``(labels (n,), landmarks (N', 2), cov (N', 2, 2))``, N' >= N.
    """
    old_l, old_c = np.asarray(landmarks, dtype=float).reshape(-1, 2), np.asarray(cov, dtype=float).reshape(-1, 2, 2)
    n_old = len(old_l)
    xs = sighting_poses(log, poses)
    z = log.stream.z
    new_l, new_c, n_new = np.empty((len(z), 2)), np.empty((len(z), 2, 2)), 0  # the landmarks this pass starts
    labels = np.full(len(z), OUTLIER, dtype=np.int64)
    d2_old = mahalanobis_d2(xs, z, log.R, old_l, old_c, pose_cov)
    gate, penalty = settings.gate, settings.penalty
    for k in frame_order(log):
        a, b = log.stream.offsets[k], log.stream.offsets[k + 1]
        d2 = d2_old[a:b]
        if n_new:
            fresh = mahalanobis_d2(xs[a:b], z[a:b], log.R[a:b], new_l[:n_new], new_c[:n_new],
                                   None if pose_cov is None else pose_cov[a:b])
            d2 = np.concatenate([d2, fresh], axis=1)
        chosen = assign_frame(d2, gate, penalty)
        for i, j in zip(range(a, b), chosen.tolist()):
            if j == d2.shape[1]:  # a new landmark, at this sighting
                l = landmark_from_measurement(xs[i], z[i])
                G = np.linalg.inv(jacobian_landmark(xs[i][None], l[None])[0])
                new_l[n_new], new_c[n_new] = l, G @ log.R[i] @ G.T
                n_new += 1
                labels[i] = n_old + n_new - 1
            elif 0 <= j:
                labels[i] = j
                if j >= n_old:  # a landmark of this pass: EKF update at the fixed pose
                    new_l[j - n_old], new_c[j - n_old] = _ekf(xs[i], z[i], log.R[i], new_l[j - n_old], new_c[j - n_old])
    return labels, np.concatenate([old_l, new_l[:n_new]]), np.concatenate([old_c, new_c[:n_new]])


def _ekf(x, z, R, l, P):
    """One EKF update of landmark ``l`` (2,), covariance ``P`` by sighting ``z`` from the fixed pose ``x``."""
    H = jacobian_landmark_unchecked(x, l)
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    nu = innovation_unchecked(z, range_bearing_unchecked(x, l))
    return l + K @ nu, (np.eye(2) - K @ H) @ P


# --------------------------------------------------------------------------- (b) least squares


def solve_labelled(log: SightingLog, labels, poses, landmarks, settings: SmootherAssociationParams):
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
    v, active, _, _, _ = solve_with_gate(problem, v, log.params.gate_chi2, settings.solver,
                                         minimise=levenberg_marquardt_schur)
    r, _, rows = problem.evaluate(v, active)
    motion = r[:rows.start]  # the prior's and the odometry's rows come first
    new_poses, lms = problem.split(v)
    landmarks = np.full((len(landmarks), 2), np.nan)
    landmarks[seen] = lms
    labels = labels.copy()
    labels[np.flatnonzero(keep)[use][~active]] = OUTLIER
    return new_poses.copy(), landmarks, labels, float(motion @ motion)


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


def _settle(log: SightingLog, poses, labels, landmarks, settings) -> _State:
    """(b) then (c) once from ``labels``: solve, prune, split, merge, fit; the state and its cost, the path's
    (prior and odometry, :math:`\\sum \\|e\\|^2_C`) plus the penalised cost of the sightings
    (:func:`penalised_cost`)."""
    labels, used = compact(labels)
    poses, lms, labels, motion = solve_labelled(log, labels, poses, np.asarray(landmarks)[used], settings)
    beta = tempering_of(log, labels)
    lms, cov, d2 = fit_map(log, poses, labels, len(lms), start=lms)
    labels, _ = prune_landmarks(log, poses, labels, lms, d2, beta, settings=settings)
    labels, _ = split_moves(log, poses, labels, beta, settings)
    labels, _ = compact(labels)
    lms, cov, d2 = fit_map(log, poses, labels, int(labels.max(initial=-1)) + 1)
    beta = tempering_of(log, labels)
    labels, _ = merge_moves(log, poses, labels, lms, cov, beta, settings=settings)
    labels, _ = compact(labels)
    N = int(labels.max(initial=-1)) + 1
    lms, cov, d2 = fit_map(log, poses, labels, N)
    beta = tempering_of(log, labels)
    return _State(poses, lms, cov, labels, motion + penalised_cost(d2, beta, labels, N, settings), motion=motion)


def alternate(log: SightingLog, poses, labels, landmarks, settings: SmootherAssociationParams) -> _State:
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


def dead_reckoned_pose_covariance(log: SightingLog, solved_until: float) -> np.ndarray:
    """The covariance (n, 3, 3) of each sighting's pose when it is dead-reckoned from the last pose solved, at
    ``solved_until`` [s]: :math:`\\mathrm{diag}(\\sigma_v^2, \\sigma_v^2, \\sigma_\\omega^2)\\,\\Delta t`, the motion
    noise's densities over the :math:`\\Delta t` since (zero for the poses solved)."""
    dt = np.maximum(log.stream.t[log.frame] - solved_until, 0.0)
    return dt[:, None, None] * motion_density(log)[None]


def truncated(stream: EventStream, n_steps: int) -> EventStream:
    """The first ``n_steps`` steps of ``stream`` and their sightings."""
    n = int(stream.offsets[n_steps])
    return dataclasses.replace(stream, t=stream.t[:n_steps], dt=stream.dt[:n_steps], u=stream.u[:n_steps],
                               offsets=stream.offsets[:n_steps + 1], z=stream.z[:n], landmark=stream.landmark[:n])


def grown_start(log: SightingLog, settings: SmootherAssociationParams, sensor=None):
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
        sub = prepare_log(truncated(stream, n_steps), log.params, log.x0, sensor)
        poses = poses_between(sub.keys, key_steps, key_poses, log.path)
        drift = dead_reckoned_pose_covariance(sub, stream.t[key_steps[-1]]) if len(key_steps) > 1 else None
        labels, lms, c = assign_sightings(sub, poses, landmarks, cov, settings, drift)
        state = _settle(sub, poses, labels, lms, settings)
        key_steps, key_poses = sub.keys, state.poses
        landmarks, cov = state.landmarks, state.cov
        keep = np.isfinite(landmarks).all(axis=1)
        landmarks, cov = landmarks[keep], cov[keep]
    poses = poses_between(log.keys, key_steps, key_poses, log.path)
    labels, landmarks, _ = assign_sightings(log, poses, landmarks, cov, settings,
                                            dead_reckoned_pose_covariance(log, stream.t[key_steps[-1]]))
    return poses, labels, landmarks


# --------------------------------------------------------------------------- the incremental start


def motion_density(log: SightingLog) -> np.ndarray:
    """:math:`Q_c = \\mathrm{diag}(\\sigma_v^2, \\sigma_v^2, \\sigma_\\omega^2)` (3, 3): the motion noise's densities
    [m²/s, m²/s, rad²/s] (``sigma_xy``, ``sigma_theta`` in the odometry mode), as in
    :func:`dead_reckoned_pose_covariance` scales them by the time since the last pose solved."""
    noise = log.params.motion_noise
    density = (np.array([noise.sigma_v ** 2, noise.sigma_v ** 2, noise.sigma_omega ** 2]) if noise.mode == "control"
               else np.array([noise.sigma_xy ** 2, noise.sigma_xy ** 2, noise.sigma_theta ** 2]))
    return np.diag(density)


def predict_pose(x, P, u, Q):
    """The pose moved by the dead-reckoned motion ``u`` (3,) (in the frame of ``x``), :math:`x' = x \\oplus u`, and
    its covariance :math:`P' = F P F^\\top + Q` with :math:`F = \\partial x' / \\partial x` (a heading error turns
    into a position error along the way travelled). ``x`` (3,), ``P``, ``Q`` (3, 3)."""
    c, s = math.cos(x[2]), math.sin(x[2])
    F = np.array([[1.0, 0.0, -s * u[0] - c * u[1]], [0.0, 1.0, c * u[0] - s * u[1]], [0.0, 0.0, 1.0]])
    return compose(x, u), F @ P @ F.T + Q


def localise(x, P, z, R, landmarks, cov):
    """One EKF update of the pose ``x`` (3,), ``P`` (3, 3) by sightings ``z`` (m, 2) (noise ``R`` (m, 2, 2)) of the
    landmarks ``landmarks`` (m, 2), held fixed with their covariances ``cov`` (m, 2, 2):

    .. math::

        S = H_x P H_x^\\top + \\mathrm{blockdiag}(R_i + H_{l,i} \\Sigma_i H_{l,i}^\\top), \\quad
        K = P H_x^\\top S^{-1}, \\quad x \\leftarrow x + K\\nu, \\quad P \\leftarrow (I - K H_x) P.

    Returns ``(x, P)``."""
    m = len(z)
    X = np.broadcast_to(x, (m, 3))
    Hx = jacobian_pose(X, landmarks).reshape(2 * m, 3)
    Hl = jacobian_landmark(X, landmarks)
    nu = innovation(z, range_bearing(X, landmarks)).ravel()
    S = Hx @ P @ Hx.T
    for i in range(m):
        S[2 * i:2 * i + 2, 2 * i:2 * i + 2] += R[i] + Hl[i] @ cov[i] @ Hl[i].T
    K = P @ Hx.T @ np.linalg.inv(S)
    P = (np.eye(3) - K @ Hx) @ P
    return x + K @ nu, 0.5 * (P + P.T)


def _map_frame(x, P, z, R, chosen, lms: list, cov: list) -> np.ndarray:
    """After :func:`localise`: each of the frame's sightings given to a landmark updates it (EKF at the pose ``x``,
    the pose's uncertainty ``P`` added to ``R``); one given "new" (``chosen == N``) starts one with covariance
    :math:`G_z R G_z^\\top + G_x P G_x^\\top`. ``lms``, ``cov`` grow in place; returns the frame's labels."""
    N = len(lms)
    labels = np.full(len(z), OUTLIER, dtype=np.int64)
    for i, j in enumerate(chosen.tolist()):
        if j == N:
            l = landmark_from_measurement(x[None], z[i][None])[0]
            Gz = np.linalg.inv(jacobian_landmark(x[None], l[None])[0])
            Gx = -Gz @ jacobian_pose(x[None], l[None])[0]
            lms.append(l)
            cov.append(Gz @ R[i] @ Gz.T + Gx @ P @ Gx.T)
            labels[i] = len(lms) - 1
        elif 0 <= j < N:
            Hx = jacobian_pose(x[None], lms[j][None])[0]
            lms[j], cov[j] = _ekf(x, z[i], R[i] + Hx @ P @ Hx.T, lms[j], cov[j])
            labels[i] = j
    return labels


def incremental_start(log: SightingLog, settings: SmootherAssociationParams):
    """A start that does not read the filter: the log walked once in time order, each camera frame (1) predicted
    from the last by dead reckoning (:func:`predict_pose`, the motion noise's densities times the time since),
    (2) assigned jointly (:func:`assign_frame`) against the map so far with the pose's covariance in :math:`d^2`,
    (3) localised against the landmarks it was given, the map held fixed (:func:`localise`), (4) mapped
    (:func:`_map_frame`). Single-hypothesis, so it can lose its way; it competes with the filter's starts by the
    final penalised cost. Returns ``(poses (N_k, 3), labels (n,), landmarks (N, 2))``."""
    stream, path, Q = log.stream, log.path, motion_density(log)
    labels = np.full(len(stream.z), OUTLIER, dtype=np.int64)
    lms, cov = [], []
    steps = np.flatnonzero(np.diff(stream.offsets))
    frame_pose = np.zeros((len(steps), 3))
    x, P, last = path[0].copy(), np.zeros((3, 3)), 0
    for f, k in enumerate(steps.tolist()):
        x, P = predict_pose(x, P, relative(path[last], path[k]), Q * (stream.t[k] - stream.t[last]))
        last = k
        a, b = stream.offsets[k], stream.offsets[k + 1]
        z, R = stream.z[a:b], log.R[a:b]
        L, C = np.array(lms).reshape(-1, 2), np.array(cov).reshape(-1, 2, 2)
        d2 = mahalanobis_d2(np.tile(x, (b - a, 1)), z, R, L, C, np.tile(P, (b - a, 1, 1)))
        chosen = assign_frame(d2, settings.gate, settings.penalty)
        old = np.flatnonzero((chosen >= 0) & (chosen < len(lms)))
        if len(old):
            x, P = localise(x, P, z[old], R[old], L[chosen[old]], C[chosen[old]])
        labels[a:b] = _map_frame(x, P, z, R, chosen, lms, cov)
        frame_pose[f] = x
    poses = poses_between(log.keys, steps, frame_pose, path) if len(steps) else path[log.keys]
    return poses, labels, np.array(lms).reshape(-1, 2)


def starts_from_filter(log: SightingLog, result, n: int, grown: bool = False):
    """Up to ``n`` starts from a run of :func:`fastslam_edu.landmark.association.run_unknown`, each
    ``(poses (N_k, 3), labels (n,) or None, landmarks (N, 2))`` or a name: its best particle (the filter's mean path,
    its final map, and its history as the first correspondences); ``"reassigned"``, the same path solved with the
    filter's correspondences and every sighting assigned again from an empty map, nearest frames first
    (:func:`reassigned_start`); ``"grown"`` if ``grown`` (:func:`grown_start`, slow on long logs); then the
    next-heaviest particles whose maps differ (their confirmed landmarks; the correspondences from step (a))."""
    poses = np.array(result.pose_mean, dtype=float)[log.keys]
    ident = np.asarray(result.landmark_ident)
    slot = {int(i): k for k, i in enumerate(ident.tolist())}
    labels = np.array([slot.get(int(h), OUTLIER) for h in np.asarray(result.history).tolist()], dtype=np.int64)
    starts = [(poses, labels, np.asarray(result.landmarks, dtype=float)), "reassigned"][:n]
    P = result.particles
    order = np.argsort(-P.logw, kind="stable")
    maps = set()
    for m in order.tolist():
        if len(starts) >= n:
            break
        k = np.arange(P.n[m])
        keep = k[P.evidence[m, k] >= result.params.n_confirm]
        key = tuple(np.round(P.mu[m, keep], 3).ravel().tolist())
        if key in maps or len(keep) == 0:
            continue
        maps.add(key)
        if m != order[0]:  # the best particle's map: the first start already
            starts.append((poses, None, P.mu[m, keep].copy()))
    return starts + (["grown"] if grown else [])


def reassigned_start(log: SightingLog, first, settings: SmootherAssociationParams):
    """The start ``"reassigned"``: the filter's path solved with its correspondences (step (b) from ``first``, the
    start of the best particle), then every sighting assigned again (step (a)) from an empty map, nearest frames first:
    a merge the filter made early, from far, is not inherited. Returns ``(poses, labels, landmarks)``."""
    poses, labels, landmarks = first
    labels, used = compact(labels)
    poses = solve_labelled(log, labels, poses, np.asarray(landmarks)[used], settings)[0]
    labels, landmarks, _ = assign_sightings(log, poses, np.zeros((0, 2)), np.zeros((0, 2, 2)), settings)
    return poses, labels, landmarks


def start_of(log: SightingLog, start, starts: list, settings: SmootherAssociationParams, sensor):
    """The ``(poses, labels, landmarks)`` of one entry of :func:`starts_from_filter` (``starts``: all of them)."""
    if isinstance(start, str):
        return reassigned_start(log, starts[0], settings) if start == "reassigned" else grown_start(log, settings,
                                                                                                 sensor)
    poses, labels, landmarks = start
    if labels is None:
        cov = np.repeat(np.eye(2)[None] * 0.1, len(landmarks), axis=0)
        labels, landmarks, _ = assign_sightings(log, poses, landmarks, cov, settings)
    return poses, labels, landmarks


def smooth_association(stream: EventStream, filter_result, params: FastSLAMParams | None = None,
                       settings: SmootherAssociationParams = SmootherAssociationParams(), *, x0=None
                       ) -> SmootherAssociationResult:
    """The associations, path and map re-decided with the whole log (module docstring), from the filter's run
    ``filter_result`` (:class:`~fastslam_edu.landmark.association.AssociationResult`) on the same anonymous
    ``stream`` (``stream.landmark`` is never read), or from several runs (a list: runs with different seeds; the
    starts of every run, :func:`starts_from_filter`, compete by their final cost). ``params``: the noise model
    (default: the first run's, ``params.filter``). Deterministic: no random step."""
    started = time.perf_counter()
    runs = list(filter_result) if isinstance(filter_result, (list, tuple)) else [filter_result]
    for run in runs:
        if len(run.t) != len(stream):
            raise ValueError(f"smooth_association: the filter ran {len(run.t)} steps but the stream has "
                             f"{len(stream)}: run the filter on the same stream")
    params = runs[0].params.filter if params is None else params
    log = prepare_log(stream, params, x0, runs[0].params)
    best, costs = None, []
    for run in runs:
        starts = starts_from_filter(log, run, settings.restarts, settings.grown_start)
        for start in starts:
            state = alternate(log, *start_of(log, start, starts, settings, run.params), settings)
            costs.append(state.cost)
            if best is None or state.cost < best.cost:
                best = state
    if settings.incremental_start:  # one start that does not depend on the runs
        state = alternate(log, *incremental_start(log, settings), settings)
        costs.append(state.cost)
        best = state if state.cost < best.cost else best
    if settings.transient_objects:
        best = without_transients(log, best, settings)
    return result_of(log, best, costs, time.perf_counter() - started)


def without_transients(log: SightingLog, state: _State, settings: SmootherAssociationParams) -> _State:
    """The solution ``state`` with every landmark more likely transient than static made outliers
    (:func:`~fastslam_edu.landmark.smoother_association_moves.transient_outliers`) and solved once more ((b), (c):
    :func:`_settle`); ``state`` itself if there is none."""
    labels = transient_outliers(log, state.poses, state.labels, state.landmarks)
    if np.array_equal(labels, state.labels):
        return state
    final = _settle(log, state.poses, labels, state.landmarks, settings)
    final.rounds, final.loops = state.rounds + 1, state.loops
    return final


def result_of(log: SightingLog, state: _State, costs: list, seconds: float) -> SmootherAssociationResult:
    """The :class:`SmootherAssociationResult` of a solution ``state`` of :func:`alternate` (``costs``: of every
    restart; ``seconds``: the wall time)."""
    N = len(state.landmarks)
    pose_mean = poses_between(np.arange(len(log.stream)), log.keys, state.poses, log.path)
    return SmootherAssociationResult(
        t=log.stream.t[log.keys], steps=log.keys, poses=state.poses, pose_mean=pose_mean, landmarks=state.landmarks,
        landmarks_cov=state.cov, landmark_ident=np.arange(N),
        landmark_seen=np.bincount(state.labels[state.labels >= 0], minlength=N), history=state.labels,
        cost=state.cost, costs=costs, rounds=state.rounds, loop_closures=state.loops,
        outliers=int(np.sum(state.labels < 0)), seconds=seconds)


__all__ = ["OUTLIER", "INFEASIBLE", "SightingLog", "prepare_log", "sighting_poses", "SmootherAssociationParams",
           "SmootherAssociationResult", "fit_landmark", "fit_map", "penalised_cost", "tempering_of", "mahalanobis_d2",
           "frame_costs", "assign_frame", "assign_sightings", "compact", "solve_labelled", "two_clusters",
           "split_moves", "merge_moves", "prune_landmarks", "maximum_clique", "loop_candidates",
           "consistent_pairs", "loop_closures", "alternate", "grown_start", "reassigned_start", "starts_from_filter",
           "motion_density", "predict_pose", "localise", "incremental_start", "smooth_association", "result_of",
           "without_transients"]
