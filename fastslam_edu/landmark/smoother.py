"""Batch least-squares SLAM: the most probable path and map under FastSLAM's own model.

FastSLAM works through the log once, forwards, and represents the posterior over
paths by M samples. Once the whole log is in, the *most probable* path and map
under the same model can be computed directly — "full SLAM" as nonlinear least
squares (Thrun, Burgard & Fox, *Probabilistic Robotics*, ch. 11, GraphSLAM;
Dellaert & Kaess's square-root SAM). With :math:`T` keyframe poses
:math:`x_0, \\dots, x_{T-1}` and :math:`N` landmarks :math:`\\mathbf l_1, \\dots, \\mathbf l_N` (here :math:`k`
numbers the keyframes and :math:`j` the landmarks) it minimises

.. math::

    \\tfrac12 \\|x_0 - \\bar x_0\\|^2_{P_0}
    + \\tfrac12 \\sum_k \\|(x_{k-1}^{-1} \\oplus x_k) \\ominus \\Delta_k\\|^2_{C_k}
    + \\tfrac12 \\sum_i \\beta_i \\|z_i \\ominus h(x_{k_i}, \\mathbf l_{j_i})\\|^2_{R_i},
    \\qquad \\|e\\|^2_C = e^\\top C^{-1} e,

* the **prior** :math:`\\bar x_0`: the stream's initial pose, where every particle starts;
* the **odometry factors**: :math:`\\Delta_k` is the dead-reckoned motion between
  keyframes :math:`k-1` and :math:`k` in the frame of :math:`x_{k-1}`, and :math:`C_k` its
  covariance under the filter's motion noise (:class:`~fastslam_edu.core.motion.MotionNoise`),
  propagated through every odometry step in between (:func:`~.smoother_factors.odometry_factors`);
* the **sightings**: range–bearing residuals with the filter's :math:`R_i` (range-dependent)
  and its tempering :math:`\\beta_i` (:func:`fastslam_edu.landmark.evidence.tempering_exponents`).

It is solved by Levenberg–Marquardt on the sparse normal equations
:math:`(J^\\top J + \\lambda\\,\\mathrm{diag}\\,J^\\top J)\\,\\delta = -J^\\top r`, first with a Huber
loss on the sightings (so that outliers cannot pull the start), then with the
filter's gate: sightings with :math:`d^2 > ` ``gate_chi2`` at the solution are
dropped and the problem solved again, until the set of dropped sightings stops changing.
The factors are built in :mod:`.smoother_factors`, the covariances at the solution in :mod:`.smoother_laplace`.

Optionally (``SolverSettings(calibrate=...)``, ``CALIBRATION_NAMES``) parameters of the model are estimated with
the path and map, each with a weak prior (``CALIBRATION_STD``): the odometry's calibration
:math:`(k_v, k_\\omega, \\tau)` — scale of the speed and of the turn rate, and the lag of the robot behind its
commands — and the angle :math:`\\delta` between its direction of travel and its heading
(:class:`~.smoother_factors.OdometryModel`: :math:`\\Delta_k` becomes :math:`\\Delta_k(c)`), or a constant bias
:math:`b` of every bearing (:func:`~.smoother_factors.sighting_residuals`). :math:`\\delta` and :math:`b` are
identifiable because the odometry ties the heading to the direction of travel; they turn the same data in opposite
frames (the prior on the first pose pins the heading that the bearings refer to), so estimate one of them.

What limits the absolute error on MR.CLAM is the frame, not the map's shape: aligned by a rigid motion, the
map and path are right to centimetres, and that motion — a rotation of a few degrees about the start — is all that
ties the map to the prior on the first pose: the odometry. The Laplace approximation says so too: the landmarks'
absolute σ is tens of centimetres. What turns it is not one constant that could be estimated: the camera's bearings
and the direction of travel both agree with the groundtruth heading, estimating either angle changes the rotation
little, and odometry made exact for the first seconds still leaves most of it. The odometry's scale and lag, right
on average, are wrong for the first turns, which fix the frame: estimated, they turn some robots further. What does
help is the weight of the sightings against the odometry: ``BEST_ESTIMATE``. The figures, robot by robot and
against groundtruth: ``benchmarks/smoother_mrclam.py``, which writes ``benchmarks/results/smoother_mrclam.json``.

Why a FastSLAM book has it: it is the yardstick. Its error against groundtruth
is what the noise model and the data allow, with all of the log used at once;
and the inverse of :math:`J^\\top J` at the solution (the Laplace approximation)
says how well the data fix each landmark *in the absolute frame*. Where that
uncertainty is tens of centimetres, no filter with this model can be expected
to put the landmark closer — whatever its particle count. (It is not a strict
bound: the MAP estimate of one log can be luckier or unluckier than its
standard deviation.)
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.datasets.log import EventStream
from fastslam_edu.landmark.fastslam import FastSLAMParams, FastSLAMResult
from fastslam_edu.core.measurement import landmark_from_measurement
from fastslam_edu.core.params import Params
from fastslam_edu.landmark.smoother_factors import (OdometryModel, dead_reckon_stream, keyframe_steps,
                                                    sighting_residuals, odometry_factors, odometry_residuals,
                                                    sighting_weights, whitening, wrap_pose_error)
from fastslam_edu.landmark.smoother_laplace import ORDERING, laplace

#: The old name of :func:`~.smoother_factors.dead_reckon_stream`, for the smoother's association modules only
#: (``smoother_association*.py`` import it from here; being split in issue 30): drop it when they name
#: ``dead_reckon_stream``.
dead_reckoning = dead_reckon_stream

#: Standard deviation of the prior on the first keyframe (the filter starts every particle there exactly).
PRIOR_STD = (1e-3, 1e-3, 1e-4)  # m, m, rad
#: A landmark's weak pull towards where it is at the start of a round [m]: it changes nothing
#: measurable, and keeps the problem solvable when the gate sets aside every sighting of a landmark
#: (that landmark is then reported as not observed).
LANDMARK_ANCHOR_STD = 1e3
#: The model parameters the smoother can estimate with the path and map (``SolverSettings.calibrate``), in the
#: order of the calibration vector :math:`c`: the scales of the speed and of the turn rate and the lag of the robot
#: behind its commands (:class:`~.smoother_factors.OdometryModel`), the angle between the robot's direction of
#: travel and its heading (``travel_offset``), and a constant offset of every bearing (``bearing_bias``,
#: :func:`~.smoother_factors.sighting_residuals`).
CALIBRATION_NAMES = ("k_v", "k_omega", "tau", "travel_offset", "bearing_bias")
#: The odometry's calibration :math:`(k_v, k_\\omega, \\tau)`.
ODOMETRY_CALIBRATION = ("k_v", "k_omega", "tau")
#: Prior standard deviations of :math:`c` when estimated, about ``params.odometry_scale`` and zero lag and angles:
#: weak against what MR.CLAM's robots measure (``benchmarks/smoother_mrclam.py``, its calibration variants).
CALIBRATION_STD = (0.2, 0.2, 0.5, 0.1, 0.1)  # -, -, s, rad, rad


@dataclass
class SmootherResult:
    """The least-squares path and map.

    Attributes
    ----------
    t : (T,) keyframe times [s]
    steps : (T,) the stream steps of the keyframes
    poses : (T, 3) keyframe poses ``(x, y, θ)`` [m, m, rad]
    pose_std : (T, 3) their standard deviations from the Laplace approximation [m, m, rad]
    landmarks : (N, 2) landmark positions [m] (NaN where never seen)
    landmarks_cov : (N, 2, 2) their covariances from the Laplace approximation [m²]
    observed : (N,) bool
    landmark_subjects : (N,)
    iterations : Levenberg–Marquardt iterations, over all rounds
    rounds : how many times the problem was solved (1 Huber round, then gate rounds)
    cost : final ½ Σ ‖whitened residual‖² (sightings inside the gate)
    measurements_used, measurements_rejected : sightings inside / beyond the gate at the solution
    measurements_zero_weight : sightings with β = 0 (a second reading of a landmark at one instant)
    seconds : wall time
    calibration : dict name → value of the estimated model parameters (``SolverSettings.calibrate``; else None):
        :math:`k_v, k_\\omega` [-], :math:`\\tau` [s], ``travel_offset``, ``bearing_bias`` [rad]
    calibration_std : dict name → their standard deviations (Laplace), or None
    backend : which solver ran, ``"scipy"`` (the package's own) or ``"gtsam"`` (:mod:`.smoother_gtsam`)
    """

    t: np.ndarray
    steps: np.ndarray
    poses: np.ndarray
    pose_std: np.ndarray
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
    seconds: float
    calibration: dict | None = None
    calibration_std: dict | None = None
    backend: str = "scipy"


# --------------------------------------------------------------------------- the solver


@dataclass
class _Problem:
    """Everything fixed while iterating: the factors, whitened, and the variable layout."""

    n_poses: int
    x0: np.ndarray
    W0: np.ndarray  # (3, 3)
    delta: np.ndarray  # (T-1, 3)
    Wo: np.ndarray  # (T-1, 3, 3)
    z: np.ndarray  # (n, 2) the sightings with β > 0
    pose_of: np.ndarray  # (n,) keyframe of each sighting
    col_of: np.ndarray  # (n,) landmark column block of each sighting
    Wm: np.ndarray  # (n, 2, 2) √β R^(-1/2)
    Wg: np.ndarray  # (n, 2, 2) R^(-1/2), for the gate's d² (untempered, as the filter's)
    anchor: np.ndarray | None = None  # (L, 2) the landmarks at the start of the round (LANDMARK_ANCHOR_STD)
    odometry: OdometryModel | None = None  # some of (k_v, k_ω, τ, δ) is estimated
    calibration0: np.ndarray | None = None  # (5,) the calibration's prior mean (CALIBRATION_NAMES, CALIBRATION_STD)
    free: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # its estimated entries

    @property
    def n_extra(self) -> int:
        return len(self.free)

    def split(self, v):
        return v[: 3 * self.n_poses].reshape(-1, 3), v[3 * self.n_poses: len(v) - self.n_extra].reshape(-1, 2)

    def calibration(self, v):
        """The whole calibration vector (5,): the estimated entries from ``v`` (last), the others at their prior
        mean; None when nothing is estimated."""
        if not self.n_extra:
            return None
        c = self.calibration0.copy()
        c[self.free] = v[len(v) - self.n_extra:]
        return c

    def evaluate(self, v, active):
        """Whitened residuals and Jacobian (sparse) of the prior, odometry and the ``active`` sightings."""
        poses, lms = self.split(v)
        T = self.n_poses
        r0 = self.W0 @ wrap_pose_error(poses[0] - self.x0)
        c = self.calibration(v)
        delta = self.delta if self.odometry is None else self.odometry.deltas(c)
        eo, Ja, Jb = odometry_residuals(poses[:-1], poses[1:], delta)
        ro = np.einsum("fij,fj->fi", self.Wo, eo)
        Ja, Jb = self.Wo @ Ja, self.Wo @ Jb
        k, lm = self.pose_of[active], self.col_of[active]
        em, Jx, Jm = sighting_residuals(poses[k], lms[lm], self.z[active], 0.0 if c is None else c[4])
        W = self.Wm[active]
        rm = np.einsum("nij,nj->ni", W, em)
        Jx, Jm = W @ Jx, W @ Jm
        # sparse layout: row blocks prior (3), odometry (3 each), sightings (2 each), landmark anchors (2 each)
        F, n = T - 1, len(k)
        rows, cols, vals = [], [], []

        def block(row0, col0, J):  # J (B, p, q) at rows row0[b] + i, cols col0[b] + j
            p, q = J.shape[1:]
            rows.append(np.broadcast_to(row0[:, None, None] + np.arange(p)[None, :, None], J.shape).ravel())
            cols.append(np.broadcast_to(col0[:, None, None] + np.arange(q)[None, None, :], J.shape).ravel())
            vals.append(J.ravel())

        block(np.array([0]), np.array([0]), self.W0[None])
        block(3 + 3 * np.arange(F), 3 * np.arange(F), Ja)
        block(3 + 3 * np.arange(F), 3 * np.arange(1, T), Jb)
        block(3 + 3 * F + 2 * np.arange(n), 3 * k, Jx)
        block(3 + 3 * F + 2 * np.arange(n), 3 * T + 2 * lm, Jm)
        L = len(lms)  # the anchors, last
        ra = (lms - self.anchor) / LANDMARK_ANCHOR_STD
        block(3 + 3 * F + 2 * n + 2 * np.arange(L), 3 * T + 2 * np.arange(L),
              np.broadcast_to(np.eye(2) / LANDMARK_ANCHOR_STD, (L, 2, 2)))
        rc = np.zeros(0)
        if c is not None:  # the calibration's columns (last) and its prior (last rows)
            self._calibration_blocks(block, c, W, F, n, L, len(v))
            sd = np.asarray(CALIBRATION_STD)[self.free]
            rc = (c - self.calibration0)[self.free] / sd
            block(np.array([3 + 3 * F + 2 * n + 2 * L]), np.array([len(v) - self.n_extra]), np.diag(1 / sd)[None])
        shape = (3 + 3 * F + 2 * n + 2 * L + len(rc), len(v))
        J = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=shape)
        sightings = slice(3 + 3 * F, 3 + 3 * F + 2 * n)
        return np.concatenate([r0, ro.ravel(), rm.ravel(), ra.ravel(), rc]), J, sightings

    def _calibration_blocks(self, block, c, W, F: int, n: int, L: int, n_v: int):
        """The Jacobian's columns of the estimated calibration: for its odometry entries
        :math:`\\partial e_o / \\partial c = -\\partial \\Delta / \\partial c` (whitened), for the bearing bias
        :math:`(0, -1)` (whitened) on every active sighting."""
        col = n_v - self.n_extra + np.arange(self.n_extra)
        odo = self.free < 4
        if odo.any():
            Jc = -self.Wo @ self.odometry.jacobian(c, self.free[odo])  # (F, 3, q)
            for j, column in enumerate(col[odo]):
                block(3 + 3 * np.arange(F), np.full(F, column), Jc[:, :, j:j + 1])
        if (~odo).any() and n:
            block(3 + 3 * F + 2 * np.arange(n), np.full(n, col[~odo][0]), W @ np.array([[0.0], [-1.0]]))

    def gate_d2(self, v):
        """Untempered :math:`d^2 = e^\\top R^{-1} e` of every sighting at ``v``."""
        poses, lms = self.split(v)
        c = self.calibration(v)
        em = sighting_residuals(poses[self.pose_of], lms[self.col_of], self.z, 0.0 if c is None else c[4])[0]
        w = np.einsum("nij,nj->ni", self.Wg, em)
        return np.sum(w * w, axis=1)


def _huber(r_m, c):
    """Per-sighting weights and cost of the Huber loss on ‖r_i‖ (``c`` None: plain least squares)."""
    s = np.sqrt(np.sum(r_m * r_m, axis=1))
    if c is None:
        return np.ones(len(s)), 0.5 * s * s
    w = np.where(s <= c, 1.0, c / np.maximum(s, 1e-300))
    return w, np.where(s <= c, 0.5 * s * s, c * s - 0.5 * c * c)


def robust_cost(problem: _Problem, v, active, huber):
    """Cost :math:`\\tfrac12\\|r\\|^2` at ``v``, with the Huber loss on each sighting's :math:`\\|r_i\\|` (radius
    ``huber``; None: plain least squares); returns ``(cost, r, J, w, rows)``: residuals, Jacobian, the sightings'
    IRLS weights and their rows in ``r``."""
    r, J, rows = problem.evaluate(v, active)
    w, rho = _huber(r[rows].reshape(-1, 2), huber)
    other = np.ones(len(r), dtype=bool)
    other[rows] = False
    return 0.5 * r[other] @ r[other] + rho.sum(), r, J, w, rows


def sparse_lu_step(A_damped, g) -> np.ndarray:
    """The damped Gauss–Newton step :math:`\\delta = -(A + \\mu\\,\\mathrm{diag}A)^{-1} g` by a sparse LU factorisation
    (``A_damped`` sparse, fill-reducing ``ORDERING``)."""
    return -splu(A_damped.tocsc(), permc_spec=ORDERING, diag_pivot_thresh=0.0).solve(g)


def levenberg_marquardt(problem: _Problem, v, active, *, huber, max_iterations, tol, damped_step=sparse_lu_step):
    """Minimise the (robust) cost over ``v``; returns ``(v, iterations, cost)``.

    Each iteration: the IRLS-weighted normal equations :math:`A = J^\\top W J`, :math:`g = J^\\top W r`, and the
    step ``damped_step(A + mu diag A, g)`` (default :func:`sparse_lu_step`; one that returns None falls back to
    it), accepted when it lowers the cost, else :math:`\\mu \\times 10`.
    """
    cost, r, J, w, rows = robust_cost(problem, v, active, huber)
    lam, it = 1e-4, 0
    for it in range(1, max_iterations + 1):
        sw = np.ones(len(r))  # IRLS: the Huber weights on the sightings' rows
        sw[rows] = np.repeat(np.sqrt(w), 2)
        Jw = sp.diags(sw) @ J
        A = (Jw.T @ Jw).tocsc()
        g = Jw.T @ (sw * r)
        D = sp.diags(A.diagonal())
        while True:
            step = damped_step(A + lam * D, g)
            if step is None:
                step = sparse_lu_step(A + lam * D, g)
            new_cost, r_new, J_new, w_new, _ = robust_cost(problem, v + step, active, huber)
            if new_cost <= cost:
                break
            lam *= 10.0
            if lam > 1e12:
                return v, it, cost
        v = v + step
        done = cost - new_cost <= tol * max(cost, 1e-12) or np.max(np.abs(step)) < 1e-9
        cost, r, J, w = new_cost, r_new, J_new, w_new
        lam = max(lam / 10.0, 1e-12)
        if done:
            break
    return v, it, cost


@dataclass(frozen=True, eq=False)
class SolverSettings(Params):
    """How the smoother solves: when it stops (Levenberg–Marquardt iterations per round, gating rounds,
    relative cost change), which model parameters it estimates with the path and map (``calibrate``: names
    from ``CALIBRATION_NAMES``, e.g. ``ODOMETRY_CALIBRATION``; each with a weak prior, ``CALIBRATION_STD``),
    and whether it weighs the sightings with the filter's tempering :math:`\\beta_i` (``tempering``, the default:
    the filter's own model) or counts each as independent, :math:`\\beta_i = 1` (``BEST_ESTIMATE``).
    ``huber=False`` skips the first round's Huber loss: plain least squares on every sighting, then the gate
    (:func:`solve_with_gate`; to compare solvers on one smooth cost)."""

    max_iterations: int = 100
    max_rounds: int = 10
    tol: float = 1e-10
    calibrate: tuple = ()
    tempering: bool = True
    huber: bool = True

    def __post_init__(self):
        object.__setattr__(self, "calibrate", tuple(self.calibrate))
        unknown = [name for name in self.calibrate if name not in CALIBRATION_NAMES]
        if unknown or len(set(self.calibrate)) != len(self.calibrate):
            raise ValueError(f"SolverSettings.calibrate: {self.calibrate!r} must be distinct names of {CALIBRATION_NAMES}")


#: The book's best estimate of path and map on MR.CLAM: every sighting counted in full (:math:`\\beta_i = 1`), nothing
#: calibrated. Tempering (the filter's :math:`\\beta_i`, for sighting errors correlated over seconds) leaves the odometry,
#: whose errors are correlated over minutes (scale, lag) and which alone ties the map to the first pose, too much
#: weight: the solution turns with it. Counted in full, the path and landmark errors are lower on MR.CLAM's robots with
#: groundtruth (``benchmarks/smoother_mrclam.py``, ``results/smoother_mrclam.json``). Its Laplace covariances are
#: those of independent sightings, so overconfident: for σ and NEES, the default (tempered) settings.
#: Estimating the odometry's scale and lag (``ODOMETRY_CALIBRATION``) turns some robots further: their first turns,
#: which fix the frame, ran nearer the command than the log's average (figures: ``results/smoother_mrclam.json``).
BEST_ESTIMATE = SolverSettings(tempering=False)


def smooth(
    stream: EventStream,
    params: FastSLAMParams | None = None,
    *,
    initial: FastSLAMResult | None = None,
    x0=None,
    x0_std=PRIOR_STD,
    max_gap_s: float = 1.0,
    pose_std: bool = False,
    solver: SolverSettings = SolverSettings(),
    backend: str = "scipy",
) -> SmootherResult:
    """The least-squares path and map of a whole log under ``params``' model (see the module docstring).

    Parameters
    ----------
    stream : EventStream
        The log (any rate).
    params : FastSLAMParams, optional
        The model: ``motion_noise``, ``measurement_covariance``, ``range_std_slope``,
        ``odometry_scale``, ``measurement_correlation_s`` (tempering) and ``gate_chi2``.
        Default ``FastSLAMParams()``. (Its ``mode`` plays no part: the smoother always estimates
        path and map together.)
    initial : FastSLAMResult, optional
        A filter run on the same stream to start from (its weighted-mean poses at the
        keyframes, its map). Default: dead reckoning, landmarks from their first sighting.
        Over a long log dead reckoning can be metres off, and least squares finds the
        optimum nearest its start: starting from the filter is the safe choice on real data
        (MR.CLAM: from dead reckoning, some robots' solutions end decimetres away from the one
        started from the filter, with many more sightings gated out; where both starts agree, dead
        reckoning takes far longer. Figures: ``benchmarks/smoother_mrclam.py`` and
        ``benchmarks/results/smoother_mrclam.json``.)
    x0 : (3,) initial pose; default ``stream.x0``.
    x0_std : (3,) standard deviations of the prior on the first pose [m, m, rad]. The default pins it
        (``PRIOR_STD``: a start from groundtruth, where every particle starts); give the start's real
        uncertainty when it is an estimate (:mod:`fastslam_edu.landmark.initial_pose`), or the first sightings
        will disagree with it and be gated out.
    max_gap_s : float
        Keyframe spacing where there are no sightings (:func:`~.smoother_factors.keyframe_steps`).
    pose_std : bool
        Compute the poses' standard deviations (one backward pass over the keyframes,
        :func:`~fastslam_edu.landmark.smoother_laplace.laplace`;
        the landmarks' covariances are always computed).
    solver : SolverSettings
        When Levenberg–Marquardt and the gating rounds stop, which model parameters are estimated with the path and
        map (``calibrate``), and whether the sightings are tempered (``BEST_ESTIMATE``: not).
    backend : ``"scipy"`` or ``"gtsam"``
        Who minimises each round and computes the Laplace covariances: the package's Levenberg–Marquardt on scipy's
        sparse normal equations, or GTSAM's on the same problem as a factor graph
        (:mod:`fastslam_edu.landmark.smoother_gtsam`; needs the extra ``graph``; no ``calibrate``). The gate's rounds
        are the package's on both.
    """
    started = time.perf_counter()
    minimise, laplace = _solver_and_laplace(backend, solver)
    params = FastSLAMParams() if params is None else params
    x0 = stream.x0 if x0 is None else np.asarray(x0, dtype=float)
    if x0 is None:
        raise ValueError("smooth: the stream has no initial pose (x0 is None): pass x0=(x, y, theta)")
    if len(stream) < 2:
        raise ValueError(f"smooth: the stream has {len(stream)} step(s); at least 2 are needed")
    if initial is not None and len(initial.t) != len(stream):
        raise ValueError(
            f"smooth: initial has {len(initial.t)} steps but the stream {len(stream)}: run the filter on the same stream"
        )
    x0 = np.asarray(x0, dtype=float).reshape(3)
    keys = keyframe_steps(stream, max_gap_s)
    path = dead_reckon_stream(stream, x0, params.odometry_scale)
    problem, seen, use = build_problem(stream, params, keys, path, x0, x0_std, tempering=solver.tempering)
    if solver.calibrate:
        problem.free = np.array(sorted(CALIBRATION_NAMES.index(name) for name in solver.calibrate))
        problem.calibration0 = np.array([*params.odometry_scale, 0.0, 0.0, 0.0])
        problem.odometry = OdometryModel(stream, keys) if np.any(problem.free < 4) else None
    v = starting_point(problem, path, keys, seen, initial)
    v, active, iterations, rounds, cost = solve_with_gate(problem, v, params.gate_chi2, solver, minimise)
    poses, lms = problem.split(v)
    std, cov_lm, cov_c = laplace(problem, v, active, with_poses=pose_std)
    landmarks, landmarks_cov, observed = _landmark_table(problem, seen, active, lms, cov_lm, stream.n_landmarks)
    c, names = problem.calibration(v), [CALIBRATION_NAMES[i] for i in problem.free]
    return SmootherResult(
        t=stream.t[keys], steps=keys, poses=wrap_pose_error(poses), pose_std=std, landmarks=landmarks,
        landmarks_cov=landmarks_cov, observed=observed, landmark_subjects=stream.landmark_subjects,
        iterations=iterations, rounds=rounds, cost=float(cost), measurements_used=int(active.sum()),
        measurements_rejected=int((~active).sum()), measurements_zero_weight=int((~use).sum()),
        seconds=time.perf_counter() - started,
        calibration=None if c is None else {name: float(c[i]) for name, i in zip(names, problem.free)},
        calibration_std=None if c is None else dict(zip(names, np.sqrt(np.diag(cov_c)).tolist())),
        backend=backend,
    )


def _solver_and_laplace(backend: str, solver: SolverSettings):
    """``(minimise, laplace)`` of ``backend``: the package's, or GTSAM's (:mod:`.smoother_gtsam`)."""
    if backend == "scipy":
        return levenberg_marquardt, laplace
    if backend != "gtsam":
        raise ValueError(f"smooth: backend must be 'scipy' or 'gtsam', got {backend!r}")
    if solver.calibrate:
        raise ValueError(f"smooth: backend='gtsam' cannot estimate SolverSettings.calibrate={solver.calibrate!r}: "
                         "use backend='scipy'")
    from fastslam_edu.landmark import smoother_gtsam

    smoother_gtsam.require_gtsam()
    return smoother_gtsam.gtsam_levenberg_marquardt, smoother_gtsam.gtsam_laplace


def _landmark_table(problem, seen, active, lms, cov_lm, n_landmarks: int):
    """The map in the stream's landmark order: ``(landmarks (N, 2), covariances (N, 2, 2), observed (N,))``;
    NaN for a landmark never seen, or whose every sighting is beyond the gate."""
    landmarks = np.full((n_landmarks, 2), np.nan)
    landmarks_cov = np.full((n_landmarks, 2, 2), np.nan)
    kept = np.bincount(problem.col_of[active], minlength=len(seen)) > 0  # some sighting inside the gate
    landmarks[seen[kept]], landmarks_cov[seen[kept]] = lms[kept], cov_lm[kept]
    observed = np.zeros(n_landmarks, dtype=bool)
    observed[seen[kept]] = True
    return landmarks, landmarks_cov, observed


def build_problem(stream: EventStream, params: FastSLAMParams, keys, path, x0, x0_std, tempering: bool = True):
    """The least-squares problem over the keyframe poses ``keys`` and the landmarks seen.

    Odometry factors between consecutive keyframes (:func:`~.smoother_factors.odometry_factors`, linearised
    about the dead-reckoned ``path``), a prior on the first pose (``x0``, standard deviations ``x0_std``), and one factor per sighting, whitened by
    its :math:`R` and its tempering weight :math:`\\sqrt\\beta` (sightings with :math:`\\beta = 0` carry nothing;
    ``tempering=False``: :math:`\\beta` of ``measurement_correlation_s=None``).
    Returns ``(problem, seen, use)``: the landmark indices with a column, and the sightings used.
    """
    delta, cov = odometry_factors(stream, path, keys, params.motion_noise)
    step_of = np.repeat(np.arange(len(stream)), np.diff(stream.offsets))
    beta = sighting_weights(stream, params.measurement_correlation_s if tempering else None)
    use = beta > 0
    seen = np.unique(stream.landmark[use])
    column = np.full(stream.n_landmarks, -1)
    column[seen] = np.arange(len(seen))
    z = stream.z[use]
    Wg = whitening(params.measurement_covariance(z))
    problem = _Problem(
        n_poses=len(keys), x0=x0, W0=np.diag(1.0 / np.asarray(x0_std, dtype=float)), delta=delta,
        Wo=whitening(cov), z=z, pose_of=np.searchsorted(keys, step_of[use]), col_of=column[stream.landmark[use]],
        Wm=np.sqrt(beta[use])[:, None, None] * Wg, Wg=Wg,
    )
    return problem, seen, use


def starting_point(problem, path, keys, seen, initial: FastSLAMResult | None) -> np.ndarray:
    """The start of the optimisation: the filter's estimate, or dead reckoning and landmarks from their first
    sighting (and the calibration's prior mean, when it is estimated)."""
    if initial is not None:
        poses = np.array(initial.pose_mean[keys], dtype=float)
        poses[:, 2] = path[keys, 2] + wrap_angle(poses[:, 2] - path[keys, 2])
    else:
        poses = path[keys].copy()
    first = np.unique(problem.col_of, return_index=True)[1]
    lms = landmark_from_measurement(poses[problem.pose_of[first]], problem.z[first])
    if initial is not None:
        from_filter = initial.observed[seen] & np.all(np.isfinite(initial.landmarks_mean[seen]), axis=1)
        lms[from_filter] = initial.landmarks_mean[seen][from_filter]
    extra = [] if not problem.n_extra else [problem.calibration0[problem.free]]
    return np.concatenate([poses.ravel(), lms.ravel(), *extra])


def solve_with_gate(problem, v, gate: float | None, solver: SolverSettings, minimise=None):
    """Round 1: Huber at the gate's radius (unless ``solver.huber`` is False); then the gate itself, until the
    rejected set settles. Each round is minimised by ``minimise`` (default ``levenberg_marquardt``; or
    :func:`fastslam_edu.landmark.smoother_gtsam.gtsam_levenberg_marquardt`, the same signature).

    Returns ``(v, active, iterations, rounds, cost)``.
    """
    minimise = levenberg_marquardt if minimise is None else minimise
    active = np.ones(len(problem.z), dtype=bool)
    problem.anchor = problem.split(v)[1].copy()
    huber = None if gate is None or not solver.huber else np.sqrt(gate)
    v, iterations, cost = minimise(problem, v, active, huber=huber, max_iterations=solver.max_iterations, tol=solver.tol)
    rounds = 1
    while gate is not None and rounds < solver.max_rounds:
        new_active = problem.gate_d2(v) <= gate
        if rounds > 1 and np.array_equal(new_active, active):
            break
        active = new_active
        problem.anchor = problem.split(v)[1].copy()
        v, it, cost = minimise(problem, v, active, huber=None, max_iterations=solver.max_iterations, tol=solver.tol)
        iterations += it
        rounds += 1
    return v, active, iterations, rounds, cost
