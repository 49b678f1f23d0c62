"""THOR geometry: LiDAR → head → body → world, filtering, time matching.

References: closed forms (a level beam at 1.41 m, a pitched beam touching the
floor at 1.41 / tan φ), scipy's Rotation (intrinsic z–y Euler angles) for the
composition, and brute-force loops for the vectorised code.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fastslam_edu.grid import thor
from fastslam_edu.grid.thor import filter_returns
from fastslam_edu.datasets import thor_geometry
from fastslam_edu.datasets.thor_geometry import (
    BODY_HEIGHT,
    FLOOR_Z,
    LIDAR_HEIGHT,
    body_to_world,
    beam_directions_world,
    homogeneous,
    joints_at,
    lidar_points_world,
    lidar_to_body,
    lidar_to_world,
    nearest_sample,
    rot_y,
    rot_z,
)


def test_the_mapping_layer_reads_the_one_geometry():
    """Chapter 18 writes ``thor.lidar_points_world``: grid.thor hands out the geometry's own objects, no copies."""
    for name in thor_geometry.__all__:
        assert getattr(thor, name) is getattr(thor_geometry, name), name


def test_heights_from_the_course_handouts():
    assert BODY_HEIGHT == pytest.approx(0.93 + 0.33)
    assert LIDAR_HEIGHT == pytest.approx(1.41)


def test_zero_angles_level_beam_straight_ahead():
    for r in (0.5, 3.0, 29.0):
        p = lidar_points_world([r], [0.0], 0.0, 0.0, (0.0, 0.0, 0.0))
        np.testing.assert_allclose(p, [[r, 0.0, 1.26 + 0.15]], atol=1e-12)
    # a beam at +90° points left (y), at −135° behind on the right
    p = lidar_points_world([2.0, 2.0], np.radians([90.0, -135.0]), 0.0, 0.0, (0.0, 0.0, 0.0))
    np.testing.assert_allclose(p, [[0, 2, 1.41], [-math.sqrt(2), -math.sqrt(2), 1.41]], atol=1e-12)


def test_body_pose_translates_and_turns():
    x, y, yaw, r = 3.0, -1.5, 0.7, 4.0
    p = lidar_points_world([r], [0.0], 0.0, 0.0, (x, y, yaw))
    np.testing.assert_allclose(p, [[x + r * math.cos(yaw), y + r * math.sin(yaw), 1.41]], atol=1e-12)


@pytest.mark.parametrize("phi_deg", [5.76, 10.76, 20.0, 40.76])
def test_pitched_beam_touches_the_floor_at_1_41_over_tan_phi(phi_deg):
    phi = math.radians(phi_deg)
    r_floor = 1.41 / math.sin(phi)  # the ray's length to z = 0
    p = lidar_points_world([r_floor], [0.0], 0.0, phi, (0.0, 0.0, 0.0))[0]
    np.testing.assert_allclose(p, [1.41 / math.tan(phi), 0.0, 0.0], atol=1e-12)
    # a beam at angle α in the tilted plane falls by r cos α sin φ: z = 0 at r = 1.41 / (cos α sin φ)
    alpha = np.radians([-60.0, -20.0, 30.0, 75.0])
    r = 1.41 / (np.cos(alpha) * math.sin(phi))
    pts = lidar_points_world(r, alpha, 0.0, phi, (0.0, 0.0, 0.0))
    np.testing.assert_allclose(pts[:, 2], 0.0, atol=1e-12)
    # a little shorter stays above the floor, a little longer goes below
    assert (lidar_points_world(r * 0.99, alpha, 0.0, phi, (0, 0, 0))[:, 2] > 0).all()
    assert (lidar_points_world(r * 1.01, alpha, 0.0, phi, (0, 0, 0))[:, 2] < 0).all()
    # the floor filter drops the floor point and keeps the same beam at half the range
    f = filter_returns([r_floor, r_floor / 2], [p[2], 1.41 / 2])
    np.testing.assert_array_equal(f.keep, [False, True])
    assert (f.n_floor, f.n_kept, f.n_out_of_range) == (1, 1, 0)


def test_pitched_beams_behind_go_up():
    # |α| > 90°: R_y(φ) (cos α, sin α, 0) has z = −cos α sin φ > 0
    phi, r = math.radians(30.0), 2.0
    p = lidar_points_world([r], [math.radians(180.0)], 0.0, phi, (0, 0, 0))[0]
    np.testing.assert_allclose(p, [-r * math.cos(phi), 0.0, 1.41 + r * math.sin(phi)], atol=1e-12)


def test_neck_yaw_rotates_about_the_vertical_axis():
    rng = np.random.default_rng(1)
    r = rng.uniform(0.5, 10, 50)
    a = rng.uniform(-2.3, 2.3, 50)
    head, psi = 0.3, 0.8
    pose = np.array([1.0, 2.0, -0.4])
    p0 = lidar_points_world(r, a, 0.0, head, pose)
    p1 = lidar_points_world(r, a, psi, head, pose)
    # rotating the neck = rotating the points about the vertical line through (x, y)
    c, s = math.cos(psi), math.sin(psi)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    centre = np.array([pose[0], pose[1], 0.0])
    np.testing.assert_allclose(p1, (p0 - centre) @ Rz.T + centre, atol=1e-12)
    # … which is the same as turning the body by ψ
    np.testing.assert_allclose(p1, lidar_points_world(r, a, 0.0, head, pose + [0, 0, psi]), atol=1e-12)
    # a level beam ahead lands at (r cos ψ, r sin ψ, 1.41)
    np.testing.assert_allclose(
        lidar_points_world([2.0], [0.0], psi, 0.0, (0, 0, 0)), [[2 * c, 2 * s, 1.41]], atol=1e-12
    )


def test_composition_order_neck_then_head():
    # R_z(90°) R_y(30°): the head turned left, then pitched down 30° — the beam goes left AND down
    r = 2.0
    p = lidar_points_world([r], [0.0], math.radians(90), math.radians(30), (0, 0, 0))[0]
    np.testing.assert_allclose(p, [0.0, r * math.cos(math.radians(30)), 1.41 - r * math.sin(math.radians(30))],
                               atol=1e-12)
    # the other order, R_y(30°) R_z(90°), would leave it level: (0, r, 1.41) — it must not
    assert abs(p[2] - 1.41) > 0.5
    # T_WL = T_WB T_BL, not T_BL T_WB: the body's translation is not rotated by the head
    T = lidar_to_world(0.4, 0.2, (5.0, -3.0, 1.0))
    np.testing.assert_allclose(T[:3, 3], [5.0, -3.0, 1.41], atol=1e-12)
    np.testing.assert_allclose(T, body_to_world((5.0, -3.0, 1.0)) @ lidar_to_body(0.4, 0.2), atol=1e-12)


def test_rotations_against_scipy_and_closed_forms():
    rng = np.random.default_rng(2)
    for _ in range(20):
        neck, head = rng.uniform(-1.5, 1.5, 2)
        ref = Rotation.from_euler("ZY", [neck, head]).as_matrix()  # intrinsic: R_z(neck) R_y(head)
        np.testing.assert_allclose(lidar_to_body(neck, head)[:3, :3], ref, atol=1e-12)
    phi = 0.25
    np.testing.assert_allclose(rot_y(phi) @ [1, 0, 0], [math.cos(phi), 0, -math.sin(phi)], atol=1e-15)
    np.testing.assert_allclose(rot_z(phi) @ [1, 0, 0], [math.cos(phi), math.sin(phi), 0], atol=1e-15)
    R = rot_z(rng.uniform(-3, 3, 7)) @ rot_y(rng.uniform(-3, 3, 7))
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), (7, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    T = homogeneous(np.eye(3), [1, 2, 3])
    np.testing.assert_array_equal(T[3], [0, 0, 0, 1])


def test_vectorised_over_scans_and_beams_matches_a_loop():
    rng = np.random.default_rng(3)
    n, b = 6, 9
    ranges = rng.uniform(0.2, 20, (n, b))
    angles = np.radians(np.linspace(-135, 135, b))
    neck = rng.uniform(-0.5, 0.5, n)
    head = rng.uniform(0.0, 0.7, n)
    pose = np.column_stack([rng.uniform(-5, 5, (n, 2)), rng.uniform(-3, 3, n)])
    pts = lidar_points_world(ranges, angles, neck, head, pose)
    assert pts.shape == (n, b, 3)
    origin, dirs = beam_directions_world(angles, neck, head, pose)
    for k in range(n):  # independent reference: scipy rotations, one beam at a time
        R_head = Rotation.from_euler("ZY", [neck[k], head[k]]).as_matrix()
        R_body = Rotation.from_euler("Z", pose[k, 2]).as_matrix()
        body = np.array([pose[k, 0], pose[k, 1], 1.26])
        for j in range(b):
            p_l = ranges[k, j] * np.array([math.cos(angles[j]), math.sin(angles[j]), 0.0])
            ref = R_body @ (R_head @ p_l + [0, 0, 0.15]) + body
            np.testing.assert_allclose(pts[k, j], ref, atol=1e-12)
            np.testing.assert_allclose(origin[k] + ranges[k, j] * dirs[k, j], ref, atol=1e-12)
        # one scan at a time gives the same
        np.testing.assert_allclose(lidar_points_world(ranges[k], angles, neck[k], head[k], pose[k]), pts[k])
    # a rigid motion keeps the range: ‖p − origin‖ = r, and directions are unit vectors
    np.testing.assert_allclose(np.linalg.norm(pts - origin[:, None], axis=-1), ranges, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=-1), 1.0, atol=1e-12)


def test_filter_returns_counts():
    ranges = np.array([[0.05, 0.1, 5.0, 30.0, 30.5, np.nan, 0.0, 2.0]])
    z = np.array([[1.0, 1.0, 0.05, 1.0, 1.0, np.nan, 1.41, -0.3]])
    f = filter_returns(ranges, z)
    np.testing.assert_array_equal(f.out_of_range, [[True, False, False, False, True, True, True, False]])
    np.testing.assert_array_equal(f.floor, [[False, False, True, False, False, False, False, True]])
    np.testing.assert_array_equal(f.keep, [[False, True, False, True, False, False, False, False]])
    assert (f.n_total, f.n_out_of_range, f.n_floor, f.n_kept) == (8, 4, 2, 2)
    off = filter_returns(ranges, z, z_floor=None)
    assert (off.n_floor, off.n_kept) == (0, 4)
    assert off.n_out_of_range + off.n_kept == off.n_total
    # the threshold: z = 0.1 is kept, just below is floor
    assert filter_returns([1.0, 1.0], [FLOOR_Z, FLOOR_Z - 1e-9]).keep.tolist() == [True, False]
    with pytest.raises(ValueError, match="same shape"):
        filter_returns([1.0, 2.0], [0.5])
    with pytest.raises(ValueError, match="z is not finite"):
        filter_returns([1.0], [np.nan])
    with pytest.raises(ValueError, match="min_range"):
        filter_returns([1.0], [1.0], min_range=5.0, max_range=1.0)
    with pytest.raises(ValueError, match="min_range"):  # an empty interval is refused too
        filter_returns([1.0], [1.0], min_range=1.0, max_range=1.0)


def test_joints_at_nearest_timestamp_against_brute_force():
    rng = np.random.default_rng(4)
    tj = 1.2e9 + np.cumsum(rng.uniform(0.004, 0.012, 400))  # ~120 Hz, irregular
    neck = rng.uniform(-0.2, 0.2, 400)
    head = rng.uniform(0.0, 0.7, 400)
    ts = np.sort(rng.uniform(tj[0] - 0.05, tj[-1] + 0.05, 150))  # some outside the log
    n_k, h_k = joints_at(ts, tj, neck, head)
    j = np.abs(tj[None, :] - ts[:, None]).argmin(axis=1)  # brute force
    np.testing.assert_array_equal(n_k, neck[j])
    np.testing.assert_array_equal(h_k, head[j])
    # exact ties go to the earlier sample; queries outside clamp to the ends
    idx = nearest_sample([0.5, 1.5, -3.0, 9.0, 2.0], [0.0, 1.0, 2.0, 3.0])
    np.testing.assert_array_equal(idx, [0, 1, 0, 3, 2])
    np.testing.assert_array_equal(nearest_sample([5.0, -1.0], [2.0]), [0, 0])
    with pytest.raises(ValueError, match="max_gap"):
        joints_at([tj[-1] + 1.0], tj, neck, head, max_gap=0.05)
    assert joints_at(ts[5:10], tj, neck, head, max_gap=0.05)[0].shape == (5,)


def test_bad_inputs():
    with pytest.raises(ValueError, match="non-finite"):
        lidar_points_world([1.0, np.nan], [0.0, 0.1], 0.0, 0.0, (0, 0, 0))
    with pytest.raises(ValueError, match="non-finite"):
        lidar_points_world([1.0], [0.0], np.nan, 0.0, (0, 0, 0))
    with pytest.raises(ValueError, match=r"pose must have shape \(\.\.\., 3\)"):
        lidar_points_world([1.0], [0.0], 0.0, 0.0, (0, 0))
    with pytest.raises(ValueError, match="angles must be"):
        lidar_points_world([1.0, 2.0], [0.0], 0.0, 0.0, (0, 0, 0))
    with pytest.raises(ValueError, match="non-decreasing"):
        joints_at([1.0], [0.0, 2.0, 1.0], [0, 0, 0], [0, 0, 0])
    with pytest.raises(ValueError, match="equal length"):
        joints_at([1.0], [0.0, 1.0], [0, 0, 0], [0, 0])
    with pytest.raises(ValueError, match="non-finite"):
        joints_at([1.0], [0.0, 1.0], [0.0, np.nan], [0.0, 0.0])
    with pytest.raises(ValueError, match="non-empty"):
        nearest_sample([1.0], [])
    with pytest.raises(ValueError, match="homogeneous"):
        homogeneous(np.eye(2), [0, 0])
