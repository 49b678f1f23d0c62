"""Kümmerle et al.'s relation error (fastslam_edu.evaluation.relations): closed forms, matrices, time matching, the summed-up scores."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from fastslam_edu.evaluation.relations import match_times, reference_errors, relation_errors, score_trajectory


def T(p):
    """Homogeneous 3×3 matrix of a pose (the independent reference for SE(2) algebra)."""
    x, y, th = p
    c, s = math.cos(th), math.sin(th)
    return np.array([[c, -s, x], [s, c, y], [0, 0, 1.0]])


def pose_of(M):
    return np.array([M[0, 2], M[1, 2], math.atan2(M[1, 0], M[0, 0])])


def random_path(rng, n=30):
    steps = np.column_stack([rng.uniform(0.1, 0.8, n), rng.normal(0, 0.05, n), rng.normal(0, 0.3, n)])
    poses = [np.zeros(3)]
    for s in steps[1:]:
        poses.append(pose_of(T(poses[-1]) @ T(s)))
    return np.array(poses)


def relations_from(t, poses, pairs, perturb=None):
    """Relations computed with matrices: δ = T(x_i)⁻¹ T(x_j), optionally perturbed."""
    rows = []
    for i, j in pairs:
        d = pose_of(np.linalg.inv(T(poses[i])) @ T(poses[j]))
        if perturb is not None:
            d = d + perturb
        rows.append([t[i], t[j], d[0], d[1], 0.0, 0.0, 0.0, d[2]])
    return pd.DataFrame(rows, columns=["t1", "t2", "x", "y", "z", "roll", "pitch", "yaw"])


def test_match_times_nearest_with_tolerance_and_ties():
    ts = np.array([0.0, 1.0, 2.0, 3.0])
    idx, ok = match_times([0.1, 1.5, 2.95, 10.0, -0.3], ts, tolerance=0.2)
    assert idx.tolist() == [0, 1, 3, 3, 0]  # 1.5 is a tie: the earlier scan
    assert ok.tolist() == [True, False, True, False, False]
    # scan times in any order, with a repeated stamp: indices refer to the original order, first copy wins
    idx, ok = match_times([1.9, 0.2, 3.0], [3.0, 0.0, 2.0, 2.0, 1.0], tolerance=0.2)
    assert idx.tolist() == [2, 1, 0] and ok.all()
    with pytest.raises(ValueError, match="NaN"):
        match_times([np.nan], ts)
    with pytest.raises(ValueError, match="tolerance"):
        match_times([0.5], ts, tolerance=-1e-3)
    with pytest.raises(ValueError, match="non-empty"):
        match_times([0.5], [])


def test_match_times_repeated_stamp_reached_from_above_gives_the_first_copy():
    """Reference: by hand, 2.1 is nearest to the stamp 2.0 held by scans 2 and 3; the first in the file wins."""
    idx, ok = match_times([2.1, 2.0, 1.9], [3.0, 0.0, 2.0, 2.0, 1.0], tolerance=0.2)
    assert idx.tolist() == [2, 2, 2] and ok.all()


def test_exact_estimate_has_zero_error_and_all_relations_are_used():
    rng = np.random.default_rng(0)
    poses = random_path(rng)
    t = 100.0 + np.arange(len(poses)) * 0.7
    pairs = [(i, i + 1) for i in range(len(poses) - 1)] + [(0, 20), (3, 29)]
    rel = relations_from(t, poses, pairs)
    out = relation_errors(t, poses, rel)
    assert out["n_used"] == out["n_relations"] == len(pairs)
    assert out["trans_mean"] < 1e-12 and out["rot_mean_deg"] < 1e-9


def test_known_perturbation_gives_the_closed_form_error():
    """Relations off by (a, b, γ) in translation: the translational error is √(a²+b²), the rotational |γ|."""
    rng = np.random.default_rng(1)
    poses = random_path(rng)
    t = np.arange(len(poses), dtype=float)
    a, b, g = 0.03, -0.04, math.radians(2.0)
    rel = relations_from(t, poses, [(i, i + 2) for i in range(len(poses) - 2)], perturb=np.array([a, b, g]))
    out = relation_errors(t, poses, rel)
    np.testing.assert_allclose(out["trans_errors"], 0.05, atol=1e-12)
    np.testing.assert_allclose(out["rot_errors_deg"], 2.0, atol=1e-9)
    assert out["trans_std"] < 1e-12


def test_error_of_one_moved_pose_against_matrices_and_invariance_to_the_frame():
    rng = np.random.default_rng(2)
    truth = random_path(rng)
    t = np.arange(len(truth), dtype=float)
    pairs = [(i, j) for i in range(0, 30, 3) for j in (i + 1, i + 7) if j < 30]
    rel = relations_from(t, truth, pairs)
    est = truth.copy()
    est[7] = pose_of(T(est[7]) @ T([0.1, -0.2, 0.05]))  # move one pose
    out = relation_errors(t, est, rel)
    expected_t, expected_r = [], []
    for i, j in pairs:  # independent: e = δ*⁻¹ (T_i⁻¹ T_j)
        e = np.linalg.inv(np.linalg.inv(T(truth[i])) @ T(truth[j])) @ (np.linalg.inv(T(est[i])) @ T(est[j]))
        expected_t.append(math.hypot(e[0, 2], e[1, 2]))
        expected_r.append(abs(math.degrees(math.atan2(e[1, 0], e[0, 0]))))
    np.testing.assert_allclose(out["trans_errors"], expected_t, atol=1e-12)
    np.testing.assert_allclose(out["rot_errors_deg"], expected_r, atol=1e-9)
    assert out["trans_mean"] == pytest.approx(np.mean(expected_t)) and out["trans_std"] == pytest.approx(np.std(expected_t))
    assert out["rot_mean_deg"] == pytest.approx(np.mean(expected_r))
    assert out["rot_std_deg"] == pytest.approx(np.std(expected_r)) and np.std(expected_r) > 0.1
    assert sum(e > 1e-9 for e in expected_t) >= 2
    # relations are relative: moving the whole estimate changes nothing
    G = T([5.0, -3.0, 1.2])
    moved = np.array([pose_of(G @ T(p)) for p in est])
    np.testing.assert_allclose(relation_errors(t, moved, rel)["trans_errors"], expected_t, atol=1e-9)


def test_unmatched_and_same_scan_relations_are_not_used():
    poses = random_path(np.random.default_rng(3), n=10)
    t = np.arange(10, dtype=float)
    rel = relations_from(t, poses, [(0, 1), (2, 5), (4, 6)])
    rel.loc[1, "t2"] = 5.01  # 10 ms off: unusable at 1 ms, usable at 20 ms
    rel.loc[2, "t2"] = 4.0005  # both ends on scan 4
    out = relation_errors(t, poses, rel, tolerance=1e-3)
    assert out["n_relations"] == 3 and out["n_used"] == 1 and out["used"].tolist() == [True, False, False]
    assert relation_errors(t, poses, rel, tolerance=0.02)["n_used"] == 2
    empty = relation_errors(t, poses, rel.iloc[1:2], tolerance=1e-3)
    assert empty["n_used"] == 0 and math.isnan(empty["trans_mean"])


def test_reference_errors_after_alignment():
    rng = np.random.default_rng(4)
    ref = random_path(rng, n=40)
    t = np.arange(40, dtype=float)
    G = T([2.0, 1.0, 0.7])  # a rigidly moved copy: zero error after alignment
    moved = np.array([pose_of(G @ T(p)) for p in ref])
    out = reference_errors(t, moved, t, ref)
    assert out["n_matched"] == 40 and out["rmse"] < 1e-9
    assert abs(out["rotation_deg"]) == pytest.approx(math.degrees(0.7), abs=1e-6)
    noisy = ref.copy()
    noisy[:, :2] += rng.normal(0, 0.1, (40, 2))
    out = reference_errors(t, noisy, t, ref)
    assert 0.05 < out["rmse"] < 0.15  # ≈ 0.1·√2 minus what the 3-parameter fit absorbs
    with pytest.raises(ValueError, match="time base"):
        reference_errors(t + 1000.0, noisy, t, ref)


def test_reference_errors_statistics_against_a_closed_form_alignment():
    """Reference: the 2-D least-squares rigid fit in closed form (angle from the centred cross/dot sums)."""
    rng = np.random.default_rng(6)
    ref = random_path(rng, n=25)
    est = np.array([pose_of(T([1.0, -2.0, 0.4]) @ T(p)) for p in ref])
    est[:, :2] += rng.normal(0, 0.2, (25, 2))
    t = np.arange(25, dtype=float)
    out = reference_errors(t, est, t, ref)
    a, b = est[:, :2] - est[:, :2].mean(0), ref[:, :2] - ref[:, :2].mean(0)
    ang = math.atan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    c, s = math.cos(ang), math.sin(ang)
    e = np.hypot(c * a[:, 0] - s * a[:, 1] - b[:, 0], s * a[:, 0] + c * a[:, 1] - b[:, 1])
    np.testing.assert_allclose(out["errors"], e, atol=1e-12)
    assert out["rmse"] == pytest.approx(math.sqrt(np.mean(e**2)))
    assert out["mean"] == pytest.approx(np.mean(e)) and out["max"] == pytest.approx(np.max(e))
    assert out["rotation_deg"] == pytest.approx(math.degrees(ang))


def test_reference_errors_pairs_the_same_log_by_index_even_with_a_repeated_stamp():
    """Reference: a rigidly moved copy has zero error once each scan is paired with its own reference pose."""
    ref = random_path(np.random.default_rng(7), n=12)
    t = np.arange(12, dtype=float)
    t[5] = t[4]  # a stamp printed twice
    moved = np.array([pose_of(T([0.5, 0.5, -1.0]) @ T(p)) for p in ref])
    out = reference_errors(t, moved, t, ref)
    assert out["n_matched"] == 12 and out["max"] < 1e-9


def test_reference_errors_needs_two_matched_times():
    """Reference: a rigid fit needs at least two points; one matching time stamp is refused."""
    ref = random_path(np.random.default_rng(8), n=6)
    t_ref = np.arange(6, dtype=float)
    t = np.array([2.0, 100.0, 200.0])
    with pytest.raises(ValueError, match="only 1 of 3"):
        reference_errors(t, ref[:3], t_ref, ref)


def test_bad_input_is_rejected():
    poses = random_path(np.random.default_rng(5), n=5)
    t = np.arange(5, dtype=float)
    rel = relations_from(t, poses, [(0, 1)])
    bad = poses.copy()
    bad[2, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        relation_errors(t, bad, rel)
    with pytest.raises(ValueError, match="column"):
        relation_errors(t, poses, rel.drop(columns=["yaw"]))
    with pytest.raises(ValueError, match="shape|must be"):
        relation_errors(t[:3], poses, rel)


def test_score_trajectory_sums_up_both_errors_in_plain_numbers():
    """Reference: relation_errors and reference_errors, called directly; the scores are their statistics renamed."""
    rng = np.random.default_rng(9)
    truth = random_path(rng)
    t = 50.0 + np.arange(len(truth))
    rel = relations_from(t, truth, [(i, i + 3) for i in range(len(truth) - 3)])
    est = truth.copy()
    est[:, :2] += rng.normal(0, 0.05, est[:, :2].shape)
    s = score_trajectory(t, est, relations=rel, reference=(t, truth), tolerance=1e-3)
    e, r = relation_errors(t, est, rel), reference_errors(t, est, t, truth)
    assert s["relations"] == {"n_relations": e["n_relations"], "n_used": e["n_used"], "trans_mean_m": e["trans_mean"],
                              "trans_std_m": e["trans_std"], "rot_mean_deg": e["rot_mean_deg"],
                              "rot_std_deg": e["rot_std_deg"]}
    assert s["reference"] == {"n_matched": r["n_matched"], "rmse_m": r["rmse"], "mean_m": r["mean"], "max_m": r["max"]}
    assert s["relations"]["trans_mean_m"] > 0.01 and s["reference"]["rmse_m"] > 0.01
    json.dumps(s, allow_nan=False)  # plain numbers
    assert score_trajectory(t, est) == {"reference": None, "relations": None}
    assert score_trajectory(t, est, relations=rel)["reference"] is None


def test_score_trajectory_writes_none_where_no_relation_is_usable():
    """Relations in another time base: none usable, so the statistics are None (JSON null), not NaN."""
    poses = random_path(np.random.default_rng(10), n=8)
    t = np.arange(8, dtype=float)
    rel = relations_from(t - 1000.0, poses, [(0, 1), (2, 5)])
    s = score_trajectory(t, poses, relations=rel)["relations"]
    assert s == {"n_relations": 2, "n_used": 0, "trans_mean_m": None, "trans_std_m": None, "rot_mean_deg": None,
                 "rot_std_deg": None}
