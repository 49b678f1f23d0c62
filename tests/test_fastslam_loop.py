"""The compiled per-particle filter against an independent loop over particle objects (benchmarks/textbook_loop.py).

Same parameters, same seed: both consume the same random numbers, so they must
give the same weighted-mean path (N, 3) and the same final particles — poses,
landmark means and covariances, log weights — to rounding:

* positions: both integrate the same Euler steps, in a different order of
  operations: atol 1e-7 m on positions and landmark means, headings compared
  after wrapping (atol 1e-7 rad);
* covariances: the kernel's symmetric form vs the textbook (I − K H) Σ: measured
  ≤ 3e-13, atol 1e-10;
* log weights: log N(ν; 0, Q) changes by ν/σ² per metre of pose, ~40 m⁻¹ here
  (ν ≈ 0.1 m, σ_r = 0.05 m), so a 1e-8 m position difference gives ~4e-7 in
  log w (measured ≤ 1.4e-7 here, ≤ 1.2e-6 over 10 s logs): compared with
  atol 1e-5; the normalised weights with atol 1e-6.

The cases cover every resampler, both thresholds (0.5: resample sometimes; 1.0:
at every measurement step), the gate on and off, modes slam and localize and
both motion-noise modes, with every pair of the binary options appearing
together. Outliers are injected (outlier_prob = 0.1) so that the gate acts.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.datasets.events import event_stream
from fastslam_edu.landmark.fastslam import CHI2_2DOF_999, FastSLAMParams, run_fastslam
from fastslam_edu.core.motion import MotionNoise
from fastslam_edu.datasets.sim import simulate_dataset
from textbook_loop import Particle, run_fastslam_loop, update_particle
from fastslam_edu.core.weights import weights_from_log

from streams import with_landmark_moved, with_repeated_measurements

M = 6
R = np.diag([0.05**2, 0.02**2])
CONTROL = MotionNoise(mode="control", sigma_v=0.01, sigma_omega=0.02)
STATE = MotionNoise(mode="state", sigma_xy=0.01, sigma_theta=0.02)
GATE = CHI2_2DOF_999

# (noise, mode, resample_threshold, gate, resampler, range_std_slope): a 2^(4-1)
# design over the binary options (every pair of them appears in all 4
# combinations), each resampler twice, the range-dependent noise (slope) in half.
CASES = [
    (CONTROL, "slam", 0.5, GATE, "systematic", 0.06),
    (CONTROL, "slam", 1.0, None, "stratified", 0.0),
    (CONTROL, "localize", 0.5, None, "residual", 0.06),
    (CONTROL, "localize", 1.0, GATE, "roulette", 0.0),
    (STATE, "slam", 0.5, None, "roulette", 0.0),
    (STATE, "slam", 1.0, GATE, "residual", 0.06),
    (STATE, "localize", 0.5, GATE, "stratified", 0.0),
    (STATE, "localize", 1.0, None, "systematic", 0.06),
]


def case_id(case) -> str:
    noise, mode, thr, gate, rs, slope = case
    return f"{noise.mode}-{mode}-thr{thr}-{'gate' if gate else 'nogate'}-{rs}-slope{slope}"


@pytest.fixture(scope="module")
def world():
    data = simulate_dataset(3, duration=6.0, outlier_prob=0.1)
    stream = event_stream(data.robots[1], data.landmark_subjects)
    return data, stream


def compare(stream, params, landmarks=None, seed=7, *, loop_params=None, loop_seed=None):
    """Run both; assert agreement; return the engine's result and the largest differences.

    ``loop_params`` / ``loop_seed`` (default: the same) let a test check that a difference is caught.
    """
    r = run_fastslam(stream, params, seed, landmarks=landmarks)
    parts, path = run_fastslam_loop(stream, loop_params or params, seed if loop_seed is None else loop_seed,
                                    landmarks=landmarks)
    diff = {}
    assert path.shape == r.pose_mean.shape == (len(stream), 3)
    diff["path_xy"] = np.abs(path[:, :2] - r.pose_mean[:, :2]).max()
    diff["path_theta"] = np.abs(wrap_angle(path[:, 2] - r.pose_mean[:, 2])).max()
    poses = np.array([p.pose for p in parts])
    diff["poses_xy"] = np.abs(poses[:, :2] - r.particles.poses[:, :2]).max()
    diff["poses_theta"] = np.abs(wrap_angle(poses[:, 2] - r.particles.poses[:, 2])).max()
    logw = np.array([p.logw for p in parts])
    diff["logw"] = np.abs(logw - r.particles.logw).max()
    diff["w"] = np.abs(weights_from_log(logw) - r.particles.weights).max()
    dmu = dsig = 0.0
    for m, p in enumerate(parts):
        assert sorted(p.landmarks) == np.flatnonzero(r.particles.seen[m]).tolist()
        for k, (mu, sigma) in p.landmarks.items():
            dmu = max(dmu, np.abs(mu - r.particles.mu[m, k]).max())
            dsig = max(dsig, np.abs(sigma - r.particles.sigma[m, k]).max())
    diff["mu"], diff["sigma"] = dmu, dsig
    assert diff["path_xy"] < 1e-7 and diff["poses_xy"] < 1e-7, diff
    assert diff["path_theta"] < 1e-7 and diff["poses_theta"] < 1e-7, diff
    assert diff["mu"] < 1e-7 and diff["sigma"] < 1e-10, diff
    assert diff["logw"] < 1e-5 and diff["w"] < 1e-6, diff
    return r, diff


@pytest.mark.parametrize("case", CASES, ids=case_id)
def test_engine_equals_loop_reference(world, case):
    data, stream = world
    noise, mode, thr, gate, resampler, slope = case
    # tempered likelihoods (tempering_exponents) with resampling at every step, where they decide the selection;
    # with N_eff < M/2 the textbook weights (the short simulated log would not resample with tempered ones)
    tau = 4.0 if thr == 1.0 else None
    params = FastSLAMParams(n_particles=M, motion_noise=noise, measurement_cov=R, mode=mode,
                            resample_threshold=thr, gate_chi2=gate, resampler=resampler, range_std_slope=slope,
                            measurement_correlation_s=tau)
    landmarks = data.landmark_positions if mode == "localize" else None
    r, _ = compare(stream, params, landmarks)
    n_meas_steps = int(np.count_nonzero(np.diff(stream.offsets)))
    assert r.n_resamples > 0  # resampling is exercised ...
    if thr == 0.5:
        assert r.n_resamples < n_meas_steps  # ... and so is not resampling
    if gate is not None:
        assert r.measurements_rejected > 0  # the gate acted
    if mode == "localize":  # the known map never moves, in either implementation
        assert np.array_equal(r.particles.mu, np.broadcast_to(landmarks, r.particles.mu.shape))


def test_engine_equals_loop_with_a_landmark_measured_twice_at_one_instant(world):
    """Two readings of one landmark at one instant are applied one after the other by both."""
    _, stream = world
    twice = with_repeated_measurements(stream, every=4)
    assert twice.n_measurements > stream.n_measurements
    params = FastSLAMParams(n_particles=M, motion_noise=CONTROL, measurement_cov=R, resampler="systematic")
    compare(twice, params)


@pytest.mark.parametrize("escape_s", [0.3, None], ids=["escape", "no-escape"])
def test_engine_equals_loop_when_a_landmark_moves(world, escape_s):
    """A landmark 1 m off from t0 + 3 s: rejected by both, then (escape) applied without the gate by both."""
    _, stream = world
    k = int(np.bincount(stream.landmark).argmax())  # the landmark seen most often
    moved = with_landmark_moved(stream, k, stream.t[0] + 3.0, 1.0)
    params = FastSLAMParams(n_particles=M, motion_noise=CONTROL, measurement_cov=R, gate_chi2=GATE,
                            gate_escape_s=escape_s, range_std_slope=0.0)
    r, _ = compare(moved, params)
    before = run_fastslam(stream, params, 7).measurements_rejected  # the injected outliers
    if escape_s is None:  # every later sighting of the moved landmark is rejected (measured: 21 vs 6)
        assert r.measurements_rejected >= before + 10
    else:  # the escape lets them in after 0.3 s (measured: 7 vs 6)
        assert r.measurements_rejected <= before + 3


@pytest.mark.parametrize(
    "change",
    [{"loop_seed": 8}, {"loop_params": "range_std_2pct"}, {"loop_params": "gate_off"}],
    ids=["other-seed", "R-range-2pct", "gate-only-in-engine"],
)
def test_the_comparison_can_fail(world, change):
    """A different seed, a 2 % larger σ_r or the gate on one side only is caught."""
    _, stream = world
    params = FastSLAMParams(n_particles=M, motion_noise=CONTROL, measurement_cov=R, gate_chi2=GATE)
    if change.get("loop_params") == "range_std_2pct":
        change = {"loop_params": dataclasses.replace(params, measurement_cov=np.diag([0.051**2, 0.02**2]))}
    elif change.get("loop_params") == "gate_off":
        change = {"loop_params": dataclasses.replace(params, gate_chi2=None)}
    with pytest.raises(AssertionError):
        compare(stream, params, **change)


def test_an_outlier_against_a_landmark_seen_once_reinitialises_it():
    """Closed form of the inverse model: the landmark restarts at x + r (cos(θ + φ), sin(θ + φ)) of the new sighting,
    with σ_r² along the line of sight and r² σ_φ² across it; no weight, and still one sighting."""
    p = Particle(pose=np.array([1.0, 2.0, 0.5]))
    update_particle(p, np.array([3.0, 0.2]), 4, R, gate_chi2=GATE)  # first sighting
    z = np.array([4.0, 1.2])  # 1 m and 1 rad off: far beyond the gate
    update_particle(p, z, 4, R, gate_chi2=GATE)
    a = 0.5 + 1.2
    mu, sigma = p.landmarks[4]
    np.testing.assert_allclose(mu, [1.0 + 4.0 * np.cos(a), 2.0 + 4.0 * np.sin(a)], atol=1e-12)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    np.testing.assert_allclose(sigma, rot @ np.diag([0.05**2, (4.0 * 0.02) ** 2]) @ rot.T, atol=1e-15)
    assert p.logw == 0.0 and p.count[4] == 1


def test_the_loop_refuses_mode_map():
    """The loop reference runs only slam and localize (mode "map" is the engine's alone)."""
    data = simulate_dataset(3, duration=2.0)
    stream = event_stream(data.robots[1], data.landmark_subjects)
    with pytest.raises(ValueError, match='runs mode "slam" or "localize"'):
        run_fastslam_loop(stream, FastSLAMParams(n_particles=2, mode="map"), 0, landmarks=data.landmark_positions)
