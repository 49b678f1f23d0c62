"""SE(2) algebra against 3×3 homogeneous matrices (an independent reference) and closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fastslam_edu.core import se2


def matrix(p):
    """T(p) = [[R(θ), t], [0, 0, 1]] — the reference the module's formulas must agree with."""
    x, y, th = p
    c, s = math.cos(th), math.sin(th)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


def pose_of(T):
    return np.array([T[0, 2], T[1, 2], math.atan2(T[1, 0], T[0, 0])])


def random_poses(rng, n):
    return np.column_stack([rng.uniform(-10, 10, (n, 2)), rng.uniform(-math.pi, math.pi, n)])


def assert_pose_close(a, b, atol=1e-12):
    a, b = np.asarray(a), np.asarray(b)
    np.testing.assert_allclose(a[..., :2], b[..., :2], atol=atol)
    dth = np.angle(np.exp(1j * (a[..., 2] - b[..., 2])))
    np.testing.assert_allclose(dth, 0.0, atol=atol)


def test_compose_inverse_relative_match_matrix_algebra():
    rng = np.random.default_rng(0)
    a, b = random_poses(rng, 200), random_poses(rng, 200)
    c = se2.compose(a, b)
    inv = se2.inverse(a)
    rel = se2.relative(a, b)
    for k in range(200):
        assert_pose_close(c[k], pose_of(matrix(a[k]) @ matrix(b[k])))
        assert_pose_close(inv[k], pose_of(np.linalg.inv(matrix(a[k]))))
        assert_pose_close(rel[k], pose_of(np.linalg.inv(matrix(a[k])) @ matrix(b[k])))
    assert np.all((c[:, 2] > -math.pi) & (c[:, 2] <= math.pi))


def test_closed_forms_by_hand():
    # quarter turn: a point 1 m ahead of a robot at (1, 2) facing +y is at (1, 3)
    np.testing.assert_allclose(se2.transform_points([1.0, 2.0, math.pi / 2], [1.0, 0.0]), [1.0, 3.0], atol=1e-15)
    np.testing.assert_allclose(se2.compose([1.0, 2.0, math.pi / 2], [1.0, 0.0, math.pi / 2]),
                               [1.0, 3.0, math.pi], atol=1e-15)
    # the inverse of (1, 0, π/2): the world origin seen from there is at (0, 1), heading −π/2
    np.testing.assert_allclose(se2.inverse([1.0, 0.0, math.pi / 2]), [0.0, 1.0, -math.pi / 2], atol=1e-15)
    # angles wrap: 3 + 3 rad → 6 − 2π
    assert se2.compose([0, 0, 3.0], [0, 0, 3.0])[2] == pytest.approx(6.0 - 2 * math.pi)


def test_identities_and_broadcasting():
    rng = np.random.default_rng(1)
    a, b = random_poses(rng, 50), random_poses(rng, 50)
    assert_pose_close(se2.compose(a, se2.inverse(a)), np.zeros((50, 3)))
    assert_pose_close(se2.compose(se2.inverse(a), a), np.zeros((50, 3)))
    assert_pose_close(se2.compose(a, se2.relative(a, b)), b, atol=1e-11)
    # one increment (3,) applied to M particles (M, 3)
    u = np.array([0.3, -0.1, 0.2])
    out = se2.compose(a, u)
    assert out.shape == (50, 3)
    assert_pose_close(out[7], se2.compose(a[7], u))
    # points (B, 2) under poses (M, 1, 3) -> (M, B, 2)
    pts = rng.normal(size=(4, 2))
    w = se2.transform_points(a[:, None, :], pts)
    assert w.shape == (50, 4, 2)
    ref = (matrix(a[3]) @ np.column_stack([pts, np.ones(4)]).T).T[:, :2]
    np.testing.assert_allclose(w[3], ref, atol=1e-12)


def test_compose_increments_equals_repeated_matrix_products():
    rng = np.random.default_rng(2)
    x0 = np.array([1.0, -2.0, 2.5])
    u = np.column_stack([rng.uniform(-0.5, 1.0, 300), rng.uniform(-0.2, 0.2, 300), rng.uniform(-0.6, 0.6, 300)])
    path = se2.compose_increments(x0, u)
    assert path.shape == (301, 3)
    T = matrix(x0)
    assert_pose_close(path[0], x0)
    for k in range(300):
        T = T @ matrix(u[k])
        assert_pose_close(path[k + 1], pose_of(T), atol=1e-10)
    assert_pose_close(se2.path_increments(path), u, atol=1e-10)


def test_bad_input_is_refused_with_a_message():
    with pytest.raises(ValueError, match="non-finite"):
        se2.compose([0, np.nan, 0], [0, 0, 0])
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 3\)"):
        se2.inverse([1.0, 2.0])
    with pytest.raises(ValueError, match="points"):
        se2.transform_points([0, 0, 0], [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="compose_increments"):
        se2.compose_increments([0, 0, 0], [0.1, 0, 0])


def test_every_result_heading_lies_in_the_half_open_interval():
    """Headings of compose/inverse/relative/compose_increments in (−π, π], against atan2 of matrix products."""
    rng = np.random.default_rng(3)
    a, b = random_poses(rng, 200), random_poses(rng, 200)
    for out in (se2.compose(a, b), se2.inverse(a), se2.relative(a, b)):
        assert np.all((out[:, 2] > -math.pi) & (out[:, 2] <= math.pi))
    # θ = π: its inverse has heading −π, which the interval writes as π
    assert se2.inverse([1.0, 2.0, math.pi])[2] == pytest.approx(math.pi, abs=1e-15)
    # a robot turning 0.5 rad per step for 60 steps: 30 rad of unwrapped heading
    u = np.tile([0.2, 0.0, 0.5], (60, 1))
    path = se2.compose_increments([0.0, 0.0, 0.0], u)
    assert np.all((path[:, 2] > -math.pi) & (path[:, 2] <= math.pi))
    T = np.eye(3)
    for k in range(60):
        T = T @ matrix(u[k])
        assert_pose_close(path[k + 1], pose_of(T), atol=1e-10)


def test_wrap_angle_against_math_remainder():
    """wrap_angle equals math.remainder(a, 2π) (an independent wrap), also many turns away; ±π map to π."""
    from fastslam_edu.core.angles import wrap_angle

    a = np.random.default_rng(4).uniform(-100.0, 100.0, 500)
    ref = np.array([math.remainder(v, 2 * math.pi) for v in a])
    np.testing.assert_allclose(wrap_angle(a), ref, atol=1e-12)
    assert wrap_angle(math.pi) == math.pi and wrap_angle(-math.pi) == math.pi
    out = wrap_angle(7.0)  # a scalar in, a Python float out
    assert type(out) is float and out == pytest.approx(7.0 - 2 * math.pi, abs=1e-15)


def test_path_functions_refuse_wrong_ranks():
    """path_increments wants (N, 3) and compose_increments x0 (3,): other ranks raise a ValueError naming them."""
    with pytest.raises(ValueError, match=r"path_increments: poses must have shape \(N, 3\)"):
        se2.path_increments(np.zeros((2, 4, 3)))
    with pytest.raises(ValueError, match=r"path_increments: poses must have shape \(N, 3\)"):
        se2.path_increments([1.0, 2.0, 0.3])
    with pytest.raises(ValueError, match=r"compose_increments: x0 must have shape \(3,\)"):
        se2.compose_increments(np.zeros((2, 3)), np.zeros((4, 3)))
