"""Tests of fastslam_edu.initial_pose (the start pose from the first sightings of surveyed landmarks)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fastslam_edu.angles import wrap_angle
from fastslam_edu.datasets.events import groundtruth_at
from fastslam_edu.initial_pose import initial_pose_from_landmarks
from fastslam_edu.motion import MotionNoise
from fastslam_edu.sim import simulate_dataset


def _start_error(data, log, ip):
    truth = groundtruth_at(log, [ip.t0])[0]
    return float(np.hypot(*(ip.x0[:2] - truth[:2]))), float(abs(wrap_angle(ip.x0[2] - truth[2])))


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_recovers_the_true_start_of_a_noise_free_simulation(seed):
    """Exact sightings and exact odometry: the start pose to rounding."""
    data = simulate_dataset(seed, duration=30.0, range_std=1e-9, bearing_std=1e-9,
                            odometry_noise=MotionNoise(sigma_v=0.0, sigma_omega=0.0))
    log = data.robots[1]
    ip = initial_pose_from_landmarks(log, data.landmark_positions, data.landmark_subjects, max_window_s=30.0)
    dist, ang = _start_error(data, log, ip)
    assert dist < 2e-3 and ang < 1e-3, (dist, ang)  # Euler steps of ~15 ms against exact arcs
    assert ip.residual_m < 2e-3 and len(ip.subjects) >= 2


def test_with_noise_it_is_off_by_what_the_noise_allows():
    """Range 5 cm, bearing 0.02 rad: the start within decimetres and a few degrees; the residual says so."""
    errors = []
    for seed in range(8):
        data = simulate_dataset(seed, duration=30.0)
        log = data.robots[1]
        ip = initial_pose_from_landmarks(log, data.landmark_positions, data.landmark_subjects, max_window_s=30.0)
        errors.append(_start_error(data, log, ip))
        assert 0.0 < ip.residual_m < 0.3
    dist, ang = np.median(np.array(errors), axis=0)
    assert dist < 0.1 and ang < np.radians(3.0), (dist, np.degrees(ang))


def test_the_frame_follows_the_world():
    """Moving the whole world (landmarks, groundtruth) by a rigid motion moves the start pose with it."""
    data = simulate_dataset(5, duration=30.0)
    log = data.robots[1]
    a = initial_pose_from_landmarks(log, data.landmark_positions, data.landmark_subjects, max_window_s=30.0)
    c, s = np.cos(0.7), np.sin(0.7)
    moved = data.landmark_positions @ np.array([[c, s], [-s, c]]) + [3.0, -2.0]  # rotate by 0.7 rad, shift
    b = initial_pose_from_landmarks(log, moved, data.landmark_subjects, max_window_s=30.0)
    expected = np.array([c * a.x0[0] - s * a.x0[1] + 3.0, s * a.x0[0] + c * a.x0[1] - 2.0])
    np.testing.assert_allclose(b.x0[:2], expected, atol=1e-9)
    assert abs(wrap_angle(b.x0[2] - a.x0[2] - 0.7)) < 1e-9
    assert b.residual_m == pytest.approx(a.residual_m, abs=1e-9)


def test_too_few_landmarks_is_a_clear_error():
    data = simulate_dataset(0, duration=30.0)
    log = data.robots[1]
    first = int(log.measurements["subject"].iloc[0])
    only = dataclasses.replace(log, measurements=log.measurements[log.measurements["subject"] == first])
    with pytest.raises(ValueError, match=rf"sees 1 surveyed landmark\(s\) \[{first}\]; an initial pose needs 2"):
        initial_pose_from_landmarks(only, data.landmark_positions, data.landmark_subjects)
    with pytest.raises(ValueError, match="at least 2"):
        initial_pose_from_landmarks(log, data.landmark_positions, data.landmark_subjects, min_landmarks=1)
    with pytest.raises(ValueError, match="shape"):
        initial_pose_from_landmarks(log, data.landmark_positions[:3], data.landmark_subjects)


def test_the_window_grows_until_two_landmarks_are_far_enough_apart():
    data = simulate_dataset(2, duration=60.0)
    log = data.robots[1]
    ip = initial_pose_from_landmarks(log, data.landmark_positions, data.landmark_subjects, window_s=0.5,
                                     max_window_s=60.0)
    assert ip.window_s in (0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 60.0)
    pos = data.landmarks.loc[list(ip.subjects), ["x", "y"]].to_numpy()
    assert np.linalg.norm(pos[:, None] - pos[None], axis=2).max() >= 1.0
    assert "initial pose from" in ip.describe()
