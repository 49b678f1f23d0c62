"""Tests of fastslam_edu.evaluation.metrics.

Independent references: known rigid motions (noise-free: exact recovery; noisy:
statistical bound), a brute-force search over the rotation angle, the 2-D
closed form angle = atan2(Σ s×y, Σ s·y), and hand-computed error values.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from fastslam_edu.core.se2 import interpolate_poses
from fastslam_edu.evaluation.metrics import (
    align_se2,
    apply_se2,
    landmark_errors,
    landmark_errors_aligned,
    mean_landmark_error,
    trajectory_errors,
)


def rot(a: float) -> np.ndarray:
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def best_cost_brute_force(s, y, w=None):
    """min over angle of the weighted cost, t optimal for each angle (= centroid match)."""
    w = np.ones(len(s)) if w is None else np.asarray(w, float)
    w = w / w.sum()
    sc, yc = s - w @ s, y - w @ y

    def cost(a):
        return float(np.sum(w * np.sum((sc @ rot(a).T - yc) ** 2, axis=1)))

    grid = np.linspace(-np.pi, np.pi, 3601)
    a0 = grid[np.argmin([cost(a) for a in grid])]
    res = minimize_scalar(cost, bounds=(a0 - 0.01, a0 + 0.01), method="bounded", options={"xatol": 1e-12})
    return res.fun, res.x


def weighted_cost(s, y, w, R, t):
    w = np.ones(len(s)) if w is None else np.asarray(w, float)
    return float(np.sum(w / w.sum() * np.sum((apply_se2(s, R, t) - y) ** 2, axis=1)))


# --------------------------------------------------------------------------- alignment


@pytest.mark.parametrize("angle", [0.0, 0.7, -2.0, 3.0, np.pi, -3.1])
def test_align_recovers_known_motion_exactly(angle):
    rng = np.random.default_rng(1)
    s = rng.uniform(-5, 5, size=(20, 2))
    t_true = np.array([3.0, -2.0])
    y = s @ rot(angle).T + t_true
    R, t, a = align_se2(s, y)
    np.testing.assert_allclose(R, rot(angle), atol=1e-12)
    np.testing.assert_allclose(t, t_true, atol=1e-12)
    assert abs(np.angle(np.exp(1j * (a - angle)))) < 1e-12
    assert -np.pi < a <= np.pi
    np.testing.assert_allclose(apply_se2(s, R, t), y, atol=1e-12)


def test_align_with_noise_within_statistical_bound():
    rng = np.random.default_rng(2)
    n, sigma, angle, t_true = 400, 0.05, 0.4, np.array([-1.0, 2.5])
    s = rng.uniform(-10, 10, size=(n, 2))
    y = s @ rot(angle).T + t_true + rng.normal(scale=sigma, size=(n, 2))
    R, t, a = align_se2(s, y)
    # std of the angle estimate ≈ σ / sqrt(Σ‖s_j − s̄‖²); of each t component ≈ σ / sqrt(n) (centred s)
    sd_angle = sigma / np.sqrt(np.sum((s - s.mean(0)) ** 2))
    assert abs(a - angle) < 5 * sd_angle
    np.testing.assert_array_less(np.abs(t - (t_true + (rot(angle) - R) @ s.mean(0))), 5 * sigma / np.sqrt(n))
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-14)


@pytest.mark.parametrize("seed", range(6))
def test_align_matches_brute_force_and_2d_closed_form(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 15))
    s = rng.normal(size=(n, 2)) * 3
    y = rng.normal(size=(n, 2)) * 3  # unrelated points: a genuine least-squares problem
    w = rng.uniform(0.1, 2.0, size=n)
    R, t, a = align_se2(s, y, w)
    best, _ = best_cost_brute_force(s, y, w)
    assert weighted_cost(s, y, w, R, t) <= best + 1e-9
    # 2-D closed form for the angle: atan2(Σ w (s × y), Σ w (s · y)) on centred points
    wn = w / w.sum()
    sc, yc = s - wn @ s, y - wn @ y
    cross = np.sum(w * (sc[:, 0] * yc[:, 1] - sc[:, 1] * yc[:, 0]))
    dot = np.sum(w * np.sum(sc * yc, axis=1))
    assert abs(np.angle(np.exp(1j * (a - np.arctan2(cross, dot))))) < 1e-10


def test_align_reflection_case_returns_a_proper_rotation():
    rng = np.random.default_rng(4)
    s = rng.uniform(-3, 3, size=(12, 2))
    y = s * np.array([1.0, -1.0])  # mirror image: the unconstrained best fit is a reflection
    H = (s - s.mean(0)).T @ (y - y.mean(0))
    U, _, Vt = np.linalg.svd(H)
    assert np.linalg.det(Vt.T @ U.T) < 0  # plain Kabsch would return det −1 here
    R, t, _ = align_se2(s, y)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-14)
    np.testing.assert_allclose(R.T @ R, np.eye(2), atol=1e-14)
    best, _ = best_cost_brute_force(s, y)
    assert weighted_cost(s, y, None, R, t) <= best + 1e-9


def test_align_zero_weight_ignores_an_outlier_and_degenerate_cases():
    rng = np.random.default_rng(5)
    s = rng.normal(size=(8, 2))
    y = s @ rot(1.0).T + [1.0, 1.0]
    y[3] += 100.0
    w = np.ones(8)
    w[3] = 0.0
    R, t, a = align_se2(s, y, w)
    assert a == pytest.approx(1.0, abs=1e-12)
    # one point (or coincident points): rotation undetermined, identity returned
    R, t, a = align_se2([[1.0, 2.0]], [[4.0, 6.0]])
    np.testing.assert_array_equal(R, np.eye(2))
    np.testing.assert_allclose(t, [3.0, 4.0])
    assert a == 0.0
    R, _, _ = align_se2([[1.0, 2.0]] * 3, [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    np.testing.assert_array_equal(R, np.eye(2))


def test_apply_se2_closed_form():
    np.testing.assert_allclose(apply_se2([[1.0, 0.0], [0.0, 2.0]], rot(np.pi / 2), [1.0, 1.0]), [[1.0, 2.0], [-1.0, 1.0]], atol=1e-15)
    assert apply_se2(np.zeros((4, 5, 2)), np.eye(2), [0.0, 0.0]).shape == (4, 5, 2)


@pytest.mark.parametrize(
    "args, pattern",
    [
        (([[0.0, 0.0]], [[0.0, 0.0], [1.0, 1.0]]), "same shape"),
        (([[0.0, np.nan]], [[0.0, 0.0]]), r"source has 1 row\(s\) with NaN"),
        (([[0.0, 0.0, 0.0]], [[0.0, 0.0, 0.0]]), r"shape \(n, 2\)"),
        (([[0.0, 0.0], [1.0, 0.0]], [[0.0, 0.0], [1.0, 0.0]], [1.0, -1.0]), "non-negative"),
        (([[0.0, 0.0], [1.0, 0.0]], [[0.0, 0.0], [1.0, 0.0]], [0.0, 0.0]), "not all zero"),
        (([[0.0, 0.0], [1.0, 0.0]], [[0.0, 0.0], [1.0, 0.0]], [1.0]), r"weights must have shape \(2,\)"),
    ],
)
def test_align_bad_input(args, pattern):
    with pytest.raises(ValueError, match=pattern):
        align_se2(*args)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_align_rejects_non_finite_weights(bad):
    """Reference: the documented contract (weights must be finite); NaN/inf would silently give a NaN motion."""
    s = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]
    with pytest.raises(ValueError, match="finite"):
        align_se2(s, s, [1.0, bad, 1.0])


def test_align_small_spread_far_from_origin_still_recovers_rotation():
    """Reference: a known rigid motion of a 1 cm cluster 1 km away (rotation well determined, not degenerate)."""
    rng = np.random.default_rng(11)
    s = 1000.0 + rng.uniform(-0.01, 0.01, size=(10, 2))
    angle, t_true = 0.5, np.array([2.0, -3.0])
    y = s @ rot(angle).T + t_true
    _, _, a = align_se2(s, y)
    assert a == pytest.approx(angle, abs=1e-6)


# --------------------------------------------------------------------------- landmarks


TRUTH = np.array([[0.0, 0.0], [1.0, 1.0], [4.0, -2.0], [-3.0, 5.0]])


def test_landmark_errors_closed_form_with_unobserved():
    est = TRUTH + np.array([[3.0, 4.0], [0.0, 0.0], [np.nan, np.nan], [-0.6, 0.8]])
    observed = np.array([True, True, False, True])
    e = landmark_errors(est, TRUTH, observed)
    np.testing.assert_allclose(e[[0, 1, 3]], [5.0, 0.0, 1.0], rtol=1e-14, atol=1e-15)
    assert np.isnan(e[2])
    assert mean_landmark_error(est, TRUTH, observed) == pytest.approx(2.0, rel=1e-14)


def test_landmark_errors_bad_input():
    est = TRUTH.copy()
    est[1] = np.nan
    with pytest.raises(ValueError, match=r"estimate is NaN for landmark\(s\) \[1\] marked as observed"):
        landmark_errors(est, TRUTH)
    with pytest.raises(ValueError, match="same shape"):
        landmark_errors(TRUTH[:3], TRUTH)
    with pytest.raises(ValueError, match="boolean array of shape"):
        landmark_errors(TRUTH, TRUTH, [1, 0, 1, 1])
    with pytest.raises(ValueError, match="no landmark is observed"):
        mean_landmark_error(TRUTH, TRUTH, np.zeros(4, bool))


def test_aligned_landmark_errors_remove_a_rigid_motion():
    est = TRUTH @ rot(-0.3).T + [0.5, -1.0]
    est_unobserved = est.copy()
    est_unobserved[2] = np.nan
    observed = np.array([True, True, False, True])
    assert np.nanmin(landmark_errors(est, TRUTH)) > 0.5
    e = landmark_errors_aligned(est_unobserved, TRUTH, observed)
    np.testing.assert_allclose(e[observed], 0.0, atol=1e-12)
    assert np.isnan(e[2])


def test_aligned_landmark_errors_not_larger_than_unaligned():
    rng = np.random.default_rng(6)
    truth = rng.uniform(-5, 5, size=(15, 2))
    for _ in range(20):
        est = truth @ rot(rng.normal(scale=0.1)).T + rng.normal(scale=0.3, size=2) + rng.normal(scale=0.2, size=(15, 2))
        ea, eu = landmark_errors_aligned(est, truth), landmark_errors(est, truth)
        assert np.sum(ea**2) <= np.sum(eu**2) + 1e-12  # least squares: identity is a candidate


# --------------------------------------------------------------------------- interpolation


def test_interpolate_heading_across_pi():
    t_gt = np.array([0.0, 1.0])
    poses = np.array([[0.0, 0.0, 3.1], [1.0, 2.0, -3.1]])
    mid = interpolate_poses([0.5], t_gt, poses)[0]
    np.testing.assert_allclose(mid[:2], [0.5, 1.0])
    assert abs(abs(mid[2]) - np.pi) < 1e-12  # ±π, not 0
    quarter = interpolate_poses([0.25], t_gt, poses)[0, 2]
    assert quarter == pytest.approx(3.1 + 0.25 * (2 * np.pi - 6.2), abs=1e-12)


def test_interpolate_linear_motion_exactly():
    # straight line at constant speed and constant turn rate 2 rad/s: many wraps of θ
    t_gt = np.arange(0.0, 20.0, 0.01)
    poses = np.column_stack([1.0 + 0.5 * t_gt, -2.0 * t_gt, np.angle(np.exp(2j * t_gt))])
    tq = np.random.default_rng(7).uniform(0.0, t_gt[-1], size=500)
    got = interpolate_poses(tq, t_gt, poses)
    np.testing.assert_allclose(got[:, 0], 1.0 + 0.5 * tq, atol=1e-12)
    np.testing.assert_allclose(got[:, 1], -2.0 * tq, atol=1e-12)
    np.testing.assert_allclose(np.angle(np.exp(1j * (got[:, 2] - 2.0 * tq))), 0.0, atol=1e-9)
    assert np.all(got[:, 2] > -np.pi) and np.all(got[:, 2] <= np.pi)


def test_interpolate_tolerance_and_span_error():
    t_gt = np.array([10.0, 11.0, 12.0])
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    np.testing.assert_allclose(interpolate_poses([9.8, 12.3], t_gt, poses)[:, 0], [0.0, 2.0])  # clamped
    with pytest.raises(ValueError, match=r"1 query time\(s\) fall outside the groundtruth span \[10\.000, 12\.000\] s"):
        interpolate_poses([9.0, 11.0], t_gt, poses)
    with pytest.raises(ValueError, match="outside"):
        interpolate_poses([12.2], t_gt, poses, tolerance=0.1)


@pytest.mark.parametrize(
    "tq, tg, pg, pattern",
    [
        ([0.5], [0.0, 1.0, 1.0], np.zeros((3, 3)), r"strictly increasing, but t_gt\[1\] = 1.0"),
        ([0.5], [0.0, 1.0], np.zeros((2, 2)), r"shape \(T, 3\)"),
        ([np.nan], [0.0, 1.0], np.zeros((2, 3)), r"interpolate_poses: t_query contains a non-finite value \(nan\) at index \(0,\)"),
        ([0.5], [0.0, 1.0], [[0.0, 0.0, np.nan], [0.0, 0.0, 0.0]], r"interpolate_poses: poses_gt contains a non-finite value \(nan\) at index \(0, 2\)"),
        ([[0.5]], [0.0, 1.0], np.zeros((2, 3)), "t_query must be 1-D"),
    ],
)
def test_interpolate_bad_input(tq, tg, pg, pattern):
    with pytest.raises(ValueError, match=pattern):
        interpolate_poses(tq, tg, pg)


# --------------------------------------------------------------------------- trajectories


def circle_groundtruth():
    t = np.arange(0.0, 30.0, 0.01)
    poses = np.column_stack([2 * np.cos(0.3 * t), 2 * np.sin(0.3 * t), np.angle(np.exp(1j * (0.3 * t + np.pi / 2)))])
    return t, poses


def test_trajectory_errors_closed_forms():
    t_gt, gt = circle_groundtruth()
    t_est = np.arange(0.0, 30.0, 1.0)  # 30 samples, all on groundtruth samples
    truth = interpolate_poses(t_est, t_gt, gt)
    offsets = np.arange(1, 31, dtype=float)  # errors 1, 2, …, 30 m along x
    est = truth + np.column_stack([offsets, np.zeros(30), np.full(30, -0.2)])
    r = trajectory_errors(t_est, est, t_gt, gt)
    np.testing.assert_allclose(r["errors"], offsets, atol=1e-12)
    assert r["mean"] == pytest.approx(15.5)
    assert r["rmse"] == pytest.approx(np.sqrt(31 * 61 / 6))  # sqrt(Σk²/n) = sqrt((n+1)(2n+1)/6)
    assert r["max"] == pytest.approx(30.0)
    np.testing.assert_allclose(r["heading_errors"], 0.2, atol=1e-12)  # wraps across ±π correctly
    assert r["heading_mean"] == pytest.approx(0.2) and r["heading_max"] == pytest.approx(0.2)
    assert r["alignment"] is None


def test_trajectory_heading_error_across_pi_and_xy_only():
    t_gt = np.array([0.0, 1.0])
    gt = np.array([[0.0, 0.0, -np.pi + 0.05], [0.0, 0.0, -np.pi + 0.05]])
    r = trajectory_errors([0.5], [[0.3, 0.4, np.pi - 0.05]], t_gt, gt)
    assert r["errors"][0] == pytest.approx(0.5)
    assert r["heading_errors"][0] == pytest.approx(0.1, abs=1e-12)
    r2 = trajectory_errors([0.5], [[0.3, 0.4]], t_gt, gt)
    assert r2["mean"] == pytest.approx(0.5) and r2["heading_errors"] is None and r2["heading_rmse"] is None


def test_trajectory_aligned_removes_rigid_motion_and_never_increases_rmse():
    t_gt, gt = circle_groundtruth()
    t_est = np.linspace(0.0, 29.0, 200)
    truth = interpolate_poses(t_est, t_gt, gt)
    angle, shift = 0.4, np.array([1.0, -0.5])
    est = np.column_stack([apply_se2(truth[:, :2], rot(angle), shift), truth[:, 2] + angle])
    r = trajectory_errors(t_est, est, t_gt, gt, align=True)
    assert r["max"] < 1e-10 and r["heading_max"] < 1e-10
    assert r["alignment"]["angle"] == pytest.approx(-angle, abs=1e-12)
    assert trajectory_errors(t_est, est, t_gt, gt)["mean"] > 1.0
    rng = np.random.default_rng(9)
    noisy = est + np.column_stack([rng.normal(scale=0.2, size=(200, 2)), rng.normal(scale=0.05, size=200)])
    ra, ru = trajectory_errors(t_est, noisy, t_gt, gt, align=True), trajectory_errors(t_est, noisy, t_gt, gt)
    assert ra["rmse"] <= ru["rmse"]
    assert ra["rmse"] < 0.35  # only the noise is left: E‖n‖² = 2·0.2² → rmse ≈ 0.28


@pytest.mark.parametrize(
    "t_est, poses_est, pattern",
    [
        ([0.0, 1.0], np.zeros((3, 3)), r"shape \(n,\)"),
        ([0.0], np.zeros((1, 4)), r"\(n, 3\) or \(n, 2\)"),
        ([0.0], [[np.nan, 0.0, 0.0]], "poses_est contains 1 NaN"),
        ([100.0], np.zeros((1, 3)), "outside the groundtruth span"),
    ],
)
def test_trajectory_bad_input(t_est, poses_est, pattern):
    t_gt, gt = circle_groundtruth()
    with pytest.raises(ValueError, match=pattern):
        trajectory_errors(t_est, poses_est, t_gt, gt)
