"""Tests of fastslam_edu.landmark.initial_pose (the start pose from the first sightings of surveyed landmarks)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.datasets.events import groundtruth_at
from fastslam_edu.landmark.initial_pose import initial_pose_from_landmarks
from fastslam_edu.core.motion import MotionNoise
from fastslam_edu.datasets.sim import simulate_dataset


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


def _noise_free(seed):
    return simulate_dataset(seed, duration=30.0, range_std=1e-9, bearing_std=1e-9,
                            odometry_noise=MotionNoise(sigma_v=0.0, sigma_omega=0.0))


def test_each_landmark_is_placed_by_the_median_of_its_sightings():
    """Known truth: the first sighting of every landmark read 1 m too far (each has >= 6 in the window) does not
    move the start: the median of a landmark's sightings ignores it."""
    data = _noise_free(0)
    log = data.robots[1]
    m = log.measurements.copy()
    first = m.groupby("subject").head(1).index
    m.loc[first, "range"] += 1.0
    ip = initial_pose_from_landmarks(dataclasses.replace(log, measurements=m), data.landmark_positions,
                                     data.landmark_subjects, max_window_s=10.0)
    dist, ang = _start_error(data, log, ip)
    assert dist < 2e-3 and ang < 1e-3, (dist, ang)


def test_reports_what_it_used():
    """Reference: counts made here from the log — t0 is the earlier of the first odometry and first measurement
    times; ``sightings`` is the number of sightings of surveyed landmarks in [t0, t0 + window_s]; the window is
    the first of window_s·2^k for which two landmarks ≥ 1 m apart have been seen; min_landmarks is honoured."""
    data = _noise_free(3)
    log = data.robots[1]
    meas = log.measurements
    late = dataclasses.replace(log, odometry=log.odometry[log.odometry["time"] > meas["time"].iloc[0] + 0.5])
    ip = initial_pose_from_landmarks(late, data.landmark_positions, data.landmark_subjects, window_s=0.25)
    assert ip.t0 == float(meas["time"].iloc[0])
    pos = data.landmarks[["x", "y"]]
    window = 0.25
    while True:
        seen = meas[meas["time"] <= ip.t0 + window]
        p = pos.loc[sorted(set(seen["subject"]))].to_numpy()
        if len(p) >= 2 and np.linalg.norm(p[:, None] - p[None], axis=2).max() >= 1.0:
            break
        window *= 2
    assert ip.window_s == window and ip.sightings == len(seen) and ip.subjects == tuple(sorted(set(seen["subject"])))
    assert window == 2.0  # 0.25 → 0.5 → 1 → 2: the search had to grow the window three times
    five = initial_pose_from_landmarks(log, data.landmark_positions, data.landmark_subjects, window_s=0.25,
                                       min_landmarks=5)
    assert len(five.subjects) >= 5


def test_landmarks_too_close_together_or_not_finite_are_refused():
    """Reference: the documented contract — two landmarks at least min_separation_m apart within max_window_s
    (the window capped at max_window_s, named in the message), and finite surveyed positions."""
    data = simulate_dataset(0, duration=30.0)
    log = data.robots[1]
    with pytest.raises(ValueError, match=r"in the first 5 s .* at least 100.0 m apart"):
        initial_pose_from_landmarks(log, data.landmark_positions, data.landmark_subjects, window_s=0.5,
                                    max_window_s=5.0, min_separation_m=100.0)
    bad = data.landmark_positions.copy()
    bad[2, 0] = np.nan
    with pytest.raises(ValueError, match="finite"):
        initial_pose_from_landmarks(log, bad, data.landmark_subjects)
