"""Grid SLAM on a simulated THOR sequence (``fastslam_edu.grid.thor_slam``), scored against the simulation's truth.

No real data: the joint log is synthetic (neck sway ±0.3 rad, head level at 3° except 25° down for the last 5 s,
when THOR stands and the beams hit the floor 3.0 m ahead), the sequence is simulated
(:func:`fastslam_edu.datasets.thor_sim.simulate_thor`) with drifting odometry, written in both THOR ``.mat``
variants and read back. References: closed forms for the rasterised walls and the map scores, the simulated
true path and floor hits, the floor line ``1.41 / tan φ`` ahead of the head, and the filter's own definition
(its shared map is the map of the best particle's poses).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from fastslam_edu.datasets.thor_lidar import read_thor_lidar
from fastslam_edu.datasets.thor_sim import (FLOOR, FloorPlan, ThorSimConfig, default_floor_plan, simulate_thor,
                                           write_sequence)
from fastslam_edu.grid.gridslam import GridSLAMParams
from fastslam_edu.grid.occupancy import OccupancyGrid
from fastslam_edu.datasets.thor_geometry import LIDAR_HEIGHT, lidar_points_world
from fastslam_edu.grid.gridslam import map_from_poses
from fastslam_edu.grid.thor_slam import map_scores, planar_scans, thor_grid_slam, wall_cells

T0 = 1.6e9
DURATION = 36.0  # [s]
RATE = 5.0  # scans per second: 181 scans
PITCH_DOWN = math.radians(25.0)
DOWN = (31.0, DURATION + 1.0)  # [s] head pitched down to the end (THOR stands still: above 15°)
#: a tour of the start room, ending 4.5 m from a wall (the floor line, 3.0 m ahead, lies on open floor)
WAYPOINTS = np.array([(0.0, 0.0), (3.5, 0.0), (3.5, 2.0), (0.5, 2.0), (0.5, 0.5), (1.5, 0.5)])
STEP = math.radians(1.0)  # planar bearing step


def joint_log():
    s = np.arange(0.0, DURATION + 0.5, 1 / 120)
    neck = 0.3 * np.sin(2 * np.pi * s / 9.0)
    head = np.where((s > DOWN[0]) & (s < DOWN[1]), PITCH_DOWN, math.radians(3.0))
    return T0 + s, neck, head


def params(**changes):
    x0, x1, y0, y1 = default_floor_plan().extent
    # the grid covers the building with walls through cell centres (the walls lie on multiples of 0.5 m)
    return GridSLAMParams.writeup(n_particles=10, extent=(x0 - 1.05, x1 + 1.05, y0 - 1.05, y1 + 1.05), **changes)


@pytest.fixture(scope="module")
def sequence():
    cfg = ThorSimConfig(scan_rate=RATE, duration=DURATION, odom_scale=0.05, odom_yaw_drift=0.05)
    return simulate_thor(*joint_log(), np.random.default_rng(3), cfg, waypoints=WAYPOINTS)


@pytest.fixture(scope="module")
def lidars(sequence, tmp_path_factory):
    d = tmp_path_factory.mktemp("thor_slam")
    return {v: read_thor_lidar(write_sequence(sequence, d / f"lidar_v{v}.mat", variant=v)) for v in (1, 2)}


@pytest.fixture(scope="module")
def runs(lidars):
    """The write-up's filter (10 particles, seed 0) on variant 1 and 2 with the floor filter, and on 1 without."""
    out = {}
    for key, variant, ff in (("v1", 1, True), ("v2", 2, True), ("off", 1, False)):
        out[key] = thor_grid_slam(lidars[variant], joint_log(), params(), np.random.default_rng(0),
                                  floor_filter=ff, bearing_step=STEP)
    return out


def rmse(path, truth):
    return float(np.sqrt(np.mean(np.sum((path[:, :2] - truth[:, :2]) ** 2, axis=1))))


# --------------------------------------------------------------------------- scoring a map


def test_wall_cells_closed_forms():
    grid = OccupancyGrid((0.1), (0.0, 0.0), (20, 20))
    # a horizontal wall through the middle of row 5, from the middle of column 0 to the middle of column 10
    one = FloorPlan(np.array([[(0.05, 0.55), (1.05, 0.55)]]))
    np.testing.assert_array_equal(wall_cells(one, grid), [(5, c) for c in range(11)])
    # the diagonal through the cell corners (0.1 i, 0.1 i): only the diagonal cells
    diag = FloorPlan(np.array([[(0.05, 0.05), (0.95, 0.95)]]))
    np.testing.assert_array_equal(wall_cells(diag, grid), [(i, i) for i in range(10)])
    # parts outside the grid are left out
    out = FloorPlan(np.array([[(-1.0, 0.55), (0.25, 0.55)]]))
    np.testing.assert_array_equal(wall_cells(out, grid), [(5, 0), (5, 1), (5, 2)])


def test_map_scores_closed_forms():
    plan = FloorPlan(np.array([[(0.05, 0.55), (2.05, 0.55)], [(0.05, 0.55), (0.05, 1.95)]]))  # an L of 21 + 15 cells
    grid = OccupancyGrid((0.1), (0.0, 0.0), (30, 30))
    walls = wall_cells(plan, grid)
    assert len(walls) == 21 + 15 - 1  # the corner cell once
    grid.log_odds[walls[:, 0], walls[:, 1]] = 2.0
    grid.observed[:] = True
    s = map_scores(grid, plan)
    assert (s.n_occupied, s.n_on_walls, s.n_phantom, s.precision, s.coverage) == (35, 35, 0, 1.0, 1.0)
    # five obstacles that are not there, ≥ 0.7 m from both walls
    far = np.array([(25, 25), (25, 20), (20, 25), (15, 15), (12, 20)])
    grid.log_odds[far[:, 0], far[:, 1]] = 2.0
    s = map_scores(grid, plan)
    assert s.n_phantom == 5 and s.precision == pytest.approx(35 / 40) and s.coverage == 1.0
    np.testing.assert_allclose(np.sort(s.phantom, axis=0), np.sort(grid.cell_to_world(far), axis=0))
    # the walls mapped 0.3 m off (three rows up, three columns right): nothing on a wall, nothing covered
    shifted = OccupancyGrid((0.1), (0.0, 0.0), (30, 30), log_odds=np.zeros((30, 30)), observed=np.ones((30, 30)))
    shifted.log_odds[walls[:, 0] + 3, walls[:, 1] + 3] = 2.0
    s = map_scores(shifted, plan)
    assert s.n_on_walls == 0 and s.precision == 0.0 and s.coverage == 0.0
    # one row off (0.1 m): still on the walls (tol 0.15 m) and covered; not so with tol 0.05 m
    one_off = OccupancyGrid((0.1), (0.0, 0.0), (30, 30), log_odds=np.zeros((30, 30)), observed=np.ones((30, 30)))
    one_off.log_odds[walls[:, 0] + 1, walls[:, 1] + 1] = 2.0
    assert map_scores(one_off, plan).precision == 1.0 and map_scores(one_off, plan).coverage == 1.0
    assert map_scores(one_off, plan, tol=0.05).precision < 0.1
    empty = map_scores(OccupancyGrid((0.1), (0.0, 0.0), (30, 30)), plan)
    assert empty.n_occupied == 0 and math.isnan(empty.precision) and empty.coverage == 0.0
    with pytest.raises(ValueError, match="tol"):
        map_scores(grid, plan, tol=-0.1)


# --------------------------------------------------------------------------- the planar scans


def test_floor_filter_switch_keeps_the_floor_line_only_when_off(sequence, lidars):
    """Off: the extra planar points are the floor line, 1.41 / tan φ ahead of the head (closed form)."""
    on = planar_scans(lidars[1], *joint_log(), bearing_step=STEP)
    off = planar_scans(lidars[1], *joint_log(), floor_filter=False, bearing_step=STEP)
    assert off.counts["floor"] == 0 and on.counts["floor"] >= int((sequence.kind == FLOOR).sum()) > 500
    down = np.flatnonzero(sequence.head > math.radians(20))
    assert len(down) >= 15
    d_floor = LIDAR_HEIGHT / math.tan(PITCH_DOWN)  # 3.02 m
    n_checked = 0
    for k in down:
        extra = np.isfinite(off.ranges[k]) & ~(off.ranges[k] >= on.ranges[k])  # new or nearer with the floor kept
        r, b = off.ranges[k][extra], off.angles[extra]
        # the floor line: points p with p · (cos ψ_n, sin ψ_n) = d_floor (range noise 1 cm, bearing bins 1°) …
        # a point is moved sideways by up to r · step / 2 when its bearing is rounded to its bin
        tol = 0.03 + r * STEP / 2
        on_line = np.abs(r * np.cos(b - sequence.neck[k]) - d_floor) < tol
        # … or the foot of a wall (a wall hit below 0.1 m, which the filter drops with the floor)
        x, y, th = sequence.true_pose[k]
        world = np.column_stack([x + r * np.cos(th + b), y + r * np.sin(th + b)])
        assert np.all(on_line | (sequence.plan.distance_to_walls(world) < tol))
        n_checked += on_line.sum()
    assert n_checked > 500
    level = sequence.head < math.radians(5)  # a level head sees no floor: both logs agree there
    np.testing.assert_array_equal(np.isnan(on.ranges[level]), np.isnan(off.ranges[level]))


# --------------------------------------------------------------------------- the write-up's filter


def test_both_variants_give_the_same_run(runs, lidars):
    np.testing.assert_allclose(lidars[2].odometry_poses(), lidars[1].odometry_poses(), atol=1e-9)
    np.testing.assert_allclose(runs["v2"].result.estimate, runs["v1"].result.estimate, atol=1e-6)
    np.testing.assert_array_equal(runs["v2"].result.grid.binary(), runs["v1"].result.grid.binary())


def test_write_up_filter_beats_odometry_against_the_truth(sequence, runs):
    res = runs["v1"].result
    est, odo = rmse(res.estimate, sequence.true_pose), rmse(res.odometry, sequence.true_pose)
    assert est < 0.1 and est < 0.3 * odo, (est, odo)  # measured: 0.07 vs 0.50 m
    assert res.resampled[1:].all()  # the write-up resamples at every step
    s = map_scores(res.grid, sequence.plan)
    assert s.precision > 0.97 and s.coverage > 0.3, s.row()  # measured: 1.0, 0.39 (one room of four seen)


def test_shared_map_is_the_map_of_the_best_particles_poses(sequence, runs):
    """The write-up maps each scan from the best particle: rebuilding from those poses gives the same map."""
    run = runs["v1"]
    rebuilt = map_from_poses(run.log, run.result.poses, params())
    np.testing.assert_allclose(rebuilt.log_odds, run.result.grid.log_odds, atol=1e-9)


def test_truth_map_is_exact_and_odometry_map_is_not(sequence, runs):
    log = runs["v1"].log
    truth = map_scores(map_from_poses(log, sequence.true_pose, params()), sequence.plan)
    odo = map_scores(map_from_poses(log, log.odometry, params()), sequence.plan)
    assert truth.precision == 1.0 and truth.n_occupied > 200
    assert odo.precision < 0.9 * truth.precision and odo.n_phantom > 20, (odo.row(), truth.row())
    with pytest.raises(ValueError, match="poses"):
        map_from_poses(log, sequence.true_pose[:-1], params())
    with pytest.raises(ValueError, match="every"):
        map_from_poses(log, sequence.true_pose, params(), every=0)


def test_without_the_floor_filter_the_floor_becomes_phantom_walls(sequence, runs):
    """Control for the precision check above: it fails when floor returns reach the map."""
    on = map_scores(runs["v1"].result.grid, sequence.plan)
    off = map_scores(runs["off"].result.grid, sequence.plan)
    assert off.n_phantom >= 20 and on.n_phantom < off.n_phantom / 2, (on.row(), off.row())  # measured: 48 vs 0
    assert off.precision < 0.95 <= on.precision
    # the phantom cells are where the simulated floor returns landed (within 0.2 m: path error + a cell)
    fl = sequence.kind == FLOOR
    p = lidar_points_world(np.where(fl, sequence.true_range, 0.0), sequence.angles, sequence.neck, sequence.head,
                           sequence.true_pose)[fl][:, :2]
    dist, _ = cKDTree(p).query(off.phantom)
    assert np.quantile(dist, 0.9) < 0.2, np.quantile(dist, 0.9)
