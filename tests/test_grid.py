"""Occupancy grid: hand-worked updates, ray casting (vectorised == Bresenham), endpoints, map correlation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fastslam_edu.grid.occupancy import OccupancyGrid, map_correlation, scan_endpoints
from fastslam_edu.grid.rays import bresenham, ray_cells

L_OCC = math.log(0.7 / 0.3)
L_FREE = math.log(0.4 / 0.6)


def unit_grid(h=5, w=10, **kw):
    """1 m cells, origin (0, 0): cell (row, col) covers x ∈ [col, col+1), y ∈ [row, row+1)."""
    return OccupancyGrid(resolution=1.0, origin=(0.0, 0.0), shape=(h, w), **kw)


# --------------------------------------------------------------------------- log-odds and the update


def test_inverse_sensor_model_is_the_log_odds_of_the_probabilities():
    """Reference: l = ln(p / (1 − p)) by hand: ln(7/3), ln(2/3) (defaults), ln 9, ln(3/7)."""
    g = unit_grid()
    assert g.l_occ == pytest.approx(0.8472978603872037, rel=1e-14)
    assert g.l_free == pytest.approx(-0.4054651081081644, rel=1e-14)
    g = OccupancyGrid.around(2.0, 0.1, p_hit=0.9, p_miss=0.3)
    assert g.l_occ == pytest.approx(math.log(9), rel=1e-14) and g.l_free == pytest.approx(math.log(3 / 7), rel=1e-14)
    for bad in (0.0, 1.0, 1.5, float("nan")):
        with pytest.raises(ValueError, match="p_hit must lie strictly between 0 and 1"):
            OccupancyGrid.around(2.0, 0.1, p_hit=bad)
        with pytest.raises(ValueError, match="p_miss must lie strictly between 0 and 1"):
            OccupancyGrid.around(2.0, 0.1, p_miss=bad)
        with pytest.raises(ValueError, match="threshold must lie strictly between 0 and 1"):
            g.binary(bad)


def test_single_ray_along_a_row_by_hand():
    g = unit_grid()
    # robot in cell (2, 0) looking along +x; one beam ending in cell (2, 7)
    g.update([0.5, 2.5, 0.0], [[7.5, 2.5]])
    expect = np.zeros((5, 10))
    expect[2, 0:7] = L_FREE
    expect[2, 7] = L_OCC
    np.testing.assert_allclose(g.log_odds, expect, atol=0)
    seen = np.zeros((5, 10), bool)
    seen[2, 0:8] = True
    np.testing.assert_array_equal(g.observed, seen)
    b = g.binary()
    assert b.dtype == np.int8
    np.testing.assert_array_equal(b[2], [0, 0, 0, 0, 0, 0, 0, 1, -1, -1])
    assert (b[[0, 1, 3, 4]] == -1).all()
    np.testing.assert_allclose(g.probability()[2, [0, 7, 9]], [0.4, 0.7, 0.5], atol=1e-15)


def test_each_cell_updated_once_per_scan_and_the_endpoint_wins():
    g = unit_grid()
    # three beams along row 2 from cell (2, 0): they share cells (2, 1)…(2, 3);
    # the beam ending in (2, 4) crosses nothing the others end in, but the beam
    # ending in (2, 7) crosses (2, 4): that cell must count as a hit only.
    g.update([0.5, 2.5, 0.0], [[4.5, 2.5], [7.5, 2.5], [7.2, 2.9]])
    np.testing.assert_allclose(g.log_odds[2, :4], L_FREE)  # once, not three times
    assert g.log_odds[2, 4] == pytest.approx(L_OCC)  # hit, not hit + free
    np.testing.assert_allclose(g.log_odds[2, 5:7], L_FREE)
    assert g.log_odds[2, 7] == pytest.approx(L_OCC)  # two endpoints in one cell: once


def test_clipping_at_l_max_and_how_long_the_map_takes_to_change_its_mind():
    g = unit_grid(l_max=5.0)
    for _ in range(20):
        g.update([0.5, 2.5, 0.0], [[7.5, 2.5]])
    assert g.log_odds[2, 7] == 5.0  # 20 × 0.847 = 16.9 clipped
    assert g.log_odds[2, 3] == -5.0  # 20 × −0.405 = −8.1 clipped
    # now the obstacle is gone (a door opened): beams pass through cell (2, 7) to (2, 9)
    n = 0
    while g.binary()[2, 7] == 1:
        g.update([0.5, 2.5, 0.0], [[9.5, 2.5]])
        n += 1
    assert n == math.ceil(5.0 / -L_FREE)  # 13 scans: l_max / |l_free| rounded up
    # without clipping (l_max huge) the same history would need 20·l_occ/|l_free| scans
    h = unit_grid(l_max=1e6)
    for _ in range(20):
        h.update([0.5, 2.5, 0.0], [[7.5, 2.5]])
    assert h.log_odds[2, 7] == pytest.approx(20 * L_OCC)
    assert math.ceil(20 * L_OCC / -L_FREE) == 42


def test_probability_and_binary_thresholds():
    lo = np.array([[0.0, L_OCC, L_FREE, 3.0]])
    g = OccupancyGrid(1.0, (0.0, 0.0), (1, 4), log_odds=lo, observed=np.array([[False, True, True, True]]))
    np.testing.assert_allclose(g.probability(), [[0.5, 0.7, 0.4, 1 / (1 + math.exp(-3))]], atol=1e-15)
    np.testing.assert_array_equal(g.binary(0.5), [[-1, 1, 0, 1]])
    np.testing.assert_array_equal(g.binary(0.75), [[-1, 0, 0, 1]])  # 0.7 is not above 0.75
    np.testing.assert_array_equal(g.binary(0.35), [[-1, 1, 1, 1]])
    # probability() stays finite and warning-free for huge log-odds
    big = OccupancyGrid(1.0, (0.0, 0.0), (1, 2), l_max=1e4, log_odds=np.array([[1e3, -1e3]]))
    np.testing.assert_array_equal(big.probability(), [[1.0, 0.0]])


def test_update_with_a_sensor_offset_starts_rays_at_the_sensor():
    g = unit_grid()
    # robot in cell (2, 0) facing +x, laser mounted 2 m ahead: rays start in cell (2, 2)
    g.update([0.5, 2.5, 0.0], [[6.5, 2.5]], sensor_offset=(2.0, 0.0))
    assert (g.log_odds[2, :2] == 0).all()
    np.testing.assert_allclose(g.log_odds[2, 2:6], L_FREE)
    assert g.log_odds[2, 6] == pytest.approx(L_OCC)


def test_rays_leaving_the_grid_update_only_the_inside():
    g = unit_grid()
    g.update([0.5, 2.5, 0.0], [[25.0, 2.5], [-3.0, 2.5]])
    np.testing.assert_allclose(g.log_odds[2], L_FREE)  # the whole row is crossed, no hit inside
    assert (g.log_odds[[0, 1, 3, 4]] == 0).all()


def test_copy_is_independent():
    g = unit_grid()
    c = g.copy()
    c.update([0.5, 2.5, 0.0], [[7.5, 2.5]])
    assert (g.log_odds == 0).all() and not g.observed.any()
    assert c.log_odds[2, 7] > 0


def test_observed_defaults_to_the_nonzero_cells_of_given_log_odds():
    """Reference: the documented rule (a cell with l != 0 was touched by an update), on a hand-made map."""
    g = OccupancyGrid(1.0, (0.0, 0.0), (1, 3), log_odds=np.array([[0.0, 2.0, -1.0]]))
    np.testing.assert_array_equal(g.observed, [[False, True, True]])
    np.testing.assert_array_equal(g.binary(), [[-1, 1, 0]])


# --------------------------------------------------------------------------- coordinates


def test_world_cell_round_trip_and_boundaries():
    g = OccupancyGrid(resolution=0.05, origin=(-2.0, 1.0), shape=(40, 60))
    rng = np.random.default_rng(3)
    cells = np.column_stack([rng.integers(0, 40, 500), rng.integers(0, 60, 500)])
    np.testing.assert_array_equal(g.world_to_cell(g.cell_to_world(cells)), cells)
    np.testing.assert_allclose(g.cell_to_world([0, 0]), [-2.0 + 0.025, 1.0 + 0.025])
    np.testing.assert_allclose(g.cell_to_world([39, 59]), [-2.0 + 59.5 * 0.05, 1.0 + 39.5 * 0.05])
    # row from y, column from x; the lower-left corner belongs to cell (0, 0)
    np.testing.assert_array_equal(g.world_to_cell([[-2.0, 1.0], [-1.0, 1.5], [-2.0 - 1e-9, 1.0]]),
                                  [[0, 0], [10, 20], [0, -1]])
    x_right, y_top = -2.0 + 60 * 0.05, 1.0 + 40 * 0.05
    np.testing.assert_array_equal(g.world_to_cell([[x_right - 1e-9, y_top - 1e-9], [x_right, y_top]]),
                                  [[39, 59], [40, 60]])
    np.testing.assert_array_equal(g.inside([[0, 0], [39, 59], [40, 0], [0, 60], [-1, 5]]),
                                  [True, True, False, False, False])
    assert g.extent == pytest.approx((-2.0, 1.0, 1.0, 3.0))


def test_around_builds_the_stated_extent():
    g = OccupancyGrid.around(2.0, 0.1)
    assert g.shape == (40, 40) and g.origin == (-2.0, -2.0)
    g = OccupancyGrid.around((0.0, 3.05, -1.0, 1.0), 0.5, margin=1.0, p_hit=0.9, p_miss=0.3)
    assert g.origin == (-1.0, -2.0) and g.shape == (8, 11)  # ceil(5.05 / 0.5) = 11, 4 / 0.5 = 8
    assert g.l_occ == pytest.approx(math.log(9)) and g.l_free == pytest.approx(math.log(3 / 7))
    pts = np.array([[1.0, 2.0], [-3.0, 5.0], [0.0, 0.0]])
    g = OccupancyGrid.around(pts, 0.25)
    assert g.origin == (-3.0, 0.0) and g.shape == (21, 17)  # ⌊5 / 0.25⌋ + 1, ⌊4 / 0.25⌋ + 1
    assert g.inside(g.world_to_cell(pts)).all()


# --------------------------------------------------------------------------- ray casting


def test_bresenham_by_hand_and_its_tie_rule():
    np.testing.assert_array_equal(bresenham(0, 0, 2, 5), [[0, 0], [0, 1], [1, 2], [1, 3], [2, 4], [2, 5]])
    np.testing.assert_array_equal(bresenham(0, 0, 5, 2), [[0, 0], [1, 0], [2, 1], [3, 1], [4, 2], [5, 2]])
    # exact half-way: rounded back towards the start, so A→B and B→A differ
    np.testing.assert_array_equal(bresenham(0, 0, 1, 2), [[0, 0], [0, 1], [1, 2]])
    np.testing.assert_array_equal(bresenham(1, 2, 0, 0), [[1, 2], [1, 1], [0, 0]])
    np.testing.assert_array_equal(bresenham(3, 3, 3, 3), [[3, 3]])
    np.testing.assert_array_equal(bresenham(2, 5, 2, 1), [[2, 5], [2, 4], [2, 3], [2, 2], [2, 1]])
    np.testing.assert_array_equal(bresenham(0, 0, -3, -3), [[0, 0], [-1, -1], [-2, -2], [-3, -3]])


def _check_digital_line(cells, r0, c0, r1, c1):
    """Independent characterisation: n+1 cells, 8-connected, each within ½ cell of the true line."""
    n = max(abs(r1 - r0), abs(c1 - c0))
    assert len(cells) == n + 1
    assert tuple(cells[0]) == (r0, c0) and tuple(cells[-1]) == (r1, c1)
    if n:
        steps = np.abs(np.diff(cells, axis=0))
        assert steps.max() == 1 and (steps.sum(axis=1) >= 1).all()
        i = np.arange(n + 1)
        for k, d in enumerate((r1 - r0, c1 - c0)):
            exact = (cells[0, k] + i * d / n).astype(float)
            assert np.abs(cells[:, k] - exact).max() <= 0.5 + 1e-12


def _random_rays(rng, n):
    start = rng.integers(-40, 40, 2)
    ends = start + rng.integers(-60, 61, (n, 2))
    # force the special directions: zero length, horizontal, vertical, both diagonals, all octants
    special = np.array([[0, 0], [0, 9], [0, -9], [9, 0], [-9, 0], [7, 7], [-7, 7], [7, -7], [-7, -7],
                        [2, 5], [5, 2], [-2, 5], [-5, 2], [2, -5], [5, -2], [-2, -5], [-5, -2], [1, 2], [2, 1]])
    return start, np.vstack([ends, start + special])


def test_vectorised_ray_casting_gives_exactly_bresenhams_cells():
    rng = np.random.default_rng(4)
    checked = 0
    octants = set()
    for _ in range(6):
        start, ends = _random_rays(rng, 800)
        free, hit = ray_cells(start, ends)
        np.testing.assert_array_equal(hit, ends)
        lengths = np.abs(ends - start).max(axis=1)
        assert len(free) == lengths.sum()
        pos = 0
        for e, n in zip(ends, lengths):
            ref = bresenham(*start, *e)
            _check_digital_line(ref, *start, *e)
            np.testing.assert_array_equal(free[pos : pos + n], ref[:-1])
            pos += n
            d = e - start
            octants.add((np.sign(d[0]), np.sign(d[1]), abs(d[0]) > abs(d[1])))
            checked += 1
    assert checked == 6 * 819
    assert len(octants) == 13  # 4 quadrants × (steep or not) + 4 axis directions + zero length


def test_ray_cells_zero_length_ray_has_no_free_cell():
    free, hit = ray_cells([3, 4], [[3, 4]])
    assert free.shape == (0, 2)
    np.testing.assert_array_equal(hit, [[3, 4]])


# --------------------------------------------------------------------------- scan endpoints


def test_scan_endpoints_closed_forms():
    pose = np.array([1.0, 2.0, math.pi / 2])
    ends = scan_endpoints(pose, [1.0, 2.0], [0.0, math.pi / 2])
    np.testing.assert_allclose(ends, [[1.0, 3.0], [-1.0, 2.0]], atol=1e-15)
    # laser 0.5 m ahead of the robot centre: the sensor is at (1, 2.5)
    ends = scan_endpoints(pose, [1.0, 2.0], [0.0, math.pi / 2], sensor_offset=(0.5, 0.0))
    np.testing.assert_allclose(ends, [[1.0, 3.5], [-1.0, 2.5]], atol=1e-15)


def test_scan_endpoints_for_many_particles_rotate_with_the_pose():
    rng = np.random.default_rng(5)
    r = rng.uniform(0.2, 10.0, 30)
    a = np.linspace(-math.pi / 2, math.pi / 2, 30, endpoint=False)
    poses = np.column_stack([rng.normal(size=(7, 2)), rng.uniform(-math.pi, math.pi, 7)])
    ends = scan_endpoints(poses, r, a, sensor_offset=(0.1, -0.05))
    assert ends.shape == (7, 30, 2)
    for m in range(7):
        x, y, th = poses[m]
        c, s = math.cos(th), math.sin(th)
        local = np.column_stack([0.1 + r * np.cos(a), -0.05 + r * np.sin(a)])  # points in the robot frame
        ref = np.column_stack([x + c * local[:, 0] - s * local[:, 1], y + s * local[:, 0] + c * local[:, 1]])
        np.testing.assert_allclose(ends[m], ref, atol=1e-12)
        np.testing.assert_allclose(ends[m], scan_endpoints(poses[m], r, a, (0.1, -0.05)))


# --------------------------------------------------------------------------- map correlation


def test_map_correlation_counts_endpoints_on_occupied_cells():
    g = unit_grid(h=6, w=6)
    g.log_odds[3, 4] = 2.0  # occupied
    g.log_odds[5, 5] = 0.5  # occupied
    g.log_odds[1, 1] = -1.0  # free
    g.observed[:] = True
    ends = np.array([
        [[4.5, 3.5], [5.2, 5.9], [1.5, 1.5]],  # two on occupied cells
        [[4.5, 3.5], [4.9, 3.1], [40.0, 3.5]],  # two in the same occupied cell, one outside the map
        [[-0.5, 0.5], [0.5, 0.5], [6.0, 5.5]],  # nothing occupied (x = 6 is just outside)
    ])
    np.testing.assert_array_equal(map_correlation(g, ends), [2.0, 2.0, 0.0])
    np.testing.assert_array_equal(map_correlation(g, ends, threshold=0.85), [1.0, 2.0, 0.0])  # p(0.5) = 0.62
    # summing log-odds instead: 2 + 0.5 − 1, 2 + 2, 0 (outside counts 0)
    np.testing.assert_allclose(map_correlation(g, ends, values=g.log_odds), [1.5, 4.0, 0.0])
    assert map_correlation(g, ends[0]).shape == ()


# --------------------------------------------------------------------------- bad input


def test_bad_input_raises_clear_errors():
    g = unit_grid()
    with pytest.raises(ValueError, match="pose contains a non-finite"):
        g.update([np.nan, 0, 0], [[1.0, 1.0]])
    with pytest.raises(ValueError, match=r"endpoints must have shape \(n, 2\)"):
        g.update([0, 0, 0], [1.0, 1.0])
    with pytest.raises(ValueError, match="no return"):
        scan_endpoints([0, 0, 0], [1.0, np.nan], [0.0, 0.1])
    with pytest.raises(ValueError, match="non-finite"):
        scan_endpoints([0, np.nan, 0], [1.0], [0.0])
    with pytest.raises(ValueError, match=r"shape \(B,\)"):
        scan_endpoints([0, 0, 0], [1.0, 2.0], [0.0])
    with pytest.raises(ValueError, match="negative range"):
        scan_endpoints([0, 0, 0], [-1.0], [0.0])
    with pytest.raises(ValueError, match="integer cell"):
        ray_cells([0.5, 0], [[1, 1]])
    with pytest.raises(ValueError, match="resolution"):
        OccupancyGrid(resolution=-1.0, origin=(0, 0), shape=(2, 2))
    for shape in [(0, 3), (3, 0)]:  # an empty grid has no cell to hold the robot
        with pytest.raises(ValueError, match="positive integers"):
            OccupancyGrid(resolution=1.0, origin=(0, 0), shape=shape)
    with pytest.raises(ValueError, match="l_free"):
        OccupancyGrid(resolution=1.0, origin=(0, 0), shape=(2, 2), l_free=0.3)
    with pytest.raises(ValueError, match="shape"):
        OccupancyGrid(resolution=1.0, origin=(0, 0), shape=(2, 2), log_odds=np.zeros((3, 2)))
    with pytest.raises(ValueError, match="endpoints contains a non-finite"):
        map_correlation(g, np.full((2, 3, 2), np.nan))
    with pytest.raises(ValueError, match="OccupancyGrid"):
        map_correlation(np.zeros((5, 10)), np.zeros((2, 3, 2)))
    with pytest.raises(ValueError, match="extent"):
        OccupancyGrid.around((0.0, 1.0, 2.0), 0.1)
