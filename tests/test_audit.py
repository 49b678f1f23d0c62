"""Tests of fastslam_edu.evaluation.audit (landmark table vs its own measurements).

Reference: the simulator's truth. Its landmark table is exact, so every
landmark's median implied position lies within a few centimetres of its table
position. A table with rows exchanged is made here by hand, so the pair to
find and the positions to restore are known.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from fastslam_edu.evaluation.audit import COLUMNS, apply_landmark_audit, audit_landmarks, landmark_swaps
from fastslam_edu.datasets.sim import simulate_dataset



@pytest.fixture(scope="module")
def data():
    return simulate_dataset(3, duration=40.0)


def most_measured(data, count: int) -> list[int]:
    return data.robots[1].measurements["subject"].value_counts().index[:count].astype(int).tolist()


def exchanged(data, a: int, b: int):
    table = data.landmarks.copy()
    table.loc[[a, b], ["x", "y"]] = table.loc[[b, a], ["x", "y"]].to_numpy()
    return dataclasses.replace(data, landmarks=table)


@pytest.fixture(scope="module")
def pair(data):
    """The two most measured landmarks (7 and 14 here: ~100 sightings each, 2.2 m apart)."""
    a, b = sorted(most_measured(data, 2))
    assert np.hypot(*(data.landmarks.loc[a, ["x", "y"]] - data.landmarks.loc[b, ["x", "y"]])) > 1.0
    return a, b


def test_consistent_table_statistics(data):
    audit = audit_landmarks(data)
    assert list(audit.columns) == COLUMNS and audit.index.name == "subject"
    counts = data.robots[1].measurements["subject"].value_counts()
    assert sorted(audit.index) == sorted(counts.index)  # every measured landmark, nothing else
    np.testing.assert_array_equal(audit["n"].to_numpy(), counts.loc[audit.index].to_numpy())
    assert not audit["suspect"].any()  # nothing flagged
    many = audit[audit["n"] >= 30]
    assert (many["nearest"].to_numpy() == many.index.to_numpy()).all()
    assert len(many) >= 5
    assert (many["offset"] < 0.05).all(), many["offset"]
    assert landmark_swaps(audit) == []


def test_unswapped_dataset_is_unchanged(data):
    out, notes = apply_landmark_audit(data)
    assert notes == []
    pd.testing.assert_frame_equal(out.landmarks, data.landmarks)


def test_swapped_rows_are_found_and_restored(data, pair):
    a, b = pair
    bad = exchanged(data, a, b)
    audit = audit_landmarks(bad)
    for s, other in ((a, b), (b, a)):
        assert audit.loc[s, "suspect"]  # flagged
        assert audit.loc[s, "nearest"] == other
    others = audit.drop(index=[a, b])
    assert not others["suspect"].any()
    others = others[others["n"] >= 30]
    assert (others["nearest"].to_numpy() == others.index.to_numpy()).all()
    assert landmark_swaps(audit) == [(a, b)]
    fixed, notes = apply_landmark_audit(bad)
    pd.testing.assert_frame_equal(fixed.landmarks, data.landmarks)  # the original positions
    assert len(notes) == 1 and str(a) in notes[0] and str(b) in notes[0]
    # the input is not modified, and the robots are passed through
    assert bad.landmarks.loc[a, "x"] == data.landmarks.loc[b, "x"]
    assert fixed.robots is bad.robots


def test_robots_argument_and_two_swaps(data):
    a, b, c, d = most_measured(data, 4)
    bad = exchanged(exchanged(data, a, b), c, d)
    swaps = landmark_swaps(audit_landmarks(bad, robots=[1]))
    assert sorted(swaps) == sorted([tuple(sorted((a, b))), tuple(sorted((c, d)))])
    fixed, notes = apply_landmark_audit(bad)
    pd.testing.assert_frame_equal(fixed.landmarks, data.landmarks)
    assert len(notes) == 2
    # auditing with robots that are not in the dataset finds nothing to check
    assert audit_landmarks(bad, robots=[2]).empty


def test_a_three_way_rotation_is_flagged_but_not_swapped(data):
    """a's measurements fit b, b's fit c, c's fit a: no mutual pair, so nothing is exchanged."""
    a, b, c = most_measured(data, 3)
    table = data.landmarks.copy()
    table.loc[[a, b, c], ["x", "y"]] = table.loc[[b, c, a], ["x", "y"]].to_numpy()
    bad = dataclasses.replace(data, landmarks=table)
    audit = audit_landmarks(bad)
    assert audit.loc[[a, b, c], "suspect"].all()
    assert landmark_swaps(audit) == []
    out, notes = apply_landmark_audit(bad)
    assert notes == [] and out is bad


def test_rarely_seen_pair_is_not_trusted(data):
    """A pair with fewer than MIN_SIGHTINGS sightings each is flagged but not exchanged."""
    counts = data.robots[1].measurements["subject"].value_counts()
    rare = counts[counts < 20].index.astype(int).tolist()
    if len(rare) < 2:
        pytest.skip("no two rarely seen landmarks in this simulation")
    a, b = sorted(rare[:2])
    audit = audit_landmarks(exchanged(data, a, b))
    assert landmark_swaps(audit) == [] and landmark_swaps(audit, min_sightings=1) == [(a, b)]


def test_no_groundtruth_means_no_audit(data, pair):
    bad = exchanged(data, *pair)
    log = dataclasses.replace(bad.robots[1], groundtruth=None)
    blind = dataclasses.replace(bad, robots={1: log})
    audit = audit_landmarks(blind)
    assert audit.empty and list(audit.columns) == COLUMNS
    assert landmark_swaps(audit) == []
    out, notes = apply_landmark_audit(blind)
    assert notes == []
    pd.testing.assert_frame_equal(out.landmarks, blind.landmarks)


def test_a_robot_without_groundtruth_gets_the_table_checked_by_the_others(tmp_path):
    """load_mrclam audits the dataset's table with the robots that have groundtruth (Dataset 1, robots 3-5)."""
    from fastslam_edu.datasets.mrclam import write_dataset
    from fastslam_edu.app.experiment import load_mrclam

    two = simulate_dataset(3, duration=40.0, n_robots=2)
    a, b = sorted(two.robots[1].measurements["subject"].value_counts().index[:2].astype(int).tolist())
    folder = write_dataset(exchanged(two, a, b), tmp_path / "MRCLAM_Swapped")
    (folder / "Robot2_Groundtruth.dat").unlink()  # robot 2 has no groundtruth, robot 1 has
    data2, log2, notes2 = load_mrclam(folder, 2)
    assert log2.groundtruth is None
    assert len(notes2) == 1 and f"{a} and {b} exchanged" in notes2[0] and "[checked with robots 1]" in notes2[0]
    np.testing.assert_allclose(data2.landmarks[["x", "y"]].to_numpy(), two.landmarks[["x", "y"]].to_numpy(), atol=1e-6)
    assert list(data2.robots) == [2]  # the robot asked for, nothing else
    data1, _, notes1 = load_mrclam(folder, 1)  # a robot with groundtruth checks with its own
    assert len(notes1) == 1 and "checked with" not in notes1[0]
    np.testing.assert_array_equal(data1.landmarks.to_numpy(), data2.landmarks.to_numpy())
    _, _, kept = load_mrclam(folder, 2, audit=False)
    assert kept == []


def _audit_table(rows):
    """A hand-made audit table: rows (subject, n, nearest, suspect)."""
    frame = pd.DataFrame(rows, columns=["subject", "n", "nearest", "suspect"]).set_index("subject")
    return frame


def test_swap_rule_on_hand_made_audit_tables():
    """Reference: the documented rule — a pair is exchanged only if both are suspect, each is nearest the other,
    both are in the table and both have at least min_sightings sightings; a suspect landmark nearest its own
    position, or nearest a table entry that was never measured, is no pair."""
    assert landmark_swaps(_audit_table([(6, 20, 7, True), (7, 20, 6, True)])) == [(6, 7)]  # exactly 20 each
    assert landmark_swaps(_audit_table([(6, 50, 7, False), (7, 50, 6, True)])) == []  # 6 not suspect
    assert landmark_swaps(_audit_table([(6, 50, 7, True), (7, 50, 6, False)])) == []  # 7 not suspect
    assert landmark_swaps(_audit_table([(6, 50, 7, True), (7, 19, 6, True)])) == []  # 7 seen too rarely
    assert landmark_swaps(_audit_table([(6, 19, 7, True), (7, 50, 6, True)])) == []  # 6 seen too rarely
    assert landmark_swaps(_audit_table([(6, 50, 6, True), (7, 50, 7, False)])) == []  # off, but nearest itself
    assert landmark_swaps(_audit_table([(6, 50, 9, True), (7, 50, 7, False)])) == []  # 9 never measured


def test_a_robot_without_sightings_is_skipped(data):
    """Reference: the documented contract — only robots with groundtruth *and* sightings are used; with none left
    the audit is an empty table indexed by subject."""
    log = data.robots[1]
    silent = dataclasses.replace(data, robots={1: dataclasses.replace(log, measurements=log.measurements.iloc[:0])})
    audit = audit_landmarks(silent)
    assert audit.empty and list(audit.columns) == COLUMNS and audit.index.name == "subject"
    out, notes = apply_landmark_audit(silent)
    assert notes == [] and out is silent
