"""The batch least-squares smoother: Jacobians against finite differences, the odometry covariance
against Monte Carlo of the motion model, and the solution against a simulation's known truth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fastslam_edu.datasets.log import EventStream
from fastslam_edu.app.experiment import score_estimate, summarize_smoother
from fastslam_edu.landmark.fastslam import FastSLAMParams, run_fastslam
from fastslam_edu.evaluation.metrics import align_se2, landmark_errors_aligned
from fastslam_edu.core.motion import MotionNoise, move_segment
from fastslam_edu.core.se2 import relative
from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.landmark.smoother import (BEST_ESTIMATE, CALIBRATION_NAMES, ODOMETRY_CALIBRATION, PRIOR_STD,
                                            SolverSettings, smooth)
from fastslam_edu.landmark.smoother_factors import (OdometryModel, dead_reckon_stream, lagged_commands,
                                                    keyframe_steps, sighting_residuals, odometry_factors,
                                                    odometry_residuals, sighting_weights, whitening)
from fastslam_edu.landmark.smoother_laplace import block_tridiagonal_inverse_diagonal
from streams import path_rmse, simulate
from fastslam_edu.datasets.events import event_stream

NOISE = MotionNoise(sigma_v=0.01, sigma_omega=0.02)


def _numeric_jacobian(f, x, h=1e-6):
    x = np.asarray(x, dtype=float)
    cols = []
    for i in range(x.size):
        d = np.zeros_like(x)
        d.flat[i] = h
        cols.append((f(x + d) - f(x - d)) / (2 * h))
    return np.stack(cols, axis=-1)


def test_odometry_jacobians_match_finite_differences():
    rng = np.random.default_rng(0)
    xa, xb = rng.normal(size=(5, 3)) * [2, 2, 2], rng.normal(size=(5, 3)) * [2, 2, 2]
    delta = rng.normal(size=(5, 3)) * 0.3
    _, Ja, Jb = odometry_residuals(xa, xb, delta)
    for f in range(5):
        na = _numeric_jacobian(lambda a: odometry_residuals(a[None], xb[f:f + 1], delta[f:f + 1])[0][0], xa[f])
        nb = _numeric_jacobian(lambda b: odometry_residuals(xa[f:f + 1], b[None], delta[f:f + 1])[0][0], xb[f])
        np.testing.assert_allclose(Ja[f], na, atol=1e-6)
        np.testing.assert_allclose(Jb[f], nb, atol=1e-6)


def test_measurement_jacobians_match_finite_differences():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(6, 3))
    m = x[:, :2] + rng.uniform(1, 4, size=(6, 1)) * np.stack([np.cos(rng.uniform(0, 6, 6)),
                                                              np.sin(rng.uniform(0, 6, 6))], axis=1)
    z = rng.normal(size=(6, 2)) * [0.1, 0.1] + [2.0, 0.0]
    _, Jx, Jm = sighting_residuals(x, m, z)
    for i in range(6):
        nx = _numeric_jacobian(lambda p: sighting_residuals(p[None], m[i:i + 1], z[i:i + 1])[0][0], x[i])
        nm = _numeric_jacobian(lambda q: sighting_residuals(x[i:i + 1], q[None], z[i:i + 1])[0][0], m[i])
        np.testing.assert_allclose(Jx[i], nx, atol=1e-6)
        np.testing.assert_allclose(Jm[i], nm, atol=1e-6)


def test_odometry_residual_is_zero_on_the_dead_reckoned_path():
    _, _, stream = simulate(0, duration=20.0)
    path = dead_reckon_stream(stream, stream.x0)
    keys = keyframe_steps(stream)
    delta, _ = odometry_factors(stream, path, keys, NOISE)
    e, _, _ = odometry_residuals(path[keys[:-1]], path[keys[1:]], delta)
    np.testing.assert_allclose(e, 0.0, atol=1e-9)


def test_dead_reckoning_is_the_motion_model_without_noise():
    _, _, stream = simulate(1, duration=10.0)
    path = dead_reckon_stream(stream, stream.x0, odometry_scale=(1.1, 0.9))
    u = stream.u * [1.1, 0.9]
    ref = move_segment(stream.x0[None], u, stream.dt, MotionNoise(), np.zeros((1, len(stream), 2)))[0]
    np.testing.assert_allclose(path[:, :2], ref[:, :2], atol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * (path[:, 2] - ref[:, 2]))), 0.0, atol=1e-9)


@pytest.mark.parametrize("noise", [MotionNoise(sigma_v=0.02, sigma_omega=0.05),
                                   MotionNoise(mode="state", sigma_xy=0.01, sigma_theta=0.05)])
def test_odometry_covariance_matches_monte_carlo(noise):
    """C_k from the first-order formula against the spread of 20 000 noisy runs of the motion model.

    (First order: the sideways variance misses a term σ_v² σ_ω² T² / 2 — 1–2 % here, ~8 % at
    σ_v = 0.05 m/√s, σ_ω = 0.1 rad/√s over 0.2 s.)
    """
    _, _, stream = simulate(2, duration=6.0)
    path = dead_reckon_stream(stream, stream.x0)
    keys = keyframe_steps(stream, max_gap_s=2.0)
    _, cov = odometry_factors(stream, path, keys, noise)
    rng = np.random.default_rng(3)
    a, b = keys[1], keys[2]  # one interval, simulated from the pose at a
    steps = slice(a + 1, b + 1)
    n = 20000
    eps = rng.standard_normal((n, b - a, noise.n_draws))
    ends = move_segment(np.repeat(path[a][None], n, axis=0), stream.u[steps], stream.dt[steps], noise, eps)[:, -1]
    rel = relative(np.broadcast_to(path[a], ends.shape), ends)
    mc = np.cov(rel.T)
    C = cov[1] - np.diag([1e-8, 1e-8, 1e-10])  # less the floor
    # compared as correlations: a Monte Carlo covariance entry has standard error ~ sqrt(C_ii C_jj / n)
    scale = 1.0 / np.sqrt(np.diag(C))
    np.testing.assert_allclose(scale[:, None] * (C - mc) * scale[None, :], 0.0, atol=4.5 / np.sqrt(n))
    # and the check can fail: a covariance without the turn noise's swing is far off
    wrong = odometry_factors(stream, path, keys, dataclasses.replace(noise, sigma_omega=0.0, sigma_theta=0.0))[1][1]
    assert np.max(np.abs(scale[:, None] * (wrong - mc) * scale[None, :])) > 0.3


def test_keyframes_hold_every_sighting_and_bound_the_gaps():
    _, _, stream = simulate(4, duration=30.0)
    keys = keyframe_steps(stream, max_gap_s=0.5)
    with_sightings = np.flatnonzero(np.diff(stream.offsets) > 0)
    assert set(with_sightings) <= set(keys)
    assert keys[0] == 0 and keys[-1] == len(stream) - 1
    assert np.max(np.diff(stream.t[keys])) <= 2 * 0.5
    with pytest.raises(ValueError, match="max_gap_s"):
        keyframe_steps(stream, max_gap_s=0.0)


def test_sighting_weights_are_the_filters_exponents():
    _, _, stream = simulate(5, duration=20.0)
    beta = sighting_weights(stream, 4.0)
    last = {}
    for k in range(len(stream)):
        s = stream.offsets[k]
        for i, lm in enumerate(stream.measurements_at(k)[1]):
            expected = min(1.0, (stream.t[k] - last.get(lm, -np.inf)) / 4.0)
            assert beta[s + i] == pytest.approx(expected)
        for lm in stream.measurements_at(k)[1]:
            last[lm] = stream.t[k]
    assert np.all(sighting_weights(stream, None) == 1.0)


def test_whitening_gives_the_mahalanobis_distance():
    rng = np.random.default_rng(6)
    A = rng.normal(size=(4, 3, 3))
    C = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(3)
    e = rng.normal(size=(4, 3))
    w = np.einsum("nij,nj->ni", whitening(C), e)
    np.testing.assert_allclose(np.sum(w * w, axis=1), np.einsum("ni,nij,nj->n", e, np.linalg.inv(C), e))


def _params(**kw):
    """The filter's model matched to the simulation: its noise, its R, no tempering (white errors)."""
    base = dict(motion_noise=NOISE, measurement_cov=np.diag([0.05**2, 0.02**2]), range_std_slope=0.0,
                measurement_correlation_s=None)
    base.update(kw)
    return FastSLAMParams(**base)


def test_without_noise_the_smoother_recovers_the_truth():
    data, log, stream = simulate(7, duration=40.0, odometry_noise=MotionNoise(), range_std=0.0, bearing_std=0.0)
    result = smooth(stream, _params())
    s = score_estimate(result.t, result.poses, result.landmarks, result.observed, result.landmark_subjects, data, log)
    # the simulator drives exact arcs, the filter's model steps along the heading: millimetres apart
    assert s["landmark_error_mean_m"] < 0.005
    assert s["path_rmse_m"] < 0.005


def test_smoother_beats_dead_reckoning_and_is_consistent():
    """Known truth, 8 simulated logs: the least-squares map is far closer than dead reckoning's,
    its shape is right to centimetres, and its errors are what its covariance says: the NEES
    eᵀ Σ⁻¹ e of the landmarks averages 2, their dimension. (Within one log the landmarks share
    the frame's error, so one log's mean NEES is a single draw: only the pooled mean is tested.)"""
    nees, e_sm, e_dr = [], [], []
    for seed in range(8, 16):
        data, log, stream = simulate(seed, duration=90.0)
        params = _params()
        result = smooth(stream, params)
        truth = data.landmark_positions
        seen = result.observed
        err = result.landmarks[seen] - truth[seen]
        nees.append(np.einsum("ni,nij,nj->n", err, np.linalg.inv(result.landmarks_cov[seen]), err).mean())
        e_sm.append(np.linalg.norm(err, axis=1).mean())
        dr = smooth(stream, params, solver=SolverSettings(max_iterations=0))  # zero iterations: the start, dead reckoning
        e_dr.append(np.linalg.norm(dr.landmarks[seen] - truth[seen], axis=1).mean())
        assert np.nanmean(landmark_errors_aligned(result.landmarks, truth, seen)) < 0.03
        assert result.measurements_rejected == 0  # no outliers simulated: the gate (d² > 27.6) keeps all
    assert 1.0 < np.mean(nees) < 3.5
    assert np.mean(e_sm) < 0.5 * np.mean(e_dr)


def test_the_gate_sets_outliers_aside():
    data, log, stream = simulate(11, duration=90.0, outlier_prob=0.05)
    gated = summarize_smoother(smooth(stream, _params()), data, log)
    ungated = summarize_smoother(smooth(stream, _params(gate_chi2=None)), data, log)
    # 5 % of ~1600 sightings have ranges 0.5–2 m off (d² > 100 at σ_r = 5 cm): about 80
    assert 50 < gated["measurements_rejected"] < 110
    # the map's shape (the frame's error is the start's drift, the same in both)
    assert gated["landmark_error_aligned_mean_m"] < 0.5 * ungated["landmark_error_aligned_mean_m"]


def test_starting_from_the_filter_reaches_the_same_optimum():
    data, log, stream = simulate(12, duration=60.0)
    params = _params(n_particles=30)
    filt = run_fastslam(stream, params, np.random.default_rng(0))
    a = smooth(stream, params)
    b = smooth(stream, params, initial=filt)
    np.testing.assert_allclose(b.landmarks, a.landmarks, atol=1e-4)
    np.testing.assert_allclose(b.poses, a.poses, atol=1e-4)


def test_bad_input_gets_a_clear_message():
    _, _, stream = simulate(13, duration=10.0)
    with pytest.raises(ValueError, match="no initial pose"):
        smooth(dataclasses.replace(stream, x0=None))
    filt = run_fastslam(stream, _params(n_particles=5), np.random.default_rng(0))
    short = dataclasses.replace(stream, t=stream.t[:-5], dt=stream.dt[:-5], u=stream.u[:-5],
                                offsets=stream.offsets[:-5])
    with pytest.raises(ValueError, match="same stream"):
        smooth(short, initial=filt)


def test_bad_commands_are_refused_with_the_step():
    _, _, stream = simulate(14, duration=10.0)
    u = stream.u.copy()
    u[7, 1] = np.nan
    with pytest.raises(ValueError, match="non-finite commands .* step 7"):
        smooth(dataclasses.replace(stream, u=u))


def test_without_sightings_the_smoother_is_dead_reckoning():
    _, _, stream = simulate(15, duration=10.0)
    blind = dataclasses.replace(stream, offsets=np.zeros_like(stream.offsets), z=np.zeros((0, 2)),
                                landmark=np.zeros(0, dtype=np.int64))
    result = smooth(blind)
    path = dead_reckon_stream(blind, blind.x0)
    np.testing.assert_allclose(result.poses[:, :2], path[result.steps, :2], atol=1e-6)
    assert not result.observed.any() and result.measurements_used == 0


def test_pose_standard_deviations():
    """The first pose is pinned by the prior (its σ is the prior's); every σ is finite and positive."""
    _, _, stream = simulate(16, duration=20.0)
    result = smooth(stream, _params(), pose_std=True)
    np.testing.assert_allclose(result.pose_std[0], PRIOR_STD, rtol=0.01)
    assert np.all(np.isfinite(result.pose_std)) and np.all(result.pose_std > 0)
    assert np.all(np.isnan(smooth(stream, _params()).pose_std))  # not asked for


def test_block_tridiagonal_inverse_diagonal_matches_dense_inverse():
    rng = np.random.default_rng(3)
    N, d = 7, 3
    blocks = rng.normal(size=(N, d, d))
    P = np.zeros((N * d, N * d))
    for k in range(N):  # a random symmetric block-tridiagonal matrix
        P[k * d:(k + 1) * d, k * d:(k + 1) * d] = blocks[k] @ blocks[k].T + np.eye(d)
        if k:
            a = rng.normal(size=(d, d)) * 0.5
            P[k * d:(k + 1) * d, (k - 1) * d:k * d] = a
            P[(k - 1) * d:k * d, k * d:(k + 1) * d] = a.T
    P += np.eye(N * d) * (np.abs(P).sum(axis=1).max())  # diagonally dominant: positive definite
    D = np.stack([P[k * d:(k + 1) * d, k * d:(k + 1) * d] for k in range(N)])
    C = np.stack([P[k * d:(k + 1) * d, (k + 1) * d:(k + 2) * d] for k in range(N - 1)])
    inverse = np.linalg.inv(P)
    expected = np.stack([inverse[k * d:(k + 1) * d, k * d:(k + 1) * d] for k in range(N)])
    np.testing.assert_allclose(block_tridiagonal_inverse_diagonal(D, C), expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(block_tridiagonal_inverse_diagonal(D[:1], C[:0]), np.linalg.inv(D[:1]))


def _spy_on_laplace(monkeypatch) -> dict:
    """Record, at the smoother's Laplace step, the dense (JᵀJ)⁻¹ ("inverse") and the number of poses ("n_poses")."""
    import fastslam_edu.landmark.smoother as smoother

    seen, laplace = {}, smoother.laplace

    def spy(problem, v, active, with_poses=True):
        J = problem.evaluate(v, active)[1]
        seen["inverse"], seen["n_poses"] = np.linalg.inv((J.T @ J).toarray()), problem.n_poses
        return laplace(problem, v, active, with_poses)

    monkeypatch.setattr(smoother, "laplace", spy)
    return seen


def test_laplace_blocks_match_the_dense_inverse_of_the_normal_matrix(monkeypatch):
    """The poses' σ and the landmarks' covariances are the diagonal blocks of (JᵀJ)⁻¹ at the solution."""
    _, _, stream = simulate(16, duration=20.0)
    seen = _spy_on_laplace(monkeypatch)
    result = smooth(stream, _params(), pose_std=True)
    inverse, p = seen["inverse"], 3 * seen["n_poses"]
    np.testing.assert_allclose(result.pose_std.ravel(), np.sqrt(np.diag(inverse)[:p]), rtol=1e-9)
    K = (len(inverse) - p) // 2
    assert K == result.observed.sum() > 0
    landmarks = inverse[p:, p:].reshape(K, 2, K, 2)[np.arange(K), :, np.arange(K), :]
    np.testing.assert_allclose(result.landmarks_cov[result.observed], landmarks, rtol=1e-9)


def _stationary_stream(n_steps, sightings, dt=0.1, n_landmarks=2):
    """A robot standing at the origin (heading 0) for ``n_steps`` steps; ``sightings`` maps step -> [(landmark, point)]:
    the reading (r, φ) of each world point is computed here in closed form."""
    z, lm, offsets = [], [], [0]
    for k in range(n_steps):
        for j, (px, py) in sightings.get(k, []):
            z.append([np.hypot(px, py), np.arctan2(py, px)])
            lm.append(j)
        offsets.append(len(z))
    t = dt * np.arange(n_steps)
    return EventStream(t=t, dt=np.r_[0.0, np.diff(t)], u=np.zeros((n_steps, 2)), offsets=np.array(offsets),
                       z=np.array(z, dtype=float).reshape(-1, 2), landmark=np.array(lm, dtype=np.int64),
                       landmark_subjects=np.arange(6, 6 + n_landmarks), x0=np.zeros(3))


STILL = MotionNoise(sigma_v=1e-6, sigma_omega=1e-6)  # the robot is known to stand still


def test_tempered_sightings_count_as_fractions_in_the_covariance():
    """Closed form: n readings of one landmark with exponents β_i from a pinned pose give the covariance
    R_cart / Σβ_i, R_cart = diag((r σ_φ)², σ_r²) for a landmark straight left at range r (β = 1, then Δt/τ)."""
    r, s_r, s_phi, tau = 2.0, 0.05, 0.02, 1.0
    stream = _stationary_stream(46, {k: [(0, (0.0, r))] for k in range(0, 46, 5)})  # every 0.5 s: β = 1, 0.5, 0.5, …
    params = _params(motion_noise=STILL, measurement_correlation_s=tau)
    result = smooth(stream, params, x0_std=(1e-6, 1e-6, 1e-7))
    sum_beta = 1.0 + 0.5 * 9
    np.testing.assert_allclose(result.landmarks[0], [0.0, r], atol=1e-9)
    np.testing.assert_allclose(result.landmarks_cov[0], np.diag([(r * s_phi) ** 2, s_r**2]) / sum_beta, rtol=0.02,
                               atol=1e-8)


def test_a_landmark_whose_every_sighting_is_gated_out_is_not_observed():
    """Closed form: three readings of 'one' landmark at the corners of a 1 m equilateral triangle are each
    0.58 m (d² ≈ 150 > 27.6) from any compromise point, so all are gated; a consistent landmark is kept."""
    corners = [(3.0 + 0.577 * np.cos(a), 0.577 * np.sin(a)) for a in (0.0, 2.1, 4.2)]
    sightings = {3: [(0, (0.0, 2.0))], 8: [(0, (0.0, 2.0))], 13: [(0, (0.0, 2.0))],
                 5: [(1, corners[0])], 10: [(1, corners[1])], 15: [(1, corners[2])]}
    result = smooth(_stationary_stream(20, sightings), _params(motion_noise=STILL))
    assert result.measurements_rejected == 3 and result.measurements_used == 3
    np.testing.assert_array_equal(result.observed, [True, False])
    assert np.all(np.isnan(result.landmarks[1]))
    np.testing.assert_allclose(result.landmarks[0], [0.0, 2.0], atol=1e-6)


def test_rejected_sightings_are_exactly_those_beyond_the_gate():
    """Reference: d² = (Δr/σ_r)² + (Δφ/σ_φ)² recomputed here by hand at the returned path and map; the
    sightings beyond ``gate_chi2`` must be exactly the ones reported rejected."""
    data, log, stream = simulate(11, duration=90.0, outlier_prob=0.05)
    params = _params()
    result = smooth(stream, params)
    assert result.rounds < 10  # the gate's set settled
    step = np.repeat(np.arange(len(stream)), np.diff(stream.offsets))
    pose = result.poses[np.searchsorted(result.steps, step)]
    m = result.landmarks[stream.landmark]
    dx, dy = m[:, 0] - pose[:, 0], m[:, 1] - pose[:, 1]
    dr = stream.z[:, 0] - np.hypot(dx, dy)
    dphi = np.angle(np.exp(1j * (stream.z[:, 1] - np.arctan2(dy, dx) + pose[:, 2])))
    d2 = (dr / 0.05) ** 2 + (dphi / 0.02) ** 2
    outside = ~(d2 <= params.gate_chi2)  # NaN (landmark not kept) counts as outside
    assert 50 < result.measurements_rejected == int(outside.sum())


def test_the_huber_round_alone_resists_outliers():
    """Known truth: with 5 % outliers, the first (Huber) round's map shape is close to the truth and far better
    than plain least squares (no gate, no Huber)."""
    data, log, stream = simulate(11, duration=60.0, outlier_prob=0.05)
    truth = data.landmark_positions
    huber = smooth(stream, _params(), solver=SolverSettings(max_rounds=1))
    plain = smooth(stream, _params(gate_chi2=None))
    assert huber.rounds == 1 and huber.measurements_rejected == 0
    e_huber = np.nanmean(landmark_errors_aligned(huber.landmarks, truth, huber.observed))
    e_plain = np.nanmean(landmark_errors_aligned(plain.landmarks, truth, plain.observed))
    assert e_huber < 0.03 and e_huber < 0.5 * e_plain


def test_converges_from_a_poor_dead_reckoning_start():
    """Known truth: very noisy odometry (dead reckoning metres off) must still end at the right map shape with no
    sighting gated out (none is an outlier): Levenberg–Marquardt may only accept steps that lower the cost."""
    data, log, stream = simulate(21, duration=60.0, odometry_noise=MotionNoise(sigma_v=0.05, sigma_omega=0.2))
    params = _params(motion_noise=MotionNoise(sigma_v=0.1, sigma_omega=0.2))
    result = smooth(stream, params)
    assert result.measurements_rejected == 0
    assert np.nanmean(landmark_errors_aligned(result.landmarks, data.landmark_positions, result.observed)) < 0.03


def test_lagged_commands_shift_the_integral_of_the_commands():
    """Piecewise-constant commands read τ later: each step's command is the mean over its window moved back by τ."""
    t = np.arange(0.0, 3.01, 0.1)
    u = np.zeros((len(t), 2))
    u[(t > 1.0 + 1e-9) & (t <= 1.5 + 1e-9)] = [0.2, 0.4]  # in force over (1.0, 1.5]
    stream = EventStream(t=t, dt=np.r_[0.0, np.diff(t)], u=u, offsets=np.zeros(len(t) + 1, dtype=np.int64),
                         z=np.zeros((0, 2)), landmark=np.zeros(0, dtype=np.int64), landmark_subjects=np.arange(6, 8),
                         x0=np.zeros(3))
    lagged = lagged_commands(stream, 0.2)
    expected = np.where(((t > 1.2 + 1e-9) & (t <= 1.7 + 1e-9))[:, None], [0.2, 0.4], 0.0)
    np.testing.assert_allclose(lagged, expected, atol=1e-12)
    half = lagged_commands(stream, 0.05)  # steps 11 and 16 hold half of the pulse each
    np.testing.assert_allclose(half[[11, 16]], [[0.1, 0.2], [0.1, 0.2]], atol=1e-12)
    for tau in (0.05, 0.25, -0.3):
        np.testing.assert_allclose(np.sum(lagged_commands(stream, tau) * stream.dt[:, None], axis=0), [0.1, 0.2])
    np.testing.assert_array_equal(lagged_commands(stream, 0.0), u)


def _calibration(result, names=ODOMETRY_CALIBRATION):
    """The estimated calibration and its σ as arrays, in the order of ``names``."""
    return (np.array([result.calibration[n] for n in names]), np.array([result.calibration_std[n] for n in names]))


def _miscalibrated(seed, scale, lag, duration=90.0):
    """A simulation whose recorded commands are ``1 / scale`` times the executed ones and ``lag`` seconds early: the robot
    executes ``scale`` times what is logged, ``lag`` seconds after it is logged."""
    data, log, stream = simulate(seed, duration=duration)
    odometry = log.odometry.copy()
    odometry["time"] -= lag
    odometry["v"] /= scale[0]
    odometry["omega"] /= scale[1]
    bad = event_stream(dataclasses.replace(log, odometry=odometry), data.landmark_subjects)
    return data, log, dataclasses.replace(bad, x0=stream.x0)


@pytest.mark.parametrize("seed", [22, 26])
def test_odometry_scale_and_lag_are_estimated_with_the_path(seed):
    """Known truth: the robot moves at 0.92 × the logged speed, turns at 0.90 × the logged rate, 0.2 s late.
    Estimated jointly (``calibrate=ODOMETRY_CALIBRATION``), the calibration comes back within a few of its own σ and
    the path error drops several times; without it, the scale error bends the whole path."""
    kv, kw, tau = 0.92, 0.90, 0.2
    data, log, stream = _miscalibrated(seed, (kv, kw), tau)
    plain = smooth(stream, _params())
    fitted = smooth(stream, _params(), solver=SolverSettings(calibrate=ODOMETRY_CALIBRATION))
    assert plain.calibration is None
    c, sd = _calibration(fitted)
    assert np.all(np.abs(c - [kv, kw, tau]) < [0.02, 0.02, 0.03]), c
    assert np.all(sd > 0) and np.all(np.abs(c - [kv, kw, tau]) < 4 * sd)
    e_plain, e_fitted = path_rmse(plain.t, plain.poses, log), path_rmse(fitted.t, fitted.poses, log)
    assert e_fitted < 0.3 * e_plain
    # and it is only the calibration: the log as recorded right gives the same path
    _, _, right = simulate(seed, duration=90.0)
    assert e_fitted < path_rmse(*(lambda r: (r.t, r.poses))(smooth(right, _params())), log) + 0.05


def test_a_calibrated_log_is_left_calibrated():
    """No scale error, no lag: the estimate stays at (1, 1, 0) within its σ, and the solution barely moves."""
    data, log, stream = simulate(24, duration=90.0)
    plain = smooth(stream, _params())
    fitted = smooth(stream, _params(), solver=SolverSettings(calibrate=ODOMETRY_CALIBRATION))
    c, sd = _calibration(fitted)
    assert np.all(np.abs(c - [1.0, 1.0, 0.0]) < 4 * sd) and np.all(sd < [0.03, 0.03, 0.05])
    assert abs(path_rmse(fitted.t, fitted.poses, log) - path_rmse(plain.t, plain.poses, log)) < 0.05


@pytest.mark.parametrize("calibrate", [ODOMETRY_CALIBRATION, ("bearing_bias",), ("k_omega", "travel_offset", "bearing_bias")])
def test_calibration_covariance_is_the_laplace_block(monkeypatch, calibrate):
    """With the calibration estimated, the landmarks' covariances and the calibration's σ are still the blocks of
    (JᵀJ)⁻¹ (the calibration is more variables after the landmarks)."""
    _, _, stream = _miscalibrated(25, (1.05, 1.1), 0.1, duration=30.0)
    seen = _spy_on_laplace(monkeypatch)
    result = smooth(stream, _params(), pose_std=True, solver=SolverSettings(calibrate=calibrate))
    inverse, p, q = seen["inverse"], 3 * seen["n_poses"], len(calibrate)
    assert list(result.calibration) == [n for n in CALIBRATION_NAMES if n in calibrate]
    np.testing.assert_allclose(result.pose_std.ravel(), np.sqrt(np.diag(inverse)[:p]), rtol=1e-7)
    np.testing.assert_allclose(_calibration(result, list(result.calibration))[1], np.sqrt(np.diag(inverse)[-q:]), rtol=1e-7)
    K = result.observed.sum()
    landmarks = inverse[p:p + 2 * K, p:p + 2 * K].reshape(K, 2, K, 2)[np.arange(K), :, np.arange(K), :]
    np.testing.assert_allclose(result.landmarks_cov[result.observed], landmarks, rtol=1e-7)


def test_calibration_jacobian_matches_finite_differences():
    """∂Δ/∂c of the speed and turn scales and of the travel offset δ (exact: Δ_xy turned by δ) against central
    differences of the relative motions. (Not τ's: piecewise-constant commands make Δ piecewise linear in τ, and
    the model takes a 10 ms secant on purpose.)"""
    _, _, stream = _miscalibrated(27, (0.95, 0.9), 0.15, duration=20.0)
    keys = keyframe_steps(stream)
    model = OdometryModel(stream, keys)
    c = np.array([0.97, 0.93, 0.12, 0.02, 0.0])
    J = model.jacobian(c, [0, 1, 3])
    for j, (i, h) in enumerate(((0, 1e-5), (1, 1e-5), (3, 1e-6))):
        d = np.zeros(5)
        d[i] = h
        numeric = (model.deltas(c + d) - model.deltas(c - d)) / (2 * h)
        np.testing.assert_allclose(J[:, :, j], numeric, atol=1e-7)
    turned = model.deltas(c)
    plain = model.deltas(np.r_[c[:3], 0.0, 0.0])
    np.testing.assert_allclose(np.hypot(turned[:, 0], turned[:, 1]), np.hypot(plain[:, 0], plain[:, 1]), atol=1e-12)
    np.testing.assert_allclose(turned[:, 2], plain[:, 2])


def _with_bearing_bias(stream: EventStream, bias: float) -> EventStream:
    """The stream with every bearing read ``bias`` [rad] too far anticlockwise."""
    z = np.array(stream.z, dtype=float)
    z[:, 1] = wrap_angle(z[:, 1] + bias)
    return dataclasses.replace(stream, z=z)


@pytest.mark.parametrize("seed", [31, 32])
def test_a_bearing_bias_is_estimated_with_the_path(seed):
    """Known truth: every bearing 0.03 rad (1.7°) too far anticlockwise. Estimated jointly (``bearing_bias``), the
    bias comes back within 3 of its own σ (about 0.002 rad), and the path is as good as from the unbiased log; left
    unmodelled, it turns the solution by degrees."""
    bias = 0.03
    data, log, stream = simulate(seed, duration=90.0)
    biased = _with_bearing_bias(stream, bias)
    fitted = smooth(biased, _params(), solver=SolverSettings(calibrate=("bearing_bias",)))
    b, sd = fitted.calibration["bearing_bias"], fitted.calibration_std["bearing_bias"]
    assert 0 < sd < 0.005 and abs(b - bias) < 3 * sd, (b, sd)
    clean = smooth(stream, _params())
    e_clean, e_fitted = path_rmse(clean.t, clean.poses, log), path_rmse(fitted.t, fitted.poses, log)
    assert abs(e_fitted - e_clean) < 0.01
    plain = smooth(biased, _params())
    assert path_rmse(plain.t, plain.poses, log) > 3 * e_clean


def _map_rotation(result, data) -> float:
    """The angle [rad] of the rigid motion that best maps the estimated landmarks onto the true ones."""
    return align_se2(result.landmarks[result.observed], data.landmark_positions[result.observed])[2]


def test_a_travel_offset_explains_a_bearing_bias_in_another_frame():
    """The same biased log with the travel offset δ estimated instead: the odometry then drives along θ + δ with
    δ ≈ the bias (within 3 σ), and the bearings fit unbiased — the same shape, turned by −δ about the first pose,
    whose heading the prior pins. δ and b are identifiable because the odometry ties the heading to the direction
    of travel; which of the two is the frame's error, the data cannot tell."""
    bias = 0.03
    data, log, stream = simulate(32, duration=90.0)
    biased = _with_bearing_bias(stream, bias)
    travel = smooth(biased, _params(), solver=SolverSettings(calibrate=("travel_offset",)))
    d, sd = travel.calibration["travel_offset"], travel.calibration_std["travel_offset"]
    assert 0 < sd < 0.005 and abs(d - bias) < 3 * sd, (d, sd)
    clean = smooth(stream, _params())
    turned = _map_rotation(travel, data) - _map_rotation(clean, data)
    assert abs(turned + d) < 0.004, (turned, d)
    assert np.nanmean(landmark_errors_aligned(travel.landmarks, data.landmark_positions, travel.observed)) < 0.05


def test_best_estimate_counts_every_sighting_in_full():
    """``BEST_ESTIMATE`` is the default model with β = 1 for every sighting: the same solution as the model
    with ``measurement_correlation_s=None``, and not the tempered one."""
    _, _, stream = simulate(28, duration=30.0)
    tempered = _params(measurement_correlation_s=4.0)
    best = smooth(stream, tempered, solver=BEST_ESTIMATE)
    untempered = smooth(stream, _params())
    default = smooth(stream, tempered)
    np.testing.assert_allclose(best.poses, untempered.poses, atol=1e-9)
    np.testing.assert_allclose(best.landmarks_cov, untempered.landmarks_cov, rtol=1e-6)
    assert np.abs(default.poses - best.poses).max() > 1e-4
    assert np.trace(default.landmarks_cov[default.observed], axis1=1, axis2=2).sum() > \
        np.trace(best.landmarks_cov[best.observed], axis1=1, axis2=2).sum()


@pytest.mark.parametrize("calibrate", [("k_v", "scale"), ("tau", "tau"), "bearing_bias"])
def test_unknown_or_repeated_calibration_names_are_refused(calibrate):
    with pytest.raises(ValueError, match="SolverSettings.calibrate"):
        SolverSettings(calibrate=calibrate)
