"""The simulated THOR sequence: ray casting in 3D, floor hits, drifting odometry, the THOR file round trip.

The joint log here is synthetic (no real data needed): a head pitch profile
like the real one (level, 10.8° for a while, down to 41°), a small neck sway,
~120 Hz irregular samples. References: closed forms for single walls, a
per-beam 2×2 linear solve for the ray caster, the known walls for the hits,
brute-force nearest timestamps.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fastslam_edu.datasets.thor_lidar import read_thor_lidar
from fastslam_edu.grid.occupancy import OccupancyGrid
from fastslam_edu.core.se2 import path_increments
from fastslam_edu.datasets.thor_geometry import joints_at, lidar_points_world
from fastslam_edu.grid.thor import filter_returns
from fastslam_edu.datasets.thor_sim import (
    FLOOR,
    NO_HIT,
    WALL,
    FloorPlan,
    ThorSimConfig,
    cast_rays,
    default_floor_plan,
    drifting_odometry,
    real_thor_joints,
    simulate_thor,
    walking_path,
    write_sequence,
)

RANGE_STD = 0.01
#: Scan rate of the test sequences [Hz] (40 in the real sensor; fewer scans keep the tests fast).
RATE = 4.0


def synthetic_joints(rng, duration=90.0):
    """A joint log shaped like THOR's sequence 0: level, then 10.8°, then down to 41° (the end)."""
    t = 1.23e9 + np.cumsum(rng.uniform(0.006, 0.011, int(duration * 120)))
    s = t - t[0]
    head = np.radians(np.select([s < 15, s < 70, s < 80], [0.75, 10.76, 10.76 + (s - 70) * 3.0], 40.76))
    neck = 0.05 * np.sin(2 * np.pi * s / 20.0)  # a small sway, to exercise the neck joint
    return t, neck, head


@pytest.fixture(scope="module")
def joints():
    return synthetic_joints(np.random.default_rng(100))


@pytest.fixture(scope="module")
def seq(joints):
    return simulate_thor(*joints, np.random.default_rng(7), ThorSimConfig(scan_rate=RATE, range_std=RANGE_STD))


def world_points(seq, ranges=None):
    return lidar_points_world(seq.ranges if ranges is None else ranges, seq.angles, seq.neck, seq.head, seq.true_pose)


# --------------------------------------------------------------------------- ray casting


def test_cast_rays_single_wall_closed_forms():
    d, h = 4.0, 2.5
    plan = FloorPlan(np.array([[(d, -50.0), (d, 50.0)]]), height=h)
    o = np.array([0.0, 0.0, 1.41])
    phi = np.radians([0.0, 5.0, 10.76, 19.4, 30.0, 40.76, -10.0, -20.0])  # > 0: down, < 0: up
    dirs = np.stack([np.cos(phi), np.zeros_like(phi), -np.sin(phi)], axis=-1)
    r, kind = cast_rays(o, dirs, plan)
    wall = d / np.cos(phi)
    floor = np.where(phi > 0, 1.41 / np.sin(np.where(phi > 0, phi, 1.0)), np.inf)
    z_at_wall = 1.41 - d * np.tan(phi)
    expect = np.where(z_at_wall <= h, np.minimum(wall, floor), floor)  # over the wall: only the floor
    np.testing.assert_allclose(r, expect, rtol=1e-12)
    np.testing.assert_array_equal(kind, np.where(~np.isfinite(expect), NO_HIT, np.where(wall <= floor, WALL, FLOOR)))
    # pitched up by 20°: z at the wall = 1.41 + 4 tan 20° = 2.87 m > 2.5 m — over the wall, no return
    assert kind[-1] == NO_HIT and np.isinf(r[-1])
    # a beam pointing away from the wall and level: nothing
    r2, k2 = cast_rays(o, np.array([[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), plan)
    assert np.isinf(r2).all() and (k2 == NO_HIT).all()


def test_default_floor_plan_extent_is_the_building_shifted_to_the_start():
    """Reference: the 20 m × 12 m building with the start (2, 2.5) moved to the origin."""
    assert default_floor_plan().extent == pytest.approx((-2.0, 18.0, -2.5, 9.5))


def test_cast_rays_matches_a_per_beam_linear_solve():
    rng = np.random.default_rng(5)
    plan = default_floor_plan()
    origin = np.array([[0.3, 0.2, 1.41], [9.0, 4.0, 1.41]])
    v = rng.normal(size=(2, 300, 3))
    v[..., 2] *= 0.3
    dirs = v / np.linalg.norm(v, axis=-1, keepdims=True)
    r, kind = cast_rays(origin, dirs, plan)
    for k in range(2):
        for b in range(300):
            o, d = origin[k], dirs[k, b]
            best = -o[2] / d[2] if d[2] < 0 else np.inf
            for p, q in plan.walls:  # o_xy + s d_xy = p + u (q − p): a 2×2 system
                A = np.array([[d[0], p[0] - q[0]], [d[1], p[1] - q[1]]])
                if abs(np.linalg.det(A)) < 1e-12:
                    continue
                s, u = np.linalg.solve(A, p - o[:2])
                if s > 0 and 0 <= u <= 1 and 0 <= o[2] + s * d[2] <= plan.height:
                    best = min(best, s)
            np.testing.assert_allclose(r[k, b], best, rtol=1e-9)
    assert (kind == WALL).sum() > 100 and (kind == FLOOR).sum() > 50


# --------------------------------------------------------------------------- the sequence


def test_sequence_shape_and_the_joints_are_the_nearest_samples(seq, joints):
    t_j, neck, head = joints
    n = len(seq)
    assert n == int(math.floor((t_j[-1] - t_j[0]) * RATE)) + 1
    assert seq.ranges.shape == (n, 1081)
    np.testing.assert_allclose(np.degrees(seq.angles[[0, 540, -1]]), [-135, 0, 135])
    np.testing.assert_allclose(np.diff(seq.t), 1 / RATE, atol=1e-6)
    j = np.abs(t_j[None, :] - seq.t[:, None]).argmin(axis=1)  # brute force
    np.testing.assert_array_equal(seq.joint_index, j)
    np.testing.assert_array_equal(seq.neck, neck[j])
    np.testing.assert_array_equal(seq.head, head[j])
    np.testing.assert_allclose(seq.true_pose[0], [0, 0, 0], atol=1e-12)


def test_wall_hits_lie_on_walls_and_floor_hits_on_the_floor(seq):
    pts = world_points(seq)
    wall, floor = seq.kind == WALL, seq.kind == FLOOR
    d_wall = seq.plan.distance_to_walls(pts[wall][:, :2])
    # the range noise moves a point along its beam by |ε| ≤ 6σ: at most that far from the wall's plane
    assert d_wall.max() < 6 * RANGE_STD
    assert np.abs(pts[floor][:, 2]).max() < 6 * RANGE_STD
    z = pts[wall][:, 2]
    assert z.min() > -6 * RANGE_STD and z.max() < seq.plan.height + 6 * RANGE_STD
    # noise-free ranges: exactly on the walls / the floor
    exact = world_points(seq, np.where(seq.kind != NO_HIT, seq.true_range, 0.0))
    assert seq.plan.distance_to_walls(exact[wall][:, :2]).max() < 1e-9
    assert np.abs(exact[floor][:, 2]).max() < 1e-9
    # the noise has the stated spread
    err = (seq.ranges - seq.true_range)[seq.kind != NO_HIT]
    assert abs(err.std() / RANGE_STD - 1) < 0.01 and abs(err.mean()) < 1e-4
    # floor hits appear only with the head pitched down: none while level (0.75°: floor at 108 m)
    level = np.degrees(seq.head) < 1
    assert int(floor[level].sum()) == 0 and int(floor[~level].sum()) > 10_000
    # the floor filter (z < 0.1 m) drops every floor hit, and the wall hits less than 0.1 m above the
    # floor (the foot of a wall seen with the head pitched down) — up to the noise at the threshold
    f = filter_returns(seq.ranges, pts[..., 2])
    assert f.n_out_of_range == int((seq.kind == NO_HIT).sum())
    assert np.array_equal(f.floor & floor, floor)
    low_wall = wall & (exact[..., 2] < 0.1)
    differ = (f.floor & wall) != low_wall
    assert np.all(np.abs(exact[differ][:, 2] - 0.1) < 6 * RANGE_STD)
    assert int(low_wall.sum()) > 0 and int(differ.sum()) < 0.05 * int(low_wall.sum())


def occupied_off_walls(seq, z_floor, every=1):
    """Map with the TRUE poses; occupied cells whose centre is > 0.15 m from every wall."""
    pts = world_points(seq)
    grid = OccupancyGrid.around(seq.plan.extent, 0.1, margin=0.5)
    kept = floor_kept = 0
    for k in range(0, len(seq), every):
        f = filter_returns(seq.ranges[k], pts[k, :, 2], z_floor=z_floor)
        grid.update(seq.true_pose[k], pts[k, f.keep, :2])
        kept += f.n_kept
        floor_kept += int((f.keep & (seq.kind[k] == FLOOR)).sum())
    cells = np.argwhere(grid.binary() == 1)
    centres = grid.cell_to_world(cells)
    off = seq.plan.distance_to_walls(centres) > 0.15
    return centres[off], len(cells), floor_kept


def test_floor_filter_removes_the_phantom_obstacles(seq):
    off_without, n_occ_without, floor_without = occupied_off_walls(seq, z_floor=None)
    off_with, n_occ_with, floor_with = occupied_off_walls(seq, z_floor=0.1)
    # without the filter the floor returns are mapped and leave occupied cells away from every wall
    assert floor_without > 5_000 and len(off_without) >= 50
    # … and those cells are where floor hits landed (within a cell diagonal of one)
    pts = world_points(seq)
    floor_xy = pts[seq.kind == FLOOR][:, :2]
    near = np.array([np.hypot(*(floor_xy - c).T).min() for c in off_without])
    assert near.max() < 0.1 * math.sqrt(2)
    # with the filter: no floor return is mapped, no occupied cell away from the walls
    assert floor_with == 0 and len(off_with) == 0
    assert n_occ_without - len(off_without) > 0.9 * n_occ_with  # the walls are mapped either way


def test_path_stays_in_free_space_and_stops_while_looking_down(seq):
    assert seq.plan.distance_to_walls(seq.true_pose[:, :2]).min() > 0.3
    down = seq.head > seq.config.stop_above_pitch
    steps = np.linalg.norm(np.diff(seq.true_pose, axis=0), axis=1)
    assert down.sum() > 50 and np.all(steps[down[1:]] == 0)
    assert steps[~down[1:]].sum() > 20  # it walks the tour otherwise


def test_same_seed_same_sequence(joints):
    cfg = ThorSimConfig(scan_rate=2.0, duration=30.0, t_start=40.0)
    a = simulate_thor(*joints, np.random.default_rng(3), cfg)
    b = simulate_thor(*joints, np.random.default_rng(3), cfg)
    c = simulate_thor(*joints, np.random.default_rng(4), cfg)
    for name in ("ranges", "odom_pose", "true_pose", "kind"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.ranges, c.ranges) and not np.array_equal(a.odom_pose, c.odom_pose)
    np.testing.assert_array_equal(a.true_pose, c.true_pose)  # the truth does not depend on the seed
    np.testing.assert_allclose(a.t[0] - joints[0][0], 40.0)


# --------------------------------------------------------------------------- odometry


def test_odometry_drift_closed_forms():
    t = np.arange(0, 60, 0.025)
    path = walking_path([(0, 0), (10, 0)], t)  # straight 10 m along x at 10 m / t[-1]
    np.testing.assert_allclose(path[-1], [10, 0, 0], atol=1e-9)
    np.testing.assert_allclose(np.diff(path[:, 0]), 10 / t[-1] * 0.025, rtol=1e-9)
    rng = np.random.default_rng(0)
    exact = ThorSimConfig(odom_scale=0, odom_yaw_drift=0, odom_trans_noise=0, odom_rot_noise=0)
    np.testing.assert_allclose(drifting_odometry(path, rng, exact), path, atol=1e-12)
    scale = ThorSimConfig(odom_scale=0.05, odom_yaw_drift=0, odom_trans_noise=0, odom_rot_noise=0)
    np.testing.assert_allclose(drifting_odometry(path, rng, scale)[-1], [10.5, 0, 0], atol=1e-9)
    # a yaw drift β per metre on a straight walk: heading error β·s, the path bends on an arc of radius 1/β
    beta = 0.02
    drift = drifting_odometry(path, rng, ThorSimConfig(odom_scale=0, odom_yaw_drift=beta, odom_trans_noise=0,
                                                       odom_rot_noise=0))
    np.testing.assert_allclose(drift[-1, 2], beta * 10, rtol=1e-9)
    arc_end = [math.sin(beta * 10) / beta, (1 - math.cos(beta * 10)) / beta]
    np.testing.assert_allclose(drift[-1, :2], arc_end, atol=2e-3)  # up to the step discretisation
    # noise: the increments' x errors have variance σ_t² d per step
    noisy = ThorSimConfig(odom_scale=0, odom_yaw_drift=0, odom_trans_noise=0.02, odom_rot_noise=0)
    u = path_increments(drifting_odometry(path, np.random.default_rng(1), noisy))
    d = 10 / t[-1] * 0.025
    z = (u[:, 0] - d) / (0.02 * math.sqrt(d))
    assert abs(z.std() - 1) < 0.05 and abs(z.mean()) < 0.1


def test_walking_path_turns_the_short_way_across_pi():
    """Reference: closed form; headings 174.3° then −168.7° differ by a 17° left turn, not a 343° right one."""
    w = [(0.0, 0.0), (-1.0, 0.1), (-2.0, -0.1)]
    t = np.arange(0, 20, 0.01)
    path = walking_path(w, t, turn_rate=0.5)
    turn = math.atan2(-0.2, -1.0) - math.atan2(0.1, -1.0) + 2 * math.pi  # +0.295 rad
    steps = np.angle(np.exp(1j * np.diff(path[:, 2])))
    assert steps.min() > -1e-12 and steps.sum() == pytest.approx(turn, abs=1e-9)
    still = np.all(np.diff(path[:, :2], axis=0) == 0, axis=1)  # turning in place
    assert still.sum() * 0.01 == pytest.approx(turn / 0.5, abs=0.02)


def test_odometry_yaw_noise_variance_grows_with_the_turn():
    """Reference: Δθ̂ − Δθ ~ N(0, σ_r² |Δθ|) for a body turning in place (no translation, no drift)."""
    dth = 0.01
    path = np.column_stack([np.zeros(3001), np.zeros(3001), np.angle(np.exp(1j * dth * np.arange(3001)))])
    cfg = ThorSimConfig(odom_scale=0, odom_yaw_drift=0, odom_trans_noise=0, odom_rot_noise=0.05)
    u = path_increments(drifting_odometry(path, np.random.default_rng(2), cfg))
    z = (u[:, 2] - dth) / (0.05 * math.sqrt(dth))
    assert abs(z.std() - 1) < 0.05 and abs(z.mean()) < 0.1
    np.testing.assert_allclose(u[:, :2], 0.0, atol=1e-12)


def test_delta_pose_yaw_is_wrapped_when_the_odometry_crosses_pi(joints):
    """Reference: walking west, each step's yaw change is small; wrap(θ_k − θ_{k−1}) by complex exponentials."""
    cfg = ThorSimConfig(scan_rate=1.0, duration=40.0, n_beams=5, odom_yaw_drift=0.05)
    s = simulate_thor(*joints, np.random.default_rng(0), cfg, waypoints=[(0, 0), (4, 0), (4, 2), (0, 2)])
    assert np.abs(np.diff(s.odom_pose[:, 2])).max() > math.pi  # the odometry yaw does cross ±π
    np.testing.assert_allclose(s.delta_pose[1:, 2], np.angle(np.exp(1j * np.diff(s.odom_pose[:, 2]))), atol=1e-12)
    assert np.abs(s.delta_pose[1:, 2]).max() < 1.0  # turn_rate / scan_rate = 0.5 rad per scan, plus noise


def test_max_range_and_no_return_value_are_honoured(joints):
    """Reference: the configuration itself: returns never exceed max_range, beams without one hold no_return."""
    cfg = ThorSimConfig(scan_rate=1.0, duration=30.0, max_range=3.0, no_return=-1.0)
    s = simulate_thor(*joints, np.random.default_rng(1), cfg)
    hit = s.kind != NO_HIT
    assert hit.sum() > 1000 and (~hit).sum() > 1000
    assert s.ranges[hit].max() <= 3.0
    assert (s.ranges[~hit] == -1.0).all() and np.isinf(s.true_range[~hit]).all()


def test_default_odometry_drifts(seq):
    err = np.hypot(*(seq.odom_pose[:, :2] - seq.true_pose[:, :2]).T)
    assert err[0] == 0 and err[-1] > 0.3  # ~1 m after the tour with the defaults
    np.testing.assert_allclose(np.cumsum(seq.delta_pose, axis=0)[:, :2], seq.odom_pose[:, :2], atol=1e-9)


# --------------------------------------------------------------------------- the THOR file


@pytest.mark.parametrize("variant", [1, 2])
def test_write_and_read_back_in_the_thor_format(seq, joints, tmp_path, variant):
    path = write_sequence(seq, tmp_path / f"train_lidar_sim_v{variant}.mat", variant=variant)
    lid = read_thor_lidar(path)
    assert lid.variant == variant and len(lid) == len(seq)
    np.testing.assert_array_equal(lid.t, seq.t)
    np.testing.assert_array_equal(lid.ranges, seq.ranges)
    np.testing.assert_allclose(lid.angles, seq.angles, atol=1e-15)
    np.testing.assert_allclose(lid.odometry_poses(), seq.odom_pose, atol=1e-9)
    if variant == 1:
        np.testing.assert_array_equal(lid.pose, seq.odom_pose)
        assert lid.res == pytest.approx(math.radians(0.25))
    else:
        np.testing.assert_array_equal(lid.delta_pose, seq.delta_pose)
    # "no return" is written as 0 m: the reader's valid range (0.1–30 m) drops exactly those
    np.testing.assert_array_equal(lid.valid(), seq.kind != NO_HIT)
    # a reader matching the file's scans to the joint log by nearest time gets the simulator's angles
    neck, head = joints_at(lid.t, *joints)
    np.testing.assert_array_equal(head, seq.head)
    np.testing.assert_array_equal(neck, seq.neck)


# --------------------------------------------------------------------------- bad input


def test_bad_inputs(joints, tmp_path, monkeypatch):
    t, neck, head = joints
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="equal lengths"):
        simulate_thor(t, neck[:-1], head, rng)
    bad = head.copy()
    bad[10] = np.nan
    with pytest.raises(ValueError, match=r"head\[10\] = nan"):
        simulate_thor(t, neck, bad, rng)
    with pytest.raises(ValueError, match="must increase"):
        simulate_thor(t[::-1], neck, head, rng)
    with pytest.raises(ValueError, match="outside the joint log"):
        simulate_thor(t, neck, head, rng, ThorSimConfig(t_start=80.0, duration=30.0))
    with pytest.raises(ValueError, match="Generator"):
        simulate_thor(t, neck, head, 42)
    with pytest.raises(ValueError, match="too short for the turns"):
        simulate_thor(t, neck, head, rng, ThorSimConfig(duration=5.0, scan_rate=2.0))
    with pytest.raises(ValueError, match="scan_rate"):
        ThorSimConfig(scan_rate=0.0)
    with pytest.raises(ValueError, match="shape"):
        FloorPlan(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="zero length"):
        FloorPlan(np.array([[(1.0, 1.0), (1.0, 1.0)]]))
    with pytest.raises(ValueError, match="height"):
        FloorPlan(np.array([[(0.0, 0.0), (1.0, 0.0)]]), height=0.0)
    with pytest.raises(ValueError, match="n_beams"):
        ThorSimConfig(n_beams=0)
    repeated = t.copy()
    repeated[5] = repeated[4]  # two joint samples at the same time
    with pytest.raises(ValueError, match="must increase"):
        simulate_thor(repeated, neck, head, rng)
    with pytest.raises(ValueError, match="variant"):
        seq = simulate_thor(t, neck, head, rng, ThorSimConfig(scan_rate=1.0, duration=30.0))
        write_sequence(seq, tmp_path / "x.mat", variant=3)
    monkeypatch.setenv("FASTSLAM_EDU_DATA", str(tmp_path))
    with pytest.raises(FileNotFoundError, match="train_joint0.mat"):
        real_thor_joints()


def test_the_simulator_hands_out_the_one_floor_plan():
    """Chapter 18 imports the world from thor_sim: the same objects as datasets.floor_plan's, no copies."""
    from fastslam_edu.datasets import floor_plan, thor_sim

    for name in floor_plan.__all__:
        assert getattr(thor_sim, name) is getattr(floor_plan, name), name
        assert name in thor_sim.__all__, name
