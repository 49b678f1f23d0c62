"""Tests of EKF-SLAM (fastslam_edu.landmark.ekf_slam), on simulated data only.

* one prediction and one update against filterpy's ExtendedKalmanFilter on the same joint state (to 1e-10);
* the composed prediction of a segment against step-by-step predictions;
* every Jacobian against central finite differences; the new landmark's cross-covariances against the
  linearised augmentation computed from scratch;
* a simulated run with known truth: small landmark errors, and the NEES of the whole final map inside the χ²
  interval — while the same map with its covariance divided by 3 is outside it (the test can fail);
* Σ symmetric and positive semi-definite after a run; the gate rejects an outlier; same input, same numbers;
* bad input gives clear errors; ``fastslam-edu run --filter ekf`` writes FastSLAM's JSON keys;
* unknown correspondences (table 10.2): the distances against the dense update's, a new landmark exactly when
  every distance exceeds the threshold, a near-duplicate pair split by mutual exclusion, the scoring, correct
  association in simulation (and a too-small threshold caught), the same numbers with and without barcodes.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from filterpy.kalman import ExtendedKalmanFilter
from scipy.stats import chi2

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.measurement import (innovation, jacobian_inverse, jacobian_landmark, landmark_from_measurement,
                                           range_bearing)
from fastslam_edu.core.motion import MotionNoise, advance, propagate
from fastslam_edu.datasets.events import event_stream
from fastslam_edu.datasets.sim import SimConfig, simulate_dataset
from fastslam_edu.evaluation.consistency import nees, simulator_params
from fastslam_edu.landmark.ekf_slam import EKFSLAMParams, run_ekf_slam
from fastslam_edu.landmark.ekf_slam_association import (NEW, SET_ASIDE, add_new_landmark, associate,
                                                        association_distances)
from fastslam_edu.landmark.ekf_slam_steps import (EKFSLAMState, augment_state, correlation_matrix,
                                                  full_measurement_jacobian, jacobian_inverse_pose, landmark_slice,
                                                  measurement_jacobian, motion_jacobian, motion_noise_covariance,
                                                  predict, predict_segment, update)
from fastslam_edu.evaluation.association import association_accuracy, match_landmarks
from fastslam_edu.landmark.fastslam import FastSLAMParams

CONTROL = MotionNoise(mode="control", sigma_v=0.02, sigma_omega=0.05)
STATE = MotionNoise(mode="state", sigma_xy=0.03, sigma_theta=0.04)
R = np.diag([0.1**2, 0.03**2])


def joint_state(seed: int = 0, n_landmarks: int = 4, seen=(0, 2)) -> EKFSLAMState:
    """A joint state with some landmarks seen, a random positive definite Σ over the pose and those landmarks."""
    rng = np.random.default_rng(seed)
    state = EKFSLAMState.initial(n_landmarks, [0.4, -0.3, 2.9])  # heading near π: wrapping matters
    rows = [0, 1, 2] + [i for k in seen for i in range(3 + 2 * k, 5 + 2 * k)]
    A = rng.normal(size=(len(rows), len(rows))) * 0.1
    state.sigma[np.ix_(rows, rows)] = A @ A.T + 0.01 * np.eye(len(rows))
    for k in seen:
        state.mu[landmark_slice(k)] = rng.uniform(-4, 4, 2)
        state.seen[k] = True
    return state


def numeric_jacobian(f, x, eps=1e-6) -> np.ndarray:
    """Central differences of ``f`` (returning an array) at ``x``; angle outputs are wrapped differences."""
    x = np.asarray(x, dtype=float)
    cols = []
    for i in range(len(x)):
        d = np.zeros_like(x)
        d[i] = eps
        cols.append((np.asarray(f(x + d)) - np.asarray(f(x - d))) / (2 * eps))
    return np.stack(cols, axis=-1)


# ---------------------------------------------------------------- against filterpy


@pytest.mark.parametrize("noise", [CONTROL, STATE], ids=["control", "state"])
def test_one_prediction_matches_filterpy(noise):
    state = joint_state(1)
    n, u, dt = len(state.mu), np.array([0.3, -0.8]), 0.25
    ekf = ExtendedKalmanFilter(dim_x=n, dim_z=2)
    ekf.x, ekf.P = state.mu.copy(), state.sigma.copy()
    ekf.F = np.eye(n)
    ekf.F[:3, :3] = motion_jacobian(state.mu[:3], u, dt)
    ekf.Q = np.zeros((n, n))
    ekf.Q[:3, :3] = motion_noise_covariance(state.mu[:3], dt, noise)

    def predict_x(u_):  # the nonlinear motion on the pose; the map stays
        ekf.x = ekf.x.copy()
        ekf.x[:3] = propagate(ekf.x[:3], u_, dt)

    ekf.predict_x = predict_x
    ekf.predict(u)
    predict(state, u, dt, noise)
    np.testing.assert_allclose(state.mu, ekf.x, rtol=0, atol=1e-10)
    np.testing.assert_allclose(state.sigma, ekf.P, rtol=0, atol=1e-10)
    assert not np.allclose(ekf.P, joint_state(1).sigma)  # the step changed something


def test_one_update_matches_filterpy():
    state = joint_state(2)
    state.mu[2] = 3.13  # the update turns the heading past π: it must come back wrapped
    k = 2
    z = range_bearing(state.mu[:3], state.mu[landmark_slice(k)]) + np.array([0.15, -0.04])
    ekf = ExtendedKalmanFilter(dim_x=len(state.mu), dim_z=2)
    ekf.x, ekf.P = state.mu.copy(), state.sigma.copy()

    def H_of(x):
        return full_measurement_jacobian(EKFSLAMState(x, state.sigma, state.seen), k)

    def h_of(x):
        return range_bearing(x[:3], x[landmark_slice(k)])

    ekf.update(z, H_of, h_of, R=R, residual=innovation)
    outcome = update(state, z, k, R)
    assert outcome == "updated"
    x_filterpy = ekf.x.copy()
    assert x_filterpy[2] > math.pi  # filterpy adds K ν and leaves the angle as it is
    x_filterpy[2] = wrap_angle(x_filterpy[2])
    np.testing.assert_allclose(state.mu, x_filterpy, rtol=0, atol=1e-10)
    np.testing.assert_allclose(state.sigma, ekf.P, rtol=0, atol=1e-10)
    unseen = landmark_slice(1)  # a landmark not seen yet stays out of it
    assert not state.sigma[unseen].any() and not state.mu[unseen].any()


# ---------------------------------------------------------------- prediction over a segment


@pytest.mark.parametrize("noise", [CONTROL, STATE], ids=["control", "state"])
def test_segment_prediction_equals_step_by_step(noise):
    rng = np.random.default_rng(3)
    u = np.column_stack([rng.uniform(0, 0.4, 40), rng.uniform(-1.5, 1.5, 40)])
    dt = rng.uniform(0.0, 0.05, 40)
    dt[0] = 0.0
    one, many = joint_state(4), joint_state(4)
    path = predict_segment(many, u, dt, noise)
    steps = []
    for ui, di in zip(u, dt):
        predict(one, ui, di, noise)
        steps.append(one.mu[:3].copy())
    np.testing.assert_allclose(many.mu, one.mu, rtol=0, atol=1e-10)
    np.testing.assert_allclose(many.sigma, one.sigma, rtol=0, atol=1e-10)
    np.testing.assert_allclose(path, np.array(steps), rtol=0, atol=1e-10)
    landmarks = slice(3, None)
    np.testing.assert_array_equal(many.sigma[landmarks, landmarks], joint_state(4).sigma[landmarks, landmarks])


# ---------------------------------------------------------------- Jacobians


def test_motion_jacobians_against_finite_differences():
    x, u, dt = np.array([1.0, -2.0, 2.5]), np.array([0.4, 0.9]), 0.3
    G = numeric_jacobian(lambda p: propagate(p, u, dt), x)
    np.testing.assert_allclose(motion_jacobian(x, u, dt), G, atol=1e-8)
    # control noise: V = ∂g/∂(Δs, Δθ), and the noise in pose space V M Vᵀ
    V = numeric_jacobian(lambda d: advance(x, d[0], d[1]), np.array([u[0] * dt, u[1] * dt]))
    M = np.diag([CONTROL.sigma_v**2 * dt, CONTROL.sigma_omega**2 * dt])
    np.testing.assert_allclose(motion_noise_covariance(x, dt, CONTROL), V @ M @ V.T, atol=1e-12)


def test_segment_jacobian_against_finite_differences():
    """The composed prediction's G: the derivative of the dead-reckoned end pose with respect to the start pose."""
    rng = np.random.default_rng(5)
    u = np.column_stack([rng.uniform(0, 0.4, 30), rng.uniform(-1, 1, 30)])
    dt = rng.uniform(0.01, 0.05, 30)

    def end_pose(x0):
        s = EKFSLAMState.initial(0, x0)
        predict_segment(s, u, dt, MotionNoise())
        return s.mu[:3]

    x0 = np.array([0.5, 0.2, -0.4])
    G = numeric_jacobian(end_pose, x0)
    s = EKFSLAMState.initial(0, x0, pose_cov=np.eye(3))
    predict_segment(s, u, dt, MotionNoise())  # no noise: Σ = G I Gᵀ
    np.testing.assert_allclose(s.sigma, G @ G.T, atol=1e-8)


def test_measurement_jacobians_against_finite_differences():
    state = joint_state(6)
    k = 0
    x, m = state.mu[:3].copy(), state.mu[landmark_slice(k)].copy()
    z_hat, Gx, H = measurement_jacobian(state, k)
    np.testing.assert_allclose(z_hat, range_bearing(x, m))
    np.testing.assert_allclose(Gx, numeric_jacobian(lambda p: range_bearing(p, m), x), atol=1e-8)
    np.testing.assert_allclose(H, numeric_jacobian(lambda q: range_bearing(x, q), m), atol=1e-8)
    np.testing.assert_allclose(H, jacobian_landmark(x, m), atol=1e-14)
    Ht = full_measurement_jacobian(state, k)
    np.testing.assert_allclose(Ht, numeric_jacobian(lambda y: range_bearing(y[:3], y[landmark_slice(k)]), state.mu),
                               atol=1e-8)


def test_inverse_model_jacobians_against_finite_differences():
    x, z = np.array([0.3, -1.0, 2.0]), np.array([2.5, 0.7])
    np.testing.assert_allclose(jacobian_inverse_pose(x, z),
                               numeric_jacobian(lambda p: landmark_from_measurement(p, z), x), atol=1e-8)
    np.testing.assert_allclose(jacobian_inverse(x, z),
                               numeric_jacobian(lambda w: landmark_from_measurement(x, w), z), atol=1e-8)


def test_new_landmark_covariance_is_the_linearised_augmentation():
    """(y, z) ↦ (y, h⁻¹(x, z)), linearised and applied to diag(Σ, R): the new landmark's rows, from scratch."""
    state = joint_state(7)
    k, z = 1, np.array([2.0, -0.5])
    n = len(state.mu)

    def augment(v):  # v = (y, z)
        y = v[:n].copy()
        y[landmark_slice(k)] = landmark_from_measurement(v[:3], v[n:])
        return y

    J = numeric_jacobian(augment, np.concatenate([state.mu, z]))
    big = np.zeros((n + 2, n + 2))
    big[:n, :n], big[n:, n:] = state.sigma, R
    expected = J @ big @ J.T
    augment_state(state, z, k, R)
    np.testing.assert_allclose(state.sigma, expected, atol=1e-8)
    np.testing.assert_allclose(state.mu[landmark_slice(k)], landmark_from_measurement(state.mu[:3], z))
    assert state.seen[k]


# ---------------------------------------------------------------- a simulated run with known truth


def simulated_run(seed: int, **sim):
    data = simulate_dataset(seed, **{"duration": 60.0, **sim})
    config = SimConfig(**{"duration": 60.0, **sim})
    stream = event_stream(data.robots[1], data.landmark_subjects)
    return data, stream, run_ekf_slam(stream, simulator_params(config))


def map_nees(result, truth, scale: float = 1.0) -> tuple[float, int]:
    """NEES of the whole final map (the landmarks are correlated: one joint statistic) and its degrees of freedom."""
    seen = np.flatnonzero(result.observed)
    rows = np.concatenate([[3 + 2 * k, 4 + 2 * k] for k in seen])
    error = (result.landmarks_mean[seen] - truth[seen]).ravel()
    return float(nees(error, result.cov[np.ix_(rows, rows)] * scale)), len(rows)


@pytest.fixture(scope="module")
def runs():
    return [simulated_run(seed) for seed in range(6)]


def test_simulated_landmarks_are_accurate_and_their_covariance_honest(runs):
    errors, total, total_bold, dof = [], 0.0, 0.0, 0
    for data, stream, result in runs:
        truth = data.landmark_positions
        assert result.observed.sum() >= 8
        errors.append(np.nanmean(np.hypot(*(result.landmarks_mean - truth).T)))
        eps, d = map_nees(result, truth)
        total, dof = total + eps, dof + d
        total_bold += map_nees(result, truth, scale=1 / 3)[0]
        assert result.measurements_used == stream.n_measurements and result.measurements_rejected == 0
    lo, hi = chi2.ppf([0.005, 0.995], dof)  # the sum of the runs' NEES is χ² with the summed dimensions
    assert np.median(errors) < 0.1 and max(errors) < 0.4
    assert lo < total < hi, (total / dof, lo / dof, hi / dof)
    assert total_bold > hi  # a covariance 3 times too small is caught


def test_covariance_is_symmetric_and_positive_semidefinite_after_a_run(runs):
    for _, _, result in runs:
        P = result.cov
        np.testing.assert_array_equal(P, P.T)
        assert np.linalg.eigvalsh(P).min() > -1e-12 * np.abs(P).max()
        for C in result.pose_cov:
            assert np.all(np.linalg.eigvalsh(C) >= -1e-15)
        rho = correlation_matrix(P)
        seen = np.isfinite(np.diag(rho))
        assert np.nanmax(np.abs(rho)) <= 1 + 1e-9 and np.allclose(np.diag(rho)[seen], 1.0)


def test_the_map_becomes_correlated_through_the_pose(runs):
    """Landmarks seen from uncertain poses share their error: strongly correlated in the final Σ."""
    _, _, result = runs[0]
    rho = correlation_matrix(result.cov)[3:, 3:]
    seen = np.repeat(result.observed, 2)
    off = rho[np.ix_(seen, seen)][~np.eye(2 * result.observed.sum(), dtype=bool)]
    assert np.median(np.abs(off)) > 0.3


def test_same_input_same_numbers(runs):
    data, stream, first = runs[2]
    again = run_ekf_slam(stream, simulator_params(SimConfig(duration=60.0)))
    np.testing.assert_array_equal(first.pose_mean, again.pose_mean)
    np.testing.assert_array_equal(first.cov, again.cov)
    _, _, other = simulated_run(3)  # another seed, other numbers
    assert not np.array_equal(first.landmarks_mean, other.landmarks_mean)


# ---------------------------------------------------------------- the gate


def test_gate_rejects_an_outlier_and_leaves_the_state_alone():
    state = joint_state(8)
    k = 0
    z = range_bearing(state.mu[:3], state.mu[landmark_slice(k)]) + np.array([2.0, 0.0])  # 2 m off
    before = state.copy()
    assert update(state, z, k, R, gate_chi2=FastSLAMParams().gate_chi2) == "rejected"
    np.testing.assert_array_equal(state.mu, before.mu)
    np.testing.assert_array_equal(state.sigma, before.sigma)
    assert update(state, z, k, R, gate_chi2=FastSLAMParams().gate_chi2, escape=True) == "updated"
    fresh = joint_state(8)
    assert update(fresh, z, k, R, gate_chi2=None) == "updated"  # no gate: applied
    near = range_bearing(fresh.mu[:3], fresh.mu[landmark_slice(k)])
    assert update(fresh, near, k, R, gate_chi2=FastSLAMParams().gate_chi2) == "updated"


def test_gate_keeps_a_run_with_outliers_on_track():
    data, stream, gated = simulated_run(1, outlier_prob=0.05)
    config = SimConfig(duration=60.0, outlier_prob=0.05)
    ungated = run_ekf_slam(stream, simulator_params(config, gate_chi2=None))
    truth = data.landmark_positions
    err = {name: np.nanmean(np.hypot(*(r.landmarks_mean - truth).T)) for name, r in (("gated", gated),
                                                                                    ("ungated", ungated))}
    assert gated.measurements_rejected >= 0.5 * 0.05 * stream.n_measurements
    assert ungated.measurements_rejected == 0
    assert err["gated"] < 0.15 and err["gated"] < err["ungated"] / 2, err


# ---------------------------------------------------------------- parameters and bad input


def test_params_share_fastslams_defaults_and_check_them():
    p, f = EKFSLAMParams(), FastSLAMParams()
    assert p.motion_noise == f.motion_noise and np.array_equal(p.measurement_cov, f.measurement_cov)
    assert (p.range_std_slope, p.gate_chi2, p.gate_escape_s) == (f.range_std_slope, f.gate_chi2, f.gate_escape_s)
    z = np.array([[1.0, 0.1], [4.0, -0.3]])
    np.testing.assert_array_equal(p.measurement_covariance(z), f.measurement_covariance(z))
    assert EKFSLAMParams.from_fastslam(f) == p
    assert json.dumps(p.to_dict())
    with pytest.raises(ValueError, match="measurement_cov"):
        EKFSLAMParams(measurement_cov=np.diag([1.0, -1.0]))
    with pytest.raises(ValueError, match="gate_chi2"):
        EKFSLAMParams(gate_chi2=-1.0)


def test_bad_input_gives_clear_errors():
    data = simulate_dataset(0, duration=5.0)
    stream = event_stream(data.robots[1], data.landmark_subjects)
    with pytest.raises(ValueError, match="initial pose"):
        run_ekf_slam(stream, x0=[0.0, math.nan, 0.0])
    with pytest.raises(ValueError, match="params"):
        run_ekf_slam(stream, params={"gate_chi2": 3})
    with pytest.raises(ValueError, match="EventStream"):
        run_ekf_slam("not a stream")
    state = joint_state(0)
    with pytest.raises(ValueError, match="landmark index"):
        update(state, [1.0, 0.0], 4, R)
    with pytest.raises(ValueError, match="negative range"):
        update(state, [-1.0, 0.0], 0, R)
    with pytest.raises(ValueError, match="shape"):
        update(state, [1.0, 0.0, 0.0], 0, R)
    with pytest.raises(ValueError, match="non-finite"):
        update(state, [1.0, 0.0], 0, np.full((2, 2), np.nan))
    with pytest.raises(ValueError, match="MotionNoise"):
        predict(state, [0.1, 0.0], 0.1, noise=(0.1, 0.1))
    with pytest.raises(ValueError, match="dt"):
        predict(state, [0.1, 0.0], -0.1, CONTROL)
    with pytest.raises(ValueError, match="pose_cov"):
        EKFSLAMState.initial(3, [0, 0, 0], pose_cov=-np.eye(3))


def test_fastslam_params_are_accepted_for_a_fair_comparison():
    data = simulate_dataset(2, duration=20.0)
    stream = event_stream(data.robots[1], data.landmark_subjects)
    a, b = run_ekf_slam(stream, FastSLAMParams()), run_ekf_slam(stream, EKFSLAMParams())
    np.testing.assert_array_equal(a.cov, b.cov)
    assert a.pose_mean.shape == (len(stream), 3) and a.pose_cov.shape == (len(a.update_t), 3, 3)


# ---------------------------------------------------------------- the command line


def test_command_line_filter_ekf_writes_fastslams_keys(tmp_path, capsys):
    from fastslam_edu.app.cli import main
    from fastslam_edu.datasets.mrclam import write_dataset

    folder = write_dataset(simulate_dataset(4, duration=30.0), tmp_path / "MRCLAM_Sim")
    args = ["run", "--data", str(folder), "--robot", "1", "--quiet"]
    assert main(args + ["--json", str(tmp_path / "fs.json"), "--particles", "20"]) == 0
    ekf_args = ["--filter", "ekf", "--json", str(tmp_path / "ekf.json"), "--plot", str(tmp_path / "e.png")]
    assert main(args + ekf_args) == 0
    fs, ekf = (json.loads((tmp_path / f).read_text()) for f in ("fs.json", "ekf.json"))
    assert ekf["filter"] == "ekf" and fs["filter"] == "fastslam"
    shared = set(fs) - {"resamples"}  # nothing to resample in an EKF
    assert shared <= set(ekf), shared - set(ekf)
    for key in ("path_rmse_m", "path_rmse_aligned_m", "landmark_error_mean_m", "landmark_error_aligned_mean_m"):
        assert isinstance(ekf[key], float) and math.isfinite(ekf[key]), key
    assert ekf["landmark_error_aligned_mean_m"] < 0.2 and ekf["path_rmse_aligned_m"] < 0.3
    assert ekf["measurements_used"] + ekf["measurements_rejected"] == fs["measurements_used"] + fs[
        "measurements_rejected"]
    assert (tmp_path / "e.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    capsys.readouterr()
    assert main(args + ["--filter", "ekf", "--particles", "50"]) == 1
    assert "--particles" in capsys.readouterr().err


# ---------------------------------------------------------------- unknown correspondences (table 10.2)


def test_association_distances_are_the_updates_mahalanobis_distances():
    """d² of every map landmark at once equals νᵀQ⁻¹ν with Q = H_t Σ H_tᵀ + R from the dense Jacobian."""
    state = joint_state(11, n_landmarks=5, seen=(0, 2, 3))
    z = np.array([3.0, 0.4])
    d2 = association_distances(state, z, R)
    assert np.isinf(d2[[1, 4]]).all()  # not seen: never chosen
    for k in (0, 2, 3):
        Ht = full_measurement_jacobian(state, k)
        nu = innovation(z, range_bearing(state.mu[:3], state.mu[landmark_slice(k)]))
        Q = Ht @ state.sigma @ Ht.T + R
        assert d2[k] == pytest.approx(float(nu @ np.linalg.solve(Q, nu)), rel=1e-10)


def test_a_new_landmark_when_every_distance_exceeds_the_threshold():
    state = EKFSLAMState.initial(0, [0.4, -0.3, 2.9])
    for m in ([2.0, 1.0], [-1.0, 2.0], [-2.0, -2.0]):
        add_new_landmark(state, range_bearing(state.mu[:3], np.array(m)), R)
    near = range_bearing(state.mu[:3], state.mu[landmark_slice(1)]) + np.array([0.05, 0.0])
    d2 = association_distances(state, near, R)
    assert int(np.argmin(d2)) == 1 and d2.min() < 1.0
    assert int(associate(d2[None], 9.0)[0]) == 1
    far = near + np.array([0.0, 0.6])  # 0.6 rad off: far from every landmark
    d2_far = association_distances(state, far, R)
    assert d2_far.min() > 20.0
    alpha = d2_far.min()
    assert int(associate(d2_far[None], alpha * 0.999)[0]) == NEW  # every distance above the threshold: new
    assert int(associate(d2_far[None], alpha * 1.001)[0]) == int(np.argmin(d2_far))  # one below: associated
    # between the gate and the new-landmark threshold: set aside (neither updated nor new)
    assert int(associate(d2_far[None], alpha * 2, gate_chi2=alpha / 2)[0]) == SET_ASIDE
    # the state grows by one landmark, initialised from the sighting
    k = add_new_landmark(state, far, R)
    assert k == 3 and state.n_landmarks == 4 and state.mu.shape == (11,) and state.sigma.shape == (11, 11)
    np.testing.assert_allclose(state.mu[landmark_slice(k)], landmark_from_measurement(state.mu[:3], far))
    assert association_distances(state, far, R)[k] == pytest.approx(0.0, abs=1e-12)


def test_near_duplicate_pair_is_split_only_with_mutual_exclusion():
    """Two landmarks 0.15 m apart, both sighted in one instant, both sightings nearest the first one."""
    state = EKFSLAMState.initial(0, [0.0, 0.0, 0.0])
    for m in ([3.0, 0.0], [3.0, 0.15]):
        add_new_landmark(state, range_bearing(state.mu[:3], np.array(m)), R * 0.01)
    z = np.array([range_bearing(state.mu[:3], np.array([3.0, 0.01])), range_bearing(state.mu[:3], np.array([3.0, 0.05]))])
    d2 = np.stack([association_distances(state, zi, R) for zi in z])
    assert (d2.argmin(axis=1) == 0).all()  # nearest neighbour alone: both to landmark 0 (a merge)
    np.testing.assert_array_equal(associate(d2, 25.0, mutual_exclusion=False), [0, 0])
    np.testing.assert_array_equal(associate(d2, 25.0, mutual_exclusion=True), [0, 1])  # the cheaper split
    # if landmark 1 is out of reach, the second sighting is set aside: not merged into 0, and not new (d² to 0 <= α)
    far = np.stack([association_distances(state, zi, R) for zi in z])
    far[:, 1] = 100.0
    np.testing.assert_array_equal(associate(far, 25.0, mutual_exclusion=True), [0, SET_ASIDE])  # d²(0) <= 25


def scored(result, data, stream):
    """The map matched to the surveyed landmarks, and the association accuracy (evaluation.association)."""
    match = match_landmarks(result.landmarks, data.landmark_positions)
    return match, association_accuracy(result.history, stream.landmark, result.landmark_ident, match)


@pytest.fixture(scope="module")
def unknown_runs(runs):
    out = []
    for seed, (data, stream, known) in enumerate(runs[:4]):
        params = simulator_params(SimConfig(duration=60.0))
        out.append((data, stream, known, run_ekf_slam(stream, params, correspondences="unknown")))
    return out


def test_unknown_correspondences_associate_correctly_in_simulation(unknown_runs):
    for data, stream, _, result in unknown_runs:
        match, accuracy = scored(result, data, stream)
        assert result.correspondences == "unknown" and accuracy > 0.99, accuracy
        assert (match >= 0).all() and len(result.landmarks) == len(np.unique(stream.landmark)) >= 8
        err = np.hypot(*(result.landmarks - data.landmark_positions[match]).T)
        assert err.mean() < 0.1
    # the test can fail: a threshold far too small splits landmarks into spurious copies
    data, stream, _, _ = unknown_runs[0]
    eager = run_ekf_slam(stream, EKFSLAMParams.from_fastslam(simulator_params(SimConfig(duration=60.0))).replace(
        correspondences="unknown", new_landmark_chi2=0.05))
    match, accuracy = scored(eager, data, stream)
    assert (match < 0).sum() > 5 and accuracy < 0.9


def test_without_barcodes_same_numbers_when_association_is_unambiguous(unknown_runs):
    for data, stream, known, unknown in unknown_runs:
        match, accuracy = scored(unknown, data, stream)
        assert accuracy == 1.0
        np.testing.assert_array_equal(match[unknown.sighting_map], stream.landmark)
        np.testing.assert_array_equal(known.sighting_map, stream.landmark)
        assert sorted(match) == np.flatnonzero(known.observed).tolist()
        np.testing.assert_allclose(unknown.pose_mean, known.pose_mean, rtol=0, atol=1e-12)
        np.testing.assert_allclose(unknown.landmarks_mean, known.landmarks_mean[match], rtol=0, atol=1e-12)
        np.testing.assert_allclose(unknown.landmarks_cov, known.landmarks_cov[match], rtol=0, atol=1e-15)


def test_known_correspondences_ignore_the_association_settings(runs):
    data, stream, first = runs[0]
    params = EKFSLAMParams.from_fastslam(simulator_params(SimConfig(duration=60.0)))
    other = run_ekf_slam(stream, params.replace(new_landmark_chi2=1.0, mutual_exclusion=False))
    np.testing.assert_array_equal(first.cov, other.cov)
    assert first.correspondences == "known"


def test_association_settings_are_checked():
    for bad in ({"correspondences": "maybe"}, {"new_landmark_chi2": 0.0}, {"new_landmark_chi2": float("nan")},
                {"mutual_exclusion": "yes"}, {"new_landmark_max_range": -1.0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            EKFSLAMParams(**bad)
    data = simulate_dataset(2, duration=5.0)
    with pytest.raises(ValueError, match="correspondences"):
        run_ekf_slam(event_stream(data.robots[1], data.landmark_subjects), correspondences="barcodes")


def test_new_landmark_max_range_sets_far_first_sightings_aside(unknown_runs):
    data, stream, _, free = unknown_runs[0]
    params = EKFSLAMParams.from_fastslam(simulator_params(SimConfig(duration=60.0)))
    limit = float(np.median(stream.z[:, 0]))
    near = run_ekf_slam(stream, params.replace(correspondences="unknown", new_landmark_max_range=limit))
    born = [np.flatnonzero(near.sighting_map == m)[0] for m in range(len(near.landmarks))]
    born_free = [np.flatnonzero(free.sighting_map == m)[0] for m in range(len(free.landmarks))]
    assert (stream.z[born, 0] <= limit).all() and not (stream.z[born_free, 0] <= limit).all()
    assert near.measurements_rejected > free.measurements_rejected == 0
