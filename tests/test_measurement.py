"""Range–bearing model: closed forms, finite differences, round trips, wrapping, batching."""

from __future__ import annotations

import numpy as np
import pytest

from fastslam_edu.core.measurement import (
    innovation,
    innovation_unchecked,
    jacobian_inverse,
    jacobian_landmark,
    jacobian_landmark_unchecked,
    jacobian_pose,
    landmark_from_measurement,
    range_bearing,
    range_bearing_unchecked,
)

N = 300


def random_poses_landmarks(rng: np.random.Generator, n: int = N):
    """Poses anywhere in a 20 m box with any heading; landmarks 0.3–10 m away in any direction."""
    x = np.column_stack(
        (rng.uniform(-10, 10, n), rng.uniform(-10, 10, n), rng.uniform(-np.pi, np.pi, n))
    )
    dist = rng.uniform(0.3, 10.0, n)
    ang = rng.uniform(-np.pi, np.pi, n)
    m = x[:, :2] + dist[:, None] * np.column_stack((np.cos(ang), np.sin(ang)))
    return x, m


def central_difference(f, a, eps=1e-6):
    """Jacobian of f at a (one point) by central differences; output differences via ⊖."""
    cols = []
    for k in range(a.size):
        e = np.zeros_like(a)
        e[k] = eps
        cols.append(innovation(f(a + e), f(a - e)) / (2 * eps))
    return np.stack(cols, axis=-1)


def max_rel_error(J_fd, J):
    return np.abs(J_fd - J).max() / max(np.abs(J).max(), 1.0)


# --- h against hand-worked values -------------------------------------------------------


def test_range_bearing_hand_values():
    # robot at (1, 2) facing +y (θ = π/2); landmark at (1, 5): straight ahead, 3 m
    np.testing.assert_allclose(range_bearing([1, 2, np.pi / 2], [1, 5]), [3.0, 0.0], atol=1e-15)
    # landmark at (0, 2): to the left of a robot facing +y -> bearing +π/2
    np.testing.assert_allclose(range_bearing([1, 2, np.pi / 2], [0, 2]), [1.0, np.pi / 2])
    # 3-4-5 triangle, robot facing +x
    z = range_bearing([0, 0, 0], [3, 4])
    np.testing.assert_allclose(z, [5.0, np.arctan2(4, 3)])


def test_inverse_hand_values():
    m = landmark_from_measurement([1, 2, np.pi / 2], [3.0, np.pi / 2])  # 3 m to the left
    np.testing.assert_allclose(m, [-2.0, 2.0], atol=1e-14)


# --- Jacobians vs central finite differences ---------------------------------------------


def test_jacobian_landmark_finite_differences():
    x, m = random_poses_landmarks(np.random.default_rng(1))
    H = jacobian_landmark(x, m)
    for i in range(N):
        H_fd = central_difference(lambda mm: range_bearing(x[i], mm), m[i])
        assert max_rel_error(H_fd, H[i]) < 1e-6, i


def test_jacobian_pose_finite_differences():
    x, m = random_poses_landmarks(np.random.default_rng(2))
    J = jacobian_pose(x, m)
    assert J.shape == (N, 2, 3)
    for i in range(N):
        J_fd = central_difference(lambda xx: range_bearing(xx, m[i]), x[i])
        assert max_rel_error(J_fd, J[i]) < 1e-6, i


def test_jacobian_inverse_finite_differences():
    rng = np.random.default_rng(3)
    x, m = random_poses_landmarks(rng)
    z = range_bearing(x, m)
    G = jacobian_inverse(x, z)
    for i in range(N):
        # differences of m are plain differences: compute by hand (⊖ is only for z)
        cols = []
        for k in range(2):
            e = np.zeros(2)
            e[k] = 1e-6
            plus = landmark_from_measurement(x[i], z[i] + e)
            minus = landmark_from_measurement(x[i], z[i] - e)
            cols.append((plus - minus) / 2e-6)
        G_fd = np.stack(cols, axis=-1)
        assert max_rel_error(G_fd, G[i]) < 1e-6, i


def test_G_is_inverse_of_H_at_the_same_point():
    x, m = random_poses_landmarks(np.random.default_rng(4))
    z = range_bearing(x, m)
    G = jacobian_inverse(x, z)
    H = jacobian_landmark(x, m)
    np.testing.assert_allclose(G, np.linalg.inv(H), rtol=1e-10, atol=1e-10)
    # and det H = 1/r (closed form)
    np.testing.assert_allclose(np.linalg.det(H), 1.0 / z[:, 0], rtol=1e-10)


# --- round trips ---------------------------------------------------------------------------


def test_round_trip_m_to_z_to_m():
    x, m = random_poses_landmarks(np.random.default_rng(5))
    np.testing.assert_allclose(landmark_from_measurement(x, range_bearing(x, m)), m, atol=1e-12)


def test_round_trip_z_to_m_to_z():
    rng = np.random.default_rng(6)
    x, _ = random_poses_landmarks(rng)
    z = np.column_stack((rng.uniform(0.1, 10, N), rng.uniform(-np.pi, np.pi, N)))
    z_back = range_bearing(x, landmark_from_measurement(x, z))
    np.testing.assert_allclose(z_back[:, 0], z[:, 0], atol=1e-12)
    assert np.abs(innovation(z_back, z)[:, 1]).max() < 1e-12  # bearing equal up to 2π
    assert np.all((z_back[:, 1] > -np.pi) & (z_back[:, 1] <= np.pi))


# --- wrap-around --------------------------------------------------------------------------


def test_landmark_just_behind_robot_has_bearing_near_pi():
    x = np.array([0.0, 0.0, 0.0])
    above = range_bearing(x, [-5.0, 1e-6])   # just left of straight behind
    below = range_bearing(x, [-5.0, -1e-6])  # just right of straight behind
    assert above[1] == pytest.approx(np.pi - 2e-7, abs=1e-12)
    assert below[1] == pytest.approx(-np.pi + 2e-7, abs=1e-12)
    # robot heading nearly -π: bearing still wrapped into (−π, π]
    z = range_bearing([0, 0, -np.pi + 0.1], [5.0, 0.0])
    assert z[1] == pytest.approx(np.pi - 0.1, abs=1e-12)
    # their difference is a tiny angle, not ≈ 2π
    assert innovation(above, below)[1] == pytest.approx(-4e-7, abs=1e-12)


def test_innovation_reads_359_degrees_as_minus_1():
    z = np.array([4.0, np.deg2rad(179.5)])
    z_hat = np.array([3.5, np.deg2rad(-179.5)])
    nu = innovation(z, z_hat)
    np.testing.assert_allclose(nu, [0.5, np.deg2rad(-1.0)], atol=1e-12)
    np.testing.assert_allclose(innovation(z_hat, z), [-0.5, np.deg2rad(1.0)], atol=1e-12)
    # exactly π stays π (half-open interval (−π, π])
    assert innovation([1.0, np.pi / 2], [1.0, -np.pi / 2])[1] == pytest.approx(np.pi)


# --- batching --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "func, first, trailing_out",
    [
        (range_bearing, "m", (2,)),
        (jacobian_landmark, "m", (2, 2)),
        (jacobian_pose, "m", (2, 3)),
        (landmark_from_measurement, "z", (2,)),
        (jacobian_inverse, "z", (2, 2)),
    ],
)
def test_batching_shapes_match_one_at_a_time(func, first, trailing_out):
    rng = np.random.default_rng(7)
    M, K = 4, 5
    x = np.column_stack((rng.uniform(-5, 5, M), rng.uniform(-5, 5, M), rng.uniform(-4, 4, M)))
    second = rng.uniform(-5, 5, (M, K, 2))
    if first == "z":
        second[..., 0] = np.abs(second[..., 0])
    # scalar: one pose, one landmark
    assert func(x[0], second[0, 0]).shape == trailing_out
    # (M,): one landmark per particle
    out_m = func(x, second[:, 0])
    assert out_m.shape == (M,) + trailing_out
    # (M, K): every particle against every landmark (pose broadcast over K)
    out_mk = func(x[:, None, :], second)
    assert out_mk.shape == (M, K) + trailing_out
    for i in range(M):
        np.testing.assert_array_equal(out_m[i], func(x[i], second[i, 0]))
        for k in range(K):
            np.testing.assert_array_equal(out_mk[i, k], func(x[i], second[i, k]))
    # one pose against K landmarks
    assert func(x[0], second[0]).shape == (K,) + trailing_out


def test_innovation_batching():
    rng = np.random.default_rng(8)
    z = rng.uniform(-4, 4, (3, 4, 2))
    z_hat = rng.uniform(-4, 4, (4, 2))
    nu = innovation(z, z_hat)
    assert nu.shape == (3, 4, 2)
    np.testing.assert_allclose(nu[..., 0], z[..., 0] - z_hat[..., 0])
    d = np.mod(z[..., 1] - z_hat[..., 1] + np.pi, 2 * np.pi) - np.pi  # independent wrap [-π, π)
    np.testing.assert_allclose(nu[..., 1], d, atol=1e-12)


# --- bad input -------------------------------------------------------------------------------


@pytest.mark.parametrize("func", [jacobian_landmark, jacobian_pose])
def test_jacobians_refuse_landmark_on_robot(func):
    x = np.array([[0.0, 0.0, 0.0], [1.5, -2.0, 0.3]])
    m = np.array([[1.0, 1.0], [1.5, -2.0]])
    with pytest.raises(ValueError, match=r"r = 0\) at batch index \(1,\)") as info:
        func(x, m)
    assert "(1.5, -2.0)" in str(info.value)


@pytest.mark.parametrize(
    "func, args, name",
    [
        (range_bearing, ([0.0, np.nan, 0.0], [1.0, 1.0]), "x"),
        (range_bearing, ([0.0, 0.0, 0.0], [1.0, np.inf]), "m"),
        (jacobian_landmark, ([0.0, 0.0, 0.0], [np.nan, 1.0]), "m"),
        (jacobian_pose, ([0.0, 0.0, np.nan], [1.0, 1.0]), "x"),
        (landmark_from_measurement, ([0.0, 0.0, 0.0], [np.nan, 1.0]), "z"),
        (jacobian_inverse, ([0.0, 0.0, 0.0], [1.0, np.nan]), "z"),
        (innovation, ([1.0, 0.0], [1.0, np.nan]), "z_hat"),
    ],
)
def test_nan_rejected_with_name(func, args, name):
    with pytest.raises(ValueError, match=rf"{func.__name__}: {name} contains a non-finite"):
        func(*args)


def test_wrong_shape_and_negative_range_rejected():
    with pytest.raises(ValueError, match=r"x must have shape \(\.\.\., 3\), got shape \(2,\)"):
        range_bearing([0.0, 0.0], [1.0, 1.0])
    with pytest.raises(ValueError, match=r"negative range r = -1\.0"):
        landmark_from_measurement([0.0, 0.0, 0.0], [-1.0, 0.2])


def test_jacobian_inverse_refuses_negative_range():
    """G = ∂h⁻¹/∂z needs r ≥ 0 like h⁻¹ itself (the documented domain); r = 0 is still allowed."""
    with pytest.raises(ValueError, match=r"jacobian_inverse: negative range r = -0\.5 m in z at batch index \(1,\)"):
        jacobian_inverse([0.0, 0.0, 0.0], [[1.0, 0.2], [-0.5, 0.2]])
    # at r = 0 the closed form is [[cos, 0], [sin, 0]] (column φ scales with r)
    np.testing.assert_allclose(jacobian_inverse([0.0, 0.0, 0.3], [0.0, 0.2]),
                               [[np.cos(0.5), 0.0], [np.sin(0.5), 0.0]], atol=1e-15)


def test_unchecked_forms_give_the_same_numbers_as_the_checked_ones():
    """The inner-loop forms skip the checks, not the arithmetic: equal arrays, bit for bit, under broadcasting
    (every pose against every landmark, and one pose against one landmark)."""
    rng = np.random.default_rng(9)
    x, m = random_poses_landmarks(rng, 12)
    z = rng.uniform(0.5, 5.0, (12, 1, 2))
    X, L = x[:, None, :], m[None, :6]
    for checked, unchecked, a, b in ((range_bearing, range_bearing_unchecked, X, L),
                                     (jacobian_landmark, jacobian_landmark_unchecked, X, L),
                                     (innovation, innovation_unchecked, z, range_bearing(X, L))):
        out = unchecked(a, b)
        assert out.shape == checked(a, b).shape
        np.testing.assert_array_equal(out, checked(a, b))
        np.testing.assert_array_equal(unchecked(a[3, 0], b[0, 2]), checked(a[3, 0], b[0, 2]))
