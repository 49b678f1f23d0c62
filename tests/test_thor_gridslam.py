"""``fastslam-edu gridslam --format thor``: a THOR LiDAR log projected to the plane, then grid SLAM.

A short THOR sequence is simulated (:func:`fastslam_edu.datasets.thor_sim.simulate_thor`)
with a synthetic joint log: the neck sways ±0.4 rad, the head is level (3°)
except for 4 s pitched 25° down, when the beams hit the floor 3 m ahead. The
truth is the simulated body pose; the odometry drifts (5 % scale, 0.05 rad/m).
References: the simulated truth (path errors, written as a CARMEN log for
``--reference``), the simulated floor hits (which cells must stay free), and
closed forms for a level head (planar range = LiDAR range, bearing = α + ψ_n).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import scipy.io

from fastslam_edu.app.cli import main
from fastslam_edu.datasets.thor_lidar import ThorLidar, read_thor_joints, read_thor_lidar, thor_angles
from fastslam_edu.grid.gridslam import GridSLAMParams, run_grid_slam
from fastslam_edu.datasets.thor_geometry import lidar_points_world
from fastslam_edu.grid.thor import PLANAR_BEARING_STEP, planar_laser_log
from fastslam_edu.datasets.thor_sim import FLOOR, ThorSimConfig, simulate_thor, write_sequence

T0 = 1.6e9  # Unix time of the first joint sample [s]
N_DOWN_END = 161  # scans up to the end of the pitched-down window (16 s at 10 Hz)
DURATION = 30.0  # [s]; at 10 Hz: 301 scans
PITCH_DOWN = math.radians(25.0)
WAYPOINTS = np.array([(0.0, 0.0), (3.5, 0.0), (3.5, 2.0), (0.5, 2.0)])  # inside the start room
SEED = 0


def joint_log():
    """Synthetic 120 Hz joint log: neck 0.4 sin(2π s / 8), head 3° except 25° for 12 s < s < 16 s."""
    s = np.arange(0.0, DURATION + 0.5, 1 / 120)
    neck = 0.4 * np.sin(2 * np.pi * s / 8.0)
    head = np.where((s > 12.0) & (s < 16.0), PITCH_DOWN, math.radians(3.0))
    return T0 + s, neck, head


@pytest.fixture(scope="module")
def sequence():
    tj, neck, head = joint_log()
    cfg = ThorSimConfig(scan_rate=10.0, duration=DURATION, odom_scale=0.05, odom_yaw_drift=0.05)
    return simulate_thor(tj, neck, head, np.random.default_rng(1), cfg, waypoints=WAYPOINTS)


@pytest.fixture(scope="module")
def files(sequence, tmp_path_factory):
    d = tmp_path_factory.mktemp("thor")
    tj, neck, head = joint_log()
    scipy.io.savemat(d / "joints.mat", {"ts": tj[None, :], "head_angles": np.vstack([neck, head])})
    for v in (1, 2):
        write_sequence(sequence, d / f"lidar_v{v}.mat", variant=v)
    # the truth as a CARMEN log, for --reference (one dummy beam per scan)
    lines = [f"FLASER 1 1.0 {x:.6f} {y:.6f} {th:.6f} {x:.6f} {y:.6f} {th:.6f} {t:.6f} sim {t:.6f}"
             for t, (x, y, th) in zip(sequence.t, sequence.true_pose)]
    (d / "truth.log").write_text("\n".join(lines) + "\n")
    return d


def rmse_xy(path, truth) -> float:
    return float(np.sqrt(np.mean(np.sum((path[:, :2] - truth[:, :2]) ** 2, axis=1))))


def floor_cells(seq, grid, clearance: float = 0.3):
    """Grid cells hit by simulated floor returns, at least ``clearance`` [m] from every wall."""
    fl = seq.kind == FLOOR
    p = lidar_points_world(np.where(fl, seq.true_range, 0.0), seq.angles, seq.neck, seq.head, seq.true_pose)[fl]
    p = p[seq.plan.distance_to_walls(p[:, :2]) > clearance]
    cols = np.floor((p[:, 0] - grid.origin[0]) / grid.resolution).astype(int)
    rows = np.floor((p[:, 1] - grid.origin[1]) / grid.resolution).astype(int)
    return np.unique(np.column_stack([rows, cols]), axis=0)


# --------------------------------------------------------------------------- the projection


def test_level_head_projection_is_the_scan_turned_by_the_neck():
    """Head level: ρ = r and β = wrap(α + ψ_n) (to half a bearing step); heights 1.41 m are in the band."""
    alpha = thor_angles()
    rng = np.random.default_rng(3)
    n = 3
    ranges = rng.uniform(0.5, 20.0, (n, alpha.size))
    ranges[:, ::50] = 0.0  # "no return"
    neck = np.array([0.1234, 0.3, -1.0])  # no beam half-way between two bearings (ties may go either way)
    lidar = ThorLidar(t=T0 + np.arange(n) * 0.025, ranges=ranges, angles=alpha, pose=np.zeros((n, 3)),
                      delta_pose=None, rpy=None, res=None, variant=1, source="synthetic")
    tj = T0 + np.arange(n) * 0.025
    log = planar_laser_log(lidar, tj, neck, np.zeros(n))
    for k in range(n):
        beta = np.angle(np.exp(1j * (alpha + neck[k])))
        ok = ranges[k] > 0
        i = np.rint((beta[ok] + math.pi) / PLANAR_BEARING_STEP).astype(int) % log.angles.size
        # nearest point per bin: the minimum of the LiDAR ranges falling in that bin
        expect = np.full(log.angles.size, np.inf)
        np.minimum.at(expect, i, ranges[k][ok])
        expect[np.isinf(expect)] = np.nan
        np.testing.assert_allclose(log.ranges[k], expect, rtol=1e-12, equal_nan=True)
        d = np.angle(np.exp(1j * (log.angles[i] - beta[ok])))
        assert np.abs(d).max() <= PLANAR_BEARING_STEP / 2 + 1e-12
    assert log.counts["out_of_range"] == int((ranges == 0).sum())
    assert log.counts["floor"] == 0 and log.counts["kept"] == int((ranges > 0).sum())


def test_pitched_head_projection_band_and_counts_by_hand():
    """Reference: closed form R_y(φ)(r cos α, r sin α, 0) + 1.41 ẑ per beam, sorted into floor / band / above."""
    phi = math.radians(30.0)
    alpha = np.array([0.0, 0.5, 3.0, 3.0])
    r = np.array([2.0, 5.0, 2.0, 0.5])
    lidar = ThorLidar(t=np.array([T0]), ranges=r[None], angles=alpha, pose=np.zeros((1, 3)), delta_pose=None,
                      rpy=None, res=None, variant=1, source="synthetic")
    log = planar_laser_log(lidar, np.array([T0]), np.zeros(1), np.array([phi]))
    x, y, z = r * np.cos(alpha) * math.cos(phi), r * np.sin(alpha), 1.41 - r * np.cos(alpha) * math.sin(phi)
    # z ≈ 0.41 (kept), −0.78 (floor), 2.40 (above the 2 m band), 1.66 (kept)
    assert z[1] < 0.1 and z[2] > 2.0 and 0.1 < z[0] < 2.0 and 0.1 < z[3] < 2.0
    assert log.counts == {"total": 4, "out_of_range": 0, "floor": 1, "outside_band": 1, "kept": 2, "planar_beams": 2}
    assert log.ranges.shape == (1, 720)  # 360° / 0.5°
    np.testing.assert_allclose(log.angles, -math.pi + PLANAR_BEARING_STEP * np.arange(720), atol=1e-12)
    expect = np.full(720, np.nan)
    for b in (0, 3):
        expect[int(round((math.atan2(y[b], x[b]) + math.pi) / PLANAR_BEARING_STEP)) % 720] = math.hypot(x[b], y[b])
    np.testing.assert_allclose(log.ranges[0], expect, rtol=1e-12, equal_nan=True)
    for bad in ({"band": (2.0, 0.1)}, {"bearing_step": 0.0}, {"bearing_step": -0.01}, {"bearing_step": 4.0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            planar_laser_log(lidar, np.array([T0]), np.zeros(1), np.array([phi]), **bad)


def test_projection_drops_floor_and_needs_joints_in_time(sequence, files):
    lidar = read_thor_lidar(files / "lidar_v1.mat")
    tj, neck, head = read_thor_joints(files / "joints.mat")
    log = planar_laser_log(lidar, tj, neck, head)
    down = sequence.head > math.radians(20)
    assert down.sum() > 20 and (sequence.kind[down] == FLOOR).sum() > 1000  # the floor really is seen
    # every simulated floor return is dropped: counted as floor (or out of the band) and absent from the plane
    assert log.counts["floor"] >= int((sequence.kind == FLOOR).sum())
    np.testing.assert_allclose(log.odometry, sequence.odom_pose, atol=1e-9)
    with pytest.raises(ValueError, match="joint sample"):
        planar_laser_log(lidar, tj[:1200], neck[:1200], head[:1200])  # joints end at 10 s, scans at 30 s


# --------------------------------------------------------------------------- the command line


@pytest.mark.parametrize("variant", [1, 2])
def test_cli_gridslam_thor_beats_odometry(sequence, files, tmp_path, variant):
    out = tmp_path / "out.json"
    rc = main(["gridslam", "--scans", str(files / f"lidar_v{variant}.mat"), "--format", "thor",
               "--joints", str(files / "joints.mat"), "--particles", "10", "--seed", str(SEED),
               "--reference", str(files / "truth.log"), "--json", str(out), "--quiet"])
    assert rc == 0
    s = json.loads(out.read_text())
    for key in ("scans_file", "format", "n_scans", "seed", "params", "filter_seconds", "seconds_per_scan",
                "resampling_steps", "mean_n_eff", "grid", "planar_projection", "reference", "relations"):
        assert key in s, key
    assert s["format"] == "thor" and s["n_scans"] == len(sequence) and s["params"]["n_particles"] == 10
    assert s["planar_projection"]["counts"]["floor"] > 0
    ref = s["reference"]
    assert ref["n_matched"] == len(sequence)
    assert ref["rmse_m"] < 0.5 * ref["odometry_rmse_m"], ref  # measured: 0.036 vs 0.094 m (SE(2)-aligned)

    # the same run by hand, for the path and the map, scored against the truth without alignment
    log = planar_laser_log(read_thor_lidar(files / f"lidar_v{variant}.mat"), *read_thor_joints(files / "joints.mat"))
    res = run_grid_slam(log, GridSLAMParams().replace(n_particles=10), np.random.default_rng(SEED))
    assert int(res.resampled.sum()) == s["resampling_steps"]
    est, odo = rmse_xy(res.estimate, sequence.true_pose), rmse_xy(res.odometry, sequence.true_pose)
    assert est < 0.1 and est < 0.5 * odo, (est, odo)  # measured: 0.050 vs 0.311 m
    # floor returns never reach the map: no occupied cell where the pitched-down beams hit the floor, in the
    # map at the end of the pitched-down window (later level scans would clear such cells again)
    part = run_grid_slam(log, GridSLAMParams().replace(n_particles=10), np.random.default_rng(SEED), n_scans=N_DOWN_END)
    cells = floor_cells(sequence, part.grid)
    assert len(cells) > 100
    p = part.grid.probability()[cells[:, 0], cells[:, 1]]
    assert (p > 0.5).sum() == 0, int((p > 0.5).sum())


def test_floor_check_can_fail_without_the_floor_filter(sequence, files):
    """Control: with the floor filter off and the band reaching below the floor, floor cells become occupied."""
    log = planar_laser_log(read_thor_lidar(files / "lidar_v2.mat"), *read_thor_joints(files / "joints.mat"),
                           z_floor=None, band=(-1.0, 2.0))
    res = run_grid_slam(log, GridSLAMParams().replace(n_particles=10), np.random.default_rng(SEED), n_scans=N_DOWN_END)
    cells = floor_cells(sequence, res.grid)
    n_occ = int((res.grid.probability()[cells[:, 0], cells[:, 1]] > 0.5).sum())
    assert n_occ >= 10, n_occ  # measured: 20 (0 with the filter on)


def test_cli_thor_without_joints_is_one_clear_error(files, capsys):
    rc = main(["gridslam", "--scans", str(files / "lidar_v1.mat"), "--quiet"])
    assert rc == 1
    assert "--joints" in capsys.readouterr().err
    rc = main(["gridslam", "--scans", str(files / "lidar_v1.mat"), "--joints", str(files / "nope.mat"), "--quiet"])
    assert rc == 1
    assert "nope.mat" in capsys.readouterr().err
