"""Several robots in one least-squares problem: their paths, one shared map, and their sightings of each other.

MR.CLAM is a *multi-robot* dataset: five robots drive among the same landmarks, and each robot's camera also
reads the barcodes of the others (:func:`fastslam_edu.datasets.mrclam.robot_sightings`). The single-robot
smoother (:mod:`fastslam_edu.landmark.smoother`) solves one robot's log; here the robots :math:`a = 1 \\dots A`,
with keyframe poses :math:`x^a_0 \\dots x^a_{N_a}`, share the landmarks :math:`l_1 \\dots l_N` and minimise

.. math::

    \\sum_a \\Big[ \\tfrac12 \\|x^a_0 - \\bar x^a_0\\|^2_{P_0}
      + \\tfrac12 \\sum_k \\|(x^a_{k-1})^{-1} \\oplus x^a_k \\ominus \\Delta^a_k\\|^2_{C^a_k}
      + \\tfrac12 \\sum_i \\beta_i \\|z_i \\ominus h(x^a_{k_i}, l_{j_i})\\|^2_{R_i} \\Big]
    + \\tfrac12 \\sum_s \\beta_s \\|z_s \\ominus h(x^a(t_s), p^b(t_s))\\|^2_{R_s},

the first three terms exactly the single-robot smoother's for each robot (its prior on the first pose, its
odometry factors, its landmark sightings, built by :func:`~fastslam_edu.landmark.smoother.build_problem`), the last
one per **robot-robot sighting** :math:`s`: at time :math:`t_s` robot :math:`a` measures range and bearing
:math:`z_s = (r, \\varphi)` to the centre :math:`p^b = (x^b, y^b)` of robot :math:`b`, with the landmarks' model
:math:`h` and noise :math:`R` (:func:`~fastslam_edu.landmark.smoother_factors.sighting_residuals`).

**The poses at the sighting's instant.** A sighting time is rarely a keyframe of both robots. Rather than adding
keyframes (which would change each robot's problem), each robot's pose at :math:`t_s` is its last keyframe at or
before :math:`t_s` moved on by the dead-reckoned motion since:

.. math::

    x^a(t_s) = x^a_k \\oplus \\delta^a_s, \\qquad
    \\delta^a_s = (\\hat x^a_{k})^{-1} \\oplus \\hat x^a(t_s),

with :math:`\\hat x^a` the dead-reckoned path (:func:`~fastslam_edu.landmark.smoother_factors.dead_reckon_stream`,
linear between its steps). Keyframes are at most ``max_gap_s`` (1 s) apart, so :math:`\\delta` covers under a second of
odometry, whose noise (millimetres at MR.CLAM's motion noise) is left out of :math:`R_s`. The Jacobian of
:math:`x \\oplus \\delta` with respect to :math:`x` is
:math:`\\begin{pmatrix} I & (-(R\\delta)_y, (R\\delta)_x)^\\top \\\\ 0 & 1 \\end{pmatrix}`
(:func:`compose_jacobian`), so a sighting links keyframe :math:`k` of :math:`a` and keyframe :math:`j` of :math:`b`.

**Variable order.** All robots' keyframe poses sorted by time, then the landmarks: a sighting links two poses
close in time, so the poses' normal matrix stays banded and the factorisation in this order
(``smoother_laplace.ORDERING``) fills in only the band and the landmarks' border.

Gate, Huber round and tempering are the single-robot smoother's
(:func:`~fastslam_edu.landmark.smoother.solve_with_gate`): the robot sightings go through the same gate
(``params.gate_chi2``) and are counted apart (used / gated). Their tempering :math:`\\beta_s` treats each robot
seen as a landmark of its observer (:func:`~fastslam_edu.landmark.evidence.tempering_exponents`). The landmarks'
covariances are the Laplace approximation's, by the Schur complement of the poses (:func:`laplace_landmarks`).

One robot given, this is :func:`~fastslam_edu.landmark.smoother.smooth` (the same factors, in the same order).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from fastslam_edu.datasets.log import EventStream
from fastslam_edu.landmark.fastslam import FastSLAMParams
from fastslam_edu.landmark.smoother import (LANDMARK_ANCHOR_STD, PRIOR_STD, SmootherResult, SolverSettings,
                                            build_problem, solve_with_gate, starting_point)
from fastslam_edu.landmark.smoother_factors import (dead_reckon_stream, keyframe_steps, sighting_residuals,
                                                    odometry_residuals, whitening, wrap_pose_error)
from fastslam_edu.landmark.robot_sightings import (compose_jacobian, compose_unwrapped, keyframe_offsets,
                                                    robot_sighting_table, robot_sighting_weights)
from fastslam_edu.landmark.smoother_laplace import ORDERING

#: The robots' subject numbers in MR.CLAM.
ROBOTS = (1, 2, 3, 4, 5)


@dataclass
class MultiRobotResult:
    """The least-squares paths of several robots and their shared map.

    Attributes
    ----------
    robots : tuple of the robot numbers, in the order given
    t, steps, poses : dict robot → keyframe times (N_a,) [s], stream steps (N_a,), poses (N_a, 3) [m, m, rad]
    landmarks : (N, 2) the shared map [m] (NaN where no robot saw the landmark inside the gate)
    landmarks_cov : (N, 2, 2) Laplace covariances [m²]
    observed : (N,) bool
    landmark_subjects : (N,)
    iterations, rounds, cost : as :class:`~fastslam_edu.landmark.smoother.SmootherResult`
    measurements_used, measurements_rejected : landmark sightings inside / beyond the gate (all robots)
    measurements_zero_weight : landmark sightings with β = 0
    robot_sightings_used, robot_sightings_gated : robot-robot sightings inside / beyond the gate
    robot_sightings_skipped : robot-robot sightings left out: of a robot not solved, or outside the time span
        of either robot
    seconds : wall time
    notes : remarks for the reader (e.g. that there is no robot-robot sighting at all)
    backend : which solver ran, ``"scipy"`` (the package's) or ``"gtsam"`` (:mod:`.smoother_gtsam`)
    """

    robots: tuple
    t: dict
    steps: dict
    poses: dict
    landmarks: np.ndarray
    landmarks_cov: np.ndarray
    observed: np.ndarray
    landmark_subjects: np.ndarray
    iterations: int
    rounds: int
    cost: float
    measurements_used: int
    measurements_rejected: int
    measurements_zero_weight: int
    robot_sightings_used: int
    robot_sightings_gated: int
    robot_sightings_skipped: int
    seconds: float
    notes: list = field(default_factory=list)
    backend: str = "scipy"

    def robot(self, a: int) -> SmootherResult:
        """Robot ``a``'s path with the shared map, as a single-robot :class:`SmootherResult` (for scoring);
        counts and time are the whole problem's, the poses' σ are not computed (NaN)."""
        if a not in self.t:
            raise ValueError(f"robot {a} is not in this solution (robots {list(self.robots)})")
        return SmootherResult(
            t=self.t[a], steps=self.steps[a], poses=self.poses[a], pose_std=np.full(self.poses[a].shape, np.nan),
            landmarks=self.landmarks, landmarks_cov=self.landmarks_cov, observed=self.observed,
            landmark_subjects=self.landmark_subjects, iterations=self.iterations, rounds=self.rounds,
            cost=self.cost, measurements_used=self.measurements_used,
            measurements_rejected=self.measurements_rejected,
            measurements_zero_weight=self.measurements_zero_weight, seconds=self.seconds, backend=self.backend,
        )


# --------------------------------------------------------------------------- input checks


def check_robot_numbers(robots) -> tuple:
    """The robot numbers as a tuple of ints, each in ``ROBOTS`` (1–5) and none repeated; else one-line ValueError."""
    numbers = []
    for r in robots:
        if isinstance(r, bool) or not isinstance(r, (int, np.integer)) or int(r) not in ROBOTS:
            raise ValueError(f"robot {r!r} is not a MR.CLAM robot: robots are numbered {ROBOTS[0]}-{ROBOTS[-1]}")
        numbers.append(int(r))
    if not numbers:
        raise ValueError("no robot given")
    repeated = sorted({r for r in numbers if numbers.count(r) > 1})
    if repeated:
        raise ValueError(f"robot(s) {repeated} given more than once in {numbers}")
    return tuple(numbers)


def check_streams(streams: dict) -> None:
    """Same landmark table and overlapping time spans (else the logs are from different datasets); each stream with
    at least 2 steps and an initial pose. One-line ValueError naming the robot(s)."""
    robots = list(streams)
    first = streams[robots[0]]
    for a in robots:
        s = streams[a]
        if not isinstance(s, EventStream):
            raise ValueError(f"robot {a}: expected an EventStream, got {type(s).__name__}")
        if len(s) < 2:
            raise ValueError(f"robot {a}: the stream has {len(s)} step(s); at least 2 are needed")
        if s.x0 is None:
            raise ValueError(f"robot {a}: the stream has no initial pose (x0 is None): pass x0={{{a}: (x, y, theta)}}")
        if not np.array_equal(s.landmark_subjects, first.landmark_subjects):
            raise ValueError(f"robots {robots[0]} and {a} have different landmark tables "
                             f"({first.landmark_subjects.tolist()} vs {s.landmark_subjects.tolist()}): "
                             "robots from different datasets?")
    for a in robots[1:]:
        s = streams[a]
        if s.t[0] > first.t[-1] or first.t[0] > s.t[-1]:
            raise ValueError(f"robots {robots[0]} and {a} share no time: [{first.t[0]:.1f}, {first.t[-1]:.1f}] s "
                             f"vs [{s.t[0]:.1f}, {s.t[-1]:.1f}] s: robots from different datasets?")


def _per_robot(value, robots, name: str, default):
    """A setting given once for all robots, or as a dict robot → value."""
    if isinstance(value, dict):
        unknown = sorted(set(value) - set(robots))
        if unknown:
            raise ValueError(f"{name}: robot(s) {unknown} are not among the robots solved {list(robots)}")
        return {a: value.get(a, default) for a in robots}
    return {a: default if value is None else value for a in robots}


# --------------------------------------------------------------------------- the joint problem


@dataclass
class _JointProblem:
    """The factors of all robots, whitened, and the variable layout: the keyframe poses of every robot in time
    order (``slots``), then the landmarks. The same interface as the single-robot problem, so that
    :func:`~fastslam_edu.landmark.smoother.solve_with_gate` solves it."""

    n_poses: int
    prior_slot: np.ndarray  # (A,) the first keyframe of each robot
    x0: np.ndarray  # (A, 3)
    W0: np.ndarray  # (A, 3, 3)
    odo_a: np.ndarray  # (F,) slots of the odometry factors' first poses
    odo_b: np.ndarray  # (F,)
    delta: np.ndarray  # (F, 3)
    Wo: np.ndarray  # (F, 3, 3)
    z: np.ndarray  # (n_l + n_r, 2): the landmark sightings, then the robot-robot sightings
    n_landmark_sightings: int
    pose_of: np.ndarray  # (n_l,) slot of each landmark sighting
    col_of: np.ndarray  # (n_l,) landmark column
    ra: np.ndarray  # (n_r,) slot of the observer's keyframe
    rb: np.ndarray  # (n_r,) slot of the seen robot's keyframe
    da: np.ndarray  # (n_r, 3) dead-reckoned motion from that keyframe to the sighting's time
    db: np.ndarray  # (n_r, 3)
    Wm: np.ndarray  # (n_l + n_r, 2, 2) √β R^(-1/2)
    Wg: np.ndarray  # (n_l + n_r, 2, 2) R^(-1/2)
    anchor: np.ndarray | None = None
    n_extra: int = 0

    def split(self, v):
        return v[: 3 * self.n_poses].reshape(-1, 3), v[3 * self.n_poses:].reshape(-1, 2)

    def sighting_errors(self, poses, lms, which):
        """Residuals and Jacobians of the sightings ``which`` (bool, all sightings): landmark sightings
        ``(e, Jx, Jm)`` and robot-robot sightings ``(e, Ja, Jb)`` (Jacobians wrt the two keyframe poses, 2×3 each)."""
        n_l = self.n_landmark_sightings
        wl, wr = which[:n_l], which[n_l:]
        k, lm = self.pose_of[wl], self.col_of[wl]
        landmark = sighting_residuals(poses[k], lms[lm], self.z[:n_l][wl])
        xa, xb = poses[self.ra[wr]], poses[self.rb[wr]]
        ya, yb = compose_unwrapped(xa, self.da[wr]), compose_unwrapped(xb, self.db[wr])
        e, Jx, Jm = sighting_residuals(ya, yb[:, :2], self.z[n_l:][wr])
        Ja = Jx @ compose_jacobian(xa, self.da[wr])
        Jb = Jm @ compose_jacobian(xb, self.db[wr])[:, :2, :]
        return landmark, (e, Ja, Jb)

    def evaluate(self, v, active):
        """Whitened residuals and sparse Jacobian: priors, odometry, sightings (landmarks, then robots), anchors."""
        poses, lms = self.split(v)
        rows, cols, vals = [], [], []

        def block(row0, col0, J):  # J (B, p, q) at rows row0[b] + i, cols col0[b] + j
            p, q = J.shape[1:]
            rows.append(np.broadcast_to(row0[:, None, None] + np.arange(p)[None, :, None], J.shape).ravel())
            cols.append(np.broadcast_to(col0[:, None, None] + np.arange(q)[None, None, :], J.shape).ravel())
            vals.append(J.ravel())

        A, F = len(self.prior_slot), len(self.odo_a)
        r0 = np.einsum("aij,aj->ai", self.W0, wrap_pose_error(poses[self.prior_slot] - self.x0))
        block(3 * np.arange(A), 3 * self.prior_slot, self.W0)
        eo, Ja, Jb = odometry_residuals(poses[self.odo_a], poses[self.odo_b], self.delta)
        ro = np.einsum("fij,fj->fi", self.Wo, eo)
        row = 3 * A
        block(row + 3 * np.arange(F), 3 * self.odo_a, self.Wo @ Ja)
        block(row + 3 * np.arange(F), 3 * self.odo_b, self.Wo @ Jb)
        row += 3 * F
        (el, Jx, Jm), (er, Jra, Jrb) = self.sighting_errors(poses, lms, active)
        n_l = self.n_landmark_sightings
        Wl, Wr = self.Wm[:n_l][active[:n_l]], self.Wm[n_l:][active[n_l:]]
        nl, nr = len(el), len(er)
        rl = np.einsum("nij,nj->ni", Wl, el)
        block(row + 2 * np.arange(nl), 3 * self.pose_of[active[:n_l]], Wl @ Jx)
        block(row + 2 * np.arange(nl), 3 * self.n_poses + 2 * self.col_of[active[:n_l]], Wl @ Jm)
        rr = np.einsum("nij,nj->ni", Wr, er)
        block(row + 2 * nl + 2 * np.arange(nr), 3 * self.ra[active[n_l:]], Wr @ Jra)
        block(row + 2 * nl + 2 * np.arange(nr), 3 * self.rb[active[n_l:]], Wr @ Jrb)
        sightings = slice(row, row + 2 * (nl + nr))
        row += 2 * (nl + nr)
        L = len(lms)
        ra = (lms - self.anchor) / LANDMARK_ANCHOR_STD
        block(row + 2 * np.arange(L), 3 * self.n_poses + 2 * np.arange(L),
              np.broadcast_to(np.eye(2) / LANDMARK_ANCHOR_STD, (L, 2, 2)))
        J = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(row + 2 * L, len(v)))
        return np.concatenate([r0.ravel(), ro.ravel(), rl.ravel(), rr.ravel(), ra.ravel()]), J, sightings

    def gate_d2(self, v):
        """Untempered :math:`d^2 = e^\\top R^{-1} e` of every sighting (landmarks, then robots) at ``v``."""
        poses, lms = self.split(v)
        (el, _, _), (er, _, _) = self.sighting_errors(poses, lms, np.ones(len(self.z), dtype=bool))
        w = np.einsum("nij,nj->ni", self.Wg, np.concatenate([el, er]))
        return np.sum(w * w, axis=1)


def laplace_landmarks(problem: _JointProblem, v, active) -> np.ndarray:
    """The landmarks' covariances (L, 2, 2) from the Laplace approximation: the 2×2 diagonal blocks of
    :math:`\\Sigma_{ll} = (M - B^\\top P^{-1} B)^{-1}`, with :math:`J^\\top J = \\begin{pmatrix} P & B \\\\
    B^\\top & M\\end{pmatrix}` (poses first): the Schur complement of the poses. :math:`P` is banded in the
    time order of the poses, so its factorisation in that order fills in nothing outside the band."""
    _, J, _ = problem.evaluate(v, active)
    A = (J.T @ J).tocsc()
    p = 3 * problem.n_poses
    L = (A.shape[0] - p) // 2
    if L == 0:
        return np.zeros((0, 2, 2))
    P, B, M = A[:p, :p], A[:p, p:], A[p:, p:].toarray()
    X = splu(P.tocsc(), permc_spec=ORDERING, diag_pivot_thresh=0.0).solve(B.toarray())
    cov = np.linalg.inv(M - B.T @ X)
    return cov.reshape(L, 2, L, 2)[np.arange(L), :, np.arange(L), :]


# --------------------------------------------------------------------------- the solver


def smooth_robots(
    streams: dict,
    robot_sightings: dict | None = None,
    params: FastSLAMParams | None = None,
    *,
    initial: dict | None = None,
    x0=None,
    x0_std=PRIOR_STD,
    max_gap_s: float = 1.0,
    solver: SolverSettings = SolverSettings(),
    backend: str = "scipy",
) -> MultiRobotResult:
    """The least-squares paths of several robots and their shared map (see the module docstring).

    Parameters
    ----------
    streams : dict robot → EventStream
        Each robot's log (the same landmark table; times that overlap: one dataset).
    robot_sightings : dict robot → DataFrame, optional
        Each robot's sightings of the other robots, columns ``time, subject, range, bearing``
        (``RobotLog.robot_sightings``). Sightings of robots not in ``streams`` are left out (counted in
        ``robot_sightings_skipped``). None or no sighting at all: the robots share only the map (and a note says so).
    params : FastSLAMParams, optional
        The model (as :func:`~fastslam_edu.landmark.smoother.smooth`); the robot-robot sightings use its
        measurement covariance and gate.
    initial : dict robot → FastSLAMResult, optional
        A filter run per robot to start from (its poses; the map: the mean of the robots' maps).
    x0, x0_std : a pose / standard deviations for all robots, or a dict robot → value
        The prior on each robot's first pose (default: the stream's ``x0``, pinned with ``PRIOR_STD``).
    max_gap_s : float
        Keyframe spacing (:func:`~fastslam_edu.landmark.smoother_factors.keyframe_steps`).
    solver : SolverSettings
        Iterations, gate rounds, tempering (``BEST_ESTIMATE``: none). ``calibrate`` is not supported here.
    backend : ``"scipy"`` or ``"gtsam"``
        Who minimises each gate round and computes the landmarks' Laplace covariances: the package's
        Levenberg–Marquardt, or GTSAM's on the same factors (:func:`fastslam_edu.landmark.smoother_gtsam.robots_factor_graph`;
        needs the extra ``graph``). The gate's rounds are the package's on both.

    Returns
    -------
    MultiRobotResult
    """
    started = time.perf_counter()
    minimise, landmark_covariances = _backend(backend)
    params = FastSLAMParams() if params is None else params
    robots, streams, stds, initial = _checked_inputs(streams, solver, x0, x0_std, initial)
    own = {a: _robot_problem(streams[a], params, stds[a], initial[a], max_gap_s, solver) for a in robots}
    layout = _variable_layout(streams, robots, own)
    problem, skipped = _joint_problem(streams, robots, own, layout, robot_sightings, params, solver)
    v = _joint_start(problem, robots, own, layout)
    v, active, iterations, rounds, cost = solve_with_gate(problem, v, params.gate_chi2, solver, minimise)
    fit = _Fit(v, active, iterations, rounds, float(cost), landmark_covariances(problem, v, active), skipped)
    result = _result(streams, robots, own, layout, problem, fit)
    return dataclasses.replace(result, seconds=time.perf_counter() - started, backend=backend)


class _RobotProblem(NamedTuple):
    """One robot's own least-squares problem (as :func:`~fastslam_edu.landmark.smoother.smooth` builds it):
    its keyframe steps, dead-reckoned path, factors, landmarks seen, start vector and the sightings it uses."""

    keys: np.ndarray
    path: np.ndarray
    problem: object
    seen: np.ndarray
    start: np.ndarray
    use: np.ndarray


class _Layout(NamedTuple):
    """The joint vector: every keyframe pose in time order (``slot[a]``: robot a's keyframes), then the
    landmarks seen by any robot (``seen_all``; ``column[n]``: landmark n's column, -1 if unseen)."""

    n_poses: int
    slot: dict
    seen_all: np.ndarray
    column: np.ndarray


class _Fit(NamedTuple):
    """What the gated minimisation returns, with the landmarks' Laplace covariances and the sightings skipped."""

    v: np.ndarray
    active: np.ndarray
    iterations: int
    rounds: int
    cost: float
    landmark_cov: np.ndarray
    skipped: int


def _checked_inputs(streams, solver: SolverSettings, x0, x0_std, initial):
    """The robots (checked), their streams with ``x0`` applied, the prior's standard deviations and the initial
    filter runs, each as a dict robot → value."""
    if not isinstance(streams, dict) or not streams:
        raise ValueError("smooth_robots: streams must be a non-empty dict robot → EventStream")
    robots = check_robot_numbers(list(streams))
    if solver.calibrate:
        raise ValueError(f"smooth_robots: calibrate={solver.calibrate!r} is not supported with several robots")
    x0s = _per_robot(x0, robots, "x0", None)
    stds = _per_robot(x0_std, robots, "x0_std", PRIOR_STD)
    streams = {a: streams[a] if x0s[a] is None else _with_x0(streams[a], x0s[a]) for a in robots}
    check_streams(streams)
    if initial is not None and not isinstance(initial, dict):
        raise ValueError("smooth_robots: initial must be a dict robot → FastSLAMResult")
    initial = _per_robot(initial, robots, "initial", None)
    for a in robots:
        if initial[a] is not None and len(initial[a].t) != len(streams[a]):
            raise ValueError(f"robot {a}: initial has {len(initial[a].t)} steps but the stream {len(streams[a])}")
    return robots, streams, stds, initial


def _robot_problem(stream: EventStream, params: FastSLAMParams, x0_std, initial, max_gap_s: float,
                   solver: SolverSettings) -> _RobotProblem:
    """One robot's own problem, as the single-robot smoother builds it, and its starting point."""
    keys = keyframe_steps(stream, max_gap_s)
    path = dead_reckon_stream(stream, stream.x0, params.odometry_scale)
    problem, seen, use = build_problem(stream, params, keys, path, stream.x0, x0_std, tempering=solver.tempering)
    return _RobotProblem(keys, path, problem, seen, starting_point(problem, path, keys, seen, initial), use)


def _variable_layout(streams: dict, robots, own: dict) -> _Layout:
    """Where each robot's keyframe poses and each landmark sit in the joint vector (:class:`_Layout`)."""
    times = np.concatenate([streams[a].t[own[a].keys] for a in robots])
    order = np.argsort(times, kind="stable")
    slot_of_all = np.empty(len(times), dtype=np.int64)
    slot_of_all[order] = np.arange(len(times))
    bounds = np.cumsum([0] + [len(own[a].keys) for a in robots])
    slot = {a: slot_of_all[bounds[i]:bounds[i + 1]] for i, a in enumerate(robots)}
    seen_all = np.unique(np.concatenate([own[a].seen for a in robots]).astype(np.int64))
    column = np.full(streams[robots[0]].n_landmarks, -1)
    column[seen_all] = np.arange(len(seen_all))
    return _Layout(len(times), slot, seen_all, column)


def _robot_sighting_factors(streams: dict, robots, own: dict, layout: _Layout, robot_sightings, params,
                            solver: SolverSettings):
    """The robot-robot sightings as factors: observer and seen robot's keyframe slots ``ra``, ``rb`` and the
    dead-reckoned offsets ``da``, ``db`` to the sighting's instant, ``z``, the tempering weights β and the
    whitening; returns ``(columns dict, number skipped)``."""
    observer, other, t_s, z_s, skipped = robot_sighting_table(robot_sightings or {}, streams)
    ra, rb = np.zeros(len(t_s), np.int64), np.zeros(len(t_s), np.int64)
    da, db = np.zeros((len(t_s), 3)), np.zeros((len(t_s), 3))
    for a in robots:
        for rows, out_slot, out_delta in ((observer == a, ra, da), (other == a, rb, db)):
            if rows.any():
                k, d = keyframe_offsets(streams[a], own[a].path, own[a].keys, t_s[rows])
                out_slot[rows], out_delta[rows] = layout.slot[a][k], d
    beta_s = robot_sighting_weights(observer, other, t_s, params.measurement_correlation_s if solver.tempering else None)
    used = beta_s > 0
    Wg_s = whitening(params.measurement_covariance(z_s)) if len(z_s) else np.zeros((0, 2, 2))
    factors = dict(ra=ra[used], rb=rb[used], da=da[used], db=db[used], z=z_s[used],
                   Wm=np.sqrt(beta_s[used])[:, None, None] * Wg_s[used], Wg=Wg_s[used])
    return factors, skipped


def _joint_problem(streams: dict, robots, own: dict, layout: _Layout, robot_sightings, params,
                   solver: SolverSettings):
    """Every robot's factors and the robot-robot sightings in one :class:`_JointProblem`; and the number of
    robot-robot sightings skipped."""
    rr, skipped = _robot_sighting_factors(streams, robots, own, layout, robot_sightings, params, solver)
    cat, slot, P = np.concatenate, layout.slot, {a: own[a].problem for a in robots}
    problem = _JointProblem(
        n_poses=layout.n_poses, prior_slot=np.array([slot[a][0] for a in robots]),
        x0=np.array([P[a].x0 for a in robots]), W0=np.array([P[a].W0 for a in robots]),
        odo_a=cat([slot[a][:-1] for a in robots]), odo_b=cat([slot[a][1:] for a in robots]),
        delta=cat([P[a].delta for a in robots]), Wo=cat([P[a].Wo for a in robots]),
        z=cat([*(P[a].z for a in robots), rr["z"]]),
        n_landmark_sightings=sum(len(P[a].z) for a in robots),
        pose_of=cat([slot[a][P[a].pose_of] for a in robots]),
        col_of=cat([layout.column[own[a].seen[P[a].col_of]] for a in robots]),
        ra=rr["ra"], rb=rr["rb"], da=rr["da"], db=rr["db"],
        Wm=cat([*(P[a].Wm for a in robots), rr["Wm"]]),
        Wg=cat([*(P[a].Wg for a in robots), rr["Wg"]]),
    )
    return problem, skipped


def _result(streams: dict, robots, own: dict, layout: _Layout, problem, fit: _Fit) -> MultiRobotResult:
    """The solution as a :class:`MultiRobotResult`: each robot's keyframe poses, the map in survey order (only
    landmarks with a sighting through the gate), the counts and the notes."""
    poses, lms = problem.split(fit.v)
    active, n_l, seen_all = fit.active, problem.n_landmark_sightings, layout.seen_all
    kept = np.bincount(problem.col_of[active[:n_l]], minlength=len(seen_all)) > 0
    N = streams[robots[0]].n_landmarks
    landmarks, landmarks_cov, observed = np.full((N, 2), np.nan), np.full((N, 2, 2), np.nan), np.zeros(N, dtype=bool)
    landmarks[seen_all[kept]], landmarks_cov[seen_all[kept]] = lms[kept], fit.landmark_cov[kept]
    observed[seen_all[kept]] = True
    notes = []
    if len(robots) > 1 and len(problem.z) == n_l:  # no robot-robot sighting went into the problem
        notes.append(f"no robot-robot sighting between robots {', '.join(map(str, robots))}: "
                     "the robots are tied together only by the landmarks they share")
    if fit.skipped:
        notes.append(f"{fit.skipped} robot-robot sighting(s) left out: of robots not solved, or outside a robot's log")
    return MultiRobotResult(
        robots=robots, t={a: streams[a].t[own[a].keys] for a in robots}, steps={a: own[a].keys for a in robots},
        poses={a: wrap_pose_error(poses[layout.slot[a]]) for a in robots}, landmarks=landmarks,
        landmarks_cov=landmarks_cov, observed=observed, landmark_subjects=streams[robots[0]].landmark_subjects,
        iterations=fit.iterations, rounds=fit.rounds, cost=fit.cost, measurements_used=int(active[:n_l].sum()),
        measurements_rejected=int((~active[:n_l]).sum()),
        measurements_zero_weight=int(sum((~own[a].use).sum() for a in robots)),
        robot_sightings_used=int(active[n_l:].sum()), robot_sightings_gated=int((~active[n_l:]).sum()),
        robot_sightings_skipped=int(fit.skipped), seconds=0.0, notes=notes, backend="scipy",
    )


def _backend(backend: str):
    """``(minimise, landmark_covariances)`` of ``backend``: the package's (``None``: ``solve_with_gate``'s default,
    :func:`laplace_landmarks`), or GTSAM's (:mod:`fastslam_edu.landmark.smoother_gtsam`)."""
    if backend == "scipy":
        return None, laplace_landmarks
    if backend != "gtsam":
        raise ValueError(f"smooth_robots: backend must be 'scipy' or 'gtsam', got {backend!r}")
    from fastslam_edu.landmark import smoother_gtsam

    smoother_gtsam.require_gtsam()
    return smoother_gtsam.gtsam_levenberg_marquardt, smoother_gtsam.landmark_covariances


def _with_x0(stream: EventStream, x0) -> EventStream:
    x0 = np.asarray(x0, dtype=float)
    if x0.shape != (3,) or not np.isfinite(x0).all():
        raise ValueError(f"x0 must be a finite pose (x, y, θ), got {x0.tolist()}")
    return dataclasses.replace(stream, x0=x0)


def _joint_start(problem, robots, own: dict, layout: _Layout) -> np.ndarray:
    """Each robot's start (:func:`~fastslam_edu.landmark.smoother.starting_point`) in the joint layout; a landmark
    seen by several robots starts at the mean of their starts."""
    n_landmarks = len(layout.seen_all)
    poses = np.zeros((problem.n_poses, 3))
    lms, count = np.zeros((n_landmarks, 2)), np.zeros(n_landmarks)
    for a in robots:
        p, lm = own[a].problem.split(own[a].start)
        poses[layout.slot[a]] = p
        np.add.at(lms, layout.column[own[a].seen], lm)
        np.add.at(count, layout.column[own[a].seen], 1)
    return np.concatenate([poses.ravel(), (lms / np.maximum(count, 1)[:, None]).ravel()])


__all__ = ["ROBOTS", "MultiRobotResult", "check_robot_numbers", "check_streams", "laplace_landmarks", "smooth_robots"]
