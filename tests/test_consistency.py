"""NEES and the particle cloud's covariance: against the chi-square distribution, numpy's weighted covariance,
and simulations with known truth (a consistent case, and FastSLAM's documented overconfidence)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from fastslam_edu.evaluation.consistency import (
    SpreadRecorder,
    align_pose,
    nees,
    nees_interval,
    pose_mean_and_covariance,
    pose_error,
    simulator_params,
)
from fastslam_edu.datasets.events import groundtruth_at
from fastslam_edu.landmark.fastslam import run_fastslam
from fastslam_edu.landmark.hooks import Monitor
from fastslam_edu.landmark.particle_set import combined_pose
from fastslam_edu.datasets.sim import SimConfig
from streams import simulate


def _random_spd(rng, d):
    A = rng.normal(size=(d, d))
    return A @ A.T + 0.1 * np.eye(d)


@pytest.mark.parametrize("d", [1, 2, 3])
def test_nees_of_gaussian_errors_is_chi_square(d):
    rng = np.random.default_rng(d)
    P = _random_spd(rng, d)
    e = rng.multivariate_normal(np.zeros(d), P, size=20000)
    eps = nees(e, np.broadcast_to(P, (20000, d, d)))
    assert abs(eps.mean() - d) < 4 * np.sqrt(2 * d / 20000)  # mean d, variance 2d
    assert stats.kstest(eps, stats.chi2(d).cdf).pvalue > 1e-3
    # and a covariance twice too small doubles it
    assert abs(nees(e, np.broadcast_to(P / 2, (20000, d, d))).mean() - 2 * d) < 8 * np.sqrt(2 * d / 20000)


def test_nees_matches_the_explicit_inverse():
    rng = np.random.default_rng(5)
    P = np.stack([_random_spd(rng, 3) for _ in range(7)])
    e = rng.normal(size=(7, 3))
    np.testing.assert_allclose(nees(e, P), [x @ np.linalg.inv(p) @ x for x, p in zip(e, P)], rtol=1e-10)
    assert nees(e[0], P[0]).shape == ()


def test_nees_rejects_bad_input_with_a_message():
    with pytest.raises(ValueError, match="do not match"):
        nees(np.zeros((4, 3)), np.eye(2))
    with pytest.raises(ValueError, match="covariance 1 is not positive definite"):
        nees(np.zeros((2, 2)), np.stack([np.eye(2), np.diag([1.0, -1.0])]))
    with pytest.raises(ValueError, match="NaN"):
        nees([np.nan, 0.0], np.eye(2))


def test_nees_interval_covers_the_mean_of_consistent_runs():
    lo, hi = nees_interval(3, 10)
    assert (round(lo, 2), round(hi, 2)) == (1.68, 4.70)
    rng = np.random.default_rng(0)
    means = (rng.standard_normal((20000, 10, 3)) ** 2).sum(axis=2).mean(axis=1)  # 10 runs of a consistent 3-D estimate
    inside = ((means >= lo) & (means <= hi)).mean()
    assert abs(inside - 0.95) < 0.01
    with pytest.raises(ValueError):
        nees_interval(0, 10)


def test_pose_covariance_is_the_weighted_covariance():
    rng = np.random.default_rng(2)
    poses = rng.normal(size=(200, 3)) * [0.3, 0.2, 0.1] + [1.0, -2.0, 0.5]
    w = rng.uniform(size=200)
    w /= w.sum()
    mean, cov = pose_mean_and_covariance(poses, w)
    np.testing.assert_allclose(mean, combined_pose(poses, w))
    # numpy's weighted covariance about the weighted mean (the circular mean differs from it by ~1e-4 rad here)
    np.testing.assert_allclose(cov, np.cov(poses.T, aweights=w, bias=True), atol=1e-6)


def test_pose_covariance_of_a_cloud_across_pi_is_small():
    rng = np.random.default_rng(3)
    theta = np.pi + 0.05 * rng.standard_normal(500)  # headings on both sides of +-pi once wrapped
    poses = np.column_stack([np.zeros(500), np.zeros(500), np.angle(np.exp(1j * theta))])
    mean, cov = pose_mean_and_covariance(poses, np.full(500, 1 / 500))
    assert abs(abs(mean[2]) - np.pi) < 0.01
    assert abs(np.sqrt(cov[2, 2]) - 0.05) < 0.005
    with pytest.raises(ValueError, match="sum to 1"):
        pose_mean_and_covariance(poses, np.ones(500))


def test_pose_error_wraps_the_heading():
    np.testing.assert_allclose(pose_error([0, 0, 3.1], [0, 0, -3.1]), [0, 0, 6.2 - 2 * np.pi])


def test_align_pose_moves_pose_and_covariance_together():
    rng = np.random.default_rng(4)
    a = 0.7
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    t = np.array([1.0, -2.0])
    pose, P = np.array([0.5, 0.3, 0.2]), _random_spd(rng, 3)
    truth = np.array([0.4, 0.35, 0.25])
    moved, P2 = align_pose(pose, P, R, t, a)
    truth2, _ = align_pose(truth, P, R, t, a)
    np.testing.assert_allclose(moved[:2], R @ pose[:2] + t)
    assert abs(moved[2] - 0.9) < 1e-12
    # a rigid motion of both the estimate and the truth leaves the NEES unchanged
    assert abs(nees(pose_error(moved, truth2), P2) - nees(pose_error(pose, truth), P)) < 1e-9
    same, P3 = align_pose(pose, P, np.eye(2), np.zeros(2), 0.0)
    np.testing.assert_allclose(same, pose)
    np.testing.assert_allclose(P3, P)


def test_spread_recorder_sees_what_the_filter_estimates_and_changes_nothing():
    data, log, stream = simulate(0, duration=20.0)
    params = simulator_params(n_particles=50)
    plain = run_fastslam(stream, params, 1)
    every = SpreadRecorder(maps=True)
    watched = run_fastslam(stream, params, 1, hooks=[Monitor(every)])
    np.testing.assert_array_equal(plain.pose_mean, watched.pose_mean)
    np.testing.assert_array_equal(plain.particles.mu, watched.particles.mu)
    # one record per measurement step, whose mean is the filter's estimate at that step
    np.testing.assert_array_equal(every.t, plain.ess_t)
    steps = np.searchsorted(plain.t, every.t)
    np.testing.assert_allclose(np.array(every.mean), plain.pose_mean[steps], atol=1e-12)
    np.testing.assert_allclose(every.maps[-1][0], plain.landmarks_mean, atol=1e-12)
    some = SpreadRecorder(times=stream.t[0] + np.array([5.0, 10.0, 10.1, 1e9]))
    run_fastslam(stream, params, 1, hooks=[Monitor(some)])
    # one record per time passed: 10 and 10.1 s fall on one step (recorded twice), 1e9 s never comes
    assert len(some.t) == 3 and some.t[0] >= stream.t[0] + 5.0 and some.t[1] == some.t[2] >= stream.t[0] + 10.1


def _mean_pose_nees(n_runs, duration, times, **changes):
    """Mean over simulated runs of the pose NEES at ``times`` [s from the start], and the landmark NEES at the end."""
    pose, landmarks = [], []
    for seed in range(n_runs):
        data, log, stream = simulate(seed, duration=duration)
        rec = SpreadRecorder(times=stream.t[0] + np.asarray(times))
        extra = {"landmarks": data.landmark_positions} if changes.get("mode") == "localize" else {}
        result = run_fastslam(stream, simulator_params(**changes), seed, hooks=[Monitor(rec)], **extra)
        truth = groundtruth_at(log, np.array(rec.t))
        pose.append(nees(pose_error(np.array(rec.mean), truth), np.array(rec.cov) + 1e-12 * np.eye(3)))
        seen = result.observed
        if changes.get("mode") != "localize":
            landmarks.append(nees(result.landmarks_mean[seen] - data.landmark_positions[seen],
                                  result.landmarks_cov[seen]).mean())
    return np.mean(pose, axis=0), np.array(landmarks)


def test_localisation_with_the_true_model_and_many_particles_is_consistent():
    """With the map given and the simulator's own noise model, 1000 particles are honest about the pose:
    the mean NEES of 8 runs lies within (twice) the 95 % interval. A covariance that ignored the weights, or
    the heading wrap, or a monitor that saw the particles before resampling, would not be."""
    mean, _ = _mean_pose_nees(8, 30.0, [10.0, 20.0, 29.0], n_particles=1000, mode="localize")
    lo, hi = nees_interval(3, 8)
    assert (mean > lo / 2).all() and (mean < 2 * hi).all(), mean


def test_fastslam_is_overconfident_about_the_map_in_the_world_frame():
    """Bailey, Nieto and Nebot (2006): FastSLAM's covariances are far too small. With the simulator's own model,
    100 particles and 60 s, the landmark NEES of the median run is beyond 5x the 95 % interval, while the same
    particles are near-consistent in the first seconds (the initial pose is known)."""
    pose, landmarks = _mean_pose_nees(6, 60.0, [1.0, 55.0], n_particles=100)
    lo, hi = nees_interval(2, 1)
    assert np.median(landmarks) > 5 * hi, landmarks
    assert pose[0] < 3 * nees_interval(3, 6)[1] and pose[1] > 10 * nees_interval(3, 6)[1], pose


def test_simulator_params_take_the_simulators_noise():
    c = SimConfig(range_std=0.1, bearing_std=0.03)
    p = simulator_params(c, n_particles=7)
    np.testing.assert_allclose(p.measurement_covariance(np.array([[4.0, 0.0]]))[0], np.diag([0.01, 0.0009]))
    assert p.motion_noise == c.odometry_noise and p.n_particles == 7 and p.measurement_correlation_s is None


def test_spread_recorder_reads_tree_backed_particles_too():
    from fastslam_edu.landmark.fastslam_tree import TreeParticleSet

    data, log, stream = simulate(1, duration=10.0)
    params = simulator_params(n_particles=20)
    dense, tree = SpreadRecorder(maps=True), SpreadRecorder(maps=True)
    run_fastslam(stream, params, 3, hooks=[Monitor(dense)])
    run_fastslam(stream, params, 3, hooks=[Monitor(tree)], particle_class=TreeParticleSet)
    np.testing.assert_allclose(np.array(tree.cov), np.array(dense.cov), atol=1e-12)
    np.testing.assert_allclose(tree.maps[-1][0], dense.maps[-1][0], atol=1e-12)


def test_nees_rejects_scalars_and_singular_covariances():
    """Reference: the documented contract — e must be (..., d); a covariance with a zero eigenvalue is not
    positive definite (ε would be infinite), and the message names it."""
    with pytest.raises(ValueError, match="do not match"):
        nees(1.0, 1.0)
    with pytest.raises(ValueError, match="covariance 0 is not positive definite"):
        nees(np.zeros((1, 2)), np.diag([1.0, 0.0])[None])


def test_nees_interval_rejects_zero_runs_and_degenerate_confidence():
    """Reference: the documented domain (n_runs >= 1, confidence strictly inside (0, 1): at 1 the interval
    would be [0, ∞))."""
    for bad in [(3, 0), (3, 10, 1.0), (3, 10, 0.0)]:
        with pytest.raises(ValueError):
            nees_interval(*bad)


def test_pose_covariance_rejects_negative_weights_summing_to_one():
    """Reference: the documented contract — weights must be non-negative, not only sum to 1."""
    with pytest.raises(ValueError, match="non-negative"):
        pose_mean_and_covariance(np.zeros((2, 3)), np.array([1.5, -0.5]))


def test_pose_error_rejects_poses_without_heading():
    """Reference: the documented contract — poses are (..., 3)."""
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        pose_error([0.0, 0.0], [1.0, 1.0])


def test_spread_recorder_takes_a_step_exactly_at_a_requested_time():
    """Reference: the documented rule "the first measurement step at or after it", checked at times that are
    exactly measurement steps' times (read from the filter's own list of measurement steps)."""
    data, log, stream = simulate(2, duration=5.0)
    params = simulator_params(n_particles=10)
    steps_t = run_fastslam(stream, params, 1).ess_t
    rec = SpreadRecorder(times=[steps_t[3], steps_t[7]])
    run_fastslam(stream, params, 1, hooks=[Monitor(rec)])
    assert rec.t == [float(steps_t[3]), float(steps_t[7])]
