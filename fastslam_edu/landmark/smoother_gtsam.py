"""The smoother's least-squares problem as a GTSAM factor graph: a second, independent solver.

:func:`fastslam_edu.landmark.smoother.smooth` minimises

.. math::

    \\tfrac12 \\|x_0 - \\bar x_0\\|^2_{P_0}
    + \\tfrac12 \\sum_k \\|(x_{k-1}^{-1} \\oplus x_k) \\ominus \\Delta_k\\|^2_{C_k}
    + \\tfrac12 \\sum_i \\beta_i \\|z_i \\ominus h(x_{k_i}, l_{j_i})\\|^2_{R_i}
    + \\tfrac12 \\sum_k \\|l_k - \\bar l_k\\|^2 / \\sigma_a^2

by its own Levenberg–Marquardt on scipy's sparse normal equations. With ``backend="gtsam"`` the same terms
become factors of GTSAM (Dellaert & Kaess, *Factor Graphs for Robot Perception*, 2017), solved by
``gtsam.LevenbergMarquardtOptimizer`` from the package's starting point, and the Laplace covariances come from
``gtsam.Marginals``. Each factor's error :math:`e_g` against the package's residual :math:`e`:

* **prior on** :math:`x_0`, ``PriorFactorPose2``: :math:`e_g = \\operatorname{Log}(\\bar x_0^{-1} x_0)`, in the frame
  of :math:`\\bar x_0`; the package's :math:`e = x_0 - \\bar x_0` (heading wrapped) is in the world frame. To first order
  :math:`e_g = T(\\bar\\theta_0)\\, e` with :math:`T(\\theta) = \\mathrm{blockdiag}(R(\\theta)^\\top, 1)`, so the factor gets
  the covariance :math:`T P_0 T^\\top` (:func:`rotated_covariance`; :math:`P_0` is diagonal with ``x0_std``). The
  second-order difference (the logarithm's, as for the odometry below) is of the order of the prior's heading
  residual: negligible with the default ``PRIOR_STD``, which pins :math:`x_0`; not measured with a loose ``x0_std``.
* **odometry**: GTSAM's own ``BetweenFactorPose2`` has the error
  :math:`e_g = \\operatorname{Log}(\\Delta_k^{-1}(x_{k-1}^{-1} x_k))` — the SE(2) logarithm, in the frame of
  :math:`\\Delta_k`'s end — where the package has the componentwise
  :math:`e = (x_{k-1}^{-1} \\oplus x_k) - \\Delta_k` (angle wrapped) in the frame of :math:`x_{k-1}`. With
  :math:`(t, \\phi) = \\Delta_k^{-1}(x_{k-1}^{-1} x_k)`, :math:`t = R(\\theta_{\\Delta_k})^\\top e_{xy}` and
  :math:`\\phi = e_\\theta`, and :math:`\\operatorname{Log}` gives :math:`(V(\\phi)^{-1} t, \\phi)`,
  :math:`V(\\phi)^{-1} = \\tfrac{\\phi}{2}\\cot\\tfrac{\\phi}{2}\\, I - \\tfrac{\\phi}{2} S`, :math:`S` the 90° turn. So
  :math:`e_g = T(\\theta_{\\Delta_k})\\, e` plus a term of order :math:`\\phi\\, |e_{xy}|`: with the covariance
  :math:`T C_k T^\\top` the two costs agree where the odometry residuals vanish (dead reckoning) and differ by a relative
  :math:`O(\\phi)` per factor elsewhere, :math:`\\phi` the heading residual (milliradians at the optimum). Measured
  without the Huber round on the same gated set (``benchmarks/smoother_backends.py``, which writes
  ``benchmarks/results/smoother_backends.json``), that is a different optimum on MR.CLAM, beyond the 1 mm and 1e-6
  the backends must agree to.
  So the odometry is a ``gtsam.CustomFactor`` with the package's residual and Jacobians
  (:func:`odometry_chain_factor`, covariance :math:`C_k` as it is); ``ODOMETRY_FACTOR = "between"`` gives the
  standard factor back.
* **sightings**, ``BearingRangeFactor2D``: :math:`e_g = (\\operatorname{wrap}(\\hat b - b),\\; \\hat r - r)`, bearing
  first, the sign flipped: :math:`e_g = -P e` with :math:`P` the swap, exactly; the factor gets the covariance
  :math:`P R_i P^\\top / \\beta_i` (the tempered :math:`R_i`, :math:`\\beta_i` the filter's tempering). Only the
  sightings inside the gate (the ``active`` set) become factors.
* **landmark anchors** (``LANDMARK_ANCHOR_STD``), ``PriorFactorPoint2``: :math:`e_g = l_k - \\bar l_k`, exactly.

The cost both report is :math:`\\tfrac12 \\sum \\|W e\\|^2` over all the factors above (whitened residuals,
prior and anchors included): the package's ``cost``, and GTSAM's ``NonlinearFactorGraph.error``. In the Huber round
(``SolverSettings.huber``) the sightings' noise models are ``noiseModel.Robust`` with ``mEstimator.Huber`` at
:math:`\\sqrt{\\chi^2_{gate}}`: the same loss :math:`\\rho` on :math:`\\|W e\\|` as the package's.

The gate is applied the same way on both backends: :func:`fastslam_edu.landmark.smoother.solve_with_gate` decides
the active set from the package's :math:`d^2` at each round's solution, and only the minimisation of a round
(:func:`gtsam_levenberg_marquardt`) and the Laplace covariances (:func:`gtsam_laplace`) are GTSAM's. The estimated
calibration (``SolverSettings.calibrate``) has no GTSAM factor here and is refused.
"""

from __future__ import annotations

import numpy as np

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.landmark.smoother import LANDMARK_ANCHOR_STD

#: Which factor carries the odometry: ``"componentwise"``, a ``gtsam.CustomFactor`` with the package's residual
#: :math:`e = (x_{k-1}^{-1} \\oplus x_k) - \\Delta_k` (:func:`odometry_chain_factor`): both backends minimise the same cost;
#: or ``"between"``, GTSAM's own ``BetweenFactorPose2`` (SE(2) logarithm; see the module docstring for the difference).
ODOMETRY_FACTOR = "componentwise"
#: Consecutive odometry factors per ``CustomFactor`` (:func:`odometry_chain_factor`).
CHAIN_LENGTH = 16
#: The one line shown when GTSAM is missing (the CLI prints it and exits 2).
MISSING_GTSAM = "backend='gtsam' needs GTSAM: pip install 'fastslam-edu[graph]'"
#: (bearing, range) from the package's (range, bearing).
_SWAP = np.array([[0.0, 1.0], [1.0, 0.0]])


def require_gtsam():
    """The ``gtsam`` module, or an ImportError with :data:`MISSING_GTSAM`."""
    try:
        import gtsam
    except ImportError as err:
        raise ImportError(MISSING_GTSAM) from err
    return gtsam


def pose_key(i: int) -> int:
    """GTSAM key of keyframe pose :math:`x_i`."""
    return require_gtsam().symbol("x", i)


def landmark_key(j: int) -> int:
    """GTSAM key of the landmark in column ``j`` of the problem."""
    return require_gtsam().symbol("l", j)


def covariance_of_whitening(W: np.ndarray) -> np.ndarray:
    """:math:`C = (W^\\top W)^{-1}` from a whitening :math:`W`
    (:func:`~fastslam_edu.landmark.smoother_factors.whitening`).
    Shape (..., d, d)."""
    return np.linalg.inv(np.swapaxes(W, -1, -2) @ W)


def rotated_covariance(C: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """:math:`T C T^\\top`, :math:`T = \\mathrm{blockdiag}(R(\\theta)^\\top, 1)`: a pose error's covariance in the world
    frame (or the frame of :math:`x_{k-1}`) re-expressed in a frame turned by :math:`\\theta` [rad].
    ``C`` (..., 3, 3), ``theta`` (...,)."""
    c, s = np.cos(theta), np.sin(theta)
    T = np.zeros(np.shape(theta) + (3, 3))
    T[..., 0, 0], T[..., 0, 1], T[..., 1, 0], T[..., 1, 1], T[..., 2, 2] = c, s, -s, c, 1.0
    return T @ C @ np.swapaxes(T, -1, -2)


def factor_graph(problem, active: np.ndarray, huber: float | None = None):
    """The smoother's problem (``smoother._Problem``, calibration not estimated) as a ``gtsam.NonlinearFactorGraph``:
    prior, odometry factors, the ``active`` sightings (robust Huber at ``huber`` if given) and the landmark anchors
    at ``problem.anchor`` (see the module docstring for how each error relates to the package's)."""
    if hasattr(problem, "prior_slot"):  # several robots: multi_robot._JointProblem
        return robots_factor_graph(problem, active, huber)
    gtsam = require_gtsam()
    noise = gtsam.noiseModel
    graph = gtsam.NonlinearFactorGraph()
    x0 = np.asarray(problem.x0, dtype=float)
    P0 = rotated_covariance(covariance_of_whitening(problem.W0), x0[2])
    graph.add(gtsam.PriorFactorPose2(pose_key(0), gtsam.Pose2(*x0), noise.Gaussian.Covariance(P0)))
    if ODOMETRY_FACTOR not in ("componentwise", "between"):
        raise ValueError(f"ODOMETRY_FACTOR must be 'componentwise' or 'between', got {ODOMETRY_FACTOR!r}")
    if ODOMETRY_FACTOR == "between":
        C = rotated_covariance(covariance_of_whitening(problem.Wo), problem.delta[:, 2])  # into the frame of Δ's end
        for k, (d, Ck) in enumerate(zip(problem.delta, C)):
            graph.add(gtsam.BetweenFactorPose2(pose_key(k), pose_key(k + 1), gtsam.Pose2(*d),
                                               noise.Gaussian.Covariance(Ck)))
    else:
        for first in range(0, len(problem.delta), CHAIN_LENGTH):
            chain = slice(first, first + CHAIN_LENGTH)
            graph.add(odometry_chain_factor(first, problem.delta[chain], problem.Wo[chain]))
    R = _SWAP @ covariance_of_whitening(problem.Wm[active]) @ _SWAP  # R_i / β_i, (bearing, range)
    for i, (k, j, z, Ri) in enumerate(zip(problem.pose_of[active], problem.col_of[active], problem.z[active], R)):
        model = noise.Gaussian.Covariance(Ri)
        if huber is not None:
            model = noise.Robust.Create(noise.mEstimator.Huber.Create(huber), model)
        graph.add(gtsam.BearingRangeFactor2D(pose_key(int(k)), landmark_key(int(j)), gtsam.Rot2(z[1]), z[0], model))
    anchor = noise.Isotropic.Sigma(2, LANDMARK_ANCHOR_STD)
    for j, a in enumerate(problem.anchor):
        graph.add(gtsam.PriorFactorPoint2(landmark_key(j), np.asarray(a, dtype=float), anchor))
    return graph


def odometry_chain_factor(first: int, delta: np.ndarray, W: np.ndarray, slots=None):
    """The package's odometry factors between poses ``first`` … ``first + m`` as one ``gtsam.CustomFactor``: the
    stacked whitened errors :math:`W_k e_k`, :math:`e_k = (x_{k-1}^{-1} \\oplus x_k) - \\Delta_k` (heading wrapped;
    :func:`fastslam_edu.landmark.smoother_factors.odometry_residuals`), ``delta`` (m, 3), whitening ``W`` (m, 3, 3) of
    :math:`C_k` (in the frame of :math:`x_{k-1}`); a unit noise model, so its error is :math:`\\tfrac12 \\sum_k
    \\|W_k e_k\\|^2`, the package's.

    GTSAM perturbs a pose in its own frame, :math:`x \\exp(\\delta)`: :math:`\\delta x_{world} = T(\\theta)^\\top \\delta`
    to first order, so its Jacobians are the package's times :math:`\\mathrm{blockdiag}(R(\\theta), 1)`:

    .. math::

        \\frac{\\partial e_k}{\\partial \\delta_{k-1}} = \\begin{pmatrix} -1 & 0 & r_y \\\\ 0 & -1 & -r_x \\\\ 0 & 0 & -1
        \\end{pmatrix}, \\qquad
        \\frac{\\partial e_k}{\\partial \\delta_k} = \\mathrm{blockdiag}(R(\\theta_k - \\theta_{k-1}), 1),

    with :math:`r = x_{k-1}^{-1} \\oplus x_k`. Why chains and not one factor per odometry step: inside
    GTSAM's optimizers a Python factor's call costs time in proportion to the number of variables, so one-step
    factors take minutes on a log that scipy solves in seconds; chains of :data:`CHAIN_LENGTH` steps make that many
    times fewer calls. Each chain's factor joins its m + 1 poses in one clique: (3m + 3)-dimensional dense blocks in
    the elimination, so too long a chain is slow again (the times: ``benchmarks/smoother_backends.py``).

    ``slots`` (m + 1,): the poses' variable numbers when they are not ``first`` … ``first + m`` (one robot's
    keyframes among several robots', :func:`robots_factor_graph`).
    """
    gtsam = require_gtsam()
    from fastslam_edu.landmark.smoother_factors import odometry_residuals

    delta, W = np.asarray(delta, dtype=float), np.asarray(W, dtype=float)
    m = len(delta)
    slots = first + np.arange(m + 1) if slots is None else np.asarray(slots)
    keys = [pose_key(int(i)) for i in slots]
    rows = 3 * np.arange(m)

    def error(factor, values, jacobians):
        x = np.array([_pose_array(values.atPose2(key)) for key in keys])
        e, Ja, Jb = odometry_residuals(x[:-1], x[1:], delta)
        if jacobians is not None:
            c, s = np.cos(x[:, 2]), np.sin(x[:, 2])
            T = np.zeros((m + 1, 3, 3))  # blockdiag(R(θ), 1): GTSAM's perturbation in the world frame
            T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1], T[:, 2, 2] = c, -s, s, c, 1.0
            A, B = W @ Ja @ T[:-1], W @ Jb @ T[1:]  # (m, 3, 3): wrt the first and the second pose of each step
            for i in range(m + 1):
                J = np.zeros((3 * m, 3))
                if i < m:
                    J[rows[i]:rows[i] + 3] = A[i]
                if i > 0:
                    J[rows[i - 1]:rows[i - 1] + 3] = B[i - 1]
                jacobians[i] = J
        return np.einsum("kij,kj->ki", W, e).ravel()

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(3 * m), keys, error)


def to_values(problem, v: np.ndarray):
    """The package's variable vector ``v`` (poses, then landmarks) as ``gtsam.Values``."""
    gtsam = require_gtsam()
    poses, lms = problem.split(v)
    values = gtsam.Values()
    for i, p in enumerate(poses):
        values.insert(pose_key(i), gtsam.Pose2(*p))
    for j, m in enumerate(lms):
        values.insert(landmark_key(j), np.asarray(m, dtype=float))
    return values


def from_values(problem, values, v_start: np.ndarray) -> np.ndarray:
    """``gtsam.Values`` back to the package's vector; headings continued from ``v_start`` (GTSAM wraps them)."""
    poses0, lms0 = problem.split(v_start)
    poses = np.array([_pose_array(values.atPose2(pose_key(i))) for i in range(len(poses0))]).reshape(-1, 3)
    poses[:, 2] = poses0[:, 2] + wrap_angle(poses[:, 2] - poses0[:, 2])
    lms = np.array([values.atPoint2(landmark_key(j)) for j in range(len(lms0))], dtype=float).reshape(-1, 2)
    return np.concatenate([poses.ravel(), lms.ravel()])


def _pose_array(p) -> np.ndarray:
    return np.array([p.x(), p.y(), p.theta()])


def gtsam_levenberg_marquardt(problem, v, active, *, huber, max_iterations, tol):
    """One round of the smoother solved by ``gtsam.LevenbergMarquardtOptimizer`` from ``v``: the same signature and
    returns as ``smoother.levenberg_marquardt``, ``(v, iterations, cost)``; ``cost`` is GTSAM's
    :math:`\\tfrac12 \\sum \\|W e\\|^2` (or :math:`\\sum \\rho` with ``huber``). It stops when the cost's relative
    decrease is below ``tol`` or after ``max_iterations``."""
    gtsam = require_gtsam()
    if problem.n_extra:
        raise ValueError("backend='gtsam' cannot estimate SolverSettings.calibrate: use backend='scipy'")
    graph = factor_graph(problem, active, huber)
    start = to_values(problem, v)
    if max_iterations == 0:
        return v, 0, graph.error(start)
    settings = gtsam.LevenbergMarquardtParams()
    settings.setMaxIterations(max_iterations)
    settings.setRelativeErrorTol(tol)
    settings.setAbsoluteErrorTol(0.0)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, start, settings)
    result = optimizer.optimize()
    return from_values(problem, result, v), int(optimizer.iterations()), float(graph.error(result))


def gtsam_laplace(problem, v, active, with_poses=True):
    """The Laplace covariances from ``gtsam.Marginals`` at ``v`` (the same returns as ``smoother_laplace.laplace``):
    pose standard deviations (T, 3) [m, m, rad] in the world frame (NaN unless ``with_poses``), the landmarks'
    covariances (N, 2, 2) [m²], and an empty (0, 0) calibration block.

    GTSAM gives a pose's covariance :math:`\\Sigma_g` in its own frame (a perturbation :math:`x \\exp(\\delta)`);
    in the world frame it is :math:`T(\\theta)^\\top \\Sigma_g T(\\theta)` (:func:`rotated_covariance` by
    :math:`-\\theta`). A landmark's is in the world frame already."""
    gtsam = require_gtsam()
    values = to_values(problem, v)
    marginals = gtsam.Marginals(factor_graph(problem, active), values)
    poses, lms = problem.split(v)
    cov_lm = np.array([marginals.marginalCovariance(landmark_key(j)) for j in range(len(lms))]).reshape(-1, 2, 2)
    std = np.full((len(poses), 3), np.nan)
    if with_poses:
        local = np.array([marginals.marginalCovariance(pose_key(i)) for i in range(len(poses))])
        world = rotated_covariance(local, -poses[:, 2])
        std = np.sqrt(np.maximum(np.diagonal(world, axis1=1, axis2=2), 0.0))
    return std, cov_lm, np.zeros((0, 0))


# --------------------------------------------------------------------------- several robots (multi_robot.smooth_robots)

#: Robot-robot sightings per ``CustomFactor`` (:func:`robot_sighting_factor`): as for the odometry chains, a Python
#: factor's call inside GTSAM's optimizer costs time in proportion to the number of variables, and the five robots of
#: MR.CLAM Dataset 6 have 13 000 keyframes and 4000 mutual sightings.
SIGHTING_GROUP = 16


def robots_factor_graph(problem, active, huber: float | None = None):
    """Several robots' problem (``multi_robot._JointProblem``) as a ``gtsam.NonlinearFactorGraph``: per robot the
    factors of :func:`factor_graph` (its prior, its odometry chain, its ``active`` landmark sightings), then the
    ``active`` robot-robot sightings in groups of :data:`SIGHTING_GROUP` (:func:`robot_sighting_factor`), then the
    landmark anchors. ``active`` (n_l + n_r,): the landmark sightings, then the robot sightings."""
    gtsam = require_gtsam()
    noise = gtsam.noiseModel
    graph = gtsam.NonlinearFactorGraph()
    P0 = rotated_covariance(covariance_of_whitening(problem.W0), problem.x0[:, 2])
    for slot, x0, P in zip(problem.prior_slot, np.asarray(problem.x0, dtype=float), P0):
        graph.add(gtsam.PriorFactorPose2(pose_key(int(slot)), gtsam.Pose2(*x0), noise.Gaussian.Covariance(P)))
    # each robot's odometry factors are a run of consecutive entries: x_a of one is x_b of the one before
    starts = np.flatnonzero(np.r_[True, problem.odo_a[1:] != problem.odo_b[:-1]])
    for lo, hi in zip(starts, np.r_[starts[1:], len(problem.odo_a)]):
        for first in range(lo, hi, CHAIN_LENGTH):
            f = np.arange(first, min(first + CHAIN_LENGTH, hi))
            slots = np.r_[problem.odo_a[f], problem.odo_b[f[-1]]]
            graph.add(odometry_chain_factor(0, problem.delta[f], problem.Wo[f], slots=slots))
    n_l = problem.n_landmark_sightings
    landmark, robot = active[:n_l], active[n_l:]
    R = _SWAP @ covariance_of_whitening(problem.Wm[:n_l][landmark]) @ _SWAP  # R_i / β_i, (bearing, range)
    for k, j, z, Ri in zip(problem.pose_of[landmark], problem.col_of[landmark], problem.z[:n_l][landmark], R):
        model = noise.Gaussian.Covariance(Ri)
        if huber is not None:
            model = noise.Robust.Create(noise.mEstimator.Huber.Create(huber), model)
        graph.add(gtsam.BearingRangeFactor2D(pose_key(int(k)), landmark_key(int(j)), gtsam.Rot2(z[1]), z[0], model))
    ra, rb, da, db = problem.ra[robot], problem.rb[robot], problem.da[robot], problem.db[robot]
    z, W = problem.z[n_l:][robot], problem.Wm[n_l:][robot]
    order = np.argsort(np.minimum(ra, rb), kind="stable")  # close in time: a group's poses are neighbours
    for first in range(0, len(order), SIGHTING_GROUP):
        g = order[first:first + SIGHTING_GROUP]
        graph.add(robot_sighting_factor(ra[g], rb[g], da[g], db[g], z[g], W[g], huber))
    anchor = noise.Isotropic.Sigma(2, LANDMARK_ANCHOR_STD)
    for j, a in enumerate(problem.anchor):
        graph.add(gtsam.PriorFactorPoint2(landmark_key(j), np.asarray(a, dtype=float), anchor))
    return graph


def robot_sighting_factor(ra, rb, da, db, z, W, huber: float | None = None):
    """Robot-robot sightings ``s`` = 1 … n as one ``gtsam.CustomFactor`` with the package's residual and Jacobians
    (:meth:`fastslam_edu.landmark.multi_robot._JointProblem.sighting_errors`): robot a at keyframe slot ``ra[s]``
    sees robot b at slot ``rb[s]``,

    .. math::

        r_s = W_s\\, e_s, \\qquad e_s = z_s \\ominus h(x_{a} \\oplus \\delta_{a},\\; (x_{b} \\oplus \\delta_{b})_{xy}),

    ``da``, ``db`` (n, 3) the dead-reckoned motions from the keyframes to the sighting's time, ``z`` (n, 2) range
    [m] and bearing [rad], ``W`` (n, 2, 2) :math:`\\sqrt{\\beta_s} R_s^{-1/2}`; a unit noise model, so its error is
    :math:`\\tfrac12 \\sum_s \\|r_s\\|^2`, the package's. The Jacobians are the package's
    (:math:`W\\,\\partial e/\\partial x` through :func:`~fastslam_edu.landmark.robot_sightings.compose_jacobian`) times
    :math:`\\mathrm{blockdiag}(R(\\theta), 1)`, GTSAM's perturbation :math:`x \\exp(\\delta)` in the world frame.

    With ``huber`` (the first round's Huber loss at :math:`c`, per sighting as the package's), a sighting with
    :math:`s = \\|r_s\\| > c` returns :math:`g(s)\\, r_s`, :math:`g(s) = \\sqrt{2cs - c^2}/s`, so that
    :math:`\\tfrac12 \\|g r_s\\|^2 = \\rho(s) = cs - c^2/2`: the same cost as the package's (a ``noiseModel.Robust``
    would apply the loss to the whole group's residual). Its Jacobian is
    :math:`g J + g'(s)\\, r_s r_s^\\top J / s`, :math:`g'(s) = -c (s - c) / (s^2 \\sqrt{2cs - c^2})`.
    """
    gtsam = require_gtsam()
    from fastslam_edu.landmark.robot_sightings import compose_jacobian, compose_unwrapped
    from fastslam_edu.landmark.smoother_factors import sighting_residuals

    slots, index = np.unique(np.r_[ra, rb], return_inverse=True)
    n = len(ra)
    ia, ib = index[:n], index[n:]
    keys = [pose_key(int(s)) for s in slots]
    da, db, z, W = (np.asarray(a, dtype=float) for a in (da, db, z, W))

    def error(factor, values, jacobians):
        x = np.array([_pose_array(values.atPose2(key)) for key in keys])
        xa, xb = x[ia], x[ib]
        e, Jx, Jm = sighting_residuals(compose_unwrapped(xa, da), compose_unwrapped(xb, db)[:, :2], z)
        r = np.einsum("nij,nj->ni", W, e)
        if jacobians is None and huber is None:
            return r.ravel()
        c, s = np.cos(x[:, 2]), np.sin(x[:, 2])
        T = np.zeros((len(x), 3, 3))  # blockdiag(R(θ), 1): GTSAM's perturbation in the world frame
        T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1], T[:, 2, 2] = c, -s, s, c, 1.0
        Ja = W @ Jx @ compose_jacobian(xa, da) @ T[ia]  # (n, 2, 3)
        Jb = W @ Jm @ compose_jacobian(xb, db)[:, :2, :] @ T[ib]
        if huber is not None:
            r, Ja, Jb = _huber_rows(r, Ja, Jb, huber)
        if jacobians is not None:
            for p in range(len(keys)):
                J = np.zeros((n, 2, 3))
                J[ia == p] += Ja[ia == p]
                J[ib == p] += Jb[ib == p]
                jacobians[p] = J.reshape(2 * n, 3)
        return r.ravel()

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(2 * n), keys, error)


def _huber_rows(r, Ja, Jb, c: float):
    """Each 2-row residual ``r`` (n, 2) with :math:`\\|r\\| > c` scaled by :math:`g = \\sqrt{2cs - c^2}/s`
    (:func:`robot_sighting_factor`), and its Jacobians ``Ja``, ``Jb`` (n, 2, 3) by the chain rule."""
    s = np.sqrt(np.sum(r * r, axis=1))
    out = s > c
    if not out.any():
        return r, Ja, Jb
    so = s[out]
    root = np.sqrt(2 * c * so - c * c)
    g, dg = np.ones(len(s)), np.zeros(len(s))
    g[out], dg[out] = root / so, -c * (so - c) / (so * so * root)
    outer = (dg / np.maximum(s, 1e-300))[:, None, None] * r[:, :, None] * r[:, None, :]  # g'(s) r rᵀ / s
    scale = g[:, None, None] * np.eye(2) + outer
    return g[:, None] * r, scale @ Ja, scale @ Jb


def landmark_covariances(problem, v, active) -> np.ndarray:
    """The landmarks' Laplace covariances (N, 2, 2) [m²] from ``gtsam.Marginals`` at ``v`` (:func:`gtsam_laplace`,
    without the poses'): GTSAM's counterpart of :func:`fastslam_edu.landmark.multi_robot.laplace_landmarks`."""
    return gtsam_laplace(problem, v, active, with_poses=False)[1]
