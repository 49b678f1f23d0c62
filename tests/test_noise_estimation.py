"""Tests of fastslam_edu.evaluation.noise_estimation against simulations with known noise.

References: the simulator's stated noise (odometry densities σ_v, σ_ω, range
and bearing standard deviations, outlier probability) with sampling bounds;
closed forms (relative motion, robust std of Gaussian samples); a
particle-free loop of motion.propagate for dead reckoning; the angle-aware
1 Hz average (events.clean_1hz_table) to find the glitches of a naive one.
No real data is needed.
"""

from __future__ import annotations

import dataclasses
import math
import statistics

import numpy as np
import pandas as pd
import pytest
from scipy.stats import norm

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.datasets.events import clean_1hz_table
from fastslam_edu.datasets.log import Dataset, RobotLog
from fastslam_edu.core.motion import MotionNoise, dead_reckon_at, propagate
from fastslam_edu.evaluation import noise_estimation as ne
from fastslam_edu.evaluation.noise_estimation import (
    estimate_noise,
    fit_random_walk,
    fit_range_noise,
    heading_glitches,
    increment_variances,
    landmark_check,
    measurement_noise,
    measurement_residuals,
    motion_noise,
    odometry_increment_errors,
    range_noise_profile,
    relative_motion,
    robust_std,
    usable_groundtruth,
)
from fastslam_edu.datasets.sim import simulate_dataset

ODOMETRY = MotionNoise(sigma_v=0.02, sigma_omega=0.05)
RANGE_STD, BEARING_STD = 0.05, 0.02


@pytest.fixture(scope="module")
def clean() -> Dataset:
    """3 robots × 600 s, no outliers: ~28 000 measurements, 1800 one-second windows."""
    return simulate_dataset(1, duration=600.0, n_robots=3, odometry_noise=ODOMETRY,
                            range_std=RANGE_STD, bearing_std=BEARING_STD)


@pytest.fixture(scope="module")
def with_outliers() -> Dataset:
    return simulate_dataset(2, duration=600.0, n_robots=2, odometry_noise=ODOMETRY,
                            range_std=RANGE_STD, bearing_std=BEARING_STD, outlier_prob=0.05)


def one_hz(log: RobotLog, angle_aware: bool = True) -> RobotLog:
    """The log with its groundtruth averaged per whole second (as Dataset 1's groundtruth_1hz)."""
    gt = clean_1hz_table(log.groundtruth, angle_columns=("theta",) if angle_aware else ())
    return dataclasses.replace(log, groundtruth=gt)


# --------------------------------------------------------------------------- robust statistics


def test_robust_std_is_the_std_for_gaussians_and_ignores_outliers():
    rng = np.random.default_rng(0)
    e = rng.normal(0.3, 2.0, 40_000)
    # relative standard error of the MAD estimate ≈ 0.78/√n = 0.4 %
    assert robust_std(e) == pytest.approx(2.0, rel=0.02)
    # the MAD about the median, scaled by 1/Φ⁻¹(3/4), by hand
    assert robust_std(e) == pytest.approx(np.median(np.abs(e - np.median(e))) / norm.ppf(0.75), rel=1e-14)
    assert robust_std([1.0, 2.0, 4.0]) == pytest.approx(1.0 / norm.ppf(0.75), rel=1e-14)  # |e − 2| = 1, 0, 2
    e[:2000] = 1e3  # 5 % gross outliers
    assert np.std(e) > 100
    # a one-sided 5 % contamination moves the MAD by ≈ 1.4826·(Φ⁻¹(0.75+0.025)−Φ⁻¹(0.75))… < 10 %
    assert robust_std(e) == pytest.approx(2.0, rel=0.10)


def test_robust_std_rejects_empty_and_nan():
    with pytest.raises(ValueError, match="empty"):
        robust_std([])
    with pytest.raises(ValueError, match="NaN"):
        robust_std([1.0, np.nan])
    with pytest.raises(ValueError, match="inf"):
        robust_std([1.0, 2.0, np.inf])


# --------------------------------------------------------------------------- groundtruth


def test_heading_glitches_are_the_naive_averages_across_pi(clean):
    log = clean.robots[1]
    naive = one_hz(log, angle_aware=False).groundtruth
    aware = one_hz(log, angle_aware=True).groundtruth
    wrong = np.abs(wrap_angle(naive["theta"].to_numpy() - aware["theta"].to_numpy()))
    assert (wrong > 1.0).sum() >= 3  # the path crosses θ = ±π several times: the test has teeth
    found = heading_glitches(naive["time"], naive["theta"], log.odometry)
    assert found[wrong > 1.0].all()  # every gross glitch is found …
    assert not found[wrong < 0.2].any()  # … and no good row is condemned
    assert not heading_glitches(aware["time"], aware["theta"], log.odometry).any()
    assert not heading_glitches(log.groundtruth["time"], log.groundtruth["theta"], log.odometry).any()
    # without the odometry the sharp turns of the simulated robot would look like glitches
    assert heading_glitches(aware["time"], aware["theta"]).sum() > 0


def test_heading_glitch_on_a_hand_made_heading():
    theta = np.array([3.0, 3.1, 0.05, -3.1, -3.0, -2.9])  # row 2: mean of ±3.1, a glitch (no turning)
    assert heading_glitches(np.arange(6.0), theta).tolist() == [False, False, True, False, False, False]
    with pytest.raises(ValueError, match="threshold"):
        heading_glitches(np.arange(6.0), theta, threshold=0.0)


# --------------------------------------------------------------------------- measurement noise


def test_residuals_vanish_without_noise():
    data = simulate_dataset(3, duration=120.0, range_std=0.0, bearing_std=0.0)
    e = measurement_residuals(data.robots[1], data)
    assert len(e) > 300
    # truth is the simulator's exact pose; 100 Hz linear interpolation errs by < 1e-4
    assert np.abs(e["range_residual"]).max() < 1e-3
    assert np.abs(e["bearing_residual"]).max() < 1e-3
    truth = data.landmarks.loc[e["subject"], ["x", "y"]].to_numpy()
    assert np.abs(e[["x_seen", "y_seen"]].to_numpy() - truth).max() < 1e-3
    # the same with landmarks given as an array and subjects
    e2 = measurement_residuals(data.robots[1], data.landmark_positions, data.landmark_subjects)
    np.testing.assert_allclose(e2["range_residual"], e["range_residual"])


def test_measurement_noise_recovers_sigmas(clean):
    e = [measurement_residuals(g, clean) for g in clean.robots.values()]
    m = measurement_noise(e)
    n = sum(len(f) for f in e)
    assert m.n == n > 20_000
    # MAD-based σ: relative standard error 0.78/√n ≈ 0.5 %; bound 5 %
    assert m.sigma_range == pytest.approx(RANGE_STD, rel=0.05)
    assert m.sigma_bearing == pytest.approx(BEARING_STD, rel=0.05)
    assert m.range_std_inliers == pytest.approx(RANGE_STD, rel=0.05)
    # biases: standard error σ/√n ≈ 3e-4 m; bound 10 standard errors
    assert abs(m.range_bias_median) < 10 * 1.25 * RANGE_STD / math.sqrt(n)
    assert abs(m.bearing_bias_mean) < 10 * BEARING_STD / math.sqrt(n)
    assert m.outlier_fraction == 0.0
    np.testing.assert_allclose(m.R, np.diag([m.sigma_range**2, m.sigma_bearing**2]))


def test_outlier_fraction_and_robust_sigma_with_outliers(with_outliers):
    e = [measurement_residuals(g, with_outliers) for g in with_outliers.robots.values()]
    m = measurement_noise(e, outlier_threshold=0.5)
    # an outlier adds U(0.5, 2) m: it exceeds 0.5 m unless the noise pulls it back,
    # P(jump + ε > 0.5) = 1 − E_j Φ((0.5 − j)/σ_r)
    j = np.linspace(0.5, 2.0, 20_001)
    p = 0.05 * (1 - np.mean(norm.cdf((0.5 - j) / RANGE_STD)))
    assert m.outlier_fraction == pytest.approx(p, abs=4 * math.sqrt(p * (1 - p) / m.n))
    # the robust σ barely moves (the plain std would be ~0.2 m); brief's bound 15 %
    assert m.sigma_range == pytest.approx(RANGE_STD, rel=0.15)
    assert np.std(pd.concat(e)["range_residual"]) > 3 * RANGE_STD
    assert m.sigma_bearing == pytest.approx(BEARING_STD, rel=0.05)


def test_range_profile_is_flat_in_simulation_and_finds_growth(clean):
    e = pd.concat([measurement_residuals(g, clean) for g in clean.robots.values()])
    a, b = fit_range_noise(range_noise_profile(e))
    assert abs(b) < 0.005  # constant σ_r in the simulator
    assert a == pytest.approx(RANGE_STD, rel=0.15)
    # a synthetic residual table whose σ grows as 0.02 + 0.03 r
    rng = np.random.default_rng(5)
    r = rng.uniform(0.5, 6.0, 50_000)
    fake = pd.DataFrame({"subject": 6, "range": r, "range_expected": r,
                         "range_residual": rng.normal(0, 0.02 + 0.03 * r), "bearing_residual": 0.0})
    a, b = fit_range_noise(range_noise_profile(fake))
    assert a == pytest.approx(0.02, rel=0.15)
    assert b == pytest.approx(0.03, rel=0.15)


def test_skipped_measurements_are_counted(clean):
    log = clean.robots[1]
    gt = log.groundtruth
    t0 = gt["time"].iloc[0]
    cut = gt[((gt["time"] < t0 + 30) | (gt["time"] > t0 + 33)) & (gt["time"] <= t0 + 500)]
    e = measurement_residuals(dataclasses.replace(log, groundtruth=cut), clean)
    t = log.measurements["time"].to_numpy()
    last_before_gap = cut["time"][cut["time"] < t0 + 30].max()
    first_after_gap = cut["time"][cut["time"] > t0 + 33].min()
    outside = (t > cut["time"].max()).sum()
    in_gap = ((t > last_before_gap) & (t < first_after_gap)).sum()
    assert outside > 0 and in_gap > 0
    assert e.attrs["n_outside_span"] == outside
    assert e.attrs["n_in_gaps"] == in_gap
    assert len(e) + outside + in_gap == len(t) == e.attrs["n_measurements"]


def test_landmark_check_finds_swapped_landmarks(clean):
    swapped = clean.landmarks.copy()
    swapped.loc[[8, 12], ["x", "y"]] = swapped.loc[[12, 8], ["x", "y"]].to_numpy()
    e = [measurement_residuals(g, swapped) for g in clean.robots.values()]
    check = landmark_check(e, swapped)
    assert sorted(check.index[check["suspect"]]) == [8, 12]
    assert check.loc[8, "nearest"] == 12 and check.loc[12, "nearest"] == 8
    assert check.loc[~check["suspect"], "offset"].max() < 0.05
    bad = dataclasses.replace(clean, landmarks=swapped)
    kept = estimate_noise(bad)
    assert kept["suspect"] == [8, 12]
    assert kept["measurement"].outlier_fraction < 0.01
    assert estimate_noise(bad, exclude_suspect=False)["measurement"].outlier_fraction > 0.03


# --------------------------------------------------------------------------- motion noise


def test_relative_motion_closed_form():
    ds, dl, dth = relative_motion([1.0, 2.0, math.pi / 2], [0.0, 5.0, math.pi])
    assert (ds, dl, dth) == pytest.approx((3.0, 1.0, math.pi / 2))


def test_dead_reckoning_matches_a_loop_of_propagate(clean):
    odo = clean.robots[1].odometry.iloc[:700]
    times = np.array([odo["time"].iloc[0] - 0.3, odo["time"].iloc[100] + 0.004, odo["time"].iloc[650]])
    x0 = np.array([1.0, -2.0, 3.0])
    got = dead_reckon_at(odo, times, x0)
    # reference: a plain loop, command held until the next row, zero before the first
    t, u = odo["time"].to_numpy(), odo[["v", "omega"]].to_numpy()
    x, now, out, theta = x0.copy(), times[0], [], x0[2]
    for q in times:
        while True:
            nxt = t[t > now].min() if (t > now).any() else np.inf
            step_end = min(nxt, q)
            i = np.searchsorted(t, now, side="right") - 1
            cmd = u[i] if i >= 0 else np.zeros(2)
            x = propagate(x, cmd, step_end - now)
            theta += cmd[1] * (step_end - now)
            now = step_end
            if now == q:
                break
        out.append([x[0], x[1], theta])
    np.testing.assert_allclose(got, np.array(out), atol=1e-9)


def test_increment_errors_are_zero_without_odometry_noise():
    data = simulate_dataset(4, duration=120.0, odometry_noise=MotionNoise())
    e = odometry_increment_errors(data.robots[1], 2.0)
    assert len(e) == 59  # windows [⌈t0⌉ + 2k, +2] inside 120 s
    # the turn Σ ω Δt is exact (up to interpolating the 100 Hz groundtruth); the distance
    # keeps the Euler-vs-arc error, of order
    # v ω Δt τ / 2 ≈ 0.3 · 1 · 0.015 · 2 / 2 ≈ 4.5 mm at most (sharp turns at 67 Hz)
    assert np.abs(e["dtheta_error"]).max() < 1e-6
    assert np.abs(e["ds_error"]).max() < 5e-3
    assert np.median(np.abs(e["ds_error"])) < 1e-5
    assert (np.diff(e["t_start"]) == 2.0).all() and (e["t_start"] % 1 == 0).all()


def test_motion_noise_recovers_densities(clean):
    v = increment_variances(clean, (1, 2, 4))
    # a random walk: Var/τ is the same at every τ (standard error ~ 4–9 %)
    ratio = v["var_s_per_s"] / ODOMETRY.sigma_v**2
    assert ratio.between(0.7, 1.3).all()
    ratio = v["var_theta_per_s"] / ODOMETRY.sigma_omega**2
    assert ratio.between(0.7, 1.3).all()
    noise = motion_noise(clean)
    assert noise.mode == "control"
    # the fitted slope has a standard error ≈ 5 %; bound 15 %
    assert noise.sigma_v == pytest.approx(ODOMETRY.sigma_v, rel=0.15)
    assert noise.sigma_omega == pytest.approx(ODOMETRY.sigma_omega, rel=0.15)


def test_motion_noise_from_1hz_groundtruth(clean):
    logs = [one_hz(g) for g in clean.robots.values()]
    noise = motion_noise(logs)
    assert noise.sigma_v == pytest.approx(ODOMETRY.sigma_v, rel=0.15)
    assert noise.sigma_omega == pytest.approx(ODOMETRY.sigma_omega, rel=0.15)


def test_estimate_noise_pools_robots(with_outliers):
    res = estimate_noise(with_outliers)
    assert res["robots"] == [1, 2]
    assert res["measurement"].n == sum(p["measurement"].n for p in res["per_robot"].values())
    assert res["motion"].sigma_v == pytest.approx(ODOMETRY.sigma_v, rel=0.15)
    assert res["motion"].sigma_omega == pytest.approx(ODOMETRY.sigma_omega, rel=0.15)
    assert res["suspect"] == []


# --------------------------------------------------------------------------- bad input


def test_bad_inputs_raise_clearly(clean):
    log = clean.robots[1]
    blind = dataclasses.replace(log, groundtruth=None)
    with pytest.raises(ValueError, match="no groundtruth"):
        measurement_residuals(blind, clean)
    with pytest.raises(ValueError, match="no groundtruth"):
        odometry_increment_errors(blind)
    with pytest.raises(ValueError, match="no robot has groundtruth"):
        estimate_noise(dataclasses.replace(clean, robots={1: blind}))
    with pytest.raises(ValueError, match=r"robots \[9\]"):
        estimate_noise(clean, robots=[9])
    with pytest.raises(ValueError, match="whole number"):
        odometry_increment_errors(log, 0.5)
    with pytest.raises(ValueError, match="subjects"):
        measurement_residuals(log, clean.landmark_positions)
    with pytest.raises(ValueError, match=r"subjects \[6\]"):
        measurement_residuals(log, clean.landmarks.drop(index=6))
    m = log.measurements.copy()
    m.loc[5, "range"] = np.nan
    with pytest.raises(ValueError, match="row 5 has NaN"):
        measurement_residuals(dataclasses.replace(log, measurements=m), clean)
    gt = log.groundtruth.copy()
    gt.loc[3, "theta"] = np.inf
    with pytest.raises(ValueError, match="groundtruth row 3"):
        measurement_residuals(dataclasses.replace(log, groundtruth=gt), clean)
    with pytest.raises(ValueError, match="max_gap"):
        measurement_residuals(log, clean, max_gap=0)


# --------------------------------------------------------------------------- hand-made logs


def hand_log(t_gt, x, y, theta, v=0.0, omega=0.0, measurements=None, t_end=10.0) -> RobotLog:
    """A log written by hand: groundtruth rows as given, odometry (v, ω) constant at 10 Hz over [0, t_end]."""
    t_odo = np.round(np.arange(0.0, t_end + 1e-9, 0.1), 10)
    odo = pd.DataFrame({"time": t_odo, "v": v, "omega": omega})
    gt = pd.DataFrame({"time": np.asarray(t_gt, float), "x": np.asarray(x, float) * np.ones(len(t_gt)),
                       "y": np.asarray(y, float) * np.ones(len(t_gt)), "theta": np.asarray(theta, float) * np.ones(len(t_gt))})
    m = measurements if measurements is not None else pd.DataFrame(
        {"time": np.zeros(0), "subject": np.zeros(0, np.int64), "range": np.zeros(0), "bearing": np.zeros(0)})
    return RobotLog(robot=1, odometry=odo, measurements=m, groundtruth=gt, source="hand-made")


def test_usable_groundtruth_keeps_the_first_of_repeated_times():
    """Reference: the documented rule (times strictly increasing, a repeated time keeps its first row)."""
    log = hand_log([0.0, 1.0, 1.0, 2.0, 3.0], [0.0, 1.0, 9.0, 2.0, 3.0], 0.0, 0.0)
    gt = usable_groundtruth(log)
    assert gt["time"].tolist() == [0.0, 1.0, 2.0, 3.0]
    assert gt["x"].tolist() == [0.0, 1.0, 2.0, 3.0]


def test_measurements_on_a_row_or_across_a_gap_of_exactly_max_gap_are_kept():
    """Reference: hand count. Groundtruth every 1 s with a 3 s hole (4 → 7 s), max_gap = 1 s: a sighting between
    rows 1 s apart is kept, one on the row before the hole is kept, one inside the hole is skipped."""
    t_gt = [0, 1, 2, 3, 4, 7, 8, 9, 10]
    m = pd.DataFrame({"time": [2.5, 4.0, 5.0, 7.0], "subject": 6, "range": 2.0, "bearing": 0.0})
    log = hand_log(t_gt, 0.0, 0.0, 0.0, measurements=m)
    e = measurement_residuals(log, np.array([[2.0, 0.0]]), [6], max_gap=1.0)
    assert e["time"].tolist() == [2.5, 4.0, 7.0]
    assert e.attrs["n_in_gaps"] == 1 and e.attrs["n_outside_span"] == 0
    np.testing.assert_allclose(e["range_residual"], 0.0, atol=1e-12)


def test_bearing_residual_is_wrapped_behind_the_robot():
    """Closed form: a landmark straight behind is expected at bearing π; a reading of −π + 0.01 is 0.01 off."""
    m = pd.DataFrame({"time": [1.0], "subject": 6, "range": 2.0, "bearing": -np.pi + 0.01})
    log = hand_log([0, 1, 2], 0.0, 0.0, 0.0, measurements=m)
    e = measurement_residuals(log, np.array([[-2.0, 0.0]]), [6])
    assert e["bearing_residual"].iloc[0] == pytest.approx(0.01, abs=1e-12)


def test_window_ending_exactly_at_the_end_of_the_data_is_used():
    """Reference: hand count. Data over [0, 10] s exactly: ten 1 s windows [0, 1] … [9, 10]; noise-free odometry
    of a straight drive at 0.5 m/s, so every error is 0."""
    t = np.arange(11.0)
    e = odometry_increment_errors(hand_log(t, 0.5 * t, 0.0, 0.0, v=0.5), 1.0)
    assert e["t_start"].tolist() == list(range(10))
    np.testing.assert_allclose(e["ds_error"], 0.0, atol=1e-9)


def test_windows_overlapping_a_groundtruth_gap_are_dropped():
    """Reference: hand count. Rows at 0–4 s and 7–10 s (a 3 s gap), 2 s windows: [4, 6] and [6, 8] overlap the
    gap, [0, 2], [2, 4], [8, 10] do not."""
    t = np.array([0, 1, 2, 3, 4, 7, 8, 9, 10], float)
    e = odometry_increment_errors(hand_log(t, 0.5 * t, 0.0, 0.0, v=0.5), 2.0)
    assert e["t_start"].tolist() == [0.0, 2.0, 8.0]
    assert e.attrs["n_skipped"] == 2


def test_turn_error_is_wrapped_when_the_groundtruth_aliases_a_fast_spin():
    """Closed form: spinning at 4 rad/s seen by 1 Hz groundtruth, unwrapping reads each second's turn as
    4 − 2π; the odometry's 4 rad is the same heading change, so the (wrapped) error is 0."""
    t = np.arange(11.0)
    e = odometry_increment_errors(hand_log(t, 0.0, 0.0, wrap_angle(4.0 * t), omega=4.0), 1.0)
    assert len(e) == 10
    np.testing.assert_allclose(e["dtheta_error"], 0.0, atol=1e-9)


def test_measurement_noise_counts_short_outliers_and_uses_the_sample_std():
    """Reference: hand count (|e_r| > 0.5 m on either side) and Python's statistics.stdev / mean of the inliers."""
    er = [-1.0, 0.8, 0.01, -0.02, 0.03, 0.0]
    eb = [0.5, -0.5, 0.001, 0.002, -0.003, 0.004]
    m = measurement_noise(pd.DataFrame({"subject": 6, "range": 2.0, "range_residual": er, "bearing_residual": eb}))
    assert m.n_outliers == 2 and m.outlier_fraction == pytest.approx(2 / 6)
    assert m.range_std_inliers == pytest.approx(statistics.stdev(er[2:]), rel=1e-12)
    assert m.bearing_std_inliers == pytest.approx(statistics.stdev(eb[2:]), rel=1e-12)
    assert m.range_bias_mean == pytest.approx(statistics.mean(er[2:]), rel=1e-12)


def test_range_profile_default_bins_hold_every_residual():
    """Reference: hand count — the default 0.5 m bins reach past the largest expected range (2.9 m), so every
    residual lands in a bin."""
    r = np.array([0.2, 0.7, 1.1, 1.6, 2.2, 2.6, 2.9])
    frame = pd.DataFrame({"subject": 6, "range": r, "range_expected": r, "range_residual": 0.01 * np.arange(7),
                          "bearing_residual": 0.0})
    prof = range_noise_profile(frame, min_count=1)
    assert prof["n"].sum() == 7
    assert prof["r_high"].max() >= 2.9


def test_fit_range_noise_is_weighted_least_squares_with_weights_n():
    """Reference: the weighted normal equations (Aᵀ W A) c = Aᵀ W σ with W = diag(n), solved here."""
    prof = pd.DataFrame({"r_mid": [1.0, 2.0, 3.0], "n": [10, 100, 1000], "sigma_range": [0.05, 0.09, 0.10]})
    A = np.column_stack([np.ones(3), prof["r_mid"]])
    W = np.diag(prof["n"].to_numpy(float))
    ref = np.linalg.solve(A.T @ W @ A, A.T @ W @ prof["sigma_range"].to_numpy())
    np.testing.assert_allclose(fit_range_noise(prof), ref, rtol=1e-10)


def test_fit_random_walk_weights_single_window_and_negative_slope():
    """References: weighted normal equations with row weights √n / Var (standard error of a variance ∝ Var/√n);
    the documented closed forms σ² = Var/τ for one window and σ = 0 for a negative slope."""
    tab = pd.DataFrame({"window": [1.0, 2.0, 4.0], "n": [400, 200, 100],
                        "var_s": [1.5e-3, 2.0e-3, 4.4e-3], "var_theta": [3e-3, 5e-3, 1.1e-2]})
    fit = fit_random_walk(tab)
    A = np.column_stack([np.ones(3), tab["window"]])
    for col, c, slope in (("var_s", fit.intercept_s, fit.slope_s), ("var_theta", fit.intercept_theta, fit.slope_theta)):
        W = np.diag(tab["n"] / tab[col] ** 2)
        ref = np.linalg.solve(A.T @ W @ A, A.T @ W @ tab[col].to_numpy())
        np.testing.assert_allclose([c, slope], ref, rtol=1e-9)
    assert fit.sigma_v == pytest.approx(math.sqrt(fit.slope_s))
    one = fit_random_walk(tab.iloc[[2]])
    assert one.slope_s == pytest.approx(4.4e-3 / 4.0) and one.intercept_s == 0.0
    assert one.sigma_omega == pytest.approx(math.sqrt(1.1e-2 / 4.0))
    falling = fit_random_walk(tab.assign(var_s=[4e-3, 3e-3, 1e-3]))
    assert falling.slope_s < 0 and falling.sigma_v == 0.0


def test_thresholds_are_strict():
    """Reference: the documented rules — a glitch *exceeds* the threshold, a suspect landmark's offset is
    *above* max_offset — checked at exactly the threshold (0.5, representable exactly)."""
    theta = np.array([0.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0])  # row 3 is exactly 0.5 rad off its neighbours
    assert not heading_glitches(np.arange(7.0), theta, threshold=0.5).any()
    assert heading_glitches(np.arange(7.0), theta, threshold=0.49).tolist() == [False] * 3 + [True] + [False] * 3
    frame = pd.DataFrame({"subject": [6, 7], "range": 1.0, "range_residual": 0.0, "bearing_residual": 0.0,
                          "x_seen": [0.5, 3.0], "y_seen": [0.0, 0.6]})
    check = landmark_check(frame, np.array([[0.0, 0.0], [3.0, 0.0]]), [6, 7], max_offset=0.5)
    assert check["offset"].tolist() == [0.5, 0.6]
    assert check["suspect"].tolist() == [False, True]


def test_residual_correlation_of_an_ar1_error():
    """An AR(1) residual with coefficient φ, sampled every second: ρ(lag) = φ^lag (closed form); white noise: 0."""
    from fastslam_edu.evaluation.noise_estimation import residual_correlation

    rng = np.random.default_rng(0)
    n, phi = 20000, 0.8
    e = np.empty(n)
    e[0] = rng.standard_normal()
    for i in range(1, n):
        e[i] = phi * e[i - 1] + np.sqrt(1 - phi**2) * rng.standard_normal()
    frame = pd.DataFrame({"robot": 1, "subject": np.repeat([6, 7], n // 2), "time": np.tile(np.arange(n // 2.0), 2),
                          "bearing_residual": e, "range_residual": rng.standard_normal(n)})
    assert abs(residual_correlation(frame, 1.0, "bearing_residual") - phi) < 0.02
    assert abs(residual_correlation(frame, 4.0, "bearing_residual") - phi**4) < 0.03
    assert abs(residual_correlation(frame, 1.0, "range_residual")) < 0.03
    with pytest.raises(ValueError, match="no column"):
        residual_correlation(frame.drop(columns="subject"), 1.0, "bearing_residual")
    with pytest.raises(ValueError, match="fewer than 3 pairs"):
        residual_correlation(frame, 1e6, "bearing_residual")


#: What the chapters call as ``ne.<name>`` (notebooks 01–04, 09, 12, 20): the package keeps every one of them.
CHAPTER_NAMES = ("dead_reckoning", "estimate_noise", "fit_random_walk", "fit_range_noise", "heading_glitches",
                 "increment_variances", "landmark_check", "measurement_noise", "measurement_residuals", "motion_noise",
                 "odometry_increment_errors", "range_noise_profile", "relative_motion", "residual_correlation",
                 "robust_std", "usable_groundtruth")


def test_the_package_keeps_every_name_the_chapters_use():
    missing = [n for n in CHAPTER_NAMES if not callable(getattr(ne, n, None))]
    assert not missing, missing
    assert set(ne.__all__) >= set(CHAPTER_NAMES)
    assert ne.dead_reckoning is dead_reckon_at  # one function, the chapters' name for it
