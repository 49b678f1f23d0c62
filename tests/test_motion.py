"""Tests of fastslam_edu.core.motion: closed forms, the exact arc, and the rate test.

The rate test is the point of the module: with noise given as densities the
spread of the pose after one second is the same at 1 Hz, 10 Hz and 67 Hz, and
equals the analytic covariance; with the write-up's per-step standard deviation
it shrinks like 1/rate.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.motion import (
    MotionNoise,
    move,
    move_segment,
    propagate,
    propagate_arc,
    sample_motion,
)

# --------------------------------------------------------------------------- references


def circle_pose(x0, v, omega, t):
    """Exact unicycle pose after t seconds of constant (v, ω ≠ 0), by geometry.

    The robot turns about the centre c = p0 + R (-sin θ0, cos θ0), R = v/ω.
    """
    px, py, th = x0
    radius = v / omega
    cx, cy = px - radius * math.sin(th), py + radius * math.cos(th)
    th_t = th + omega * t
    return np.array([cx + radius * math.sin(th_t), cy - radius * math.cos(th_t), wrap_angle(th_t)])


def loop_move(x, u, dt, noise, eps):
    """Particle-by-particle reference of the noisy step, written from the equations."""
    out = np.empty_like(x)
    for i in range(len(x)):
        px, py, th = x[i]
        if noise.mode == "control":
            ds = u[0] * dt + noise.sigma_v * math.sqrt(dt) * eps[i, 0]
            dth = u[1] * dt + noise.sigma_omega * math.sqrt(dt) * eps[i, 1]
            out[i] = px + ds * math.cos(th), py + ds * math.sin(th), th + dth
        else:
            s = math.sqrt(dt)
            out[i] = (
                px + u[0] * dt * math.cos(th) + noise.sigma_xy * s * eps[i, 0],
                py + u[0] * dt * math.sin(th) + noise.sigma_xy * s * eps[i, 1],
                th + u[1] * dt + noise.sigma_theta * s * eps[i, 2],
            )
        out[i, 2] = math.remainder(out[i, 2], 2 * math.pi)
    return out


def linearised_covariance(x0, u, dt, n_steps, noise):
    """Pose covariance after n Euler steps, propagated to first order (EKF style).

    P ← F P Fᵀ + G Q Gᵀ with F = ∂f/∂x, and the noise entering through
    G = ∂f/∂(Δs, Δθ), Q = diag(σ_v², σ_ω²) Δt (control mode), or additively
    with Q = diag(σ_xy², σ_xy², σ_θ²) Δt (state mode).
    """
    v, omega = u
    mean = np.array(x0, dtype=float)
    cov = np.zeros((3, 3))
    for _ in range(n_steps):
        c, s = math.cos(mean[2]), math.sin(mean[2])
        ds = v * dt
        jac_x = np.array([[1, 0, -ds * s], [0, 1, ds * c], [0, 0, 1]])
        if noise.mode == "control":
            jac_n = np.array([[c, 0], [s, 0], [0, 1]])
            q = np.diag([noise.sigma_v**2, noise.sigma_omega**2]) * dt
        else:
            jac_n = np.eye(3)
            q = np.diag([noise.sigma_xy**2, noise.sigma_xy**2, noise.sigma_theta**2]) * dt
        cov = jac_x @ cov @ jac_x.T + jac_n @ q @ jac_n.T
        mean = mean + np.array([ds * c, ds * s, omega * dt])
    return cov


# --------------------------------------------------------------------------- closed forms


def test_straight_line_is_exact():
    x0 = np.array([[1.0, -2.0, 0.7], [0.0, 0.0, -2.5]])
    x = x0.copy()
    for _ in range(10):
        x = propagate(x, [0.3, 0.0], 0.25)
    expected = x0 + np.stack([0.75 * np.cos(x0[:, 2]), 0.75 * np.sin(x0[:, 2]), np.zeros(2)], axis=-1)
    np.testing.assert_allclose(x, expected, atol=1e-12)


def test_pure_rotation_keeps_position_and_wraps_heading():
    x = propagate([2.0, 3.0, 3.0], [0.0, 1.0], 1.0)
    np.testing.assert_allclose(x, [2.0, 3.0, 4.0 - 2 * np.pi], atol=1e-12)
    assert -np.pi < x[2] <= np.pi


def test_one_euler_step_uses_the_start_heading():
    x = propagate([0.0, 0.0, 0.5], [2.0, 1.0], 0.5)
    np.testing.assert_allclose(x, [math.cos(0.5), math.sin(0.5), 1.0], atol=1e-12)


def test_zero_dt_leaves_pose_unchanged():
    x0 = np.array([[1.0, 2.0, 0.3], [-1.0, 0.5, np.pi]])
    noise = MotionNoise(sigma_v=0.5, sigma_omega=0.5)
    for out in (
        propagate(x0, [0.3, 1.0], 0.0),
        propagate_arc(x0, [0.3, 1.0], 0.0),
        sample_motion(x0, [0.3, 1.0], 0.0, noise, np.random.default_rng(0)),
        sample_motion(x0, [0.3, 1.0], 0.0, MotionNoise("state", sigma_xy=1.0, sigma_theta=1.0),
                      np.random.default_rng(0)),
    ):
        assert np.isfinite(out).all()
        np.testing.assert_allclose(out, x0, atol=1e-15)


def test_arc_matches_circle_geometry_and_straight_line():
    x0 = (0.5, -1.0, 2.9)
    for omega in (0.8, -1.3, 3.0):
        np.testing.assert_allclose(propagate_arc(x0, [0.3, omega], 2.0), circle_pose(x0, 0.3, omega, 2.0),
                                   atol=1e-12)
    np.testing.assert_allclose(propagate_arc(x0, [0.3, 0.0], 2.0),
                               [0.5 + 0.6 * math.cos(2.9), -1.0 + 0.6 * math.sin(2.9), 2.9], atol=1e-12)


def test_euler_converges_to_exact_arc_first_order():
    x0, v, omega, duration = (0.0, 0.0, 0.4), 0.3, 0.8, 3.0
    exact = circle_pose(x0, v, omega, duration)
    errors = []
    for n in (100, 200, 400, 800):
        x = np.array(x0)
        for _ in range(n):
            x = propagate(x, [v, omega], duration / n)
        np.testing.assert_allclose(x[2], exact[2], atol=1e-12)  # heading is exact
        errors.append(np.hypot(*(x[:2] - exact[:2])))
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert np.all((ratios > 1.9) & (ratios < 2.1)), ratios  # halving dt halves the error: O(dt)
    # leading term: Euler's chords lag the arc by half a step's turn ωΔt/2, so the
    # error is ≈ (v/ω)·2 sin(ωT/2)·(ωΔt/2) = 1.05 mm here, at most v Δt
    assert errors[-1] < v * duration / 800


def test_batch_dimensions_broadcast():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(2, 5, 3))
    u = rng.normal(size=(5, 2))
    out = propagate(x, u, 0.1)
    assert out.shape == (2, 5, 3)
    np.testing.assert_allclose(out[1, 3], propagate(x[1, 3], u[3], 0.1), atol=0)
    # one pose, many commands
    assert propagate([0.0, 0.0, 0.0], u, 0.1).shape == (5, 3)


# --------------------------------------------------------------------------- noise

BOTH_NOISE_MODES = pytest.mark.parametrize(  # one noise of each mode, for the tests that compare with the loop reference
    "noise",
    [MotionNoise(sigma_v=0.2, sigma_omega=0.3), MotionNoise("state", sigma_xy=0.1, sigma_theta=0.4)],
    ids=["control", "state"],
)


@BOTH_NOISE_MODES
def test_move_matches_loop_reference_and_sample_motion(noise):
    rng = np.random.default_rng(11)
    x = np.column_stack([rng.normal(size=(50, 2)), rng.uniform(-np.pi, np.pi, 50)])
    u, dt = np.array([0.25, -0.7]), 0.015
    eps = np.random.default_rng(42).standard_normal((50, noise.n_draws))
    np.testing.assert_allclose(move(x, u, dt, noise, eps), loop_move(x, u, dt, noise, eps), atol=1e-12)
    # sample_motion = move with eps from the same generator state
    np.testing.assert_array_equal(sample_motion(x, u, dt, noise, np.random.default_rng(42)),
                                  move(x, u, dt, noise, eps))


def test_control_density_equals_velocity_noise_of_std_sigma_over_root_dt():
    noise = MotionNoise(sigma_v=0.05, sigma_omega=0.08)
    x = np.zeros((20, 3))
    u, dt = np.array([0.3, 0.5]), 0.02
    eps = np.random.default_rng(1).standard_normal((20, 2))
    noisy_u = u + eps * np.array([noise.sigma_v, noise.sigma_omega]) / math.sqrt(dt)
    np.testing.assert_allclose(move(x, u, dt, noise, eps), propagate(x, noisy_u, dt), atol=1e-14)


def test_from_per_step_std_reproduces_write_up_model_at_its_step():
    # write-up: N(0, 0.05²) added to v and ω at every 1 s step
    noise = MotionNoise.from_per_step_std(1.0, v_std=0.05, omega_std=0.05)
    assert (noise.mode, noise.sigma_v, noise.sigma_omega) == ("control", 0.05, 0.05)
    # at a 0.25 s step: std 0.1 on v and 0.2 on ω -> densities 0.05 and 0.1
    noise = MotionNoise.from_per_step_std(0.25, v_std=0.1, omega_std=0.2)
    x, u = np.zeros((10, 3)), np.array([0.3, 0.5])
    eps = np.random.default_rng(2).standard_normal((10, 2))
    np.testing.assert_allclose(move(x, u, 0.25, noise, eps), propagate(x, u + eps * [0.1, 0.2], 0.25),
                               atol=1e-14)
    state = MotionNoise.from_per_step_std(0.25, xy_std=0.01, theta_std=0.02)
    assert state.mode == "state"
    np.testing.assert_allclose(state.step_std(0.25), [0.01, 0.01, 0.02])
    np.testing.assert_allclose(state.step_std(1.0), [0.02, 0.02, 0.04])


RATES = (1, 10, 67)
N_PARTICLES = 20_000
X0 = (1.0, -0.5, 0.3)
U = (0.3, 0.5)  # m/s, rad/s for one second


def simulate_one_second(step, rate, n_draws, seed):
    """Final poses after 1 s at `rate` Hz; `step(x, dt, eps)` makes one step."""
    rng = np.random.default_rng(seed)
    x = np.tile(X0, (N_PARTICLES, 1))
    dt = 1.0 / rate
    for _ in range(rate):
        x = step(x, dt, rng.standard_normal((N_PARTICLES, n_draws)))
    return x


def pose_covariance(x):
    d = x - x.mean(axis=0)
    d[:, 2] = wrap_angle(x[:, 2] - X0[2] - U[1]) - wrap_angle(x[:, 2] - X0[2] - U[1]).mean()
    return d.T @ d / (len(x) - 1)


@pytest.mark.parametrize(
    "noise",
    [MotionNoise(sigma_v=0.05, sigma_omega=0.05), MotionNoise("state", sigma_xy=0.03, sigma_theta=0.05)],
    ids=["control", "state"],
)
def test_rate_test_density_noise_gives_the_same_covariance_at_any_rate(noise):
    covs = {}
    for i, rate in enumerate(RATES):
        x = simulate_one_second(lambda x, dt, eps: move(x, U, dt, noise, eps), rate, noise.n_draws, 100 + i)
        sample = pose_covariance(x)
        analytic = linearised_covariance(X0, U, 1.0 / rate, rate, noise)
        # standard error of a Gaussian sample covariance: sqrt((P_ii P_jj + P_ij²) / N)
        se = np.sqrt((np.outer(np.diag(analytic), np.diag(analytic)) + analytic**2) / N_PARTICLES)
        assert np.all(np.abs(sample - analytic) <= 5 * se + 1e-12), (rate, sample, analytic)
        covs[rate] = sample
    # Var(Δθ) = σ² · 1 s at every rate (exact: a sum of independent normals)
    sigma_theta = noise.sigma_omega if noise.mode == "control" else noise.sigma_theta
    for rate in RATES:
        assert abs(covs[rate][2, 2] / sigma_theta**2 - 1) < 5 * math.sqrt(2 / N_PARTICLES)
    # the position spread agrees across rates within 10 % (it differs only by the
    # heading noise's O(Δt) coupling into position, a few per cent here)
    spread = np.array([np.trace(covs[r][:2, :2]) for r in RATES])
    assert spread.max() / spread.min() < 1.1, spread
    if noise.mode == "control":  # the distance noise alone: Var(Δs) = σ_v² · 1 s
        assert abs(spread[0] / noise.sigma_v**2 - 1) < 5 * math.sqrt(2 / N_PARTICLES)


def test_rate_test_naive_per_step_std_fails():
    """The write-up's model: N(0, 0.05²) on v and ω at every step, whatever the step."""
    sigma = 0.05

    def naive_step(x, dt, eps):
        return propagate(x, np.asarray(U) + sigma * eps, dt)

    var_theta, spread = {}, {}
    for i, rate in enumerate(RATES):
        x = simulate_one_second(naive_step, rate, 2, 200 + i)
        cov = pose_covariance(x)
        var_theta[rate], spread[rate] = cov[2, 2], np.trace(cov[:2, :2])
    # at 1 Hz it coincides with the density model of σ = 0.05 ...
    assert abs(var_theta[1] / sigma**2 - 1) < 5 * math.sqrt(2 / N_PARTICLES)
    # ... but its variance shrinks like 1/rate: 67 times too small at 67 Hz
    assert abs(var_theta[67] * 67 / sigma**2 - 1) < 5 * math.sqrt(2 / N_PARTICLES)
    assert var_theta[1] / var_theta[67] > 30 and spread[1] / spread[67] > 30
    # so it fails the criterion the density model passes
    assert max(spread.values()) / min(spread.values()) > 1.1


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: propagate([0, 0, np.nan], [1, 1], 0.1), r"propagate: x \(poses x, y, θ\) contains a non-finite value \(nan\) at index \(2,\)"),
        (lambda: propagate([0, 0, 0], [np.inf, 1], 0.1), r"propagate: u \(commands v, ω\) contains a non-finite value \(inf\)"),
        (lambda: propagate([0, 0, 0], [1, 1], -0.1), "dt"),
        (lambda: propagate([0, 0, 0], [1, 1], float("nan")), "dt"),
        (lambda: propagate([0, 0, 0], [1, 1], "a"), "dt"),
        (lambda: propagate([0, 0], [1, 1], 0.1), "shape"),
        (lambda: propagate(np.zeros((4, 3)), [1, 1, 1], 0.1), "shape"),
        (lambda: move(np.zeros((4, 3)), [1, 1], 0.1, MotionNoise(), np.zeros((4, 3))), "eps"),
        (lambda: move(np.zeros((4, 3)), [1, 1], 0.1, MotionNoise(), np.full((4, 2), np.nan)), "eps"),
        (lambda: move(np.zeros((4, 3)), [1, 1], 0.1, (0.1, 0.1), np.zeros((4, 2))), "MotionNoise"),
        (lambda: sample_motion(np.zeros((4, 3)), [1, 1], 0.1, MotionNoise(), None), "Generator"),
        (lambda: sample_motion(np.zeros((4, 3)), [1, 1], 0.1, MotionNoise(), np.random.RandomState(0)),
         "Generator"),
        (lambda: MotionNoise(sigma_v=-0.1), "sigma_v"),
        (lambda: MotionNoise(sigma_omega=float("nan")), "sigma_omega"),
        (lambda: MotionNoise("state", sigma_xy=float("inf")), "sigma_xy"),
        (lambda: MotionNoise(sigma_theta=0.1), "mode='state'"),
        (lambda: MotionNoise("state", sigma_v=0.1), "mode='control'"),
        (lambda: MotionNoise("odometry"), "mode"),
        (lambda: MotionNoise.from_per_step_std(1.0, v_std=0.1, xy_std=0.1), "either"),
        (lambda: MotionNoise.from_per_step_std(0.0, v_std=0.1), "step"),
    ],
)
def test_bad_input_raises_clear_value_error(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_n_draws():
    assert MotionNoise().n_draws == 2
    assert MotionNoise("state").n_draws == 3


# --------------------------------------------------------------------------- segments and wrapping


@BOTH_NOISE_MODES
def test_move_segment_matches_loop_reference_step_by_step(noise):
    """move_segment over L steps = L steps of the equation-by-equation loop reference, headings wrapped."""
    rng = np.random.default_rng(21)
    m, steps = 30, 40
    x0 = np.column_stack([rng.normal(size=(m, 2)), np.pi - rng.uniform(0.0, 0.3, m)])  # start near +π
    u = np.column_stack([rng.uniform(0.1, 0.5, steps), rng.uniform(0.5, 2.0, steps)])  # turning left: crosses π
    dt = rng.uniform(0.01, 0.05, steps)
    eps = rng.standard_normal((m, steps, noise.n_draws))
    path = move_segment(x0, u, dt, noise, eps)
    assert path.shape == (m, steps, 3)
    x = x0.copy()
    for j in range(steps):
        x = loop_move(x, u[j], dt[j], noise, eps[:, j])
        np.testing.assert_allclose(path[:, j, :2], x[:, :2], atol=1e-6)  # cos/sin in single precision
        np.testing.assert_allclose(wrap_angle(path[:, j, 2] - x[:, 2]), 0.0, atol=1e-9)
    assert np.all((path[..., 2] > -np.pi) & (path[..., 2] <= np.pi))
    assert np.any(path[:, -1, 2] < 0)  # some headings did cross ±π


def test_move_segment_refuses_negative_dt():
    """A step of negative duration is refused, as by propagate (the documented domain dt >= 0)."""
    with pytest.raises(ValueError, match="dt >= 0"):
        move_segment(np.zeros((2, 3)), np.zeros((3, 2)), np.array([0.1, -0.1, 0.1]), MotionNoise(),
                     np.zeros((2, 3, 2)))


def test_state_noise_kick_across_pi_is_wrapped():
    """State mode: a heading kick from π − 0.01 by +0.05 rad lands at −π + 0.04 (closed form)."""
    noise = MotionNoise("state", sigma_xy=0.0, sigma_theta=1.0)
    out = move([[1.0, 2.0, np.pi - 0.01]], [0.0, 0.0], 0.25, noise, [[0.0, 0.0, 0.1]])  # σ√Δt ε = 0.05
    np.testing.assert_allclose(out, [[1.0, 2.0, -np.pi + 0.04]], atol=1e-12)


def test_from_per_step_std_with_no_std_at_all_raises():
    """Neither control nor state standard deviations given: refused, not silently 'no noise'."""
    with pytest.raises(ValueError, match="not neither"):
        MotionNoise.from_per_step_std(1.0)
