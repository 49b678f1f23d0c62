"""Tests of fastslam_edu.core.resampling.

Independent references: the definition E[N_i] = n w_i (unbiasedness, checked
by simulation with stated bounds), closed-form offspring variances
(multinomial n w(1-w), systematic f(1-f), residual R r(1-r)), and
filterpy.monte_carlo (same distribution; identical indices when both read
the same MT19937 stream).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest
from filterpy.monte_carlo import (
    multinomial_resample,
    residual_resample,
    stratified_resample,
    systematic_resample,
)
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2_contingency

from fastslam_edu.core import resampling as rs

SCHEMES = ["roulette", "stratified", "systematic", "residual"]

# A fixed non-uniform weight vector: some N w_i below 1, some integer, some above.
W = np.array([0.02, 0.03, 0.05, 0.07, 0.08, 0.10, 0.12, 0.15, 0.18, 0.20])
N = W.size
R = 20_000  # repetitions for the statistical tests


def counts_matrix(draw, r: int = R) -> np.ndarray:
    """(r, N) offspring counts of ``r`` calls of ``draw()``."""
    return np.array([np.bincount(draw(), minlength=N) for _ in range(r)])


@lru_cache(maxsize=None)
def our_counts(name: str) -> np.ndarray:
    rng = np.random.default_rng(20240501 + SCHEMES.index(name))
    f = rs.get_resampler(name)
    return counts_matrix(lambda: f(W, rng))


@pytest.fixture
def global_numpy_seed():
    """filterpy draws from the global np.random: seed it here, restore afterwards."""
    saved = np.random.get_state()
    yield lambda seed: np.random.seed(seed)
    np.random.set_state(saved)


def unbiasedness_violations(counts: np.ndarray, w: np.ndarray) -> np.ndarray:
    """z-scores |mean N_i - n w_i| / SE_i, SE from the empirical std (floored)."""
    n = counts[0].sum()
    r = counts.shape[0]
    se = np.maximum(counts.std(axis=0, ddof=1), 0.05) / np.sqrt(r)  # floor: std 0 is possible
    return np.abs(counts.mean(axis=0) - n * w) / se


# --------------------------------------------------------------------------- unbiasedness


@pytest.mark.parametrize("name", SCHEMES)
def test_unbiased_mean_offspring_equals_n_w(name):
    counts = our_counts(name)
    assert np.all(counts.sum(axis=1) == N)
    z = unbiasedness_violations(counts, W)
    assert z.max() < 5.0, f"{name}: max z = {z.max():.2f}, means {counts.mean(0)} vs {N * W}"


def test_filterpy_residual_resample_is_biased(global_numpy_seed):
    """filterpy 2.0 residual_resample fails the same check.

    Its residual is ``weights - num_copies`` instead of ``N*weights - num_copies``:
    the residual of every particle with k_i = floor(N w_i) >= 1 is negative, the
    normalising sum is negative, and the signs flip, so particles with N w_i < 1
    (positive residual before the flip) are never drawn at all.
    """
    k = np.floor(N * W)
    filterpy_residual = W - k
    assert np.any(filterpy_residual < 0) and filterpy_residual.sum() < 0
    global_numpy_seed(7)
    counts = counts_matrix(lambda: residual_resample(W), r=4000)
    assert np.all(counts.sum(axis=1) == N)  # the number of draws is right ...
    z = unbiasedness_violations(counts, W)
    assert z.max() > 20.0  # ... their distribution is not: the check fails clearly
    small = N * W < 1
    assert np.all(counts[:, small] == 0)  # 0 copies where N w_i = 0.2 … 0.8 are expected
    # our residual gives those particles their expected share
    ours = our_counts("residual").mean(axis=0)
    np.testing.assert_allclose(ours[small], N * W[small], atol=0.03)


# --------------------------------------------------------------------------- variances


def test_multinomial_variance_closed_form():
    var = our_counts("roulette").var(axis=0, ddof=1)
    np.testing.assert_allclose(var, N * W * (1 - W), rtol=0.06)


def test_systematic_counts_are_floor_or_ceil_with_closed_form_variance():
    counts = our_counts("systematic")
    assert np.all(counts >= np.floor(N * W - 1e-9)) and np.all(counts <= np.ceil(N * W + 1e-9))
    f = N * W - np.floor(N * W + 1e-9)  # fractional part (0 for the integer N w_i = 1, 2)
    np.testing.assert_allclose(counts.var(axis=0, ddof=1), f * (1 - f), rtol=0.06, atol=1e-3)


def test_residual_variance_closed_form():
    k = np.floor(N * W + 1e-9)
    n_rest = N - k.sum()
    r = (N * W - k) / n_rest
    counts = our_counts("residual")
    assert np.all(counts >= k)
    np.testing.assert_allclose(counts.var(axis=0, ddof=1), n_rest * r * (1 - r), rtol=0.06, atol=1e-3)


def test_variance_ordering_systematic_stratified_multinomial():
    v = {name: our_counts(name).var(axis=0, ddof=1) for name in ("systematic", "stratified", "roulette")}
    total = {name: float(x.sum()) for name, x in v.items()}
    # measured: systematic ≈ 1.56, stratified ≈ 2.8, multinomial ≈ 8.6 (closed form 8.6)
    assert total["systematic"] < total["stratified"] < total["roulette"], total
    # per particle, stratified never exceeds multinomial (theorem; 5 % sampling slack)
    assert np.all(v["stratified"] <= 1.05 * v["roulette"])


# --------------------------------------------------------------------------- against filterpy


@pytest.mark.parametrize(
    "name, theirs",
    [("roulette", multinomial_resample), ("systematic", systematic_resample), ("stratified", stratified_resample)],
)
def test_same_offspring_distribution_as_filterpy(name, theirs, global_numpy_seed):
    global_numpy_seed(123)
    r = 8000
    ref = counts_matrix(lambda: theirs(W), r=r)
    ours = our_counts(name)[:r]
    # means and variances per particle
    se = np.sqrt(ours.var(0, ddof=1) / r + ref.var(0, ddof=1) / r)
    assert np.all(np.abs(ours.mean(0) - ref.mean(0)) <= 5 * np.maximum(se, 0.05 / np.sqrt(r)))
    np.testing.assert_allclose(ours.var(0, ddof=1), ref.var(0, ddof=1), rtol=0.12, atol=2e-3)
    # chi-square homogeneity test of the count histograms, particle by particle
    p_values = []
    for i in range(N):
        values = np.union1d(ours[:, i], ref[:, i])
        if values.size == 1:
            continue  # deterministic in both (systematic, integer N w_i)
        table = np.array([[np.count_nonzero(c[:, i] == v) for v in values] for c in (ours, ref)])
        table = table[:, table.min(axis=0) >= 5] if np.any(table.min(axis=0) >= 5) else table
        if table.shape[1] >= 2:
            p_values.append(chi2_contingency(table).pvalue)
    assert min(p_values) > 1e-3 / N, p_values  # Bonferroni over the particles


@pytest.mark.parametrize(
    "name, theirs",
    [("roulette", multinomial_resample), ("systematic", systematic_resample), ("stratified", stratified_resample)],
)
def test_identical_indices_to_filterpy_on_a_shared_random_stream(name, theirs, global_numpy_seed):
    """With both reading the same MT19937 uniforms, the indices coincide exactly."""
    ours = rs.get_resampler(name)
    weights_rng = np.random.default_rng(99)
    for trial in range(200):
        m = int(weights_rng.integers(1, 40))
        w = weights_rng.dirichlet(np.full(m, 0.5))
        np.random.set_state(np.random.RandomState(np.random.MT19937(trial)).get_state())
        expected = np.sort(theirs(w))
        got = ours(w, np.random.Generator(np.random.MT19937(trial)))
        np.testing.assert_array_equal(got, expected, err_msg=f"trial {trial}, w = {w}")


# --------------------------------------------------------------------------- round-off


def test_cumulative_sum_round_off_is_removed():
    w = np.full(10, 0.1)
    assert np.cumsum(w)[-1] < 1.0  # 0.9999999999999999: the adversarial case
    c = rs.cumulative_weights(w)
    assert c[-1] == 1.0 and np.all(np.diff(c) >= 0)


def test_inverse_cdf_never_returns_index_m():
    w = np.full(10, 0.1)
    below_one = np.nextafter(1.0, 0.0)
    np.testing.assert_array_equal(rs.inverse_cdf([0.0, 0.95, below_one, 1.0], w), [0, 9, 9, 9])
    # trailing zero weights: the last particle of positive weight, not M - 1
    np.testing.assert_array_equal(rs.inverse_cdf([below_one, 1.0], [0.5, 0.5, 0.0, 0.0]), [1, 1])
    # a zero-weight particle is never selected, even at its (empty) interval's edge
    np.testing.assert_array_equal(rs.inverse_cdf([0.0, 0.5, below_one], [0.0, 0.5, 0.0, 0.5]), [1, 3, 3])


def test_systematic_last_pointer_can_round_to_one_and_is_handled():
    u = np.nextafter(1.0, 0.0)  # the largest value rng.random() can return
    pointers = (np.arange(3) + u) / 3
    assert pointers[-1] == 1.0  # round-off: (u + 2) / 3 rounds up to exactly 1
    # without the clip, searchsorted would return index 3 for the last pointer
    assert np.searchsorted(np.cumsum([0.2, 0.3, 0.5]), pointers, side="right")[-1] == 3
    np.testing.assert_array_equal(rs.inverse_cdf(pointers, [0.2, 0.3, 0.5]), [1, 2, 2])


@pytest.mark.parametrize("name", SCHEMES)
@pytest.mark.parametrize("m", [3, 10, 7])
def test_equal_thirds_and_tenths(name, m):
    w = np.full(m, 1.0 / m)
    rng = np.random.default_rng(m)
    for _ in range(200):
        idx = rs.get_resampler(name)(w, rng)
        assert idx.min() >= 0 and idx.max() <= m - 1
        if name in ("systematic", "residual"):
            np.testing.assert_array_equal(idx, np.arange(m))  # equal weights are reproduced exactly


# --------------------------------------------------------------------------- shapes, n, edge cases


@pytest.mark.parametrize("name", SCHEMES)
@pytest.mark.parametrize("n", [1, 3, 25])
def test_n_different_from_m(name, n):
    rng = np.random.default_rng(n)
    idx = rs.get_resampler(name)(W, rng, n)
    assert idx.shape == (n,) and np.issubdtype(idx.dtype, np.integer)
    assert np.all(np.diff(idx) >= 0) and idx.min() >= 0 and idx.max() < N
    if name in ("systematic", "residual"):
        counts = rs.offspring_counts(idx, N)
        assert np.all(counts >= np.floor(n * W + 1e-9) - (name == "systematic"))
        if name == "systematic":
            assert np.all(counts <= np.ceil(n * W - 1e-9))


@pytest.mark.parametrize("name", SCHEMES)
def test_unbiased_with_n_different_from_m(name):
    rng = np.random.default_rng(5)
    n = 23
    f = rs.get_resampler(name)
    counts = np.array([rs.offspring_counts(f(W, rng, n), N) for _ in range(5000)])
    assert np.all(counts.sum(axis=1) == n)
    assert unbiasedness_violations(counts, W).max() < 5.0


@pytest.mark.parametrize("name", SCHEMES)
def test_one_hot_weights_give_all_copies(name):
    w = np.zeros(8)
    w[5] = 1.0
    np.testing.assert_array_equal(rs.get_resampler(name)(w, np.random.default_rng(0)), np.full(8, 5))
    np.testing.assert_array_equal(rs.get_resampler(name)(w, np.random.default_rng(0), 3), np.full(3, 5))


@pytest.mark.parametrize("name", SCHEMES)
def test_single_particle(name):
    np.testing.assert_array_equal(rs.get_resampler(name)([1.0], np.random.default_rng(0)), [0])


@settings(max_examples=60, deadline=None)
@given(
    raw=st.lists(st.floats(0.0, 1.0), min_size=1, max_size=30).filter(lambda x: sum(x) > 1e-3),
    n=st.integers(1, 50),
    seed=st.integers(0, 2**32 - 1),
    name=st.sampled_from(SCHEMES),
)
def test_property_sorted_in_range_and_zero_weights_never_drawn(raw, n, seed, name):
    w = np.asarray(raw) / np.sum(raw)
    idx = rs.get_resampler(name)(w, np.random.default_rng(seed), n)
    assert idx.shape == (n,)
    assert np.all(np.diff(idx) >= 0)
    assert idx.min() >= 0 and idx.max() < w.size
    assert np.all(w[idx] > 0)


@pytest.mark.parametrize("name", SCHEMES)
def test_reproducible_with_same_seed(name):
    f = rs.get_resampler(name)
    w = np.random.default_rng(1).dirichlet(np.ones(50))
    a = f(w, np.random.default_rng(42))
    b = f(w, np.random.default_rng(42))
    np.testing.assert_array_equal(a, b)
    if name != "systematic":  # (systematic: different seeds may well agree)
        others = [f(w, np.random.default_rng(s)) for s in range(5)]
        assert any(not np.array_equal(a, o) for o in others)


# --------------------------------------------------------------------------- validation


def test_weights_far_from_normalised_raise_with_the_sum():
    with pytest.raises(ValueError, match=r"sum to 0\.9"):
        rs.systematic([0.3, 0.3, 0.3], np.random.default_rng(0))


def test_tiny_round_off_in_the_sum_is_accepted():
    w = np.array([0.5, 0.5 + 5e-10])
    idx = rs.systematic(w, np.random.default_rng(0))
    assert idx.shape == (2,)


@pytest.mark.parametrize(
    "w, pattern",
    [
        ([0.5, np.nan, 0.5], "1 NaN"),
        ([0.5, np.inf], "infinite"),
        ([1.5, -0.5], "negative"),
        ([2.0, -1.0, 0.0], "negative"),  # sums to exactly 1: the minimum catches it
        ([np.inf, -np.inf, 1.0], "infinite"),
        ([], "non-empty 1-D"),
        ([[0.5, 0.5]], "non-empty 1-D"),
        (["a", "b"], "real numbers"),
    ],
)
def test_bad_weights_raise(w, pattern):
    for name in SCHEMES:
        with pytest.raises(ValueError, match=pattern):
            rs.get_resampler(name)(w, np.random.default_rng(0))


def test_bad_rng_and_n_raise():
    with pytest.raises(TypeError, match="numpy.random.Generator"):
        rs.roulette([1.0], np.random)
    with pytest.raises(TypeError, match="Generator"):
        rs.systematic([1.0], 42)
    for bad in (0, -3, 2.5, True):
        with pytest.raises(ValueError, match="positive integer"):
            rs.stratified([1.0], np.random.default_rng(0), bad)


def test_get_resampler_lists_valid_names():
    assert rs.get_resampler("systematic") is rs.systematic
    assert set(rs.RESAMPLERS) == set(SCHEMES) | {"multinomial"}
    assert rs.get_resampler("multinomial") is rs.get_resampler("roulette") is rs.roulette
    with pytest.raises(ValueError, match="multinomial, residual, roulette, stratified, systematic"):
        rs.get_resampler("low_variance")


def test_offspring_counts():
    np.testing.assert_array_equal(rs.offspring_counts([0, 0, 2, 4, 4, 4], 6), [2, 0, 1, 0, 3, 0])
    assert rs.offspring_counts(np.array([], dtype=int), 3).tolist() == [0, 0, 0]
    with pytest.raises(ValueError, match=r"0 … 2"):
        rs.offspring_counts([0, 3], 3)
    with pytest.raises(ValueError, match="integer"):
        rs.offspring_counts([0.0, 1.0], 3)


def test_sum_just_beyond_the_tolerance_is_refused_and_within_it_renormalised():
    """|Σw − 1| = 1e-7 > 1e-8 raises (the documented tolerance); 5e-10 is accepted and w / Σw returned."""
    with pytest.raises(ValueError, match="normalised"):
        rs.systematic(np.array([0.5, 0.5 + 1e-7]), np.random.default_rng(0))
    w = np.array([0.25, 0.75 + 5e-10])
    np.testing.assert_allclose(rs.validate_weights(w), w / (1.0 + 5e-10), rtol=1e-15)
    assert abs(rs.validate_weights(w).sum() - 1.0) <= 2.3e-16


def test_negative_positions_never_select_a_leading_zero_weight_particle():
    """Positions below 0 (round-off) are clipped to 0: particle 0 of weight 0 owns an empty interval."""
    np.testing.assert_array_equal(rs.inverse_cdf([-0.1, -1e-17, 0.0], [0.0, 0.5, 0.5]), [1, 1, 1])


@pytest.mark.parametrize("seed, m", [(0, 1), (1, 7), (2, 100), (3, 1000)])
def test_roulette_kernel_counted_equal_the_sorted_positions(seed, m):
    """roulette_kernel (the compiled run's roulette: offspring counted, no sort) draws the same indices as
    roulette (sorted positions, then the inverse CDF) from the same random stream, weights with zeros included."""
    w = np.random.default_rng(seed).exponential(size=m) * (np.arange(m) % 3 != 1)
    if w.sum() == 0:
        w[0] = 1.0
    w /= w.sum()
    counted = rs.roulette_kernel(w, np.random.default_rng(seed + 10))
    np.testing.assert_array_equal(counted, rs.roulette(w, np.random.default_rng(seed + 10)))
    assert (np.diff(counted) >= 0).all() and (w[counted] > 0).all()


@pytest.mark.parametrize("seed", range(4))
def test_inverse_cdf_bisection_is_numpys_searchsorted(seed):
    """The compiled bisection returns what numpy's ``searchsorted(c, u, side="right")`` returns on the normalised
    cumulative weights (the definition min{i : c_i > u}): weights with zeros and ties, positions at 0, at the
    interval ends, at 1 and beyond."""
    rng = np.random.default_rng(seed)
    w = rng.random(37) * (rng.random(37) > 0.3)
    w[5] = w[6] = 0.0
    w = w / w.sum()
    c = rs.cumulative_weights(w)
    u = np.concatenate([rng.random(200), c[:-1], [0.0, 1.0, 1.5, -0.2, np.nextafter(1.0, 0.0)]])
    expected = np.searchsorted(c, np.clip(u, 0.0, np.nextafter(1.0, 0.0)), side="right")
    np.testing.assert_array_equal(rs.inverse_cdf_kernel(u, w), expected)


@pytest.mark.parametrize("seed", range(3))
def test_in_increasing_order_is_a_sort_of_the_draws(seed):
    """The counting sort returns numpy's np.sort of the indices (the same multiset, increasing)."""
    idx = np.random.default_rng(seed).integers(0, 20, 20)
    np.testing.assert_array_equal(rs.in_increasing_order(idx), np.sort(idx))
    np.testing.assert_array_equal(rs.in_increasing_order(np.sort(idx)), np.sort(idx))
