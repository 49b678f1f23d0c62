"""Tests of fastslam_edu.datasets.sim against its own stated truth.

References: the groundtruth (interpolated at measurement times) for the
measurement model, a dead-reckoning integration written here (Euler,
fastslam_edu.core.motion.propagate, a different integrator from the simulator's
exact arcs) for the odometry, and binomial / normal sampling bounds.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.datasets.log import Dataset, RobotLog
from fastslam_edu.core.motion import MotionNoise, propagate
from fastslam_edu.datasets.sim import ACCEL_MAX, ANGULAR_ACCEL_MAX, HEADING_GAIN, SimConfig, barcode_of, simulate_dataset

NO_NOISE = MotionNoise()


def groundtruth_at(gt: pd.DataFrame, times: np.ndarray) -> np.ndarray:
    """Groundtruth pose (x, y, θ) linearly interpolated at `times`, θ unwrapped first. Shape (n, 3)."""
    t = gt["time"].to_numpy()
    theta = np.unwrap(gt["theta"].to_numpy())
    return np.column_stack(
        [np.interp(times, t, gt["x"]), np.interp(times, t, gt["y"]), wrap_angle(np.interp(times, t, theta))]
    )


def true_range_bearing(data: Dataset, log: RobotLog) -> tuple[np.ndarray, np.ndarray]:
    """Range and bearing of each measurement's landmark from the interpolated groundtruth."""
    m = log.measurements
    pose = groundtruth_at(log.groundtruth, m["time"].to_numpy())
    landmark = data.landmarks.loc[m["subject"].to_numpy(), ["x", "y"]].to_numpy()
    d = landmark - pose[:, :2]
    return np.hypot(d[:, 0], d[:, 1]), wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - pose[:, 2])


def dead_reckon(log: RobotLog) -> tuple[np.ndarray, np.ndarray]:
    """Integrate the odometry with the Euler model from the first groundtruth pose.

    Row i's command is held from t_i to t_{i+1} (the last one to the end of the groundtruth).
    Returns the times t_0 … t_N and poses, shapes (N+1,), (N+1, 3).
    """
    t = np.append(log.odometry["time"].to_numpy(), log.groundtruth["time"].iloc[-1])
    u = log.odometry[["v", "omega"]].to_numpy()
    x = log.groundtruth[["x", "y", "theta"]].iloc[0].to_numpy()
    poses = [x]
    for i, dt in enumerate(np.diff(t)):
        x = propagate(x, u[i], dt)
        poses.append(x)
    return t, np.array(poses)


@pytest.fixture(scope="module")
def data() -> Dataset:
    return simulate_dataset(2024, n_robots=2)


# --------------------------------------------------------------------------- structure


def test_same_seed_same_dataframes_and_generator_equals_seed():
    a = simulate_dataset(7, duration=30.0)
    b = simulate_dataset(7, duration=30.0)
    c = simulate_dataset(np.random.default_rng(7), duration=30.0)
    for other in (b, c):
        pd.testing.assert_frame_equal(a.landmarks, other.landmarks)
        assert a.barcodes == other.barcodes
        for name in ("odometry", "measurements", "groundtruth"):
            pd.testing.assert_frame_equal(getattr(a.robots[1], name), getattr(other.robots[1], name))
    d = simulate_dataset(8, duration=30.0)
    assert not np.allclose(a.landmark_positions, d.landmark_positions)


def test_structures_columns_dtypes_and_sorted_times(data):
    config = SimConfig()
    assert isinstance(data, Dataset) and data.path is None
    assert list(data.landmarks.columns) == ["x", "y", "x_std", "y_std"]
    assert data.landmarks.index.name == "subject"
    assert data.landmarks.index.dtype == np.int64
    assert data.landmark_subjects.tolist() == list(range(6, 21))
    assert (data.landmarks.dtypes == np.float64).all()
    # barcodes: distinct numbers, mapping to robots 1..2 and landmarks 6..20
    assert sorted(data.barcodes.values()) == [1, 2, *range(6, 21)]
    assert len(set(data.barcodes)) == len(data.barcodes)
    assert sorted(data.robots) == [1, 2]
    half = np.array(config.arena) / 2
    positions = data.landmark_positions
    assert np.all(np.abs(positions) <= half - config.margin)
    gaps = np.hypot(*(positions[:, None] - positions[None]).transpose(2, 0, 1))
    assert gaps[~np.eye(len(positions), dtype=bool)].min() >= config.landmark_spacing

    for robot, log in data.robots.items():
        assert isinstance(log, RobotLog) and log.robot == robot and log.source == "simulation"
        odo, meas, gt = log.odometry, log.measurements, log.groundtruth
        assert list(odo.columns) == ["time", "v", "omega"]
        assert list(meas.columns) == ["time", "subject", "range", "bearing"]
        assert list(gt.columns) == ["time", "x", "y", "theta"]
        for frame in (odo, gt, meas.drop(columns="subject")):
            assert (frame.dtypes == np.float64).all()
        assert meas["subject"].dtype == np.int64
        assert set(meas["subject"]) <= set(data.landmark_subjects)
        assert np.all(np.diff(odo["time"]) > 0)
        assert np.all(np.diff(gt["time"]) > 0)
        assert np.all(np.diff(meas["time"]) >= 0)
        assert odo["time"].iloc[0] == config.t0 == gt["time"].iloc[0]
        assert gt["time"].iloc[-1] == pytest.approx(config.t0 + config.duration, abs=1e-6)
        assert meas["time"].iloc[-1] <= config.t0 + config.duration
        # rates: odometry ~67 Hz (irregular), groundtruth 100 Hz
        assert len(odo) / config.duration == pytest.approx(config.odometry_rate, rel=0.03)
        assert np.diff(odo["time"]).std() > 0.1 / config.odometry_rate
        np.testing.assert_allclose(np.diff(gt["time"]), 1 / config.groundtruth_rate, atol=1e-6)
        # the robot stays in the arena and drives a reasonable distance
        assert np.all(np.abs(gt[["x", "y"]].to_numpy()) < half)
        assert np.all((gt["theta"] > -np.pi) & (gt["theta"] <= np.pi))
        assert np.hypot(np.diff(gt["x"]), np.diff(gt["y"])).sum() > 0.5 * config.v_max * config.duration
        assert len(meas) > 1000


def test_no_landmarks_gives_empty_measurements():
    data = simulate_dataset(1, duration=10.0, n_landmarks=0)
    meas = data.robots[1].measurements
    assert len(meas) == 0 and list(meas.columns) == ["time", "subject", "range", "bearing"]
    assert meas["subject"].dtype == np.int64 and len(data.landmarks) == 0


# --------------------------------------------------------------------------- measurements


def test_measurement_noise_matches_configuration(data):
    config = SimConfig()
    r_true, phi_true = zip(*(true_range_bearing(data, log) for log in data.robots.values()))
    r_meas = np.concatenate([log.measurements["range"] for log in data.robots.values()])
    phi_meas = np.concatenate([log.measurements["bearing"] for log in data.robots.values()])
    dr = r_meas - np.concatenate(r_true)
    dphi = wrap_angle(phi_meas - np.concatenate(phi_true))
    n = len(dr)
    assert n > 3000
    for residual, sigma in ((dr, config.range_std), (dphi, config.bearing_std)):
        assert abs(residual.mean()) < 5 * sigma / math.sqrt(n)
        assert abs(residual.std() / sigma - 1) < 5 / math.sqrt(2 * n)
        assert abs(residual).max() < 6 * sigma  # Gaussian, no outliers by default


def test_measurements_only_within_fov_and_range_and_all_visible_ones_measured(data):
    config = SimConfig()
    tol = 1e-3  # groundtruth interpolation error
    for log in data.robots.values():
        r_true, phi_true = true_range_bearing(data, log)
        assert np.all((r_true >= config.min_range - tol) & (r_true <= config.max_range + tol))
        assert np.all((phi_true >= config.fov[0] - tol) & (phi_true <= config.fov[1] + tol))
        meas = log.measurements
        assert np.all(np.abs(meas["bearing"]) <= config.fov[1] + 6 * config.bearing_std)
        assert np.all(meas["range"] <= config.max_range + 6 * config.range_std)
        # every landmark clearly in view at a frame time is measured in that frame
        frames = np.unique(meas["time"])
        pose = groundtruth_at(log.groundtruth, frames)
        d = data.landmark_positions[None] - pose[:, None, :2]
        r = np.hypot(d[..., 0], d[..., 1])
        phi = wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - pose[:, 2:3])
        clearly = (r > config.min_range + 0.01) & (r < config.max_range - 0.01) \
            & (phi > config.fov[0] + 0.01) & (phi < config.fov[1] - 0.01)
        seen = set(zip(meas["time"], meas["subject"]))
        expected = {(frames[i], data.landmark_subjects[k]) for i, k in zip(*np.nonzero(clearly))}
        assert expected <= seen
        # rate: measurement_rate per visible landmark
        gt_pose = log.groundtruth[["x", "y", "theta"]].to_numpy()
        d = data.landmark_positions[None] - gt_pose[:, None, :2]
        r = np.hypot(d[..., 0], d[..., 1])
        phi = wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - gt_pose[:, 2:3])
        visible_seconds = ((r >= config.min_range) & (r <= config.max_range) & (phi >= config.fov[0])
                           & (phi <= config.fov[1])).sum() / config.groundtruth_rate
        assert len(meas) / visible_seconds == pytest.approx(config.measurement_rate, rel=0.1)


def test_outlier_fraction_matches_outlier_prob():
    config = SimConfig()
    p = 0.2
    data = simulate_dataset(5, outlier_prob=p)
    log = data.robots[1]
    r_true, _ = true_range_bearing(data, log)
    dr = log.measurements["range"].to_numpy() - r_true
    outlier = dr > 0.3  # > 6 σ of the range noise; an outlier adds at least 0.5 m
    n = len(dr)
    assert abs(outlier.mean() - p) < 5 * math.sqrt(p * (1 - p) / n)
    assert dr[outlier].min() > 0.5 - 5 * config.range_std and dr[outlier].max() < 2.0 + 5 * config.range_std
    # the jump is U(0.5, 2): mean 1.25 m
    assert abs(dr[outlier].mean() - 1.25) < 5 * (1.5 / math.sqrt(12)) / math.sqrt(outlier.sum()) + 0.01
    assert abs(dr[~outlier].std() / config.range_std - 1) < 5 / math.sqrt(2 * (~outlier).sum())


# --------------------------------------------------------------------------- odometry


def test_dead_reckoning_of_noise_free_odometry_reproduces_groundtruth():
    for seed in (0, 1, 2):
        data = simulate_dataset(seed, odometry_noise=NO_NOISE)
        log = data.robots[1]
        t, poses = dead_reckon(log)
        truth = groundtruth_at(log.groundtruth, t)
        assert np.hypot(*(poses[:, :2] - truth[:, :2]).T).max() < 0.01
        assert np.abs(wrap_angle(poses[:, 2] - truth[:, 2])).max() < 1e-3
        config = SimConfig()
        assert np.abs(log.odometry["v"]).max() <= config.v_max + 1e-12
        assert np.abs(log.odometry["omega"]).max() <= config.omega_max + 1e-12


def test_odometry_noise_has_the_configured_density_and_truth_does_not_depend_on_it():
    noise = MotionNoise(sigma_v=0.02, sigma_omega=0.05)
    clean = simulate_dataset(3, odometry_noise=NO_NOISE).robots[1]
    noisy = simulate_dataset(3, odometry_noise=noise).robots[1]
    pd.testing.assert_frame_equal(clean.groundtruth, noisy.groundtruth)
    pd.testing.assert_frame_equal(clean.measurements, noisy.measurements)
    t = np.append(clean.odometry["time"].to_numpy(), clean.groundtruth["time"].iloc[-1])
    root_dt = np.sqrt(np.diff(t))
    for column, sigma in (("v", noise.sigma_v), ("omega", noise.sigma_omega)):
        # (û - u) √Δt / σ must be standard normal
        z = (noisy.odometry[column] - clean.odometry[column]).to_numpy() * root_dt / sigma
        n = len(z)
        assert abs(z.mean()) < 5 / math.sqrt(n)
        assert abs(z.std() - 1) < 5 / math.sqrt(2 * n)
    # so the dead-reckoned heading drifts like a random walk of density σ_ω: Var = σ_ω² T
    _, poses = dead_reckon(noisy)
    _, clean_poses = dead_reckon(clean)
    drift = np.unwrap(poses[:, 2]) - np.unwrap(clean_poses[:, 2])
    duration = t[-1] - t[0]
    assert abs(drift[-1]) < 5 * noise.sigma_omega * math.sqrt(duration)


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"durration": 10.0}, "unknown setting"),
        ({"duration": -1.0}, "duration"),
        ({"odometry_rate": float("nan")}, "odometry_rate"),
        ({"n_robots": 6}, "n_robots"),
        ({"n_landmarks": 2.5}, "n_landmarks"),
        ({"fov": (1.0, -1.0)}, "fov"),
        ({"outlier_prob": 1.5}, "outlier_prob"),
        ({"min_range": 6.0}, "min_range"),
        ({"arena": (1.0, 8.0)}, "arena"),
        ({"odometry_noise": MotionNoise("state", sigma_xy=0.1)}, "odometry_noise"),
        ({"n_landmarks": 10, "arena": (4.0, 4.0)}, "cannot place"),  # 2 m × 2 m holds 9,
        ({"min_range": 5.0, "max_range": 5.0}, "min_range"),  # an empty range band
        ({"range_std": -0.1}, "range_std"),
        ({"fov": (0.5, 0.5)}, "fov"),  # an empty field of view
    ],
)
def test_bad_settings_raise_clear_value_error(kwargs, message):
    with pytest.raises(ValueError, match=message):
        simulate_dataset(0, **kwargs)


@pytest.mark.parametrize("seed", [None, -1, 1.5, "1", True])
def test_bad_seed_raises(seed):
    with pytest.raises(ValueError, match="seed"):
        simulate_dataset(seed, duration=1.0)


# --------------------------------------------------------------------------- the true motion, in closed form


def _true_commands(seed, duration=20.0):
    """Noise-free odometry (= the true commands), times from 0, and the groundtruth."""
    log = simulate_dataset(seed, duration=duration, t0=0.0, odometry_noise=NO_NOISE).robots[1]
    return log.odometry, log.groundtruth


def test_groundtruth_follows_exact_arcs_of_the_held_commands():
    """Closed form of the unicycle under a held (v, ω) for τ seconds: x += v/ω (sin(θ + ωτ) − sin θ),
    y −= v/ω (cos(θ + ωτ) − cos θ), θ += ωτ — written as 2 sin(ωτ/2)/ω = τ sinc(ωτ/2π) times
    (cos, sin)(θ + ωτ/2), which is exact and stable for ω → 0 — chained over the odometry rows from the first
    groundtruth pose."""

    def arc(x, y, th, v, w, tau):
        chord = v * tau * np.sinc(w * tau / (2 * np.pi))
        return x + chord * np.cos(th + w * tau / 2), y + chord * np.sin(th + w * tau / 2), th + w * tau

    odo, gt = _true_commands(0)
    t, v, w = (odo[c].to_numpy() for c in ("time", "v", "omega"))
    pose = tuple(gt[["x", "y", "theta"]].iloc[0])
    start = []
    for i, tau in enumerate(np.diff(np.append(t, 20.0))):
        start.append(pose)
        pose = arc(*pose, v[i], w[i], tau)
    start = np.array(start)
    q = gt["time"].to_numpy()
    i = np.searchsorted(t, q, side="right") - 1
    ex, ey, eth = arc(*start[i].T, v[i], w[i], q - t[i])
    np.testing.assert_allclose(gt["x"], ex, atol=1e-9)
    np.testing.assert_allclose(gt["y"], ey, atol=1e-9)
    np.testing.assert_allclose(wrap_angle(gt["theta"].to_numpy() - eth), 0.0, atol=1e-9)


def test_commands_obey_the_controller_and_its_acceleration_limits():
    """The documented controller: |Δv| ≤ a_max Δt and |Δω| ≤ α_max Δt over each held interval, and wherever
    neither limit (nor the ω clip) binds, ω = k e and v = v_max cos²(e), so v = v_max max(cos(ω/k), 0)²."""
    config = SimConfig()
    odo, _ = _true_commands(1, duration=60.0)
    t, v, w = (odo[c].to_numpy() for c in ("time", "v", "omega"))
    dt = np.diff(np.append(t, 60.0))
    dv, dw = np.diff(v, prepend=0.0), np.diff(w, prepend=0.0)
    assert np.all(np.abs(dv) <= ACCEL_MAX * dt + 1e-12)
    assert np.all(np.abs(dw) <= ANGULAR_ACCEL_MAX * dt + 1e-12)
    free = (np.abs(dv) < ACCEL_MAX * dt - 1e-9) & (np.abs(dw) < ANGULAR_ACCEL_MAX * dt - 1e-9) \
        & (np.abs(w) < config.omega_max - 1e-9) & (np.abs(w) > 0.05)
    assert free.sum() > 100
    np.testing.assert_allclose(v[free], config.v_max * np.maximum(np.cos(w[free] / HEADING_GAIN), 0.0) ** 2,
                               atol=1e-12)


def test_first_frame_is_after_the_start_and_asymmetric_fov_is_respected():
    """Reference: the documented rules — frames come after the start; only bearings in [fov[0], fov[1]] are
    measured (checked on a lopsided field of view against the interpolated groundtruth)."""
    fov = (-0.2, 1.0)
    data = simulate_dataset(3, duration=60.0, fov=fov)
    log = data.robots[1]
    assert log.measurements["time"].min() > log.groundtruth["time"].iloc[0]
    _, phi = true_range_bearing(data, log)
    assert len(phi) > 200 and phi.max() > 0.8
    assert np.all((phi >= fov[0] - 1e-3) & (phi <= fov[1] + 1e-3))


def test_barcodes_are_the_documented_bijection():
    """Closed form: 37·s mod 97 maps subjects 1 … 96 one-to-one onto 1 … 96 (97 is prime): never 0."""
    codes = [barcode_of(s) for s in range(1, 97)]
    assert sorted(codes) == list(range(1, 97))
    assert barcode_of(1) == 37 and barcode_of(3) == 14
