"""Tests of fastslam_edu.weights.

Independent references: scipy.special.logsumexp, exact ratios of weights
given as logs (including values like 1e-400 that no float can hold), and the
closed forms N_eff = M (uniform) and 1 (one-hot).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.special import logsumexp

from fastslam_edu.weights import (
    effective_sample_size,
    effective_sample_size_from_log,
    is_degenerate,
    log_sum_exp,
    normalise_log_weights,
    weights_from_log,
)

# ---------------------------------------------------------------- log-sum-exp


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("axis", [-1, 0, 1])
def test_log_sum_exp_matches_scipy(seed, axis):
    rng = np.random.default_rng(seed)
    a = rng.normal(scale=10 ** (seed + 1), size=(4, 7, 5))
    a[0, 0, 0] = -np.inf
    np.testing.assert_allclose(log_sum_exp(a, axis=axis), logsumexp(a, axis=axis), rtol=1e-13, atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(arrays(np.float64, st.integers(1, 20), elements=st.floats(-1e300, 700)))
def test_log_sum_exp_matches_scipy_property(a):
    # LSE can be ~0 (e.g. log(1 + e^-11) = 1.7e-5): relative error alone is not meaningful there
    np.testing.assert_allclose(log_sum_exp(a), logsumexp(a), rtol=1e-12, atol=1e-14)


def test_log_sum_exp_where_the_naive_formula_fails():
    # naive log(sum(exp(a))) = log(0) = -inf here, and inf for the second
    assert log_sum_exp([-1000.0, -1000.0]) == pytest.approx(-1000.0 + math.log(2.0), rel=1e-15)
    assert log_sum_exp([1000.0, 1000.0]) == pytest.approx(1000.0 + math.log(2.0), rel=1e-15)


def test_log_sum_exp_of_all_minus_inf_is_minus_inf_without_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert log_sum_exp([-np.inf, -np.inf]) == -np.inf
        np.testing.assert_array_equal(log_sum_exp(np.array([[-np.inf, -np.inf], [0.0, -np.inf]])), [-np.inf, 0.0])
        assert log_sum_exp(np.empty(0)) == -np.inf
        assert log_sum_exp([np.inf, 0.0]) == np.inf


def test_log_sum_exp_rejects_nan():
    with pytest.raises(ValueError, match="1 NaN"):
        log_sum_exp([0.0, np.nan])


# ---------------------------------------------------------------- normalisation


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
    ell = normalise_log_weights(300.0 * logw)  # wide spread: many weights underflow, their logs do not
    np.testing.assert_allclose(ell, 300.0 * logw - logsumexp(300.0 * logw, axis=-1, keepdims=True), rtol=1e-12)


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
