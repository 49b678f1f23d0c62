"""Tests of fastslam_edu.core.weights.

Independent references: the definition (kept ratios, sum 1), scipy.special.logsumexp, exact ratios of weights
given as logs (including values like 1e-400 that no float can hold), and the
closed forms N_eff = M (uniform) and 1 (one-hot).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.special import logsumexp

from fastslam_edu.core.weights import (
    effective_sample_size,
    effective_sample_size_from_log,
    is_degenerate,
    normalise_log_weights,
    weights_from_log,
)

# ---------------------------------------------------------------- normalisation (log space)


@settings(max_examples=100, deadline=None)
@given(arrays(np.float64, st.integers(1, 20), elements=st.floats(-1e300, 700) | st.just(-np.inf)))
def test_normalising_keeps_the_ratios_and_makes_the_weights_sum_to_one(a):
    """Reference: the definition. Differences of logs (the ratios) are kept; the weights sum to 1."""
    assume(np.isfinite(a).any())
    ell = normalise_log_weights(a)
    top = int(np.argmax(a))
    finite = np.isfinite(a)
    np.testing.assert_array_equal(np.isneginf(ell), ~finite)
    # ℓ̃_i − ℓ̃_top = a_i − a_top, to round-off of |a_i − a_top| (the subtraction in the shift)
    d = a[finite] - a[top]
    np.testing.assert_allclose(ell[finite] - ell[top], d, rtol=1e-15, atol=1e-13)
    assert math.fsum(np.exp(ell)) == pytest.approx(1.0, abs=1e-14)


def test_normalising_where_the_naive_formula_fails():
    # naive a - log(sum(exp(a))) is -1000 - log(0) = +inf here, and 1000 - inf = -inf for the second
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_allclose(normalise_log_weights([-1000.0, -1000.0]), [-math.log(2.0)] * 2, rtol=1e-15)
        # 1000 + log 3 is stored to the ulp of 1000 (1.1e-13), so the result is exact to that
        np.testing.assert_allclose(normalise_log_weights([1000.0, 1000.0 + math.log(3.0)]),
                                   [math.log(0.25), math.log(0.75)], rtol=0, atol=2e-13)


def test_weights_from_logs_of_numbers_below_the_float_range():
    # w = (1e-400, 2e-400, 5e-400): every one is 0.0 as a float (below ~4.9e-324) ...
    assert 1e-400 == 0.0
    logw = np.log([1.0, 2.0, 5.0]) + (-400) * np.log(10.0)
    # ... but their ratios are exact: 1 : 2 : 5
    np.testing.assert_allclose(weights_from_log(logw), np.array([1.0, 2.0, 5.0]) / 8.0, rtol=1e-12)


def test_product_of_200_likelihoods_underflows_but_the_log_sum_does_not():
    lik = np.full((3, 200), 1e-3)
    lik[1] *= 1.01  # particle 1 is 1.01 times as likely per measurement
    assert np.all(np.prod(lik, axis=1) == 0.0)  # 1e-600 underflows
    w = weights_from_log(np.sum(np.log(lik), axis=1))
    ratio = 1.01**200  # w1 / w0, exactly
    np.testing.assert_allclose(w, np.array([1.0, ratio, 1.0]) / (2.0 + ratio), rtol=1e-10)


def test_normalised_log_weights_closed_form_and_sum_to_one():
    logw = np.array([np.log(0.2) - 50.0, np.log(0.3) - 50.0, -np.inf, np.log(0.5) - 50.0])
    ell = normalise_log_weights(logw)
    np.testing.assert_allclose(ell, [np.log(0.2), np.log(0.3), -np.inf, np.log(0.5)], rtol=1e-14)
    assert abs(np.exp(ell).sum() - 1.0) < 1e-14


def test_batched_rows_are_normalised_independently():
    rng = np.random.default_rng(3)
    logw = rng.normal(scale=3.0, size=(6, 4, 25))
    w = weights_from_log(logw)
    np.testing.assert_allclose(w.sum(axis=-1), 1.0, atol=1e-14)
    np.testing.assert_allclose(np.log(w), logw - logsumexp(logw, axis=-1, keepdims=True), rtol=1e-12, atol=1e-12)
    a = 300.0 * logw  # wide spread: many weights underflow, their logs do not
    ell = normalise_log_weights(a)
    # the reference a − LSE(a) rounds to the ulp of |a| ~ 10³ (where ℓ̃ ≈ 0 that is all its relative accuracy)
    ulp = np.spacing(np.abs(a).max())
    np.testing.assert_allclose(ell, a - logsumexp(a, axis=-1, keepdims=True), rtol=1e-12, atol=4 * ulp)


def test_all_minus_inf_gives_uniform_by_default():
    logw = np.full(4, -np.inf)
    assert is_degenerate(logw)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_allclose(weights_from_log(logw), np.full(4, 0.25), rtol=1e-15)
        np.testing.assert_allclose(normalise_log_weights(logw), np.full(4, -np.log(4)))
    batch = np.array([[-np.inf, -np.inf, -np.inf], [0.0, np.log(3.0), -np.inf]])
    np.testing.assert_array_equal(is_degenerate(batch), [True, False])
    np.testing.assert_allclose(weights_from_log(batch), [[1 / 3, 1 / 3, 1 / 3], [0.25, 0.75, 0.0]], rtol=1e-14)


def test_all_minus_inf_raises_on_request():
    with pytest.raises(ValueError, match=r"all 3 log-weights are -inf.*underflowed.*logw = \[-inf -inf -inf\]"):
        normalise_log_weights(np.full(3, -np.inf), on_degenerate="raise")
    with pytest.raises(ValueError, match="on_degenerate"):
        normalise_log_weights([0.0], on_degenerate="ignore")


@pytest.mark.parametrize(
    "logw, pattern",
    [
        ([0.0, np.nan, np.nan, -1.0], "2 NaN value"),
        ([0.0, np.inf], r"1 value\(s\) equal to \+inf"),
        ([], "empty"),
        (3.0, "at least one axis"),
        (["a"], "real numbers"),
    ],
)
@pytest.mark.parametrize("func", [normalise_log_weights, weights_from_log, effective_sample_size_from_log])
def test_bad_log_weights_raise(func, logw, pattern):
    with pytest.raises(ValueError, match=pattern):
        func(logw)


@settings(max_examples=100, deadline=None)
@given(arrays(np.float64, st.integers(1, 30), elements=st.floats(-1e6, 1e6) | st.just(-np.inf)))
def test_never_nan_and_sums_to_one(logw):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        w = weights_from_log(logw)
    assert np.all(np.isfinite(w)) and np.all(w >= 0)
    assert abs(w.sum() - 1.0) < 1e-12


# ---------------------------------------------------------------- effective sample size


@pytest.mark.parametrize("m", [1, 2, 17, 1000])
def test_ess_closed_forms(m):
    assert effective_sample_size(np.full(m, 1.0 / m)) == pytest.approx(m, rel=1e-12)
    one_hot = np.zeros(m)
    one_hot[m // 2] = 1.0
    assert effective_sample_size(one_hot) == pytest.approx(1.0, rel=1e-15)
    assert effective_sample_size_from_log(np.full(m, -1234.5)) == pytest.approx(m, rel=1e-12)
    assert effective_sample_size_from_log(np.log(one_hot, where=one_hot > 0, out=np.full(m, -np.inf))) == 1.0


def test_ess_two_groups_closed_form():
    # k particles share weight 1/k, the rest zero: N_eff = k
    w = np.r_[np.full(7, 1 / 7), np.zeros(13)]
    assert effective_sample_size(w) == pytest.approx(7.0, rel=1e-12)
    # w = (p, 1-p): N_eff = 1 / (p² + (1-p)²)
    p = 0.3
    assert effective_sample_size([p, 1 - p]) == pytest.approx(1 / (p**2 + (1 - p) ** 2), rel=1e-14)


def test_ess_from_log_matches_ess_of_weights_and_survives_underflow():
    rng = np.random.default_rng(8)
    logw = rng.normal(scale=3.0, size=(5, 40))
    direct = 1.0 / np.sum(np.exp(2 * (logw - logsumexp(logw, axis=-1, keepdims=True))), axis=-1)
    np.testing.assert_allclose(effective_sample_size_from_log(logw), direct, rtol=1e-12)
    np.testing.assert_allclose(effective_sample_size_from_log(logw - 5000.0), direct, rtol=1e-9)
    np.testing.assert_allclose(effective_sample_size(weights_from_log(logw)), direct, rtol=1e-12)
    assert effective_sample_size_from_log(np.full(6, -np.inf)) == pytest.approx(6.0)
    with pytest.raises(ValueError, match="-inf"):
        effective_sample_size_from_log(np.full(6, -np.inf), on_degenerate="raise")


def test_ess_is_scale_invariant():
    w = np.array([1.0, 2.0, 3.0])
    assert effective_sample_size(w) == pytest.approx(effective_sample_size(w / 6.0), rel=1e-15)


@pytest.mark.parametrize(
    "w, pattern",
    [([0.5, np.nan], "1 NaN"), ([0.5, np.inf], "infinite"), ([1.5, -0.5], "negative"), ([0.0, 0.0], "all weights are zero"), ([], "non-empty")],
)
def test_ess_bad_input(w, pattern):
    with pytest.raises(ValueError, match=pattern):
        effective_sample_size(w)


@pytest.mark.parametrize("bad, pattern", [(np.nan, "1 NaN"), (np.inf, r"\+inf")])
def test_float_arrays_with_nan_or_plus_inf_raise_too(bad, pattern):
    """A float ndarray (the filter's fast path) is refused like a list: w = NaN is not a weight."""
    logw = np.array([0.0, -1.0, bad, -2.0])
    with pytest.raises(ValueError, match=pattern):
        weights_from_log(logw)


def test_ess_refuses_one_all_zero_row_in_a_batch():
    """N_eff = (Σw)²/Σw² is 0/0 for a zero row: refused even when the other rows are fine."""
    with pytest.raises(ValueError, match="all weights are zero"):
        effective_sample_size(np.array([[0.5, 0.5], [0.0, 0.0]]))
