"""Registration without correspondences (evaluation.registration), checked against known motions and against the
least-squares fit with the correspondences known (evaluation.metrics.align_se2)."""

import math

import numpy as np
import pytest

from fastslam_edu.evaluation import association as score
from fastslam_edu.evaluation.metrics import align_se2
from fastslam_edu.evaluation.registration import (PARTNERS, best_motion, consensus_motion, count_inliers, motion_of_two,
                                                  nearest_partners, pair_windows, pairs_by_distance, point_grid, register)


def turned(points, angle, shift):
    c, s = math.cos(angle), math.sin(angle)
    return np.asarray(points) @ np.array([[c, -s], [s, c]]).T + shift


def survey_and_map(seed, angle=1.2, shift=(-8.0, 3.0), noise=0.05, spurious=6, missing=3):
    """Surveyed landmarks (15, 2), and a map of them moved by a rigid motion, with noise, without ``missing`` of
    them and with ``spurious`` landmarks of nothing; returns (truth, estimate, index of the truth of each)."""
    rng = np.random.default_rng(seed)
    truth = rng.uniform(-5, 5, (15, 2))
    kept = np.arange(missing, 15)
    estimate = turned(truth[kept], angle, shift) + rng.normal(0, noise, (len(kept), 2))
    estimate = np.vstack([estimate, turned(rng.uniform(-5, 5, (spurious, 2)), angle, shift)])
    return truth, estimate, np.concatenate([kept, np.full(spurious, -1)])


def test_motion_of_two_maps_a_pair_onto_a_pair_moved_by_a_known_motion():
    rng = np.random.default_rng(1)
    for _ in range(20):
        a = rng.uniform(-5, 5, (2, 2))
        angle, shift = rng.uniform(-3, 3), rng.uniform(-10, 10, 2)
        b = turned(a, angle, shift)
        phi, tx, ty = motion_of_two(a[0], a[1], b[0], b[1])
        assert math.isclose(math.remainder(phi - angle, 2 * math.pi), 0.0, abs_tol=1e-9)
        np.testing.assert_allclose(turned(a, phi, (tx, ty)), b, atol=1e-9)


def test_count_inliers_counts_points_within_the_radius():
    A = np.array([[0.0, 0.0], [1.0, 0.0], [5.0, 5.0]])
    B = np.array([[0.1, 0.0], [1.0, 0.45]])
    count, cost = count_inliers(A, B, point_grid(B, 0.5), (0.0, 0.0, 0.0), 0.5)
    assert count == 2 and cost == pytest.approx(0.1 + 0.45)
    assert count_inliers(A, B, point_grid(B, 0.5), (0.0, 0.0, 0.0), 0.5, 3) == (-1, math.inf)  # 3 out of reach


@pytest.mark.parametrize("spread", [10.0, 5000.0])  # 5 km: the grid's cells grow past the radius
def test_the_grid_counts_what_every_distance_counts(spread):
    """count_inliers looks only at the 3x3 cells around each moved point; numpy's every-pair distances agree."""
    rng = np.random.default_rng(4)
    B = rng.uniform(-spread, spread, (60, 2))
    grid = point_grid(B, 0.5)
    for _ in range(30):
        A = np.vstack([B[rng.choice(60, 20)] + rng.normal(0, 0.4, (20, 2)), rng.uniform(-spread, spread, (20, 2))])
        motion = (rng.uniform(-0.01, 0.01), rng.normal(0, 0.1), rng.normal(0, 0.1))
        moved = turned(A, motion[0], motion[1:])
        nearest = np.linalg.norm(moved[:, None] - B[None], axis=-1).min(axis=1)
        count, cost = count_inliers(A, B, grid, motion, 0.5)
        assert count == np.sum(nearest <= 0.5) and cost == pytest.approx(nearest[nearest <= 0.5].sum())


def test_pairs_by_distance_are_every_ordered_pair_sorted():
    B = np.random.default_rng(5).uniform(-5, 5, (7, 2))
    dist, first, second = pairs_by_distance(B)
    assert len(dist) == 42 and (np.diff(dist) >= 0).all() and (first != second).all()
    assert {(int(a), int(b)) for a, b in zip(first, second)} == {(a, b) for a in range(7) for b in range(7) if a != b}
    np.testing.assert_allclose(dist, np.linalg.norm(B[second] - B[first], axis=1))


@pytest.mark.parametrize("seed", range(5))
def test_register_finds_the_motion_that_least_squares_finds_with_the_correspondences_known(seed):
    """A map turned by 1.2 rad and moved 8.5 m, with 3 landmarks missing and 6 spurious: the consensus motion is
    within the noise of the least-squares motion fitted to the true pairs (align_se2), and so is its inverse of the
    motion the map was made with."""
    truth, estimate, of = survey_and_map(seed)
    R, t = register(estimate, truth)
    known = of >= 0
    R_ls, t_ls, _ = align_se2(estimate[known], truth[of[known]])
    assert math.isclose(math.atan2(R[1, 0], R[0, 0]), math.atan2(R_ls[1, 0], R_ls[0, 0]), abs_tol=0.05)
    np.testing.assert_allclose(estimate[known] @ R.T + t, estimate[known] @ R_ls.T + t_ls, atol=0.25)
    np.testing.assert_allclose(estimate[known] @ R.T + t, truth[of[known]], atol=0.3)


def test_matching_without_a_start_registers_the_map_first():
    truth, estimate, of = survey_and_map(7)
    match = score.match_landmarks(estimate, truth)
    assert match.tolist() == of.tolist()
    assert np.sum(score.match_landmarks(estimate, truth, register=False) == of) <= 6  # the spurious ones, unmatched
    assert score.landmarks_spurious(estimate, truth) == 6


def test_a_wrong_start_is_overruled_by_the_registration():
    """The path's motion says the map is where it is; the map is in fact turned by 1.2 rad: the registration's
    matching has more pairs, and is kept."""
    truth, estimate, of = survey_and_map(8)
    wrong = (np.eye(2), np.zeros(2))
    assert score.match_landmarks(estimate, truth, start=wrong).tolist() == of.tolist()
    assert np.sum(score.match_landmarks(estimate, truth, start=wrong, register=False) >= 0) <= 3


def test_register_without_a_proposal_and_with_bad_input():
    assert register([[0.0, 0.0]], [[1.0, 1.0], [2.0, 2.0]]) is None  # one landmark fixes no rotation
    assert register([[0.0, 0.0], [0.5, 0.0]], [[1.0, 1.0], [1.5, 1.0]]) is None  # closer than min_baseline
    count, *_ = consensus_motion(np.zeros((0, 2)), np.ones((3, 2)), 0.5, 1.0)
    assert count == 0
    with pytest.raises(ValueError, match="register: estimate contains a non-finite value"):
        register([[0.0, np.nan], [2.0, 0.0]], [[0.0, 0.0], [2.0, 0.0]])
    with pytest.raises(ValueError, match="register: truth must have shape"):
        register([[0.0, 0.0], [2.0, 0.0]], [0.0, 0.0, 2.0])
    with pytest.raises(ValueError, match="radius > 0"):
        register([[0.0, 0.0], [2.0, 0.0]], [[0.0, 0.0], [2.0, 0.0]], radius=0.0)


def test_the_consensus_runs_as_plain_python_with_the_same_result():
    truth, estimate, _ = survey_and_map(3)
    compiled = consensus_motion(estimate, truth, 0.5, 1.0)
    partners, pairs = nearest_partners(estimate, 1.0), pairs_by_distance(truth)
    inputs = (estimate, truth, partners, pairs, pair_windows(estimate, partners, pairs[0], 0.5), point_grid(truth, 0.5),
              0.5)
    plain = getattr(best_motion, "py_func", best_motion)(*inputs)
    assert compiled[0] > 10 and plain[0] == compiled[0] and np.allclose(plain[1:], compiled[1:], atol=1e-12)


def test_nearest_partners_are_the_nearest_far_enough_by_every_distance():
    """Each point's partners are, in order, its nearest other points at least min_baseline away (checked against
    a loop over every pair); -1 fills the rows with fewer."""
    rng = np.random.default_rng(6)
    A = np.vstack([rng.uniform(-3, 3, (12, 2)), [[10.0, 10.0]]])  # one far point: partners too
    partners = nearest_partners(A, 1.0)
    assert partners.shape == (13, PARTNERS)
    for i in range(13):
        d = [(math.dist(A[i], A[j]), j) for j in range(13) if j != i and math.dist(A[i], A[j]) >= 1.0]
        expected = [j for _, j in sorted(d)][:PARTNERS]
        assert partners[i].tolist() == expected + [-1] * (PARTNERS - len(expected))
    assert nearest_partners(np.array([[0.0, 0.0], [0.5, 0.0]]), 1.0).tolist() == [[-1] * PARTNERS] * 2


def test_pair_windows_hold_the_pairs_as_far_apart_and_no_other():
    """Each window [start, stop) of the sorted pair distances holds exactly the pairs of B whose distance is within
    2 radius of that of the point and its partner (checked against every pair); a missing partner's is empty."""
    rng = np.random.default_rng(7)
    A, B = rng.uniform(-4, 4, (9, 2)), rng.uniform(-4, 4, (8, 2))
    partners, (dist, _, _) = nearest_partners(A, 1.0), pairs_by_distance(B)
    partners[0, -1] = -1
    windows = pair_windows(A, partners, dist, 0.3)
    for i1 in range(9):
        for q, i2 in enumerate(partners[i1]):
            inside = set(range(*windows[i1, q]))
            expected = set() if i2 < 0 else {p for p in range(len(dist)) if abs(dist[p] - math.dist(A[i1], A[i2])) <= 0.6}
            assert inside == expected
