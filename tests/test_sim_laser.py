"""The simulated laser world (fastslam_edu.datasets.sim_laser.simulate_laser_world): ray casting by hand, noise statistics."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fastslam_edu.datasets.laser import odometry_increments
from fastslam_edu.core.se2 import path_increments
from fastslam_edu.datasets.sim_laser import floor_plan, ray_cast, simulate_laser_world

BOX = np.array([  # the square [0, 4] × [0, 4]
    [[0, 0], [4, 0]], [[4, 0], [4, 4]], [[4, 4], [0, 4]], [[0, 4], [0, 0]],
], dtype=float)


def point_segment_distance(p, walls):
    """Distance from points (n, 2) to the nearest segment (independent closed form: projection, clamped)."""
    a, b = walls[:, 0], walls[:, 1]
    ab = b - a
    t = np.clip(((p[:, None, :] - a) * ab).sum(-1) / (ab * ab).sum(-1), 0, 1)
    q = a + t[..., None] * ab
    return np.linalg.norm(p[:, None, :] - q, axis=-1).min(axis=1)


def test_ray_cast_in_a_box_by_hand():
    # robot at (1, 2) facing +x: ahead 3 m, left (+90°) 2 m, right 2 m, behind 1 m; 45° left: corner-free diagonal
    angles = np.array([0.0, math.pi / 2, -math.pi / 2, math.pi, math.pi / 4])
    r = ray_cast([1.0, 2.0, 0.0], angles, BOX, max_range=10.0)
    np.testing.assert_allclose(r, [3.0, 2.0, 2.0, 1.0, 2.0 * math.sqrt(2.0)], atol=1e-12)
    # rotated robot: heading +90°, beam 0 looks along +y
    r = ray_cast([1.0, 2.0, math.pi / 2], np.array([0.0]), BOX, max_range=10.0)
    assert r[0] == pytest.approx(2.0)
    # beyond max_range: NaN (no return)
    r = ray_cast([1.0, 2.0, 0.0], np.array([0.0, math.pi]), BOX, max_range=2.5)
    assert math.isnan(r[0]) and r[1] == pytest.approx(1.0)


def test_floor_plan_walls_lie_in_the_rectangle():
    w = floor_plan(16.0, 10.0)
    assert w.shape[1:] == (2, 2) and len(w) >= 14
    assert w[..., 0].min() == 0 and w[..., 0].max() == 16 and w[..., 1].min() == 0 and w[..., 1].max() == 10
    with pytest.raises(ValueError, match="door"):
        floor_plan(3.0, 3.0, door=1.0)


def test_same_seed_same_world_and_odometry_differs_from_truth():
    a, b = simulate_laser_world(3), simulate_laser_world(3)
    np.testing.assert_array_equal(a.log.ranges, b.log.ranges)
    np.testing.assert_array_equal(a.log.poses, b.log.poses)
    c = simulate_laser_world(4)
    np.testing.assert_array_equal(a.truth, c.truth)  # the path does not depend on the noise
    assert not np.array_equal(a.log.poses, c.log.poses)
    assert np.linalg.norm(a.log.poses[-1, :2] - a.truth[-1, :2]) > 0.2  # odometry drifts


def test_true_path_translates_or_turns_with_the_given_steps():
    w = simulate_laser_world(0, step=0.4, turn_step=0.35)
    u = path_increments(w.truth)
    d = np.hypot(u[:, 0], u[:, 1])
    assert d.max() <= 0.4 + 1e-9 and np.abs(u[:, 2]).max() <= 0.35 + 1e-9
    assert np.all((d < 1e-9) | (np.abs(u[:, 2]) < 1e-9))  # either a straight step or a turn in place
    # the route stays inside the floor and away from the walls
    assert point_segment_distance(w.truth[:, :2], w.walls).min() > 0.3


def test_endpoints_lie_on_the_walls_within_the_range_noise():
    w = simulate_laser_world(1, range_std=0.01)
    pts = []
    for k in range(0, len(w.truth), 7):
        r, a = w.log.beams(k)
        x, y, th = w.truth[k]
        pts.append(np.column_stack([x + r * np.cos(th + a), y + r * np.sin(th + a)]))
    d = point_segment_distance(np.concatenate(pts), w.walls)
    assert np.percentile(d, 99) < 0.03 and d.max() < 0.06  # 3σ and 6σ of N(0, 0.01²)


def test_odometry_noise_has_the_stated_bias_and_spread():
    """Straight steps: Δθ error = b·d + N(0, (c·d)²), lateral error N(0, (a·d)²); checked over many seeds."""
    a_t, c_r, b = 0.05, 0.02, 0.01
    err_y, err_th, d_all = [], [], []
    for seed in range(12):
        w = simulate_laser_world(seed, trans_noise=a_t, rot_noise=0.03, rot_per_metre=c_r, rot_bias=b)
        u_true = path_increments(w.truth)
        u_odo = odometry_increments(w.log)[1:]
        straight = np.abs(u_true[:, 2]) < 1e-12
        d = np.hypot(u_true[straight, 0], u_true[straight, 1])
        err_y.append((u_odo[straight, 1] - u_true[straight, 1]) / (a_t * d))
        err_th.append(((u_odo[straight, 2] - u_true[straight, 2]) - b * d) / (c_r * d))
        d_all.append(d)
    zy, zth = np.concatenate(err_y), np.concatenate(err_th)
    n = zy.size
    assert n > 1000
    for z in (zy, zth):  # standardised: mean 0 ± 4/√n, variance 1 ± 4·√(2/n)
        assert abs(z.mean()) < 4 / math.sqrt(n)
        assert abs(z.var() - 1) < 4 * math.sqrt(2 / n)


def test_bad_settings_are_rejected():
    with pytest.raises(ValueError, match="step"):
        simulate_laser_world(0, step=0.0)
    with pytest.raises(ValueError, match="seed"):
        simulate_laser_world(-1)
