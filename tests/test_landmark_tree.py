"""The persistent landmark tree (fastslam_edu.landmark.tree) against a plain dict model.

* A hypothesis state machine applies random ``set``s to random *old* versions
  and checks every version ever made against its own dict snapshot: gets, len,
  keys — persistence means no version ever changes.
* Path copying, counted by object identity: one ``set`` creates exactly
  ⌈log2 K⌉ + 1 nodes and shares all the others (closed-form node counts of the
  complete tree are computed independently).
* Particles resampled from one parent share one tree; an update in one of
  them is invisible to all the others.
* Leaves are read-only; bad keys and bad arrays raise clear ValueErrors.
* The benchmark ``benchmarks/landmark_tree.py``: what it counts in one
  filter step (nodes created, bytes copied) is checked against closed forms,
  and its crossover K against hand-made timings.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, precondition, rule

from fastslam_edu.landmark.tree import (
    LandmarkTree,
    Landmark,
    count_new_nodes,
    count_nodes,
    gather,
    set_each,
    shared_nodes,
    tree_depth,
    trees_to_arrays,
)


def value(seed: float) -> tuple[np.ndarray, np.ndarray]:
    """A distinct (mu, sigma) per seed."""
    return np.array([seed, -2.0 * seed]), np.array([[1.0 + seed**2, 0.1 * seed], [0.1 * seed, 2.0]])


def nodes_of_complete_tree(K: int) -> int:
    """Nodes of the tree holding every key 0..K-1, counted level by level: ⌈K / 2^j⌉ nodes span 2^j keys."""
    d = math.ceil(math.log2(K)) if K > 1 else 0
    return sum(-(-K // 2**j) for j in range(d + 1))


def full_tree(K: int) -> LandmarkTree:
    return LandmarkTree.from_arrays(np.arange(2 * K, dtype=float).reshape(K, 2), np.tile(np.eye(2), (K, 1, 1)))


# ---------------------------------------------------------------- against a dict model, every version kept


class TreeVersions(RuleBasedStateMachine):
    """Random sets on random old versions; every version must keep matching its dict."""

    def __init__(self):
        super().__init__()
        self.versions: list[tuple[LandmarkTree, dict]] = []

    @precondition(lambda self: not self.versions)
    @rule(K=st.integers(1, 40))
    def start(self, K):
        self.K = K
        self.versions.append((LandmarkTree.empty(K), {}))

    @precondition(lambda self: self.versions)
    @rule(data=st.data(), x=st.floats(-100, 100, allow_nan=False))
    def set_on_some_version(self, data, x):
        i = data.draw(st.integers(0, len(self.versions) - 1), label="version")
        k = data.draw(st.integers(0, self.K - 1), label="k")
        tree, model = self.versions[i]
        mu, sigma = value(x)
        new = tree.set(k, mu, sigma)
        mu[0] = 1e9  # the tree holds a copy: changing the caller's array afterwards changes nothing
        self.versions.append((new, {**model, k: value(x)}))
        # path copying: the new tree shares all but the depth + 1 nodes of the path with its parent
        assert shared_nodes(tree, new) == count_nodes(new) - (new.depth + 1)
        assert count_new_nodes([new], [tree]) == new.depth + 1

    @invariant()
    def every_version_matches_its_model(self):
        for tree, model in self.versions:
            assert len(tree) == len(model)
            assert tree.keys() == sorted(model)
            for k in range(self.K):
                got = tree.get(k)
                if k in model:
                    assert got is not None and k in tree
                    np.testing.assert_array_equal(got[0], model[k][0])
                    np.testing.assert_array_equal(got[1], model[k][1])
                else:
                    assert got is None and k not in tree


TestTreeVersions = TreeVersions.TestCase
TestTreeVersions.settings = settings(max_examples=40, stateful_step_count=25, deadline=None)


@settings(max_examples=40, deadline=None)
@given(K=st.integers(1, 300), data=st.data())
def test_from_arrays_equals_sets_one_by_one(K, data):
    seen = np.array(data.draw(st.lists(st.booleans(), min_size=K, max_size=K)))
    mu = np.arange(2 * K, dtype=float).reshape(K, 2)
    sigma = np.tile(np.eye(2), (K, 1, 1)) * np.arange(1, K + 1)[:, None, None]
    built = LandmarkTree.from_arrays(mu, sigma, seen)
    by_hand = LandmarkTree.empty(K)
    for k in np.flatnonzero(seen):
        by_hand = by_hand.set(int(k), mu[k], sigma[k])
    assert len(built) == len(by_hand) == seen.sum()
    assert built.keys() == by_hand.keys() == np.flatnonzero(seen).tolist()
    assert count_nodes(built) == count_nodes(by_hand)
    for k, leaf in built.items():
        assert isinstance(leaf, Landmark) and leaf.count == 1
        np.testing.assert_array_equal(leaf.mu, mu[k])
        np.testing.assert_array_equal(leaf.sigma, sigma[k])


# ---------------------------------------------------------------- shape and node counts


@pytest.mark.parametrize("K", [1, 2, 3, 8, 9, 15, 16, 17, 100, 1000, 4096, 4097, 100_000])
def test_depth_is_ceil_log2_K(K):
    expected = math.ceil(math.log2(K)) if K > 1 else 0
    tree = LandmarkTree.empty(K)
    assert tree.depth == tree_depth(K) == expected
    one = tree.set(K - 1, *value(1.0))
    levels = [level for level, _, _ in one.nodes()]
    assert levels == list(range(expected + 1))  # a path root → leaf of depth + 1 nodes
    assert count_nodes(one) == expected + 1


@pytest.mark.parametrize("K", [1, 5, 8, 15, 16, 100, 1000])
def test_full_tree_node_count_and_one_update(K):
    tree = full_tree(K)
    assert count_nodes(tree) == nodes_of_complete_tree(K)
    if K == 2 ** tree.depth:
        assert count_nodes(tree) == 2 * K - 1
    new = tree.set(K // 2, *value(3.0))
    assert count_nodes(new) == count_nodes(tree)
    assert shared_nodes(tree, new) == count_nodes(tree) - (tree.depth + 1)
    assert shared_nodes(tree, tree) == count_nodes(tree)
    # the leaves a level below the root: the untouched half is literally the same object
    if tree.depth >= 1:
        untouched = 1 - ((K // 2) >> (tree.depth - 1) & 1)
        assert new.root[untouched] is tree.root[untouched]
        assert new.root is not tree.root


def test_nodes_positions_are_keys_at_the_leaves():
    tree = LandmarkTree.empty(16).set(5, *value(1.0)).set(12, *value(2.0))
    leaves = [(pos, node) for level, pos, node in tree.nodes() if level == tree.depth]
    assert [pos for pos, _ in leaves] == [5, 12]
    assert leaves[0][1] is tree.get(5)
    internal = [(level, pos) for level, pos, _ in tree.nodes() if level < tree.depth]
    # 5 = 0101, 12 = 1100: the paths share only the root
    assert internal == [(0, 0), (1, 0), (1, 1), (2, 1), (2, 3), (3, 2), (3, 6)]


# ---------------------------------------------------------------- particles: sharing after resampling


def test_resampled_particles_share_and_stay_independent():
    K, M, k = 1000, 50, 417
    parent = full_tree(K)
    old_mu, old_sigma, _ = parent.get(k)
    particles = [parent] * M  # resampling M offspring from one parent copies references
    assert count_nodes(*particles) == count_nodes(parent)
    particles[7] = particles[7].set(k, np.array([-1.0, -1.0]), np.eye(2) * 5.0)
    for m, tree in enumerate(particles):
        got_mu, got_sigma, _ = tree.get(k)
        if m == 7:
            np.testing.assert_array_equal(got_mu, [-1.0, -1.0])
        else:  # every other particle still reads the old value
            assert tree is parent
            np.testing.assert_array_equal(got_mu, old_mu)
            np.testing.assert_array_equal(got_sigma, old_sigma)
    total = count_nodes(parent)
    assert shared_nodes(parent, particles[7]) == total - (parent.depth + 1)
    assert count_nodes(*particles) == total + parent.depth + 1  # M trees, one path more than one tree


def test_set_each_and_gather_against_one_by_one():
    K, M = 37, 9
    rng = np.random.default_rng(0)
    base = full_tree(K)
    trees = [base] * M
    mu = rng.normal(size=(M, 2))
    sigma = np.tile(np.eye(2), (M, 1, 1)) * rng.uniform(1, 2, (M, 1, 1))
    which = np.arange(M) % 3 == 0
    new = set_each(trees, 20, mu, sigma, count=np.arange(1, M + 1), which=which)
    for m in range(M):
        if which[m]:
            np.testing.assert_array_equal(new[m].get(20).mu, mu[m])
            assert new[m].get(20).count == m + 1
            assert new[m] is not base
        else:
            assert new[m] is base  # untouched particles keep the very same tree
    assert count_new_nodes(new, trees) == which.sum() * (base.depth + 1)
    g_mu, g_sigma, g_seen, g_count = gather(new, [20, 3])
    assert g_mu.shape == (M, 2, 2) and g_sigma.shape == (M, 2, 2, 2) and g_seen.all()
    assert g_count[:, 0].tolist() == np.where(which, np.arange(1, M + 1), 1).tolist()
    np.testing.assert_array_equal(g_mu[which, 0], mu[which])
    np.testing.assert_array_equal(g_mu[~which, 0], np.broadcast_to(base.get(20)[0], (M - which.sum(), 2)))
    np.testing.assert_array_equal(g_mu[:, 1], np.broadcast_to([6.0, 7.0], (M, 2)))
    # unseen landmarks: seen False and NaN
    sparse = [LandmarkTree.empty(K).set(4, *value(1.0)), LandmarkTree.empty(K)]
    s_mu, s_sigma, s_seen, s_count = gather(sparse, 4)
    assert s_seen[:, 0].tolist() == [True, False] and s_count[:, 0].tolist() == [1, 0]
    assert np.isnan(s_mu[1]).all() and np.isnan(s_sigma[1]).all()
    d_mu, d_sigma, d_seen, d_count = trees_to_arrays(sparse)
    assert d_count.sum() == 1
    assert d_seen.sum() == 1 and d_seen[0, 4]
    np.testing.assert_array_equal(d_mu[0, 4], value(1.0)[0])
    np.testing.assert_array_equal(d_sigma[1, 4], np.eye(2))


def test_gather_of_sparse_trees_returns_the_counts_that_were_set():
    """Counts set by hand (3 and 5) come back from gather where some particle lacks the key (0 there)."""
    trees = [LandmarkTree.empty(8).set(2, *value(1.0), count=3), LandmarkTree.empty(8),
             LandmarkTree.empty(8).set(2, *value(2.0), count=5).set(6, *value(3.0), count=2)]
    _, _, seen, count = gather(trees, [2, 6])
    assert seen.tolist() == [[True, False], [False, False], [True, True]]
    assert count.tolist() == [[3, 0], [0, 0], [5, 2]]


# ---------------------------------------------------------------- immutability and bad input


def test_leaves_are_read_only():
    tree = LandmarkTree.empty(4).set(2, *value(1.0))
    mu, sigma, _ = tree.get(2)
    with pytest.raises(ValueError, match="read-only"):
        mu[0] = 5.0
    with pytest.raises(ValueError, match="read-only"):
        sigma[0, 0] = 5.0
    shared = set_each([tree, tree], 1, np.zeros((2, 2)), np.tile(np.eye(2), (2, 1, 1)))
    with pytest.raises(ValueError, match="read-only"):
        shared[0].get(1)[0][:] = 1.0
    with pytest.raises(AttributeError):
        tree.size = 7
    with pytest.raises(TypeError):
        tree.root[0] = None  # nodes are tuples


def test_set_keeps_frozen_arrays_by_reference_and_copies_the_others():
    """Another leaf's read-only arrays are stored as they are; writable arrays or views of them are copied."""
    tree = LandmarkTree.empty(8).set(2, *value(1.0), count=3)
    leaf = tree.get(2)
    moved = tree.set(5, leaf.mu, leaf.sigma, leaf.count + 1).get(5)
    assert moved.mu is leaf.mu and moved.sigma is leaf.sigma and moved.count == 4
    mu, sigma = value(2.0)
    view = mu.view()
    view.setflags(write=False)  # read-only, but mu can still change it
    stored = tree.set(5, view, sigma).get(5)
    assert stored.mu is not view and stored.sigma is not sigma
    mu[0], sigma[0, 0] = 99.0, 99.0
    np.testing.assert_array_equal(stored.mu, value(2.0)[0])
    np.testing.assert_array_equal(stored.sigma, value(2.0)[1])
    assert tree.set(1, [1, 2], [[1, 0], [0, 1]], np.int64(2)).get(1).count == 2  # ints and NumPy counts accepted


@pytest.mark.parametrize("key", [-1, 8, 1.5, "3", None, True, np.float64(2.0)])
def test_bad_keys_raise(key):
    tree = LandmarkTree.empty(8)
    with pytest.raises(ValueError, match="landmark index"):
        tree.get(key)
    with pytest.raises(ValueError, match="landmark index"):
        tree.set(key, *value(1.0))


def test_numpy_integer_keys_work():
    tree = LandmarkTree.empty(8).set(np.int64(3), *value(1.0))
    assert tree.get(np.int32(3)) is not None and tree.keys() == [3]


@pytest.mark.parametrize(
    "mu, sigma, match",
    [
        ([1.0, np.nan], np.eye(2), "non-finite"),
        ([1.0, 2.0], np.full((2, 2), np.inf), "non-finite"),
        ([1.0, 2.0, 3.0], np.eye(2), r"mu must have shape \(2\)"),
        ([1.0, 2.0], np.eye(3), r"sigma must have shape \(2, 2\)"),
        (["a", "b"], np.eye(2), "numeric"),
    ],
)
def test_bad_arrays_raise(mu, sigma, match):
    with pytest.raises(ValueError, match=match):
        LandmarkTree.empty(8).set(1, mu, sigma)


@pytest.mark.parametrize("count", [0, -1, 1.5, True, [1, 2]])
def test_bad_counts_raise(count):
    with pytest.raises(ValueError, match="count"):
        LandmarkTree.empty(8).set(1, [1.0, 2.0], np.eye(2), count)


@pytest.mark.parametrize("K", [0, -3, 2.5, True])
def test_bad_sizes_raise(K):
    with pytest.raises(ValueError, match="number of landmarks"):
        LandmarkTree.empty(K)


def test_bulk_functions_reject_mismatches():
    trees = [LandmarkTree.empty(8), LandmarkTree.empty(9)]
    with pytest.raises(ValueError, match="N = 8"):
        gather(trees, [0])
    with pytest.raises(ValueError, match="rows"):
        set_each([LandmarkTree.empty(8)] * 3, 0, np.zeros((2, 2)), np.tile(np.eye(2), (2, 1, 1)))
    with pytest.raises(ValueError, match="which"):
        set_each([LandmarkTree.empty(8)] * 2, 0, np.zeros((2, 2)), np.tile(np.eye(2), (2, 1, 1)), which=[1, 0])
    with pytest.raises(ValueError, match="no trees"):
        gather([], [0])


def test_bad_seen_and_which_masks_raise():
    """A seen mask of ints, or of the wrong length, and a which mask of the wrong length are refused."""
    mu, sigma = np.zeros((3, 2)), np.tile(np.eye(2), (3, 1, 1))
    with pytest.raises(ValueError, match="seen must be a bool array"):
        LandmarkTree.from_arrays(mu, sigma, seen=np.array([1, 0, 1]))
    with pytest.raises(ValueError, match="seen must be a bool array"):
        LandmarkTree.from_arrays(mu, sigma, seen=np.array([True, False]))
    with pytest.raises(ValueError, match="which"):
        set_each([LandmarkTree.empty(8)] * 2, 0, np.zeros((2, 2)), np.tile(np.eye(2), (2, 1, 1)),
                 which=np.array([True]))


# ---------------------------------------------------------------- the benchmark benchmarks/landmark_tree.py


@pytest.fixture(scope="module")
def bench():
    """``benchmarks/landmark_tree.py``, imported from its file (the benchmarks are scripts, not a package)."""
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "landmark_tree.py"
    spec = importlib.util.spec_from_file_location("benchmark_landmark_tree", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("K", [64, 1000])
def test_step_cost_counts(bench, K):
    r = bench.step_cost(K, n_particles=30, repeats=1, min_block_seconds=0.0)
    d = tree_depth(K)
    assert r["depth"] == d
    # two updates per particle: the union of two root-to-leaf paths, sharing at least the root
    assert 30 * (d + 2) <= r["tree_nodes_created"] <= r["tree_nodes_bound"] - 30 == 30 * (2 * d + 1)
    # dense: select copies every particle's K means (2 floats), covariances (4) and seen flags (1 byte)
    assert r["dense_bytes_retained"] >= 30 * K * (6 * 8 + 1)
    assert r["tree_bytes_retained"] < 30 * 2 * (d + 1) * 200 + 30 * 2 * 500  # nodes + leaf views, no K term
    assert r["dense_bytes_copied"] >= 30 * K * (6 * 8 + 1)
    assert r["tree_seconds"] > 0 and r["dense_seconds"] > 0


def test_crossover_k_interpolates_in_log_k(bench):
    """dense ∝ K, tree constant: log(dense/tree) = log(K / 1000) is linear in log K, so the crossing is exact."""
    rows = [{"K": K, "dense_seconds": K * 1e-6, "tree_seconds": 1e-3} for K in (10, 100, 10_000, 100_000)]
    assert bench.crossover_k(rows) == pytest.approx(1000.0, rel=1e-12)
    assert bench.crossover_k(rows[2:]) == 10_000  # the tree wins everywhere measured
    assert bench.crossover_k(rows[:2]) is None  # never wins
    with pytest.raises(ValueError, match="sorted"):
        bench.crossover_k(rows[::-1])


def test_step_cost_updates_every_landmark_when_k_equals_n_updates(bench):
    """K = n_updates = 2 is allowed: both leaves of a depth-1 tree change, 3 new nodes per particle (closed form)."""
    r = bench.step_cost(2, n_particles=5, n_updates=2, repeats=1, min_block_seconds=0.0)
    assert r["depth"] == 1 and r["tree_nodes_created"] == 5 * 3
    with pytest.raises(ValueError, match="need K >= 2"):
        bench.step_cost(1, n_particles=5, n_updates=2, repeats=1, min_block_seconds=0.0)
    with pytest.raises(ValueError, match="repeats must be >= 1"):
        bench.step_cost(2, n_particles=5, n_updates=2, repeats=0, min_block_seconds=0.0)


def test_set_step_equals_the_dense_set_step(bench):
    """The two sides of set_step_cost compute the same maps: trees read back as arrays equal the dense copy."""
    dense, tree, indices, keys, _ = bench.step_world(50, 6, 2, seed=3)
    mu = np.arange(24, dtype=float).reshape(6, 2, 2)
    sigma = np.tile(np.eye(2), (6, 2, 1, 1)) * np.arange(1, 13, dtype=float).reshape(6, 2, 1, 1)
    t_mu, t_sigma, _, _ = trees_to_arrays(bench.set_step(tree.trees, indices, keys.tolist(), mu, sigma))
    d_mu, d_sigma = bench.dense_set_step(dense.mu, dense.sigma, indices, keys.tolist(), mu, sigma)
    np.testing.assert_array_equal(t_mu, d_mu)
    np.testing.assert_array_equal(t_sigma, d_sigma)
    r = bench.set_step_cost(50, n_particles=6, repeats=1, min_block_seconds=0.0)
    assert r["K"] == 50 and r["tree_seconds"] > 0 and r["dense_seconds"] > 0


def test_crossover_k_ties_and_repeated_k(bench):
    """By hand: a tie at the largest K is no win (None); a K measured twice is not sorted increasing."""
    rows = [{"K": K, "dense_seconds": d, "tree_seconds": 1.0} for K, d in ((10, 0.5), (100, 1.0))]
    assert bench.crossover_k(rows) is None
    with pytest.raises(ValueError, match="sorted"):
        bench.crossover_k([rows[0], rows[0]])
