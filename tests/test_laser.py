"""Laser log readers on small files written here (CARMEN, JSON, relations, THOR .mat)."""

from __future__ import annotations

import gzip
import json
import math

import numpy as np
import pytest
import scipy.io

from fastslam_edu.datasets.laser import (LaserLog, carmen_angles, compose_increments, odometry_increments,
                                         read_carmen, read_intel_json, read_relations)
from fastslam_edu.datasets.thor_lidar import read_thor_joints, read_thor_lidar, thor_angles, write_thor_lidar


# --------------------------------------------------------------------------- an independent SE(2) reference


def T(p):
    c, s = math.cos(p[2]), math.sin(p[2])
    return np.array([[c, -s, p[0]], [s, c, p[1]], [0.0, 0.0, 1.0]])


def P(m):
    return np.array([m[0, 2], m[1, 2], math.atan2(m[1, 0], m[0, 0])])


def num(v) -> str:
    return repr(float(v))  # full precision, so that recovery is exact to ~1e-15


# --------------------------------------------------------------------------- a synthetic GMapping-corrected log


def corrected_log(rng, n_scans=25, per_scan=4, n_beams=8, extra_params=(), first_ranges=()):
    """A CARMEN log written the way GMapping writes its corrected output.

    A raw odometry path ``o_j`` is sampled ``per_scan`` times between scans; the
    scans' corrected poses ``x_k`` are the raw poses plus a growing correction.
    Every ODOM line after scan ``k−1`` is ``x_{k−1} ⊕ (o_{k−1}⁻¹ ⊕ o_j)`` (matrices),
    and an ODOM equal to ``x_{k−1}`` (time 0) follows each FLASER.

    Returns the lines and the truth: raw odometry at the scans, corrected poses,
    ranges.
    """
    raw = [np.zeros(3)]
    for _ in range(n_scans * per_scan):
        u = np.array([rng.uniform(0.0, 0.3), rng.normal(0, 0.02), rng.normal(0, 0.15)])
        raw.append(P(T(raw[-1]) @ T(u)))
    raw = np.array(raw)
    scan_idx = per_scan * np.arange(1, n_scans + 1)
    raw_at_scan = raw[scan_idx]
    corr = np.array([P(T([0.01 * k, -0.02 * k, 0.003 * k]) @ T(o)) for k, o in enumerate(raw_at_scan)])
    ranges = rng.uniform(0.5, 8.0, (n_scans, n_beams))
    ranges[0, 1] = 81.83  # no return
    ranges[-1, 5] = 81.91
    ranges[0, : len(first_ranges)] = first_ranges
    lines = ["# a comment", "PARAM robot_frontlaser_offset 0.0 1.0 host 1.0", *extra_params]
    t = 0.0
    prev_corr, prev_raw = None, None
    j = 0
    for k in range(n_scans):
        for _ in range(per_scan):
            j += 1
            t += 0.05
            if prev_corr is None:
                odom = raw[j]  # before the first scan: raw odometry from (0, 0, 0)
            else:
                odom = P(T(prev_corr) @ np.linalg.inv(T(prev_raw)) @ T(raw[j]))
            lines.append(f"ODOM {num(odom[0])} {num(odom[1])} {num(odom[2])} 0 0 0 {t:.6f} pippo {t:.6f}")
        x = corr[k]
        rs = " ".join(num(r) for r in ranges[k])
        pose = f"{num(x[0])} {num(x[1])} {num(x[2])}"
        lines.append(f"FLASER {n_beams} {rs} {pose} {pose} {t:.6f} pippo {t:.6f}")
        lines.append(f"ODOM {pose} 0 0 0 0 pippo 0")
        lines.append("NEFF 12.5")
        prev_corr, prev_raw = x, raw[j]
    lines.insert(2, "ODOM 0 0 0 0 0 0 0.0 pippo 0.0")
    return lines, raw_at_scan, corr, ranges


@pytest.fixture(scope="module")
def synthetic():
    return corrected_log(np.random.default_rng(10))


def write(path, lines, gz=False):
    text = "\n".join(lines) + "\n"
    if gz:
        with gzip.open(path, "wt") as f:
            f.write(text)
    else:
        path.write_text(text)
    return path


def test_read_carmen_parses_scans_angles_and_no_returns(tmp_path, synthetic):
    lines, raw, corr, ranges = synthetic
    log = read_carmen(write(tmp_path / "c.log", lines))
    assert len(log) == 25 and log.ranges.shape == (25, 8)
    np.testing.assert_allclose(np.degrees(log.angles), -90 + 22.5 * np.arange(8))  # 8 beams over 180°
    np.testing.assert_allclose(log.poses, corr, atol=1e-15)
    assert math.isnan(log.ranges[0, 1]) and math.isnan(log.ranges[-1, 5])
    assert np.isnan(log.ranges).sum() == 2
    keep = np.isfinite(log.ranges)
    np.testing.assert_array_equal(log.ranges[keep], ranges[keep])
    assert log.max_range == 80.0
    assert log.odometry is None  # corrected log: both pose triples are GMapping's
    # 1 initial ODOM + 4 per scan + 1 after each FLASER
    assert log.counts == {"#": 1, "PARAM": 1, "ODOM": 126, "FLASER": 25, "NEFF": 25}
    np.testing.assert_allclose(log.t[:2], [0.2, 0.4])
    r, a = log.beams(0)
    assert len(r) == 7 and a[1] == log.angles[2]
    r, _ = log.beams(0, min_range=2.0, max_range=6.0)
    assert ((r >= 2.0) & (r <= 6.0)).all()


def test_gz_log_reads_the_same(tmp_path, synthetic):
    lines = synthetic[0]
    a = read_carmen(write(tmp_path / "c.log", lines))
    b = read_carmen(write(tmp_path / "c.log.gz", lines, gz=True))
    np.testing.assert_array_equal(a.ranges, b.ranges)
    np.testing.assert_array_equal(a.poses, b.poses)


def test_raw_odometry_is_recovered_from_the_corrected_log(tmp_path, synthetic):
    lines, raw, corr, _ = synthetic
    log = read_carmen(write(tmp_path / "c.log", lines))
    u = odometry_increments(log)
    assert u.shape == (25, 3)
    truth = np.array([P(np.linalg.inv(T(raw[k - 1])) @ T(raw[k])) for k in range(1, 25)])
    np.testing.assert_allclose(u[1:], truth, atol=1e-9)
    np.testing.assert_allclose(u[0], raw[0], atol=1e-12)  # from the first ODOM (0, 0, 0) to scan 0
    path = compose_increments(raw[0], u[1:])
    np.testing.assert_allclose(path[:, :2], raw[:, :2], atol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * (path[:, 2] - raw[:, 2]))), 0.0, atol=1e-9)
    # the corrected path is NOT the raw one (the test would pass vacuously otherwise)
    assert np.abs(corr[-1, :2] - raw[-1, :2]).max() > 0.1


def test_params_set_angles_and_no_return_threshold(tmp_path):
    params = ("PARAM laser_front_laser_resolution 0.5 1 h 1", "PARAM robot_front_laser_max 50.0 1 h 1")
    lines, *_ = corrected_log(np.random.default_rng(11), n_scans=3, extra_params=params, first_ranges=(60.0, 49.0))
    log = read_carmen(write(tmp_path / "p.log", lines))
    np.testing.assert_allclose(np.degrees(log.angles), -90 + 0.5 * np.arange(8))
    assert log.max_range == 50.0
    assert math.isnan(log.ranges[0, 0]) and log.ranges[0, 1] == 49.0
    assert log.params["laser_front_laser_resolution"] == "0.5"


def test_raw_log_keeps_its_odometry_poses(tmp_path):
    lines = ["ODOM 0 0 0 0 0 0 0 h 0",
             "FLASER 2 1.0 2.0 0.1 0.0 0.0 0.0 0.0 0.0 1.0 h 1.0",
             "FLASER 2 1.0 2.0 1.1 0.0 0.5 1.0 0.0 0.5 2.0 h 2.0"]
    log = read_carmen(write(tmp_path / "raw.log", lines))
    np.testing.assert_array_equal(log.odometry, [[0, 0, 0], [1.0, 0, 0.5]])
    np.testing.assert_allclose(odometry_increments(log), [[0, 0, 0], [1.0, 0, 0.5]], atol=1e-15)
    np.testing.assert_allclose(carmen_angles(2), [-math.pi / 2, 0.0])


@pytest.mark.parametrize(
    "bad, match",
    [
        ("FLASER 4 1.0 2.0 3.0 4.0 0 0 0", r"bad\.log:3: short FLASER line"),
        ("FLASER 2 1.0 abc 0 0 0 0 0 0 1 h 1", r"bad\.log:3: non-numeric"),
        ("FLASER 2 1.0 2.0 nan 0 0 0 0 0 1 h 1", r"bad\.log:3: non-finite FLASER pose"),
        ("ODOM 1 nan 0 0 0 0 1 h 1", r"bad\.log:3: non-finite ODOM pose"),
        ("FLASER x 1.0", r"bad\.log:3: FLASER line must start with the beam count"),
    ],
)
def test_malformed_carmen_lines_name_file_and_line(tmp_path, bad, match):
    lines = ["PARAM a b 1 h 1", "ODOM 0 0 0 0 0 0 0 h 0", bad]
    with pytest.raises(ValueError, match=match):
        read_carmen(write(tmp_path / "bad.log", lines))


def test_missing_file_and_empty_log(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere.log"):
        read_carmen(tmp_path / "nowhere.log")
    with pytest.raises(ValueError, match="no FLASER"):
        read_carmen(write(tmp_path / "e.log", ["ODOM 0 0 0 0 0 0 0 h 0"]))


def test_odometry_increments_needs_odometry(tmp_path):
    log = LaserLog(t=np.arange(2.0), ranges=np.ones((2, 3)), angles=carmen_angles(3), poses=np.zeros((2, 3)),
                   odometry=None, source="made-up", max_range=80.0)
    with pytest.raises(ValueError, match="made-up"):
        odometry_increments(log)
    with pytest.raises(ValueError, match="poses must have shape"):
        LaserLog(t=np.arange(2.0), ranges=np.ones((2, 3)), angles=carmen_angles(3), poses=np.zeros((3, 3)),
                 odometry=None, source="x", max_range=80.0)


# --------------------------------------------------------------------------- Intel JSON and relations


def intel_json(path, scans):
    doc = {"map": {f"{t:.6f}": {"range": r, "x": x, "y": y, "theta": th} for t, r, x, y, th in scans}}
    with gzip.open(path, "wt") as f:
        json.dump(doc, f)
    return path


def test_read_intel_json_both_kinds(tmp_path):
    scans = [(976052890.244111, [1.0, 81.83, 2.0], 0.1, 0.2, 0.3), (976052892.4424, [1.5, 1.6, 1.7], 0.4, 0.5, -0.6)]
    raw = read_intel_json(intel_json(tmp_path / "intel_gfs.json.gz", scans))
    cor = read_intel_json(intel_json(tmp_path / "intel_corrected_log.json.gz", scans))
    np.testing.assert_allclose(raw.t, [976052890.244111, 976052892.4424], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(raw.poses, [[0.1, 0.2, 0.3], [0.4, 0.5, -0.6]])
    np.testing.assert_array_equal(raw.odometry, raw.poses)
    assert cor.odometry is None
    assert math.isnan(raw.ranges[0, 1]) and raw.ranges[1, 1] == 1.6
    np.testing.assert_allclose(np.degrees(raw.angles), [-90, -30, 30])
    u = odometry_increments(raw)
    np.testing.assert_allclose(u[1], P(np.linalg.inv(T(raw.poses[0])) @ T(raw.poses[1])), atol=1e-12)
    with pytest.raises(ValueError, match="pass kind="):
        read_intel_json(intel_json(tmp_path / "other.json.gz", scans))
    assert read_intel_json(tmp_path / "other.json.gz", kind="corrected").odometry is None


def test_read_intel_json_errors(tmp_path):
    p = intel_json(tmp_path / "intel_gfs.json.gz", [(1.0, [1.0, 2.0], 0.0, 0.0, 0.0)])
    doc = json.load(gzip.open(p, "rt"))
    del doc["map"]["1.000000"]["theta"]
    with gzip.open(p, "wt") as f:
        json.dump(doc, f)
    with pytest.raises(ValueError, match=r"scan '1\.000000': malformed"):
        read_intel_json(p)
    bad = tmp_path / "intel_gfs.json"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        read_intel_json(bad)


def test_read_relations(tmp_path):
    p = tmp_path / "x.relations"
    p.write_text("976052905.167303 976052911.885496 -0.056990 -0.128430 0.000000 0.000000 0.000000 -1.682210\n"
                 "1216.630413 1217.490267 0.407950 -0.016330 0.0 0.0 0.0 -0.069620\n")
    df = read_relations(p)
    assert list(df.columns) == ["t1", "t2", "x", "y", "z", "roll", "pitch", "yaw"]
    assert df.shape == (2, 8)
    assert df.loc[0, "yaw"] == -1.68221 and df.loc[1, "t2"] == 1217.490267
    p.write_text("1 2 0 0 0 0 0 0\n1 2 0 0 0 0 0\n")
    with pytest.raises(ValueError, match=r"x\.relations:2: expected 8 fields"):
        read_relations(p)


# --------------------------------------------------------------------------- THOR


def thor_truth(rng, n=6, b=1081):
    t = 1.23e9 + 0.025 * np.arange(n)
    scans = rng.uniform(0.05, 35.0, (n, b))
    pose = np.column_stack([rng.normal(size=(n, 2)), rng.uniform(-3, 3, n)])
    dpose = rng.normal(0, 0.01, (n, 3))
    rpy = rng.normal(0, 0.05, (n, 3))
    return t, scans, pose, dpose, rpy


def test_thor_variant_1_round_trip_and_raw_layout(tmp_path):
    t, scans, pose, dpose, rpy = thor_truth(np.random.default_rng(12))
    p = tmp_path / "train_lidar9.mat"
    write_thor_lidar(p, t, scans, pose=pose, rpy=rpy, variant=1)
    lid = read_thor_lidar(p)
    assert lid.variant == 1 and len(lid) == 6
    np.testing.assert_array_equal(lid.t, t)
    np.testing.assert_array_equal(lid.ranges, scans)
    np.testing.assert_array_equal(lid.pose, pose)
    np.testing.assert_array_equal(lid.rpy, rpy)
    assert lid.delta_pose is None and lid.res == pytest.approx(math.radians(0.25))
    np.testing.assert_allclose(np.degrees(lid.angles[[0, 1, 540, -1]]), [-135, -134.75, 0, 135])
    np.testing.assert_allclose(np.degrees(thor_angles()[-1]), 135)
    # the layout the public loaders expect: d['lidar'][0][i][0][0] is a struct, fields read by position
    d = scipy.io.loadmat(p)
    assert d["lidar"].shape == (1, 6)
    s = d["lidar"][0][2][0][0]
    assert s.dtype.names == ("t", "pose", "res", "rpy", "scan")
    nn = len(s)
    assert s[0][0][0] == t[2]
    np.testing.assert_array_equal(s[nn - 4][0], pose[2])
    np.testing.assert_array_equal(s[nn - 1][0], scans[2])
    assert s["scan"].shape == (1, 1081)
    valid = lid.valid()
    np.testing.assert_array_equal(valid, (scans >= 0.1) & (scans <= 30.0))
    np.testing.assert_allclose(lid.odometry_poses()[:, :2], pose[:, :2])


def test_thor_variant_1_with_delta_pose_and_variant_2(tmp_path):
    t, scans, pose, dpose, rpy = thor_truth(np.random.default_rng(13), b=20)
    write_thor_lidar(tmp_path / "v1.mat", t, scans, pose=pose, delta_pose=dpose, rpy=rpy, variant=1)
    v1 = read_thor_lidar(tmp_path / "v1.mat")
    assert scipy.io.loadmat(tmp_path / "v1.mat")["lidar"][0][0][0][0].dtype.names == (
        "t", "delta_pose", "pose", "res", "rpy", "scan")
    np.testing.assert_array_equal(v1.delta_pose, dpose)
    np.testing.assert_array_equal(v1.pose, pose)
    write_thor_lidar(tmp_path / "v2.mat", t, scans, delta_pose=dpose, variant=2)
    v2 = read_thor_lidar(tmp_path / "v2.mat")
    assert v2.variant == 2 and v2.pose is None and v2.rpy is None and v2.res is None
    s = scipy.io.loadmat(tmp_path / "v2.mat")["lidar"][0][4][0][0]
    np.testing.assert_array_equal(s[1][0], scans[4])  # scan = field 1, delta_pose = field 2 (public loader)
    np.testing.assert_array_equal(s[2][0], dpose[4])
    np.testing.assert_array_equal(v2.ranges, scans)
    np.testing.assert_array_equal(v2.delta_pose, dpose)
    path = v2.odometry_poses()
    np.testing.assert_allclose(path[:, :2], np.cumsum(dpose[:, :2], axis=0))
    np.testing.assert_allclose(path[-1, 2], dpose[:, 2].sum())


def test_thor_variant_1_with_other_field_names_is_read_by_position(tmp_path):
    t, scans, pose, _, rpy = thor_truth(np.random.default_rng(14), n=3, b=10)
    cells = np.empty((1, 3), dtype=object)
    for i in range(3):
        cells[0, i] = {"ts": np.array([[t[i]]]), "xyth": pose[i][None], "resolution": np.array([[0.1]]),
                       "imu": rpy[i][None], "ranges": scans[i][None]}
    scipy.io.savemat(tmp_path / "odd.mat", {"lidar": cells})
    lid = read_thor_lidar(tmp_path / "odd.mat")
    np.testing.assert_array_equal(lid.pose, pose)
    np.testing.assert_array_equal(lid.ranges, scans)
    assert lid.res == 0.1


def test_thor_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="absent.mat"):
        read_thor_lidar(tmp_path / "absent.mat")
    scipy.io.savemat(tmp_path / "nolidar.mat", {"other": np.zeros(3)})
    with pytest.raises(ValueError, match="no variable 'lidar'"):
        read_thor_lidar(tmp_path / "nolidar.mat")
    cells = np.empty((1, 2), dtype=object)
    cells[0, 0] = {"t": np.array([[1.0]]), "scan": np.ones((1, 5)), "delta_pose": np.zeros((1, 3))}
    cells[0, 1] = {"t": np.array([[2.0]]), "scan": np.ones((1, 5)), "delta_pose": np.zeros((1, 2))}
    scipy.io.savemat(tmp_path / "short.mat", {"lidar": cells})
    with pytest.raises(ValueError, match=r"lidar\{2\}: field 'delta_pose' has 2 values, expected 3"):
        read_thor_lidar(tmp_path / "short.mat")
    with pytest.raises(ValueError, match="variant 1 needs pose"):
        write_thor_lidar(tmp_path / "x.mat", [1.0], np.ones((1, 4)), variant=1)
    with pytest.raises(ValueError, match="variant 2 needs delta_pose"):
        write_thor_lidar(tmp_path / "x.mat", [1.0], np.ones((1, 4)), variant=2)


def test_read_thor_joints(tmp_path):
    rng = np.random.default_rng(15)
    ts = 1.23e9 + np.cumsum(rng.uniform(0.008, 0.009, 50))
    head = np.vstack([rng.normal(0, 0.3, 50), rng.uniform(0, 0.7, 50)])
    scipy.io.savemat(tmp_path / "j.mat", {"ts": ts[None, :], "head_angles": head, "acc": np.zeros((3, 50))})
    t, neck, pitch = read_thor_joints(tmp_path / "j.mat")
    np.testing.assert_array_equal(t, ts)
    np.testing.assert_array_equal(neck, head[0])
    np.testing.assert_array_equal(pitch, head[1])
    scipy.io.savemat(tmp_path / "bad.mat", {"ts": ts[None, :], "head_angles": head[:, :10]})
    with pytest.raises(ValueError, match=r"head_angles must be \(2, 50\)"):
        read_thor_joints(tmp_path / "bad.mat")
    with pytest.raises(FileNotFoundError):
        read_thor_joints(tmp_path / "none.mat")


