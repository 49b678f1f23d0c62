"""Joint compatibility's search (fastslam_edu.landmark.joint_compatibility.best_joint_hypothesis): its branch-and-bound
bound and its result, against every hypothesis scored by scipy's log-density of the stacked innovations."""

from __future__ import annotations

import itertools

import numpy as np
from scipy.linalg import block_diag
from scipy.stats import multivariate_normal

from fastslam_edu.landmark.joint_compatibility import N_PAIR_SLOTS, best_joint_hypothesis


def random_instance(rng, n, K, spread=0.3):
    """n sightings, each with 1..K candidate landmarks: per pair (i, k) a covariance D, a pose Jacobian H (2, 3) and
    an innovation nu; a common pose covariance Pc, log p0 per sighting, and the rows of pair_information."""
    L = rng.normal(size=(3, 3))
    Pc = L @ L.T * 0.01
    ll = np.full((n, K), -np.inf)
    D, H, nu = {}, {}, {}
    info = np.zeros((n, K, N_PAIR_SLOTS))
    for i in range(n):
        for k in rng.choice(K, size=int(rng.integers(1, K + 1)), replace=False):
            A = rng.normal(size=(2, 2)) * 0.1
            D[i, k] = A @ A.T + np.diag(rng.uniform(0.01, 0.05, 2))
            H[i, k] = rng.normal(size=(2, 3))
            nu[i, k] = rng.normal(scale=spread, size=2)
            Dinv = np.linalg.inv(D[i, k])
            info[i, k] = np.concatenate([[nu[i, k] @ Dinv @ nu[i, k]], H[i, k].T @ Dinv @ nu[i, k],
                                         (H[i, k].T @ Dinv @ H[i, k]).ravel(), [np.log(np.linalg.det(D[i, k]))]])
            ll[i, k] = 0.0  # a candidate (its value only orders the first, greedy leaf)
    p0 = rng.uniform(-9.0, -3.0, n)
    return Pc, ll, p0, D, H, nu, info


def score(choice, Pc, p0, D, H, nu):
    """log p(z | H) of a (partial) hypothesis: scipy's density of the stacked innovations of its assigned
    sightings, S = blockdiag(D) + H Pc H^T, plus log p0 for each new one."""
    assigned = [(i, k) for i, k in enumerate(choice) if k >= 0]
    total = sum(p0[i] for i, k in enumerate(choice) if k < 0)
    if assigned:
        Hs = np.vstack([H[p] for p in assigned])
        S = block_diag(*[D[p] for p in assigned]) + Hs @ Pc @ Hs.T
        total += multivariate_normal(np.zeros(2 * len(assigned)), S).logpdf(np.concatenate([nu[p] for p in assigned]))
    return total


def hypotheses(ll, group):
    """Every hypothesis: each sighting new (-1) or one of its candidates, no landmark twice in one frame."""
    options = [[-1, *np.flatnonzero(np.isfinite(row))] for row in ll]
    for choice in itertools.product(*options):
        taken = [(group[i], k) for i, k in enumerate(choice) if k >= 0]
        if len(set(taken)) == len(taken):
            yield choice


def test_the_bound_is_never_below_a_leaf():
    """Below any node (sightings 0..i decided), every leaf scores at most the node's score plus, per sighting left,
    max(log p0, its best pair's -log 2pi - log det D / 2): the claim branch and bound rests on, checked with scipy's
    densities on random instances (a bound without the log-determinants, or with the quadratic forms, fails)."""
    rng = np.random.default_rng(3)
    checked = 0
    for _ in range(30):
        n, K = int(rng.integers(2, 4)), int(rng.integers(1, 4))
        Pc, ll, p0, D, H, nu, info = random_instance(rng, n, K)
        rest = [max([p0[i]] + [-np.log(2 * np.pi) - 0.5 * np.log(np.linalg.det(D[i, k]))
                               for k in np.flatnonzero(np.isfinite(ll[i]))]) for i in range(n)]
        leaves = {c: score(c, Pc, p0, D, H, nu) for c in hypotheses(ll, np.zeros(n, dtype=int))}
        for depth in range(1, n):
            for prefix in {c[:depth] for c in leaves}:
                below = max(s for c, s in leaves.items() if c[:depth] == prefix)
                assert below <= score(prefix, Pc, p0, D, H, nu) + sum(rest[depth:]) + 1e-9
                checked += 1
    assert checked > 100


def test_the_search_finds_the_most_likely_hypothesis_and_prunes():
    """On random instances of two to five sightings in one or two frames: the slot written is the hypothesis of the
    highest scipy density among all of them, and over the instances the search scores fewer leaves than there are
    hypotheses (the bound prunes)."""
    rng = np.random.default_rng(8)
    leaves_scored = hypotheses_counted = 0
    for trial in range(40):
        n, K = int(rng.integers(2, 6)), int(rng.integers(2, 5))
        Pc, ll, p0, D, H, nu, info = random_instance(rng, n, K, spread=0.15)
        group = np.sort(rng.integers(0, 2, n)) if trial % 2 else np.zeros(n, dtype=np.int64)
        every = {c: score(c, Pc, p0, D, H, nu) for c in hypotheses(ll, group)}
        slot = np.full(n, -2, dtype=np.int64)
        leaves = best_joint_hypothesis(info, ll, p0, Pc, slot, (np.full(n, -1, dtype=np.int64),
                                                                np.zeros((n + 1, N_PAIR_SLOTS)),
                                                                group.astype(np.int64), np.zeros(n + 1)))
        best = max(every, key=every.get)
        assert tuple(slot) == best, (trial, tuple(slot), best)
        leaves_scored += leaves
        hypotheses_counted += len(every)
    assert leaves_scored < 0.7 * hypotheses_counted
