"""Event streams: full-rate hold semantics, the write-up's 1 Hz cleaning, groundtruth interpolation.

Expected values are written out by hand or come from the closed-form unicycle
arc, never from the code under test.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from fastslam_edu.datasets.events import clean_1hz_table, event_stream, groundtruth_at, round_to_second
from fastslam_edu.datasets.log import RobotLog

LANDMARKS = np.array([6, 7, 8])


def make_log(odometry, measurements, groundtruth=None) -> RobotLog:
    odo = pd.DataFrame(odometry, columns=["time", "v", "omega"])
    meas = pd.DataFrame(measurements, columns=["time", "subject", "range", "bearing"])
    meas["subject"] = meas["subject"].astype(np.int64)
    gt = None if groundtruth is None else pd.DataFrame(groundtruth, columns=["time", "x", "y", "theta"])
    return RobotLog(robot=3, odometry=odo, measurements=meas, groundtruth=gt, dropped={}, source="hand-made")


def hand_log() -> RobotLog:
    odometry = [
        (1.0, 0.1, 0.01),
        (2.0, 0.2, 0.02),   # two rows at t = 2: the later one is the latest command
        (2.0, 0.3, 0.03),
        (4.0, 0.4, 0.04),
    ]
    measurements = [
        (0.5, 8, 5.0, 0.5),   # before any odometry
        (1.5, 7, 1.0, 0.1),   # two at one instant, kept in log order
        (1.5, 6, 2.0, 0.2),
        (2.0, 6, 3.0, 0.3),   # shares the step of the odometry rows at t = 2
        (5.0, 7, 4.0, 0.4),   # after the last odometry row
    ]
    return make_log(odometry, measurements)


# --------------------------------------------------------------------------
# full rate
# --------------------------------------------------------------------------


def test_full_rate_steps_hold_and_grouping():
    s = event_stream(hand_log(), LANDMARKS)
    assert s.rate == "full" and len(s) == 6
    np.testing.assert_array_equal(s.t, [0.5, 1.0, 1.5, 2.0, 4.0, 5.0])
    np.testing.assert_array_equal(s.dt, [0.0, 0.5, 0.5, 0.5, 2.0, 1.0])
    expected_u = [
        (0.0, 0.0),    # step 0: no motion
        (0.0, 0.0),    # (0.5, 1.0]: no command yet
        (0.1, 0.01),   # (1.0, 1.5]: row at 1.0
        (0.1, 0.01),   # (1.5, 2.0]: still the row at 1.0 (held)
        (0.3, 0.03),   # (2.0, 4.0]: the last row at 2.0
        (0.4, 0.04),   # (4.0, 5.0]: row at 4.0 held past the end of the odometry
    ]
    np.testing.assert_array_equal(s.u, expected_u)
    np.testing.assert_array_equal(s.offsets, [0, 1, 1, 3, 4, 4, 5])
    np.testing.assert_array_equal(s.z, [(5.0, 0.5), (1.0, 0.1), (2.0, 0.2), (3.0, 0.3), (4.0, 0.4)])
    np.testing.assert_array_equal(s.landmark, [2, 1, 0, 0, 1])
    z, lm = s.measurements_at(2)
    np.testing.assert_array_equal(lm, [1, 0])
    np.testing.assert_array_equal(s.sighting_steps, [0, 2, 2, 3, 5])  # steps 1 and 4 see nothing
    assert s.x0 is None  # no groundtruth
    np.testing.assert_array_equal(s.landmark_subjects, LANDMARKS)


def test_landmark_index_follows_the_given_subject_order():
    s = event_stream(hand_log(), [8, 6, 7])
    np.testing.assert_array_equal(s.landmark, [0, 2, 1, 1, 2])


def test_window_keeps_the_command_from_before_it():
    s = event_stream(hand_log(), LANDMARKS, t_start=1.2, t_end=4.5)
    np.testing.assert_array_equal(s.t, [1.5, 2.0, 4.0])
    np.testing.assert_array_equal(s.u[1:], [(0.1, 0.01), (0.3, 0.03)])
    np.testing.assert_array_equal(s.offsets, [0, 2, 3, 3])


def test_bad_arguments_are_reported():
    with pytest.raises(ValueError, match=r"subjects \[8\] that are not in landmark_subjects \[6, 7\]"):
        event_stream(hand_log(), [6, 7])
    with pytest.raises(ValueError, match="rate must be one of"):
        event_stream(hand_log(), LANDMARKS, rate="10hz")
    with pytest.raises(ValueError, match="repeated"):
        event_stream(hand_log(), [6, 6, 7, 8])
    with pytest.raises(ValueError, match="x0 must be"):
        event_stream(hand_log(), LANDMARKS, x0=[0.0, np.nan, 0.0])
    with pytest.raises(ValueError, match="no odometry or measurement"):
        event_stream(hand_log(), LANDMARKS, t_start=10.0)
    log = hand_log()
    log.odometry.loc[2, "v"] = np.nan
    with pytest.raises(ValueError, match=r"robot 3 odometry row 2: NaN"):
        event_stream(log, LANDMARKS)


# --------------------------------------------------------------------------
# groundtruth interpolation
# --------------------------------------------------------------------------


def test_groundtruth_interpolation_is_angle_aware():
    gt = [(0.0, 0.0, 1.0, 3.0), (1.0, 2.0, 3.0, -3.0), (2.0, 4.0, 3.0, -2.0)]
    log = make_log([(0.0, 0.0, 0.0)], [(0.0, 6, 1.0, 0.0)], gt)
    p = groundtruth_at(log, [0.25, 0.5, 1.5])
    # 3.0 -> -3.0 goes the short way through ±π: 3.0 + (2π - 6.0)·s
    short = 2 * np.pi - 6.0
    np.testing.assert_allclose(p[:, 0], [0.5, 1.0, 3.0])
    np.testing.assert_allclose(p[:, 1], [1.5, 2.0, 3.0])
    np.testing.assert_allclose(p[0, 2], 3.0 + 0.25 * short)
    assert abs(abs(p[1, 2]) - (3.0 + 0.5 * short)) < 1e-12  # ±π boundary: either sign
    np.testing.assert_allclose(p[2, 2], -2.5)
    # clamped within the tolerance, error beyond it
    np.testing.assert_allclose(groundtruth_at(log, 2.3), [[4.0, 3.0, -2.0]])
    with pytest.raises(ValueError, match=r"t = 2\.6 s is outside the groundtruth span \[0\.0, 2\.0\]"):
        groundtruth_at(log, [1.0, 2.6])
    with pytest.raises(ValueError, match="has no groundtruth"):
        groundtruth_at(hand_log(), 1.0)


def test_x0_comes_from_groundtruth_at_the_first_step():
    gt = [(0.0, 0.0, 0.0, 0.0), (10.0, 10.0, -5.0, 1.0)]
    log = make_log([(2.0, 0.1, 0.0), (3.0, 0.1, 0.0)], [(2.5, 6, 1.0, 0.0)], gt)
    s = event_stream(log, LANDMARKS)
    np.testing.assert_allclose(s.x0, [2.0, -1.0, 0.2])
    s = event_stream(log, LANDMARKS, x0=[1.0, 2.0, 3.0])
    np.testing.assert_array_equal(s.x0, [1.0, 2.0, 3.0])


# --------------------------------------------------------------------------
# 1 Hz cleaning
# --------------------------------------------------------------------------


def test_round_to_second_rounds_halves_up():
    np.testing.assert_array_equal(round_to_second([9.5, 10.49, 10.5, 11.5, -0.5]), [10, 10, 11, 12, 0])


def test_one_hz_averages_by_hand():
    odometry = [
        (9.6, 0.10, 0.3),    # second 10
        (10.2, 0.20, 0.0),   # second 10
        (10.49, 0.60, -0.6),  # second 10
        (10.5, 0.40, 0.2),   # second 11 (halves round up)
        (11.3, 0.20, 0.4),   # second 11
        (13.0, 0.05, 0.1),   # second 13; second 12 has none
    ]
    measurements = [
        (9.7, 7, 5.0, -0.2),   # (10, 7)
        (10.1, 6, 1.0, 0.1),   # (10, 6)
        (10.3, 6, 2.0, 0.4),   # (10, 6)
        (10.4, 7, 6.0, -0.1),  # (10, 7)
        (11.6, 8, 3.0, 3.1),   # (12, 8): bearings across ±π
        (12.2, 8, 4.0, -3.1),  # (12, 8)
    ]
    log = make_log(odometry, measurements)
    s = event_stream(log, LANDMARKS, rate="1hz")
    assert s.rate == "1hz"
    np.testing.assert_array_equal(s.t, [10.0, 11.0, 12.0, 13.0])
    np.testing.assert_array_equal(s.dt, [0.0, 1.0, 1.0, 1.0])
    np.testing.assert_allclose(s.u, [
        ((0.10 + 0.20 + 0.60) / 3, (0.3 + 0.0 - 0.6) / 3),
        ((0.40 + 0.20) / 2, (0.2 + 0.4) / 2),
        (0.0, 0.0),
        (0.05, 0.1),
    ], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(s.offsets, [0, 2, 2, 3, 3])
    # second 10: subject 6 then subject 7 (ordered by subject)
    np.testing.assert_array_equal(s.landmark, [0, 1, 2])
    np.testing.assert_allclose(s.z[0], [1.5, 0.25], atol=1e-15)
    np.testing.assert_allclose(s.z[1], [5.5, -0.15], atol=1e-15)
    # mean of 3.1 and -3.1 as angles is π, not 0
    assert s.z[2, 0] == 3.5
    np.testing.assert_allclose(abs(s.z[2, 1]), np.pi, atol=1e-12)


def test_clean_1hz_table_keeps_columns():
    df = pd.DataFrame({"time": [0.9, 1.1, 1.6], "x": [1.0, 3.0, 5.0], "y": [0.0, 0.0, 1.0], "theta": [0.1, 0.3, 0.0]})
    out = clean_1hz_table(df, angle_columns=("theta",))
    assert out.columns.tolist() == ["time", "x", "y", "theta"]
    np.testing.assert_allclose(out.to_numpy(), [[1.0, 2.0, 0.0, 0.2], [2.0, 5.0, 1.0, 0.0]], atol=1e-15)
    with pytest.raises(ValueError, match="must include 'time'"):
        clean_1hz_table(df, keys=("x",))


# --------------------------------------------------------------------------
# dead reckoning through the stream reproduces the commanded path
# --------------------------------------------------------------------------


def arc(pose, v, w, dt):
    """Exact unicycle motion for a constant (v, ω) over dt (the closed form)."""
    x, y, th = pose
    if abs(w) < 1e-12:
        return np.array([x + v * dt * np.cos(th), y + v * dt * np.sin(th), th])
    return np.array([
        x + v / w * (np.sin(th + w * dt) - np.sin(th)),
        y - v / w * (np.cos(th + w * dt) - np.cos(th)),
        th + w * dt,
    ])


def dead_reckon(stream, x0):
    pose = np.asarray(x0, dtype=float)
    for (v, w), dt in zip(stream.u, stream.dt):
        pose = arc(pose, v, w, dt)
    return pose


def test_full_rate_dead_reckoning_matches_the_closed_form_path():
    # commands: straight 0.5 m/s for 3 s, then an arc of radius 0.3/0.4 m for 2.5 s,
    # then an arc turning the other way; odometry repeated at irregular times in between
    rng = np.random.default_rng(7)
    segments = [(0.0, 3.0, 0.5, 0.0), (3.0, 5.5, 0.3, 0.4), (5.5, 9.0, 0.2, -0.25)]
    rows = []
    for t0, t1, v, w in segments:
        times = np.sort(np.concatenate([[t0], rng.uniform(t0, t1, 40)]))
        rows += [(t, v, w) for t in times]
    meas_t = np.sort(rng.uniform(0.0, 9.0, 25))
    log = make_log(rows, [(t, 6, 1.0, 0.0) for t in meas_t] + [(9.0, 7, 2.0, 0.0)])
    x0 = np.array([1.0, -2.0, 0.3])
    s = event_stream(log, LANDMARKS, x0=x0)
    assert s.t[0] == 0.0 and s.t[-1] == 9.0
    # closed form: one arc per command segment
    expected = x0
    for t0, t1, v, w in segments:
        expected = arc(expected, v, w, t1 - t0)
    np.testing.assert_allclose(dead_reckon(s, s.x0), expected, atol=1e-9)
    # the straight first segment alone: x0 + 1.5 m along θ0
    s3 = event_stream(log, LANDMARKS, x0=x0, t_end=3.0)
    np.testing.assert_allclose(dead_reckon(s3, x0), x0 + [1.5 * np.cos(0.3), 1.5 * np.sin(0.3), 0.0], atol=1e-12)


def test_one_hz_dead_reckoning_on_constant_commands():
    # 50 Hz commands v = 0.2, ω = 0.1 from t = 99.7 to 120.3: seconds 100..120, 20 propagations of 1 s
    t = np.arange(99.7, 120.3, 0.02)
    log = make_log([(ti, 0.2, 0.1) for ti in t], [(110.0, 6, 1.0, 0.0)])
    s = event_stream(log, LANDMARKS, rate="1hz", x0=[0.0, 0.0, 0.0])
    np.testing.assert_array_equal(s.t, np.arange(100.0, 121.0))
    end = dead_reckon(s, s.x0)
    radius, angle = 0.2 / 0.1, 0.1 * 20
    np.testing.assert_allclose(end, [radius * np.sin(angle), radius * (1 - np.cos(angle)), angle], atol=1e-12)


# --------------------------------------------------------------------------
# edges of the contracts
# --------------------------------------------------------------------------


def test_window_bounds_are_inclusive_and_the_1hz_window_cuts_the_odometry_too():
    """Reference: the documented ``t_start <= t <= t_end``, checked at exactly an event's time (full rate) and on
    whole seconds (1 Hz: odometry and measurements outside [11, 12] play no part)."""
    s = event_stream(hand_log(), LANDMARKS, t_start=1.5, t_end=4.0)
    np.testing.assert_array_equal(s.t, [1.5, 2.0, 4.0])
    odometry = [(9.6, 0.1, 0.3), (10.8, 0.2, 0.0), (11.9, 0.4, 0.2), (13.0, 0.05, 0.1), (14.2, 0.3, 0.0)]
    log = make_log(odometry, [(11.2, 6, 1.0, 0.0), (14.0, 7, 2.0, 0.0)])
    s = event_stream(log, LANDMARKS, rate="1hz", t_start=11.0, t_end=12.0)
    np.testing.assert_array_equal(s.t, [11.0, 12.0])
    np.testing.assert_allclose(s.u, [(0.2, 0.0), (0.4, 0.2)])
    np.testing.assert_array_equal(s.offsets, [0, 1, 1])


def test_one_hz_x0_is_the_groundtruth_at_the_first_second():
    """Closed form: groundtruth x = t, y = −t, θ = 0.1 t interpolated at the first whole second (10)."""
    gt = [(t, t, -t, 0.1 * t) for t in (9.0, 12.0)]
    log = make_log([(9.8, 0.1, 0.0), (11.7, 0.1, 0.0)], [(10.6, 6, 1.0, 0.0)], gt)
    s = event_stream(log, LANDMARKS, rate="1hz")
    np.testing.assert_array_equal(s.t, [10.0, 11.0, 12.0])
    np.testing.assert_allclose(s.x0, [10.0, -10.0, 1.0])


def test_angle_mean_is_wrapped_back_into_range():
    """Hand computation: 3.1 and −3.0 rad are 0.183 rad apart across ±π; their mean 3.1 + 0.0916 rad lies beyond π
    and must come back as 3.1916 − 2π ≈ −3.0916 rad."""
    df = pd.DataFrame({"time": [4.9, 5.1], "theta": [3.1, -3.0]})
    out = clean_1hz_table(df, angle_columns=("theta",))
    expected = 3.1 + (2 * np.pi - 6.1) / 2 - 2 * np.pi
    np.testing.assert_allclose(out["theta"], [expected], atol=1e-12)


def test_more_bad_arguments_are_reported():
    """Reference: the documented contracts — landmark_subjects non-empty whole numbers, x0 of shape (3,),
    finite query times, time never going backwards (even by half a second)."""
    with pytest.raises(ValueError, match="whole numbers"):
        event_stream(hand_log(), [6.5, 7.0, 8.0])
    with pytest.raises(ValueError, match="non-empty"):
        event_stream(hand_log(), [])
    with pytest.raises(ValueError, match="x0 must be"):
        event_stream(hand_log(), LANDMARKS, x0=[0.0, 1.0])
    gt = [(0.0, 0.0, 0.0, 0.0), (2.0, 1.0, 0.0, 0.0)]
    with pytest.raises(ValueError, match="must be finite"):
        groundtruth_at(make_log([(0.0, 0.0, 0.0)], [], gt), [1.0, np.nan])
    log = hand_log()
    log.odometry.loc[3, "time"] = 1.5  # after 2.0: half a second back
    with pytest.raises(ValueError, match=r"robot 3 odometry row 3: time goes backwards"):
        event_stream(log, LANDMARKS)
