"""Grid SLAM (fastslam_edu.grid.gridslam): pieces against closed forms and the grid module, loop == vectorised, known truth."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.special import logsumexp

from fastslam_edu.grid.occupancy import OccupancyGrid, map_correlation, scan_endpoints, update_maps
from fastslam_edu.grid.rays import bresenham, ray_cells_batch
from grid_loop import run_grid_slam_loop  # benchmarks/grid_loop.py, the loop reference
from fastslam_edu.grid.gridslam import GridSLAMParams, ancestral_path, run_grid_slam
from fastslam_edu.grid.motion import increment_noise_std, sample_odometry_motion
from fastslam_edu.grid.scan_matching import correlation, correlation_weights, endpoint_cells, hit_field, scan_match
from fastslam_edu.evaluation.relations import reference_errors
from fastslam_edu.datasets.sim_laser import simulate_laser_world


@pytest.fixture(scope="module")
def world():
    return simulate_laser_world(0)


def random_grid(rng, shape=(40, 50), p_occ=0.2):
    g = OccupancyGrid(resolution=0.1, origin=(-1.0, -2.0), shape=shape)
    g.log_odds = np.where(rng.random(shape) < p_occ, 1.0, -1.0) * rng.uniform(0.1, 3, shape)
    g.observed = np.ones(shape, dtype=bool)
    return g


# --------------------------------------------------------------------------- motion


def test_increment_noise_std_closed_form():
    p = GridSLAMParams(alpha_tt=0.1, alpha_tr=0.05, alpha_rt=0.2, alpha_rr=0.3, sigma_t0=0.01, sigma_theta0=0.002)
    s = increment_noise_std([[0.3, 0.4, -0.5], [0.0, 0.0, 0.0]], p)
    np.testing.assert_allclose(s[0], [0.1 * 0.5 + 0.05 * 0.5 + 0.01] * 2 + [0.2 * 0.5 + 0.3 * 0.5 + 0.002])
    np.testing.assert_allclose(s[1], [0.01, 0.01, 0.002])  # standing still: only the floors


def test_sample_motion_uses_m_by_3_normals_and_has_the_stated_spread():
    p = GridSLAMParams()
    u = np.array([1.0, 0.0, 0.2])
    out = sample_odometry_motion(np.zeros((4, 3)), u, p, np.random.default_rng(7))
    eps = np.random.default_rng(7).standard_normal((4, 3)) * increment_noise_std(u, p)
    np.testing.assert_allclose(out, u + eps, atol=1e-12)  # from the origin, x ⊕ (u + ε) = u + ε
    # statistics: from a rotated start, the increment seen in the start's frame is u + ε
    m = 20000
    x0 = np.array([2.0, -1.0, 0.8])
    xs = sample_odometry_motion(np.tile(x0, (m, 1)), u, p, np.random.default_rng(8))
    c, s = math.cos(0.8), math.sin(0.8)
    d = xs[:, :2] - x0[:2]
    local = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], xs[:, 2] - 0.8])
    sd = increment_noise_std(u, p)
    z = (local - u) / sd
    assert np.all(np.abs(z.mean(axis=0)) < 4 / math.sqrt(m))
    assert np.all(np.abs(z.var(axis=0) - 1) < 4 * math.sqrt(2 / m))


# --------------------------------------------------------------------------- weights


def test_correlation_without_kernel_equals_the_grid_module(world):
    rng = np.random.default_rng(1)
    g = random_grid(rng)
    pts = rng.uniform([-1.5, -2.5], [4.5, 2.5], size=(6, 90, 2))  # some outside the grid
    rows, cols = endpoint_cells(g, pts)
    np.testing.assert_array_equal(correlation(g.log_odds, rows, cols), map_correlation(g, pts))
    # per-particle maps: particle i against map i
    maps = np.stack([random_grid(rng).log_odds for _ in range(6)])
    per = correlation(maps, rows, cols)
    for i in range(6):
        g.log_odds = maps[i]
        assert per[i] == map_correlation(g, pts[i])


def test_graded_correlation_by_brute_force():
    rng = np.random.default_rng(2)
    g = random_grid(rng, p_occ=0.05)
    off, wts = correlation_weights(0.1, 0.1)
    assert off.tolist()[0] == [0, 0] and wts[0] == 1.0 and len(off) == 13  # disc of radius 2 cells
    assert np.all(wts * 256 == np.round(wts * 256))
    pts = rng.uniform([-1.3, -2.3], [4.3, 2.3], size=(3, 40, 2))
    rows, cols = endpoint_cells(g, pts)
    got = correlation(g.log_odds, rows, cols, kernel=(off, wts))
    h, w = g.shape
    for i in range(3):  # independent: for each endpoint, nearest occupied cell in the disc → exp(−d²/2σ²)
        total = 0.0
        for r, c in zip(rows[i], cols[i]):
            best = 0.0
            for dr in range(-2, 3):
                for dc in range(-2, 3):
                    rr, cc = r + dr, c + dc
                    if dr * dr + dc * dc <= 4 and 0 <= rr < h and 0 <= cc < w and g.log_odds[rr, cc] > 0:
                        best = max(best, round(256 * math.exp(-(dr * dr + dc * dc) * 0.01 / 0.02)) / 256)
            total += best
        assert got[i] == pytest.approx(total, abs=1e-12)
    # the precomputed field gives the same scores
    r0, c0 = int(rows.min()) - 1, int(cols.min()) - 2
    field = hit_field(g.log_odds, 0.0, (off, wts), (r0, int(rows.max()) + 3, c0, int(cols.max()) + 1))
    np.testing.assert_allclose(field[rows - r0, cols - c0].sum(axis=-1), got, atol=1e-12)


# --------------------------------------------------------------------------- map updates


def test_ray_cells_batch_equals_bresenham_per_beam():
    rng = np.random.default_rng(3)
    starts = rng.integers(-5, 30, size=(4, 2))
    ends = rng.integers(-10, 40, size=(4, 25, 2))
    free, hit = ray_cells_batch(starts, ends)
    expect_free = []
    for i in range(4):
        for e in ends[i]:
            line = bresenham(*starts[i], *e)
            expect_free += [(i, int(r), int(c)) for r, c in line[:-1]]
    assert [tuple(v) for v in free.tolist()] == expect_free
    assert [tuple(v) for v in hit.tolist()] == [(i, *map(int, e)) for i in range(4) for e in ends[i]]


def test_update_maps_equals_occupancy_grid_update_per_particle():
    rng = np.random.default_rng(4)
    g0 = OccupancyGrid.around((-3, 3, -2, 4), 0.1, l_max=2.0)
    g0.log_odds = rng.uniform(-2, 2, g0.shape)
    m = 5
    maps = np.repeat(g0.log_odds[None], m, axis=0)
    poses = rng.uniform([-1, 0, -3], [1, 2, 3], size=(m, 3))
    r = rng.uniform(0.2, 5.0, 60)  # long beams leave the grid
    a = np.linspace(-2, 2, 60)
    ends = scan_endpoints(poses, r, a)
    s_rows, s_cols = endpoint_cells(g0, poses[:, :2])
    e_rows, e_cols = endpoint_cells(g0, ends)
    free, hit = ray_cells_batch(np.stack([s_rows, s_cols], -1), np.stack([e_rows, e_cols], -1))
    update_maps(maps, free, hit, g0.l_occ, g0.l_free, g0.l_max)
    for i in range(m):
        g = g0.copy()
        g.update(poses[i], ends[i])
        np.testing.assert_allclose(maps[i], g.log_odds, atol=1e-12)


# --------------------------------------------------------------------------- ancestry


def test_ancestral_path_by_hand():
    hist = np.arange(3 * 2 * 3, dtype=float).reshape(3, 2, 3)  # 3 scans, 2 particles
    parents = np.array([[0, 1], [1, 1], [0, 0]])
    path = ancestral_path(hist, parents, last=1)
    # scan 2 particle 1 ← scan 1 particle 0 ← scan 0 particle 1
    np.testing.assert_array_equal(path, [hist[0, 1], hist[1, 0], hist[2, 1]])


# --------------------------------------------------------------------------- the filter


@pytest.mark.parametrize("maps,hit_sigma", [("best", 0.0), ("best", 0.1), ("particles", 0.1)])
def test_vectorised_equals_the_loop_reference(world, maps, hit_sigma):
    p = GridSLAMParams(n_particles=5, maps=maps, hit_sigma=hit_sigma, margin=1.0, resample_threshold=0.8,
                       match_iterations=0)
    n = 12 if maps == "particles" else 25
    v = run_grid_slam(world.log, p, np.random.default_rng(11), n_scans=n)
    loop = run_grid_slam_loop(world.log, p, np.random.default_rng(11), n_scans=n)
    np.testing.assert_allclose(v.poses, loop.poses, atol=1e-9)
    np.testing.assert_allclose(v.path, loop.path, atol=1e-9)
    np.testing.assert_array_equal(v.resampled, loop.resampled)
    np.testing.assert_allclose(v.log_weights, loop.log_weights, atol=1e-9)
    np.testing.assert_allclose(v.grid.log_odds, loop.grid.log_odds, atol=1e-5)
    assert v.resampled.sum() >= 3 and not v.resampled.all()  # both branches of the N_eff test ran


def test_same_seed_same_result_and_resampling_follows_the_threshold(world):
    p = GridSLAMParams(n_particles=8, margin=1.0)
    a = run_grid_slam(world.log, p, np.random.default_rng(3), n_scans=30)
    b = run_grid_slam(world.log, p, np.random.default_rng(3), n_scans=30)
    np.testing.assert_array_equal(a.poses, b.poses)
    never = run_grid_slam(world.log, p.replace(resample_threshold=0.0), np.random.default_rng(3), n_scans=30)
    assert not never.resampled.any()
    assert np.all((a.n_eff < 0.5 * 8) == a.resampled)


def test_filter_beats_odometry_on_a_simulated_office(world):
    """Known truth: the plain filter and, much more, the scan-matched one, beat dead reckoning."""
    truth = world.truth
    odo = reference_errors(world.log.t, world.log.poses, world.log.t, truth)["rmse"]
    plain = run_grid_slam(world.log, GridSLAMParams(margin=2.0, match_iterations=0), np.random.default_rng(0))
    matched = run_grid_slam(world.log, GridSLAMParams(hit_sigma=0.1, margin=2.0, match_iterations=8),
                            np.random.default_rng(0))
    e_plain = reference_errors(plain.t, plain.estimate, world.log.t, truth)["rmse"]
    e_match = reference_errors(matched.t, matched.estimate, world.log.t, truth)["rmse"]
    assert odo > 0.5
    assert e_plain < 0.5 * odo
    assert e_match < 0.1 and e_match < 0.2 * odo
    # the map: endpoints of the true scans land on occupied cells of the estimated map (after alignment)
    assert matched.best_score[1:].mean() > 0.5 * matched.beams_used[1:].mean()


def test_rao_blackwellised_variant_runs_and_keeps_a_map_per_particle(world):
    p = GridSLAMParams(n_particles=6, maps="particles", hit_sigma=0.1, margin=1.0, match_iterations=0)
    res = run_grid_slam(world.log, p, np.random.default_rng(2))
    assert res.maps.shape == (6, *res.grid.shape) and res.maps.dtype == np.float32
    np.testing.assert_allclose(res.grid.log_odds, res.maps[np.argmax(res.log_weights)], atol=0)
    err = reference_errors(res.t, res.estimate, world.log.t, world.truth)["rmse"]
    odo = reference_errors(res.t, res.odometry, world.log.t, world.truth)["rmse"]
    assert err < 0.25 * odo
    # the estimate is one particle's consistent history: its map is the log-odds map of that path
    g = OccupancyGrid(res.grid.resolution, res.grid.origin, res.grid.shape, l_max=p.l_max)
    for k in range(len(res.t)):
        r, a = world.log.beams(k)
        g.update(res.path[k], scan_endpoints(res.path[k], r, a))
    np.testing.assert_allclose(g.log_odds, res.grid.log_odds, atol=1e-4)


@pytest.mark.parametrize("temp", [1.0, 2.5], ids=["writeup", "tempered"])
@pytest.mark.parametrize("runner", [run_grid_slam, run_grid_slam_loop])
def test_temperature_divides_the_scores_in_the_first_weights(world, runner, temp):
    """Reference: scan 1 re-scored by the grid module on the map of scan 0 from x0; closed-form softmax of c / T."""
    p = GridSLAMParams(n_particles=6, hit_sigma=0.0, margin=1.0, resample_threshold=0.0, match_iterations=0,
                       temperature=temp)
    res = runner(world.log, p, np.random.default_rng(5), n_scans=2)
    g = OccupancyGrid(res.grid.resolution, res.grid.origin, res.grid.shape, l_max=p.l_max)
    x0 = world.log.poses[0]
    r, a = world.log.beams(0)
    g.update(x0, scan_endpoints(x0, r, a))
    r, a = world.log.beams(1)
    c = map_correlation(g, scan_endpoints(res.particles, r, a))
    assert c.max() - c.min() >= 3  # the particles score differently, so T matters
    np.testing.assert_allclose(res.log_weights, c / temp - logsumexp(c / temp), atol=1e-9)
    np.testing.assert_allclose(np.exp(res.log_weights), np.exp(c / temp) / np.exp(c / temp).sum(), rtol=1e-9)


def test_writeup_threshold_does_not_resample_equal_weights(world):
    """Reference: Doucet's rule N_eff < M; noise-free particles stay identical, so N_eff = M exactly (M = 4)."""
    still = dict(alpha_tt=0.0, alpha_tr=0.0, alpha_rt=0.0, alpha_rr=0.0, sigma_t0=0.0, sigma_theta0=0.0)
    res = run_grid_slam(world.log, GridSLAMParams.writeup(n_particles=4, margin=1.0, **still),
                        np.random.default_rng(0), n_scans=8)
    np.testing.assert_array_equal(res.n_eff, 4.0)
    assert not res.resampled.any()


def test_scan_match_leaves_a_pose_alone_on_a_map_with_nothing_occupied():
    """Reference: on an empty map every candidate scores 0, so no move raises the score and the pose stays put."""
    g = OccupancyGrid.around((-5, 5, -5, 5), 0.1)
    start = np.array([[0.3, -0.2, 0.4], [1.0, 1.0, -2.0]])
    a = np.linspace(-1.5, 1.5, 31)
    moved = scan_match(start, g.log_odds, g, np.full(31, 2.0), a, GridSLAMParams(match_iterations=5))
    np.testing.assert_array_equal(moved, start)


def test_scan_match_pulls_a_displaced_pose_back():
    """On a map built from the true pose, a pose moved by (0.06, −0.05, 0.03) climbs back near the truth."""
    w = simulate_laser_world(5)
    k = 30
    g = OccupancyGrid.around((-1, 17, -1, 11), 0.05)
    r, a = w.log.beams(k)
    for _ in range(3):
        g.update(w.truth[k], scan_endpoints(w.truth[k], r, a))
    start = w.truth[k] + np.array([0.06, -0.05, 0.03])
    p = GridSLAMParams(hit_sigma=0.05, match_iterations=20, match_xy=0.05, match_theta=0.02)
    moved = scan_match(start[None], g.log_odds, g, r, a, p)[0]
    assert np.hypot(*(moved[:2] - w.truth[k, :2])) < 0.03
    assert abs(moved[2] - w.truth[k, 2]) < 0.01


def test_bad_input_is_rejected(world):
    with pytest.raises(ValueError, match="maps"):
        GridSLAMParams(maps="all")
    with pytest.raises(ValueError, match="temperature"):
        GridSLAMParams(temperature=0.0)
    with pytest.raises(ValueError, match="resampler"):
        GridSLAMParams(resampler="wheel")
    with pytest.raises(ValueError, match="unknown setting"):
        GridSLAMParams().replace(particles=3)
    for bad in (-0.1, 1.5):
        with pytest.raises(ValueError, match="resample_threshold"):
            GridSLAMParams(resample_threshold=bad)
    with pytest.raises(ValueError, match="max_range"):
        GridSLAMParams(min_range=0.5, max_range=0.5)  # an empty window of ranges
    for name in ("p_hit", "p_miss"):
        for bad in (0.0, 1.0, float("nan")):
            with pytest.raises(ValueError, match=f"{name} must lie strictly between 0 and 1"):
                GridSLAMParams(**{name: bad})
    one = dataclasses.replace(world.log, t=world.log.t[:1], ranges=world.log.ranges[:1], poses=world.log.poses[:1],
                              odometry=None if world.log.odometry is None else world.log.odometry[:1],
                              last_odom=None if world.log.last_odom is None else world.log.last_odom[:1])
    with pytest.raises(ValueError, match="at least 2 scans"):
        run_grid_slam(one, GridSLAMParams(), np.random.default_rng(0))
    u = np.zeros((len(world.log), 3))
    u[5, 1] = np.nan
    with pytest.raises(ValueError, match="scan 5"):
        run_grid_slam(world.log, GridSLAMParams(), np.random.default_rng(0), increments=u)
    with pytest.raises(ValueError, match="Generator"):
        run_grid_slam(world.log, GridSLAMParams(), 0)
    with pytest.raises(ValueError, match="systematic"):
        run_grid_slam_loop(world.log, GridSLAMParams(resampler="roulette"), np.random.default_rng(0))


def test_writeup_preset_is_the_writeup_rule():
    p = GridSLAMParams.writeup()
    assert (p.hit_sigma, p.temperature, p.resample_threshold, p.match_iterations, p.maps) == (0.0, 1.0, 1.0, 0, "best")
    assert correlation_weights(p.hit_sigma, p.resolution)[0].tolist() == [[0, 0]]
    assert GridSLAMParams.writeup(n_particles=7).n_particles == 7
