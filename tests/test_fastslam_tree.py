"""FastSLAM with tree maps (fastslam_edu.landmark.fastslam_tree) against the array engine, on the simulator.

Both filters draw the same random numbers (same propagate, same resampling)
and apply the measurements of an instant with the same semantics, so for the
same seed the weighted-mean path, the combined map and every particle's pose,
log weight and landmark filters must agree. The tree filter reads and writes
the same 2×2 EKF arithmetic through the trees, so the measured difference is
0.0; the tolerance asked for is 1e-6 (m, rad, log weight).

The tree filter applies the array engine's own update function to the
landmarks it reads out of the trees, so what these tests check is the
storage: reading, writing back exactly what changed, sharing after
resampling. One test compares with the loop over particle objects (benchmarks/textbook_loop.py), which
shares no update code with either.

The cases exercise resampling (sometimes / every step), the robust gate with
injected outliers, range-dependent R, a landmark measured twice at one
instant, and modes slam, localize and map. A different seed is caught.
Sharing is checked by object identity: after a run the M particles hold far
fewer distinct nodes than M separate trees would.
"""

from __future__ import annotations


import numpy as np
import pytest

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.datasets.events import event_stream, groundtruth_at
from fastslam_edu.landmark.fastslam import CHI2_2DOF_999, FastSLAMParams, run_fastslam
from fastslam_edu.landmark.fastslam_tree import TreeParticleSet, run_fastslam_tree
from fastslam_edu.landmark.tree import count_new_nodes, count_nodes, tree_depth
from fastslam_edu.core.motion import MotionNoise
from fastslam_edu.datasets.sim import simulate_dataset

from streams import with_repeated_measurements
from textbook_loop import run_fastslam_loop

TOL = 1e-6
M = 20


@pytest.fixture(scope="module")
def world():
    data = simulate_dataset(5, duration=20.0, outlier_prob=0.1)
    log = data.robots[1]
    return data, log, event_stream(log, data.landmark_subjects)


def differences(a, b) -> dict:
    """Largest differences between two results (array engine ``a``, tree filter ``b``)."""
    pa, pb = a.particles, b.particles
    seen = pa.seen & pb.seen
    observed = a.observed & b.observed
    return {
        "seen_mismatches": int((pa.seen != pb.seen).sum() + (a.observed != b.observed).sum()),
        "count_mismatches": int((pa.count != pb.count).sum()),  # sightings used (the gate's "young" test)
        "path_xy": np.abs(a.pose_mean[:, :2] - b.pose_mean[:, :2]).max(),
        "path_theta": np.abs(wrap_angle(a.pose_mean[:, 2] - b.pose_mean[:, 2])).max(),
        "map": np.abs(a.landmarks_mean[observed] - b.landmarks_mean[observed]).max(),
        "map_cov": np.abs(a.landmarks_cov[observed] - b.landmarks_cov[observed]).max(),
        "poses": np.abs(pa.poses - pb.poses).max(),
        "logw": np.abs(pa.logw - pb.logw).max(),
        "mu": np.abs(pa.mu[seen] - pb.mu[seen]).max(),
        "sigma": np.abs(pa.sigma[seen] - pb.sigma[seen]).max(),
    }


CASES = [  # (mode, resample_threshold, gate, range_std_slope, noise)
    ("slam", 0.5, CHI2_2DOF_999, 0.06, MotionNoise(mode="control", sigma_v=0.02, sigma_omega=0.05)),
    ("slam", 1.0, None, 0.0, MotionNoise(mode="state", sigma_xy=0.01, sigma_theta=0.02)),
    ("localize", 0.5, CHI2_2DOF_999, 0.0, MotionNoise(mode="control", sigma_v=0.02, sigma_omega=0.05)),
    ("map", 0.5, CHI2_2DOF_999, 0.06, MotionNoise(mode="control", sigma_v=0.02, sigma_omega=0.05)),
]


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"{c[0]}-thr{c[1]}-{'gate' if c[2] else 'nogate'}-slope{c[3]}")
def test_tree_filter_equals_array_engine(world, case):
    data, log, stream = world
    mode, thr, gate, slope, noise = case
    params = FastSLAMParams(n_particles=M, motion_noise=noise, measurement_cov=np.diag([0.05**2, 0.02**2]),
                            mode=mode, resample_threshold=thr, gate_chi2=gate, range_std_slope=slope)
    kw = {}
    if mode == "localize":
        kw["landmarks"] = data.landmark_positions
    if mode == "map":
        kw["groundtruth_poses"] = lambda t: groundtruth_at(log, t)
    a = run_fastslam(stream, params, 11, **kw)
    b = run_fastslam_tree(stream, params, 11, **kw)
    diff = differences(a, b)
    assert max(diff.values()) < TOL, diff
    assert (a.n_resamples, a.measurements_used, a.measurements_rejected) == \
           (b.n_resamples, b.measurements_used, b.measurements_rejected)
    np.testing.assert_allclose(a.ess, b.ess, rtol=1e-9)
    if mode != "map":  # (with known poses all particles weigh the same: no resampling)
        assert a.n_resamples > 0  # resampling, where tree sharing matters, is exercised
    if gate is not None and mode != "map":
        assert a.measurements_rejected > 0  # the gate acted
    if mode == "localize":  # the known map never moves (only the sighting counts change)
        assert np.array_equal(b.particles.mu, np.broadcast_to(data.landmark_positions, b.particles.mu.shape))


def test_a_landmark_measured_twice_at_one_instant(world):
    _, _, stream = world
    twice = with_repeated_measurements(stream, every=3)
    assert twice.n_measurements > stream.n_measurements
    params = FastSLAMParams(n_particles=M)
    diff = differences(run_fastslam(twice, params, 3), run_fastslam_tree(twice, params, 3))
    assert max(diff.values()) < TOL, diff


def test_tree_filter_equals_the_textbook_loop():
    """An implementation that shares no update code: the loop over particle objects of benchmarks/textbook_loop.py.

    Its tolerances are those of tests/test_fastslam_loop.py (the loop moves
    the particles step by step in double precision, the engine in segments
    with float32 cos/sin): 1e-7 m on positions, 1e-5 on log weights.
    """
    data = simulate_dataset(3, duration=6.0, outlier_prob=0.1)
    stream = event_stream(data.robots[1], data.landmark_subjects)
    params = FastSLAMParams(n_particles=6, motion_noise=MotionNoise(mode="control", sigma_v=0.01, sigma_omega=0.02),
                            measurement_cov=np.diag([0.05**2, 0.02**2]), resample_threshold=1.0,
                            gate_chi2=CHI2_2DOF_999)
    b = run_fastslam_tree(stream, params, 7)
    parts, path = run_fastslam_loop(stream, params, 7)
    assert b.measurements_rejected > 0 and b.n_resamples > 0
    assert np.abs(path[:, :2] - b.pose_mean[:, :2]).max() < 1e-7
    assert np.abs(wrap_angle(path[:, 2] - b.pose_mean[:, 2])).max() < 1e-7
    assert np.abs(np.array([p.logw for p in parts]) - b.trees.logw).max() < 1e-5
    for p, tree in zip(parts, b.trees.trees):
        assert sorted(p.landmarks) == tree.keys()
        for k, (mu, sigma) in p.landmarks.items():
            leaf = tree.get(k)
            assert np.abs(leaf.mu - mu).max() < 1e-7 and np.abs(leaf.sigma - sigma).max() < 1e-10
            assert leaf.count == p.count[k]


def test_the_comparison_can_fail(world):
    _, _, stream = world
    params = FastSLAMParams(n_particles=M)
    diff = differences(run_fastslam(stream, params, 11), run_fastslam_tree(stream, params, 12))
    assert diff["path_xy"] > 1e-3 and diff["map"] > 1e-3


def test_particles_share_their_trees_after_a_run(world):
    data, _, stream = world
    K = stream.n_landmarks
    b = run_fastslam_tree(stream, FastSLAMParams(n_particles=M, resample_threshold=1.0,
                                                 measurement_correlation_s=None), 0)
    trees = b.trees.trees
    per_tree = [count_nodes(t) for t in trees]
    assert min(per_tree) > 0 and max(per_tree) <= 2 ** (tree_depth(K) + 1) - 1
    distinct = count_nodes(*trees)
    # resampled at every measurement step: the M maps share most of their nodes
    assert distinct < 0.6 * sum(per_tree), (distinct, sum(per_tree))
    # and the dense view of the trees is the array engine's map (checked above); here: all landmarks seen
    assert b.particles.seen.sum(axis=1).max() == len({*stream.landmark.tolist()})


def test_select_shares_trees_and_updates_stay_private():
    K, n = 50, 6
    parts = TreeParticleSet.initial(n, K, np.zeros(3))
    parts.trees = [t.set(3, [4.0, 1.0], np.eye(2) * 0.1) for t in parts.trees]
    children = parts.select([0, 0, 0, 5, 5, 5])
    assert children.trees[0] is parts.trees[0] and children.trees[4] is parts.trees[5]
    assert np.all(children.logw == 0.0)
    z = np.array([[np.hypot(4.0, 1.0) + 0.05, np.arctan2(1.0, 4.0)]])
    moved = children.select(np.arange(n))
    moved.update(z, [3], np.diag([0.1**2, 0.02**2]))
    for m in range(n):  # the inputs still hold the old landmark
        np.testing.assert_array_equal(children.trees[m].get(3)[0], [4.0, 1.0])
        assert moved.trees[m].get(3).mu[0] > 4.0  # the update pulled it outwards


def test_a_particle_for_which_the_sighting_is_an_outlier_keeps_its_tree():
    """Object identity: the sighting fits particle 0's landmark and is 5 m off particle 1's (seen twice, so
    not re-initialised); only particle 0 gets a new tree, of depth + 1 new nodes."""
    parts = TreeParticleSet.initial(2, 8, np.zeros(3))
    parts.trees = [t.set(3, mu, np.eye(2) * 0.01, count=2) for t, mu in zip(parts.trees, ([4.0, 1.0], [4.0, -4.0]))]
    old = list(parts.trees)
    z = np.array([[np.hypot(4.0, 1.0) + 0.02, np.arctan2(1.0, 4.0)]])
    explained = parts.update(z, [3], np.diag([0.05**2, 0.02**2]), gate_chi2=CHI2_2DOF_999)
    assert explained.tolist() == [True]
    assert parts.trees[1] is old[1] and parts.trees[0] is not old[0]
    assert count_new_nodes(parts.trees, old) == tree_depth(8) + 1
    np.testing.assert_array_equal(parts.trees[1].get(3).mu, [4.0, -4.0])
    assert parts.trees[0].get(3).count == 3 and parts.trees[1].get(3).count == 2


@pytest.mark.parametrize("bad", [{"n_particles": 0}, {"x0": [0.0, np.nan, 0.0]}, {"n_landmarks": 0}])
def test_initial_rejects_bad_input(bad):
    kw = {"n_particles": 3, "n_landmarks": 5, "x0": np.zeros(3)} | bad
    with pytest.raises(ValueError, match="n_particles|initial pose|landmarks"):
        TreeParticleSet.initial(**kw)
