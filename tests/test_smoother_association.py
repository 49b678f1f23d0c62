"""Data association re-decided in the smoother (fastslam_edu.landmark.smoother_association) and its references from the
true correspondences (fastslam_edu.evaluation.smoother_bounds), on simulated data."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

from fastslam_edu.core.se2 import compose, relative
from fastslam_edu.datasets.events import event_stream
from fastslam_edu.datasets.sim import SimConfig, simulate_dataset
from fastslam_edu.evaluation import association as score
from fastslam_edu.evaluation.smoother_bounds import smoother_bounds, true_labels
from fastslam_edu.landmark import smoother_association as sa
from fastslam_edu.landmark.association import AssociationParams, run_unknown
from fastslam_edu.landmark.fastslam import FastSLAMParams
from fastslam_edu.landmark.smoother_association_solve import banded_upper, schur_step

SIM_FILTER = FastSLAMParams(n_particles=30, measurement_cov=np.diag([0.05**2, 0.02**2]), range_std_slope=0.0)
SIM_PARAMS = AssociationParams(filter=SIM_FILTER, max_range=5.0, fov=1.0)


@pytest.fixture(scope="module")
def sim():
    data = simulate_dataset(0, SimConfig(duration=120.0))
    stream = event_stream(data.robots[1], data.landmark_subjects)
    return data, stream, run_unknown(stream, SIM_PARAMS, 0)


def accuracy(history, ident, landmarks, data, truth):
    return score.association_accuracy(history, truth, ident, score.match_landmarks(landmarks, data.landmark_positions))


def test_smoother_beats_the_filter_and_reaches_the_truth(sim):
    data, stream, filt = sim
    truth = stream.landmark
    s = sa.smooth_association(stream, filt)
    a_filter = accuracy(filt.history, filt.landmark_ident, filt.landmarks, data, truth)
    a_smooth = accuracy(s.history, s.landmark_ident, s.landmarks, data, truth)
    assert a_smooth >= a_filter and a_smooth >= 0.99
    assert np.sum(score.match_landmarks(s.landmarks, data.landmark_positions) < 0) == 0
    again = sa.smooth_association(stream, filt)  # no random step: same numbers
    assert np.array_equal(again.history, s.history) and again.cost == s.cost


def test_assignment_never_gives_one_landmark_two_sightings_of_a_frame():
    rng = np.random.default_rng(0)
    for _ in range(200):
        s, N = rng.integers(1, 6), rng.integers(0, 6)
        d2 = rng.uniform(0, 10, (s, N))
        chosen = sa.assign_frame(d2, 13.8, 13.8)
        used = chosen[(chosen >= 0) & (chosen < N)]
        assert len(used) == len(set(used.tolist()))
        # every sighting fits every landmark: all go to distinct landmarks while any is left
        assert np.sum((chosen >= 0) & (chosen < N)) == min(s, N)


def _log_and_truth(sim):
    data, stream, filt = sim
    log = sa.prepare_log(stream, SIM_FILTER, None, SIM_PARAMS)
    return data, stream, filt, log, sa.SmootherAssociationParams()


def test_a_planted_merge_is_split(sim):
    data, stream, filt, log, settings = _log_and_truth(sim)
    truth = stream.landmark.copy()
    moved = data.landmark_positions.copy()
    k, j = 0, 1  # plant: landmark j moved 0.2 m from k, and both given one label
    counts = np.bincount(truth, minlength=len(moved))
    k, j = np.argsort(-counts)[:2]
    labels = np.where(truth == j, k, truth)
    state = sa.alternate(log, filt.pose_mean[log.keys], labels, moved, settings)
    table = score.association_table(state.labels, truth, np.arange(len(state.landmarks)), len(moved))
    assert int(np.sum(table[:, k] > 0.8 * counts[k])) == 1 and int(np.sum(table[:, j] > 0.8 * counts[j])) == 1
    assert np.argmax(table[:, k]) != np.argmax(table[:, j])


def test_a_planted_split_is_merged(sim):
    data, stream, filt, log, settings = _log_and_truth(sim)
    truth = stream.landmark.copy()
    k = int(np.argmax(np.bincount(truth)))
    i = np.flatnonzero(truth == k)
    labels = truth.copy()
    labels[i[len(i) // 2:]] = truth.max() + 1  # the second half of its sightings as another landmark
    lms = np.vstack([data.landmark_positions, data.landmark_positions[k] + [0.05, 0.0]])
    state = sa.alternate(log, filt.pose_mean[log.keys], labels, lms, settings)
    assert len(np.unique(state.labels[i])) == 1 and state.labels[i[0]] >= 0


def _block_tridiagonal_system(rng, n_poses, n_landmarks):
    """A random symmetric positive definite A: block-tridiagonal 3x3 pose blocks, a dense-ish landmark border."""
    P, L = 3 * n_poses, 2 * n_landmarks
    J = np.zeros((3 * n_poses + 2 * 4 * n_landmarks, P + L))
    row = 0
    for k in range(n_poses - 1):  # odometry-like rows tie pose k to k+1
        J[row:row + 3, 3 * k:3 * k + 6] = rng.normal(size=(3, 6))
        row += 3
    J[row:row + 3, :3] = np.eye(3)
    row += 3
    for j in range(n_landmarks):  # sighting-like rows tie a pose to a landmark
        for k in rng.choice(n_poses, 4, replace=False):
            J[row:row + 2, 3 * k:3 * k + 3] = rng.normal(size=(2, 3))
            J[row:row + 2, P + 2 * j:P + 2 * j + 2] = rng.normal(size=(2, 2))
            row += 2
    A = J[:row].T @ J[:row] + 1e-3 * np.eye(P + L)
    return A, rng.normal(size=P + L), P


def test_schur_step_solves_the_normal_equations_as_a_dense_solver():
    from scipy.sparse import csc_matrix

    from fastslam_edu.landmark.smoother_association_solve import schur_step
    rng = np.random.default_rng(1)
    for n_poses, n_landmarks in [(5, 0), (12, 3), (40, 7)]:
        A, g, P = _block_tridiagonal_system(rng, n_poses, n_landmarks)
        step = schur_step(csc_matrix(A), g, P)
        assert np.allclose(step, np.linalg.solve(A, -g), rtol=1e-8, atol=1e-10)
    A[0, 9] = A[9, 0] = 0.5  # pose 0 tied to pose 3: not banded, the caller's general solver takes it
    assert schur_step(csc_matrix(A), g, P) is None


def test_the_association_solve_is_the_smoothers_solve(sim):
    from fastslam_edu.landmark.smoother import PRIOR_STD, build_problem, levenberg_marquardt
    from fastslam_edu.landmark.smoother_association_solve import levenberg_marquardt_schur
    data, stream, filt, log, settings = _log_and_truth(sim)
    problem, seen, _ = build_problem(stream, SIM_FILTER, log.keys, log.path, log.x0, PRIOR_STD, tempering=False)
    v = np.concatenate([filt.pose_mean[log.keys].ravel(), data.landmark_positions[seen].ravel()])
    v[1::3] += 0.05  # off the filter's path: several steps to take
    problem.anchor = problem.split(v)[1].copy()
    active = np.ones(len(problem.z), dtype=bool)
    a, it_a, cost_a = levenberg_marquardt_schur(problem, v, active, huber=1.0, max_iterations=50, tol=1e-12)
    b, it_b, cost_b = levenberg_marquardt(problem, v, active, huber=1.0, max_iterations=50, tol=1e-12)
    assert it_a > 1 and np.allclose(a, b, atol=1e-8) and abs(cost_a - cost_b) <= 1e-9 * cost_b


def test_several_filter_runs_compete_by_cost(sim):
    data, stream, filt = sim
    other = run_unknown(stream, SIM_PARAMS, 1)
    alone = [sa.smooth_association(stream, run) for run in (filt, other)]
    both = sa.smooth_association(stream, [filt, other])
    assert both.costs == alone[0].costs + alone[1].costs
    assert both.cost == min(a.cost for a in alone)
    assert np.array_equal(both.history, min(alone, key=lambda a: a.cost).history)
    # the incremental start reads no run: it is tried once, last
    inc = sa.SmootherAssociationParams(incremental_start=True)
    both_inc = sa.smooth_association(stream, [filt, other], settings=inc)
    alone_inc = sa.smooth_association(stream, filt, settings=inc)
    assert both_inc.costs == alone[0].costs + alone[1].costs + alone_inc.costs[-1:]
    short = dataclasses.replace(other, t=other.t[:-1])
    with pytest.raises(ValueError, match="the filter ran"):
        sa.smooth_association(stream, [filt, short])


def test_predict_pose_jacobian_is_the_numerical_one():
    from fastslam_edu.core.se2 import compose
    x, u, P = np.array([1.0, -2.0, 0.7]), np.array([0.8, 0.3, -0.2]), np.diag([0.01, 0.02, 0.03])
    moved, P2 = sa.predict_pose(x, P, u, np.zeros((3, 3)))
    F = np.empty((3, 3))
    for i in range(3):  # central differences of x ⊕ u
        e = np.zeros(3)
        e[i] = 1e-6
        F[:, i] = (sa.predict_pose(x + e, P, u, 0 * P)[0] - sa.predict_pose(x - e, P, u, 0 * P)[0]) / 2e-6
    assert np.allclose(moved, compose(x, u)) and np.allclose(P2, F @ P @ F.T, atol=1e-9)


def test_localise_is_the_information_form_update():
    from fastslam_edu.core.measurement import jacobian_landmark, jacobian_pose, range_bearing
    x, P = np.array([0.5, 0.2, 0.3]), np.diag([0.04, 0.04, 0.01])
    L = np.array([[3.0, 1.0], [2.0, -1.5], [4.0, 3.0]])
    C = np.repeat(np.eye(2)[None] * 0.01, 3, axis=0)
    R = np.repeat(np.diag([0.05**2, 0.02**2])[None], 3, axis=0)
    z = range_bearing(np.tile(x + [0.1, -0.05, 0.02], (3, 1)), L)
    new, P2 = sa.localise(x, P, z, R, L, C)
    # information form: P'^-1 = P^-1 + sum Hx^T (R + Hl C Hl^T)^-1 Hx,  x' = x + P' sum Hx^T S^-1 nu
    info, grad = np.linalg.inv(P), np.zeros(3)
    for i in range(3):
        Hx, Hl = jacobian_pose(x[None], L[i][None])[0], jacobian_landmark(x[None], L[i][None])[0]
        Si = np.linalg.inv(R[i] + Hl @ C[i] @ Hl.T)
        info += Hx.T @ Si @ Hx
        nu = z[i] - range_bearing(x[None], L[i][None])[0]
        nu[1] = np.angle(np.exp(1j * nu[1]))
        grad += Hx.T @ Si @ nu
    assert np.allclose(P2, np.linalg.inv(info), atol=1e-10)
    assert np.allclose(new, x + np.linalg.inv(info) @ grad, atol=1e-10)


def test_incremental_start_stays_on_the_path_dead_reckoning_leaves(sim):
    from fastslam_edu.datasets.events import groundtruth_at
    data, stream, filt, log, settings = _log_and_truth(sim)
    poses, labels, landmarks = sa.incremental_start(log, settings)
    truth = groundtruth_at(data.robots[1], stream.t[log.keys])
    error = np.sqrt(np.mean(np.sum((poses[:, :2] - truth[:, :2]) ** 2, axis=1)))
    dead = np.sqrt(np.mean(np.sum((log.path[log.keys, :2] - truth[:, :2]) ** 2, axis=1)))
    assert error < 0.4 * dead
    assert accuracy(labels, np.arange(len(landmarks)), landmarks, data, stream.landmark) >= 0.95


def test_the_incremental_start_is_one_more_start_competing_by_cost(sim):
    """With incremental_start (off by default) the smoother tries one start more, and keeps the lowest final cost:
    never above the cost without it."""
    data, stream, filt = sim
    without = sa.smooth_association(stream, filt)
    with_it = sa.smooth_association(stream, filt, settings=sa.SmootherAssociationParams(incremental_start=True))
    assert not sa.SmootherAssociationParams().incremental_start
    assert len(with_it.costs) == len(without.costs) + 1
    assert with_it.cost <= without.cost + 1e-9
    assert with_it.cost == min(with_it.costs)


def twisted(pose_mean, angle):
    """The path turned by ``angle`` [rad] about its pose half-way: everything after it swings round."""
    h = len(pose_mean) // 2
    out = pose_mean.copy()
    pivot = out[h] + np.array([0.0, 0.0, angle])
    out[h:] = compose(np.broadcast_to(pivot, (len(out) - h, 3)), relative(np.broadcast_to(out[h], (len(out) - h, 3)),
                                                                           out[h:]))
    return out


def test_true_labels_make_clutter_an_outlier():
    assert true_labels([2, -1, 0, -1]).tolist() == [2, sa.OUTLIER, 0, sa.OUTLIER]


def test_the_smoothers_references_do_not_depend_on_the_filters_path(sim):
    """From a filter path swung 0.5 rad half-way, both references start from the true correspondences and solve
    their own path (the same, within 5 mm, as from the filter's own path, 1.8 m away): the truth keeps every sighting
    and the path-given bound reassigns them all correctly. On this easy log the smoother, from the same bad path,
    finds the truth too, at the same cost: J and J* are on one scale."""
    data, stream, filt = sim
    truth_index = stream.landmark
    bad = dataclasses.replace(filt, pose_mean=twisted(np.asarray(filt.pose_mean), 0.5))
    truth, given = smoother_bounds(stream, truth_index, bad)
    for r in (truth, given):
        assert accuracy(r.history, r.landmark_ident, r.landmarks, data, truth_index) >= 0.99
    assert np.sum(score.match_landmarks(given.landmarks, data.landmark_positions) < 0) == 0
    straight, _ = smoother_bounds(stream, truth_index, filt)  # from the filter's own path: the same optimum
    assert np.abs(truth.poses - straight.poses).max() < 0.005 < 1.0 < np.abs(bad.pose_mean - filt.pose_mean).max()
    assert truth.cost == pytest.approx(straight.cost, rel=1e-5)
    smoothed = sa.smooth_association(stream, bad, settings=sa.SmootherAssociationParams(restarts=1))
    assert smoothed.cost == pytest.approx(truth.cost, rel=1e-5)  # here the smoother finds the truth: J on one scale
    assert accuracy(smoothed.history, smoothed.landmark_ident, smoothed.landmarks, data, truth_index) >= 0.99
    again = smoother_bounds(stream, truth_index, bad)  # no random step: the same numbers
    assert again[0].cost == truth.cost and np.array_equal(again[1].history, given.history)


def test_the_smoothers_references_name_bad_input(sim):
    data, stream, filt = sim
    with pytest.raises(ValueError, match="true_index has shape"):
        smoother_bounds(stream, stream.landmark[:-1], filt)
    short = dataclasses.replace(stream, t=stream.t[:10], dt=stream.dt[:10], u=stream.u[:10],
                                offsets=stream.offsets[:11], z=stream.z[:stream.offsets[10]],
                                landmark=stream.landmark[:stream.offsets[10]])
    with pytest.raises(ValueError, match="the filter ran"):
        smoother_bounds(short, short.landmark, filt)


def test_a_landmark_seen_only_for_a_while_is_transient(sim):
    """static_against_transient against a loop over the camera frames with the filter's own in_view: Λ = n_out
    log((1 - p_D)/(1 - p_F)) + ln n_view for every landmark. The most-seen landmark given only its sightings of the
    middle third (another robot that stood there, then left) is transient (Λ <= 0): transient_outliers makes its
    sightings outliers, and the smoother's final step (without_transients) drops it from the map; every other
    landmark seen stays static and kept."""
    from fastslam_edu.landmark.landmark_existence import in_view
    from fastslam_edu.landmark.smoother_association_moves import static_against_transient

    data, stream, filt, log, settings = _log_and_truth(sim)
    truth = stream.landmark.copy()
    k = int(np.argmax(np.bincount(truth)))
    i = np.flatnonzero(truth == k)
    t = stream.t[log.frame[i]]
    third = (t[-1] - t[0]) / 3
    labels = truth.copy()
    labels[i[(t < t[0] + third) | (t > t[-1] - third)]] = sa.OUTLIER
    poses, landmarks = filt.pose_mean[log.keys], data.landmark_positions
    lam = static_against_transient(log, poses, labels, landmarks)
    rules, p_d, p_f = SIM_PARAMS.rules(), SIM_PARAMS.detection_probability, SIM_PARAMS.clutter_probability
    frames = np.flatnonzero(np.diff(stream.offsets)).tolist()
    for j in range(len(landmarks)):
        seen = set(log.frame[labels == j].tolist())
        view = [in_view(poses[np.searchsorted(log.keys, f)], landmarks[j], rules) for f in frames]
        if not seen:
            continue
        n_out = sum(v and f not in seen and not min(seen) <= f <= max(seen) for f, v in zip(frames, view))
        n_view = sum(v or f in seen for f, v in zip(frames, view))
        assert lam[j] == pytest.approx(n_out * np.log((1 - p_d) / (1 - p_f)) + np.log(n_view)), j
    others = [j for j in range(len(landmarks)) if j != k and np.any(labels == j)]  # (a landmark never seen: none)
    assert lam[k] <= 0 < lam[others].min()
    dropped = sa.transient_outliers(log, poses, labels, landmarks)
    assert np.all(dropped[labels == k] == sa.OUTLIER)
    assert np.array_equal(dropped[labels != k], labels[labels != k])
    lms, cov, _ = sa.fit_map(log, poses, labels, len(landmarks))
    final = sa.without_transients(log, sa._State(poses, lms, cov, labels), settings)  # the smoother's last step
    assert np.all(final.labels[labels == k] == sa.OUTLIER)
    assert len(final.landmarks) == np.unique(labels[labels >= 0]).size - 1


def test_gate_is_the_chi2_quantile_with_two_degrees_of_freedom():
    from scipy.stats import chi2
    for p in (0.9, 0.99, 0.999, 1.0 - 1e-6):
        g = sa.SmootherAssociationParams(gate_probability=p).gate
        assert g == pytest.approx(chi2.ppf(p, 2), rel=1e-12)


def test_schur_step_solves_the_normal_equations():
    """Poses first, block tridiagonal (3 x 3 blocks), then landmarks: the same step as a dense solve of the whole
    system; a pose block with an entry outside the band is left to the general solver (None)."""
    rng = np.random.default_rng(3)
    n_poses, n_lm = 40, 5
    P, V = 3 * n_poses, 3 * n_poses + 2 * n_lm
    J = np.zeros((3 * (n_poses - 1) + 3 + 60, V))
    J[:3, :3] = np.eye(3)
    for k in range(n_poses - 1):  # odometry: keyframe k against k + 1
        J[3 + 3 * k:6 + 3 * k, 3 * k:3 * k + 6] = rng.normal(size=(3, 6))
    for r in range(3 * n_poses, len(J)):  # sightings: one pose, one landmark
        k, j = rng.integers(n_poses), rng.integers(n_lm)
        J[r, 3 * k:3 * k + 3], J[r, P + 2 * j:P + 2 * j + 2] = rng.normal(size=3), rng.normal(size=2)
    A = J.T @ J + 1e-3 * np.eye(V)
    g = rng.normal(size=V)
    np.testing.assert_allclose(schur_step(sp.csr_matrix(A), g, P), -np.linalg.solve(A, g), rtol=1e-8, atol=1e-10)
    ab = banded_upper(sp.csr_matrix(A[:P, :P]))
    for i in range(P):
        for j in range(i, min(P, i + 6)):
            assert ab[5 + i - j, j] == A[i, j]
    far = A.copy()
    far[0, 9] = far[9, 0] = 0.1
    assert schur_step(sp.csr_matrix(far), g, P) is None
