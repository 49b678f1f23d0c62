"""The smoother's second backend, GTSAM (fastslam_edu.landmark.smoother_gtsam), against the package's own solver.

The reference is another library: on the same gated sighting set, without the Huber round, GTSAM's
Levenberg–Marquardt and Marginals must reach the package's optimum and Laplace covariances. The cost compared is
½ Σ ‖W e‖² over every factor (prior, odometry, sightings inside the gate, landmark anchors), whitened residuals:
the package's ``SmootherResult.cost`` on one side, GTSAM's ``NonlinearFactorGraph.error`` on the other.
"""

from __future__ import annotations

import json
import re
import sys

import numpy as np
import pytest

from fastslam_edu.app.cli import main
from fastslam_edu.core.motion import MotionNoise
from fastslam_edu.datasets.mrclam import write_dataset
from fastslam_edu.datasets.sim import simulate_dataset
from fastslam_edu.landmark import smoother_gtsam
from fastslam_edu.landmark.fastslam import FastSLAMParams
from fastslam_edu.landmark.smoother import (ODOMETRY_CALIBRATION, PRIOR_STD, SolverSettings, build_problem, smooth,
                                            starting_point)
from fastslam_edu.landmark.smoother_factors import dead_reckon_stream, keyframe_steps
from streams import simulate

NOISE = MotionNoise(sigma_v=0.01, sigma_omega=0.02)
NO_HUBER = SolverSettings(huber=False)


def _params(**kw):
    """The simulation's noise; R growing with range and tempered sightings, so that every term of the model counts."""
    base = dict(motion_noise=NOISE, measurement_cov=np.diag([0.05**2, 0.02**2]), range_std_slope=0.01,
                measurement_correlation_s=1.0)
    base.update(kw)
    return FastSLAMParams(**base)


def _problem(seed: int, duration: float, params):
    """The smoother's problem on a simulated log, at its starting point (dead reckoning), every sighting active."""
    _, _, stream = simulate(seed, duration=duration)
    keys = keyframe_steps(stream)
    path = dead_reckon_stream(stream, stream.x0)
    problem, seen, _ = build_problem(stream, params, keys, path, stream.x0, PRIOR_STD)
    v = starting_point(problem, path, keys, seen, None)
    problem.anchor = problem.split(v)[1] + 0.3  # anchors away from the landmarks: their term counts too
    return problem, v


def _package_cost(problem, v, active) -> float:
    r, _, _ = problem.evaluate(v, active)
    return 0.5 * float(r @ r)


def _sigmas(result) -> np.ndarray:
    o = result.observed
    return np.sqrt(np.diagonal(result.landmarks_cov[o], axis1=1, axis2=2))


@pytest.mark.parametrize("seed, duration, outliers", [(3, 60.0, 0.0), (5, 90.0, 0.05)])
def test_both_backends_reach_the_same_optimum(seed, duration, outliers):
    """Same gated set, no Huber round: path and landmarks within 1 mm, cost within 1e-6 relative, Laplace σ of the
    landmarks (and of the poses) within 1 %. With 5 % outliers the gate sets some aside: the same ones on both."""
    pytest.importorskip("gtsam")
    _, _, stream = simulate(seed, duration=duration, outlier_prob=outliers)
    a = smooth(stream, _params(), solver=NO_HUBER, pose_std=True)
    b = smooth(stream, _params(), solver=NO_HUBER, pose_std=True, backend="gtsam")
    assert (a.backend, b.backend) == ("scipy", "gtsam")
    assert (b.measurements_used, b.measurements_rejected) == (a.measurements_used, a.measurements_rejected)
    assert (a.measurements_rejected > 20) == (outliers > 0)
    np.testing.assert_array_equal(b.observed, a.observed)
    assert np.abs(b.poses[:, :2] - a.poses[:, :2]).max() < 1e-3
    assert np.abs(np.angle(np.exp(1j * (b.poses[:, 2] - a.poses[:, 2])))).max() < 1e-4
    assert np.abs(b.landmarks[a.observed] - a.landmarks[a.observed]).max() < 1e-3
    assert abs(b.cost - a.cost) <= 1e-6 * a.cost
    np.testing.assert_allclose(_sigmas(b), _sigmas(a), rtol=0.01)
    np.testing.assert_allclose(b.pose_std, a.pose_std, rtol=0.01)


def test_the_factor_graph_error_is_the_package_cost():
    """Away from any optimum (perturbed poses and landmarks, anchors off): GTSAM's ½ Σ ‖W e‖² of the graph equals the
    package's ½ rᵀr to rounding (1e-9 relative of a cost of 2e7, of which the sightings are 6e-5: with R_i in the
    wrong order it is 7e-6 off), term by term the same model (prior, odometry, tempered R_i in GTSAM's (bearing,
    range) order, anchors), and the same with a subset of the sightings active."""
    pytest.importorskip("gtsam")
    problem, v = _problem(6, 30.0, _params())
    rng = np.random.default_rng(0)
    v = v + rng.normal(scale=0.05, size=v.shape)
    for active in (np.ones(len(problem.z), dtype=bool), rng.random(len(problem.z)) < 0.5):
        graph = smoother_gtsam.factor_graph(problem, active)
        expected = _package_cost(problem, v, active)
        assert graph.error(smoother_gtsam.to_values(problem, v)) == pytest.approx(expected, rel=1e-9)


def test_between_factor_uses_the_se2_logarithm(monkeypatch):
    """GTSAM's own BetweenFactorPose2 (ODOMETRY_FACTOR = "between", covariance turned into the frame of Δ's end)
    equals the package's cost where the odometry residuals vanish (dead reckoning), and differs where they do
    not: Log(Δ⁻¹ x_a⁻¹ x_b) is not the componentwise difference once the heading residual φ ≠ 0."""
    pytest.importorskip("gtsam")
    problem, v = _problem(6, 30.0, _params())
    active = np.ones(len(problem.z), dtype=bool)
    monkeypatch.setattr(smoother_gtsam, "ODOMETRY_FACTOR", "between")
    graph = smoother_gtsam.factor_graph(problem, active)
    assert graph.error(smoother_gtsam.to_values(problem, v)) == pytest.approx(_package_cost(problem, v, active),
                                                                             rel=1e-12)
    moved = v.copy()
    moved[2:3 * problem.n_poses:3] += np.random.default_rng(1).normal(scale=0.05, size=problem.n_poses)
    moved[0:3 * problem.n_poses:3] += 0.02
    assert graph.error(smoother_gtsam.to_values(problem, moved)) != pytest.approx(
        _package_cost(problem, moved, active), rel=1e-6)


def test_odometry_chain_factor_matches_the_package_and_finite_differences():
    """One CustomFactor over a chain of 4 odometry steps: its error is the package's whitened residuals, its
    Jacobians central differences of that error under GTSAM's own retraction (x exp(δ))."""
    gtsam = pytest.importorskip("gtsam")
    from fastslam_edu.landmark.smoother_factors import odometry_residuals, whitening

    rng = np.random.default_rng(2)
    m = 4
    x, delta = rng.normal(size=(m + 1, 3)) * 2, rng.normal(size=(m, 3)) * 0.3
    L = rng.normal(size=(m, 3, 3)) * 0.1
    W = whitening(L @ np.swapaxes(L, 1, 2) + 0.01 * np.eye(3))
    factor = smoother_gtsam.odometry_chain_factor(3, delta, W)

    def values_at(poses):
        values = gtsam.Values()
        for i, p in enumerate(poses):
            values.insert(smoother_gtsam.pose_key(3 + i), p)
        return values

    poses = [gtsam.Pose2(*p) for p in x]
    expected = np.einsum("kij,kj->ki", W, odometry_residuals(x[:-1], x[1:], delta)[0]).ravel()
    np.testing.assert_allclose(factor.unwhitenedError(values_at(poses)), expected, atol=1e-12)
    jacobian = factor.linearize(values_at(poses)).jacobian()[0]  # [A_0 … A_m], unit noise
    numeric = np.zeros((3 * m, 3 * (m + 1)))
    for col in range(3 * (m + 1)):
        d = np.zeros(3)
        d[col % 3] = 1e-6
        i = col // 3
        plus, minus = list(poses), list(poses)
        plus[i], minus[i] = poses[i].retract(d), poses[i].retract(-d)
        numeric[:, col] = (factor.unwhitenedError(values_at(plus)) - factor.unwhitenedError(values_at(minus))) / 2e-6
    np.testing.assert_allclose(jacobian, numeric, atol=1e-5)


def test_without_gtsam_the_backend_is_refused_in_one_line(monkeypatch):
    _, _, stream = simulate(7, duration=5.0)
    monkeypatch.setitem(sys.modules, "gtsam", None)  # `import gtsam` raises ImportError
    with pytest.raises(ImportError, match=re.escape("backend='gtsam' needs GTSAM: pip install 'fastslam-edu[graph]'")):
        smooth(stream, _params(), backend="gtsam")


def test_calibration_and_unknown_backends_are_refused():
    _, _, stream = simulate(7, duration=5.0)
    with pytest.raises(ValueError, match="calibrate"):
        smooth(stream, _params(), backend="gtsam", solver=SolverSettings(calibrate=ODOMETRY_CALIBRATION))
    with pytest.raises(ValueError, match="backend must be 'scipy' or 'gtsam', got 'ceres'"):
        smooth(stream, _params(), backend="ceres")


# --------------------------------------------------------------------------- the command line


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory):
    return write_dataset(simulate_dataset(4, duration=30.0), tmp_path_factory.mktemp("sim") / "MRCLAM_Sim")


def _run(dataset_dir, out, *extra) -> int:
    return main(["run", "--data", str(dataset_dir), "--robot", "1", "--particles", "20", "--json", str(out),
                 "--quiet", *extra])


def test_cli_smoother_backend_round_trip(dataset_dir, tmp_path, capsys):
    """--smoother-backend gtsam: the JSON's smoother part says so and gives its time; its figures are the scipy
    backend's (the same problem, Huber round included, from the same filter run)."""
    pytest.importorskip("gtsam")
    assert _run(dataset_dir, tmp_path / "s.json", "--smooth") == 0
    assert _run(dataset_dir, tmp_path / "g.json", "--smooth", "--smoother-backend", "gtsam") == 0
    s, g = (json.loads((tmp_path / f"{n}.json").read_text())["smoother"] for n in "sg")
    assert (s["backend"], g["backend"]) == ("scipy", "gtsam")
    assert g["seconds"] > 0 and s["seconds"] > 0
    assert g["measurements_used"] == s["measurements_used"]
    for key in ("path_rmse_m", "landmark_error_mean_m", "landmark_std_mean_m"):
        assert g[key] == pytest.approx(s[key], abs=1e-4), key


def test_cli_refuses_the_backend_without_gtsam_or_without_smooth(dataset_dir, tmp_path, capsys, monkeypatch):
    assert _run(dataset_dir, tmp_path / "x.json", "--smoother-backend", "gtsam") == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "give --smooth too" in err
    monkeypatch.setitem(sys.modules, "gtsam", None)
    assert _run(dataset_dir, tmp_path / "x.json", "--smooth", "--smoother-backend", "gtsam") == 2
    err = capsys.readouterr().err
    assert err == "fastslam-edu run: error: backend='gtsam' needs GTSAM: pip install 'fastslam-edu[graph]'\n"
    assert not (tmp_path / "x.json").exists()


# --------------------------------------------------------------------------- several robots (smooth_robots)


def _robots(seed: int, n_robots: int, duration: float):
    """A simulated team that sees the landmarks and each other: streams and robot-robot sightings per robot."""
    from fastslam_edu.datasets.events import event_stream

    data = simulate_dataset(seed, n_robots=n_robots, see_robots=True, duration=duration)
    streams = {r: event_stream(log, data.landmark_subjects) for r, log in data.robots.items()}
    return streams, {r: log.robot_sightings for r, log in data.robots.items()}


@pytest.mark.parametrize("seed, n_robots", [(1, 2), (2, 3)])
def test_both_backends_reach_the_same_optimum_with_several_robots(seed, n_robots):
    """smooth_robots, same gated set, no Huber round: every robot's path and the shared map within 1 mm, the cost
    within 1e-6 relative, the landmarks' Laplace σ within 1 %; the robot-robot sightings are used (and gated) alike."""
    pytest.importorskip("gtsam")
    from fastslam_edu.landmark.multi_robot import smooth_robots

    streams, sightings = _robots(seed, n_robots, 40.0)
    a = smooth_robots(streams, sightings, _params(), solver=NO_HUBER)
    b = smooth_robots(streams, sightings, _params(), solver=NO_HUBER, backend="gtsam")
    assert (a.backend, b.backend, b.robot(1).backend) == ("scipy", "gtsam", "gtsam")
    assert a.robot_sightings_used > 20 and a.measurements_used > 100
    assert (b.robot_sightings_used, b.robot_sightings_gated) == (a.robot_sightings_used, a.robot_sightings_gated)
    assert (b.measurements_used, b.measurements_rejected) == (a.measurements_used, a.measurements_rejected)
    for r in a.robots:
        assert np.abs(b.poses[r][:, :2] - a.poses[r][:, :2]).max() < 1e-3
        assert np.abs(np.angle(np.exp(1j * (b.poses[r][:, 2] - a.poses[r][:, 2])))).max() < 1e-4
    np.testing.assert_array_equal(b.observed, a.observed)
    assert np.abs(b.landmarks[a.observed] - a.landmarks[a.observed]).max() < 1e-3
    assert abs(b.cost - a.cost) <= 1e-6 * a.cost
    np.testing.assert_allclose(_sigmas(b), _sigmas(a), rtol=0.01)


def test_the_robots_factor_graph_error_is_the_package_cost():
    """Away from the optimum, GTSAM's error of the several-robot graph is the package's ½ rᵀr (and Σρ with the Huber
    loss on every sighting, landmarks' and robots'): the same factors, robot-robot sightings included."""
    pytest.importorskip("gtsam")
    from fastslam_edu.landmark import multi_robot
    from fastslam_edu.landmark.smoother import levenberg_marquardt

    streams, sightings = _robots(3, 3, 30.0)
    captured = {}

    def capture(problem, v, active, **kw):  # the joint problem as solve_with_gate hands it over
        captured.update(problem=problem, v=v.copy(), active=active.copy())
        return levenberg_marquardt(problem, v, active, **kw)

    original = multi_robot._backend
    try:
        multi_robot._backend = lambda backend: (capture, multi_robot.laplace_landmarks)
        multi_robot.smooth_robots(streams, sightings, _params(), solver=NO_HUBER.replace(max_rounds=1))
    finally:
        multi_robot._backend = original
    problem, v = captured["problem"], captured["v"]
    assert len(problem.ra) > 20
    rng = np.random.default_rng(4)
    v = v + rng.normal(scale=0.05, size=v.shape)
    for slot, x0 in zip(problem.prior_slot, problem.x0):  # the priors' Log differs from x - x̄ to second order only
        v[3 * slot:3 * slot + 3] = x0 + rng.normal(scale=1e-4, size=3)  # (module docstring): keep it within 1 σ
    huber = 1.5
    for active in (np.ones(len(problem.z), dtype=bool), rng.random(len(problem.z)) < 0.5):
        values = smoother_gtsam.to_values(problem, v)
        assert smoother_gtsam.factor_graph(problem, active).error(values) == pytest.approx(
            _package_cost(problem, v, active), rel=1e-9)
        r, _, rows = problem.evaluate(v, active)
        s = np.linalg.norm(r[rows].reshape(-1, 2), axis=1)
        rho = np.where(s <= huber, 0.5 * s * s, huber * s - 0.5 * huber * huber)
        other = np.ones(len(r), dtype=bool)
        other[rows] = False
        assert (s > huber).sum() > 10
        assert smoother_gtsam.factor_graph(problem, active, huber).error(values) == pytest.approx(
            0.5 * r[other] @ r[other] + rho.sum(), rel=1e-9)


@pytest.mark.parametrize("huber", [None, 20.0])
def test_robot_sighting_factor_matches_the_package_and_finite_differences(huber):
    """A group of robot-robot sightings as one CustomFactor (two sightings share a pose): its error is the package's
    whitened residuals (the Huber loss's ½‖g r‖² = ρ per sighting), its Jacobians central differences of that error
    under GTSAM's retraction x exp(δ)."""
    gtsam = pytest.importorskip("gtsam")
    from fastslam_edu.landmark.robot_sightings import compose_unwrapped as compose
    from fastslam_edu.landmark.smoother_factors import sighting_residuals, whitening

    rng = np.random.default_rng(5)
    ra, rb = np.array([0, 2, 0]), np.array([1, 3, 3])
    x = rng.normal(size=(4, 3)) * [2.0, 2.0, 1.5]
    da, db = rng.normal(size=(3, 3)) * 0.3, rng.normal(size=(3, 3)) * 0.3
    z = np.c_[rng.uniform(1, 3, 3), rng.uniform(-1, 1, 3)]
    L = rng.normal(size=(3, 2, 2)) * 0.1
    W = whitening(L @ np.swapaxes(L, 1, 2) + 0.01 * np.eye(2))
    factor = smoother_gtsam.robot_sighting_factor(ra, rb, da, db, z, W, huber)

    def values_at(poses):
        values = gtsam.Values()
        for i, p in enumerate(poses):
            values.insert(smoother_gtsam.pose_key(i), p)
        return values

    poses = [gtsam.Pose2(*p) for p in x]
    e = sighting_residuals(compose(x[ra], da), compose(x[rb], db)[:, :2], z)[0]
    r = np.einsum("nij,nj->ni", W, e)
    s = np.linalg.norm(r, axis=1)
    if huber is None:
        np.testing.assert_allclose(factor.unwhitenedError(values_at(poses)), r.ravel(), atol=1e-12)
    else:
        assert (s > huber).any() and (s <= huber).any()
        rho = np.where(s <= huber, 0.5 * s * s, huber * s - 0.5 * huber * huber)
        assert factor.error(values_at(poses)) == pytest.approx(rho.sum(), rel=1e-12)
    jacobian = factor.linearize(values_at(poses)).jacobian()[0]
    numeric = np.zeros((6, 12))
    for col in range(12):
        d = np.zeros(3)
        d[col % 3] = 1e-6
        plus, minus = list(poses), list(poses)
        plus[col // 3], minus[col // 3] = poses[col // 3].retract(d), poses[col // 3].retract(-d)
        numeric[:, col] = (factor.unwhitenedError(values_at(plus)) - factor.unwhitenedError(values_at(minus))) / 2e-6
    np.testing.assert_allclose(jacobian, numeric, atol=1e-5)
