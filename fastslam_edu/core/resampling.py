"""Resampling: draw particle indices in proportion to the importance weights.

All four schemes share one picture. Lay the normalised weights ``w_1 … w_M``
end to end on ``[0, 1)``; particle ``i`` owns the interval
``[c_{i-1}, c_i)`` of length ``w_i``, where ``c_i = w_1 + … + w_i`` is the
cumulative sum (``c_0 = 0``, ``c_M = 1``). Pick ``n`` positions
``u_1 ≤ … ≤ u_n`` in ``[0, 1)`` and return, for each, the particle whose
interval contains it: ``i = min{ i : c_i > u }``, the *inverse CDF*,
computed for all positions at once with :func:`numpy.searchsorted`
(:func:`inverse_cdf`). The schemes differ only in how the positions are drawn:

=============  ====================================================  =========================
scheme         positions                                             offspring-count variance
=============  ====================================================  =========================
roulette       ``n`` independent ``U[0, 1)``, sorted (multinomial)   ``n w_i (1 - w_i)``
stratified     ``u_j = (j + U_j) / n``, one uniform per stratum       ≤ multinomial
systematic     ``u_j = (j + U) / n``, one uniform for all             smallest in practice
residual       ``⌊n w_i⌋`` copies, then multinomial on the rest       ``R r_i (1 - r_i)``
=============  ====================================================  =========================

Every scheme is **unbiased**: the expected number of copies (offspring) of
particle ``i`` is ``E[N_i] = n w_i``. They differ in the variance of ``N_i``;
lower variance means less randomness added by resampling. Systematic
resampling is the "low-variance sampler" of Thrun, Burgard & Fox,
*Probabilistic Robotics*, Table 4.4, used by FastSLAM.

Conventions
-----------
* Each function takes normalised weights ``w`` (shape ``(M,)``), a
  :class:`numpy.random.Generator` and an optional number of draws ``n``
  (default ``M``), and returns ``n`` integer indices into ``0 … M-1``,
  **sorted ascending** (copies of a particle are adjacent). The new particle
  set is ``particles[indices]``; reset the weights to ``1/n`` afterwards.
* ``w`` must be non-negative, finite and sum to 1 within ``1e-8``: a sum
  further from 1 is a bug upstream (forgotten normalisation) and raises;
  round-off within the tolerance is removed by renormalising.
* The cumulative sum is computed as ``cumsum(w) / cumsum(w)[-1]``, so it is
  non-decreasing and its last entry is exactly ``1.0`` (a plain cumsum of ten
  ``0.1`` ends at ``0.9999999999999999``, and a position in the gap would
  index particle ``M``). Positions are clipped below 1, since
  ``(u + n - 1) / n`` can round up to exactly ``1.0``.

References
----------
R. Douc, O. Cappé, E. Moulines, "Comparison of resampling schemes for
particle filtering", ISPA 2005. N. Chopin & O. Papaspiliopoulos, *An
Introduction to Sequential Monte Carlo*, Springer 2020, ch. 9.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numba import njit

from fastslam_edu.core.checks import array_summary

__all__ = [
    "WEIGHT_SUM_TOLERANCE",
    "validate_weights",
    "cumulative_weights",
    "inverse_cdf",
    "inverse_cdf_kernel",
    "roulette_positions",
    "roulette_kernel",
    "stratified_positions",
    "systematic_positions",
    "roulette",
    "stratified",
    "systematic",
    "residual",
    "offspring_counts",
    "RESAMPLERS",
    "get_resampler",
]

#: Largest accepted ``|Σw - 1|``; smaller deviations are treated as round-off.
WEIGHT_SUM_TOLERANCE = 1e-8

#: Largest double below 1: positions are clipped to ``[0, _BELOW_ONE]``.
_BELOW_ONE = float(np.nextafter(1.0, 0.0))


def validate_weights(w) -> np.ndarray:
    """Check normalised weights and remove round-off from their sum.

    Parameters
    ----------
    w : array_like, shape (M,)
        Weights: finite, non-negative, ``|Σw - 1| ≤ 1e-8``.

    Returns
    -------
    ndarray, shape (M,)
        ``w / Σw`` as float.

    Raises
    ------
    ValueError
        If ``w`` is not 1-D and non-empty, contains NaN, ``inf`` or negative
        values, or sums to a value further than ``1e-8`` from 1 (the message
        gives the sum).
    """
    try:
        w = np.asarray(w, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"weights must be an array of real numbers, got {w!r}") from exc
    if w.ndim == 1 and w.size:
        # the common case in two reductions: a NaN or a negative weight fails the minimum, then an inf the sum
        if np.minimum.reduce(w) >= 0.0:
            total = float(np.add.reduce(w))
            if abs(total - 1.0) <= WEIGHT_SUM_TOLERANCE:
                return w / total
    if w.ndim != 1 or w.size == 0:
        raise ValueError(f"weights must be a non-empty 1-D array (one weight per particle), got shape {w.shape}")
    n_nan = int(np.count_nonzero(np.isnan(w)))
    if n_nan:
        raise ValueError(f"weights contain {n_nan} NaN value(s) out of {w.size}: w = {array_summary(w)}")
    if not np.all(np.isfinite(w)):
        raise ValueError(f"weights contain infinite values: w = {array_summary(w)}")
    if np.any(w < 0):
        raise ValueError(
            f"weights contain {int(np.count_nonzero(w < 0))} negative value(s) "
            f"(min {w.min():.6g}): w = {array_summary(w)}"
        )
    total = float(np.sum(w))
    if abs(total - 1.0) > WEIGHT_SUM_TOLERANCE:
        raise ValueError(
            f"weights must be normalised (sum to 1 within {WEIGHT_SUM_TOLERANCE:g}), but they sum "
            f"to {total:.15g} (off by {total - 1.0:+.3g}); normalise them first (fastslam_edu.core.weights.weights_from_log)"
        )
    return w / total


def cumulative_weights(w: np.ndarray) -> np.ndarray:
    """Cumulative sum ``c_i = w_1 + … + w_i`` with ``c_M`` exactly 1.

    Dividing by the last entry (``x / x == 1`` exactly in IEEE arithmetic, and
    division by a positive number keeps the order) makes the sum end at
    ``1.0`` while staying non-decreasing.

    Parameters
    ----------
    w : ndarray, shape (M,)
        Validated weights (see :func:`validate_weights`).

    Returns
    -------
    ndarray, shape (M,)
        Non-decreasing, last entry ``1.0``.
    """
    c = np.cumsum(w)
    return c / c[-1]


def inverse_cdf(u, w) -> np.ndarray:
    """Index of the particle whose weight interval contains each position.

    .. math::

        i(u) = \\min\\{\\, i : c_i > u \\,\\}, \\qquad c_i = \\sum_{k \\le i} w_k,

    so particle ``i`` is returned for ``u ∈ [c_{i-1}, c_i)``, with probability
    ``w_i`` when ``u ~ U[0, 1)``. A particle of weight zero owns an empty
    interval and is never returned. Positions at or above 1 (round-off) are
    clipped to the largest double below 1 and select the last particle of
    positive weight.

    Parameters
    ----------
    u : array_like, shape (n,)
        Positions in ``[0, 1]``; sorted positions give sorted indices.
    w : array_like, shape (M,)
        Normalised weights (validated here).

    Returns
    -------
    ndarray of intp, shape (n,)
        Indices in ``0 … M-1``.
    """
    return inverse_cdf_kernel(np.asarray(u, dtype=float).reshape(-1), validate_weights(w))


@njit(cache=True)
def inverse_cdf_kernel(u, w):
    """:func:`inverse_cdf` for weights already validated, compiled: the resamplers here and the
    filter's compiled run (:func:`fastslam_edu.landmark.particle_resampling.resampling_indices`) share it.

    The cumulative weights :math:`c_i` (normalised to end at 1, :func:`cumulative_weights`), then for each
    position its :math:`\\min\\{i : c_i > u\\}` by bisection, the loop ``np.searchsorted(c, u, side="right")`` runs
    (the same comparisons, so the same indices; written out, it compiles without numpy's generic sort
    machinery)."""
    m = w.shape[0]
    c = np.empty(m)
    total = 0.0
    for i in range(m):
        total += w[i]
        c[i] = total
    last = c[m - 1]
    for i in range(m):
        c[i] /= last
    out = np.empty(u.shape[0], dtype=np.int64)
    for j in range(u.shape[0]):
        uj = min(max(u[j], 0.0), _BELOW_ONE)
        lo, hi = 0, m  # c[lo - 1] <= uj < c[hi] (c[-1] = -inf, c[m] = +inf): halve [lo, hi) until one index
        while lo < hi:
            mid = (lo + hi) // 2
            if c[mid] <= uj:
                lo = mid + 1
            else:
                hi = mid
        out[j] = lo
    return out


@njit(cache=True)
def roulette_positions(n, rng):
    """``n`` independent ``U[0, 1)`` positions, sorted (:func:`roulette`)."""
    return np.sort(rng.random(n))


@njit(cache=True)
def in_increasing_order(idx):
    """The particles drawn, ``idx`` (M,) with values in ``0 … M-1``, in increasing order: each particle's
    offspring counted, then written out in particle order (:math:`O(M)`, a counting sort). A resampled set is a
    multiset: the order of its members changes nothing but where each is stored."""
    m = idx.shape[0]
    offspring = np.zeros(m, dtype=np.int64)
    for i in idx:
        offspring[i] += 1
    out = np.empty(m, dtype=np.int64)
    j = 0
    for i in range(m):
        for _ in range(offspring[i]):
            out[j] = i
            j += 1
    return out


@njit(cache=True)
def roulette_kernel(w, rng):
    """:func:`roulette` with ``n = M`` for validated weights ``w`` (M,), compiled, without a sort.

    The inverse CDF :math:`i(u) = \\min\\{i : c_i > u\\}` never decreases as :math:`u` grows, so the
    indices of the *unsorted* positions, put in increasing order (:func:`in_increasing_order`), are those of the
    sorted positions: the same numbers as ``inverse_cdf_kernel(roulette_positions(M, rng), w)`` (numba compiles a
    loop in a fraction of the time it takes for ``np.sort``).
    """
    return in_increasing_order(inverse_cdf_kernel(rng.random(w.shape[0]), w))


@njit(cache=True)
def stratified_positions(n, rng):
    """``u_j = (j + U_j) / n``, one uniform per stratum (:func:`stratified`)."""
    return (np.arange(n) + rng.random(n)) / n


@njit(cache=True)
def systematic_positions(n, rng):
    """``u_j = (j + U) / n``, one uniform for all (:func:`systematic`)."""
    return (np.arange(n) + rng.random()) / n


def _check_rng(rng) -> None:
    if not isinstance(rng, np.random.Generator):
        raise TypeError(
            f"rng must be a numpy.random.Generator (e.g. numpy.random.default_rng(seed)), "
            f"got {type(rng).__name__}"
        )


def _number_of_draws(n, m: int) -> int:
    if n is None:
        return m
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n (the number of draws) must be a positive integer, got {n!r}")
    return int(n)


def _resample(w, rng, n, positions) -> np.ndarray:
    """Check the arguments, draw the ``positions(n, rng)`` and return the :func:`inverse_cdf` of them."""
    _check_rng(rng)
    w = validate_weights(w)
    return inverse_cdf_kernel(positions(_number_of_draws(n, w.size), rng), w)


def roulette(w, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """Multinomial ("roulette wheel") resampling: ``n`` independent draws.

    Positions ``u_j ~ U[0, 1)`` i.i.d. (sorted), then :func:`inverse_cdf`.
    Offspring counts are ``Multinomial(n, w)``: ``E[N_i] = n w_i``,
    ``Var[N_i] = n w_i (1 - w_i)``, the largest of the four schemes.

    Parameters
    ----------
    w : array_like, shape (M,)
        Normalised weights.
    rng : numpy.random.Generator
    n : int, optional
        Number of draws (default ``M``).

    Returns
    -------
    ndarray of intp, shape (n,)
        Sorted indices into ``0 … M-1``.
    """
    return _resample(w, rng, n, roulette_positions)


def stratified(w, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """Stratified resampling: one uniform position in each of ``n`` strata.

    ``u_j = (j + U_j) / n`` with ``U_j ~ U[0, 1)`` independent,
    ``j = 0 … n-1``: exactly one position falls in each ``[j/n, (j+1)/n)``.
    Unbiased, and ``Var[N_i]`` never exceeds the multinomial one.

    Arguments and result as :func:`roulette`.
    """
    return _resample(w, rng, n, stratified_positions)


def systematic(w, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """Systematic ("low-variance") resampling: one uniform, ``n`` evenly spaced pointers.

    ``u_j = (j + U) / n``, ``U ~ U[0, 1)``, ``j = 0 … n-1`` (Thrun et al.'s
    ``r ~ U[0, 1/n)`` and pointers ``r + j/n``). Particle ``i`` receives
    ``⌊n w_i⌋`` or ``⌈n w_i⌉`` copies, the smallest possible spread; a set
    of equal weights is reproduced exactly. Needs a single random number.

    Arguments and result as :func:`roulette`.
    """
    return _resample(w, rng, n, systematic_positions)


def residual(w, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """Residual resampling: deterministic ``⌊n w_i⌋`` copies, multinomial for the rest.

    1. Particle ``i`` gets ``k_i = ⌊n w_i⌋`` copies for sure.
    2. ``R = n - Σ_i k_i`` draws remain. They are drawn multinomially with the
       *residual* weights ``r_i = (n w_i - k_i) / R``.

    Then ``E[N_i] = k_i + R r_i = n w_i`` (unbiased) and
    ``Var[N_i] = R r_i (1 - r_i)``. (A common bug draws the ``R`` remaining
    indices with ``w_i - k_i`` instead of ``n w_i - k_i``: negative residuals
    for every particle with ``k_i ≥ 1``, and a biased result.)

    Arguments and result as :func:`roulette`.
    """
    _check_rng(rng)
    w = validate_weights(w)
    n = _number_of_draws(n, w.size)
    scaled = n * w
    counts = np.floor(scaled).astype(np.intp)
    n_rest = n - int(counts.sum())
    if n_rest > 0:
        rest = scaled - counts
        drawn = roulette(rest / rest.sum(), rng, n_rest)
        counts += np.bincount(drawn, minlength=w.size)
    return np.repeat(np.arange(w.size), counts)


def offspring_counts(indices, m: int) -> np.ndarray:
    """Number of copies ``N_i`` of each particle in a resampled index set.

    Parameters
    ----------
    indices : array_like of int, shape (n,)
        Output of a resampler.
    m : int
        Number of particles ``M`` before resampling.

    Returns
    -------
    ndarray of int, shape (M,)
        ``N_i = #{ j : indices_j = i }``; ``Σ_i N_i = n``.
    """
    idx = np.asarray(indices)
    if idx.ndim != 1 or not (idx.size == 0 or np.issubdtype(idx.dtype, np.integer)):
        raise ValueError(f"indices must be a 1-D integer array, got dtype {idx.dtype} and shape {idx.shape}")
    if idx.size and (idx.min() < 0 or idx.max() >= m):
        raise ValueError(f"indices must lie in 0 … {m - 1}, got values from {idx.min()} to {idx.max()}")
    return np.bincount(idx.astype(np.intp), minlength=m)


Resampler = Callable[..., np.ndarray]

#: Name -> resampling function, for configuration files and the CLI.
RESAMPLERS: dict[str, Resampler] = {
    "roulette": roulette,
    "multinomial": roulette,  # the statistician's name for the same wheel (filterpy: multinomial_resample)
    "systematic": systematic,
    "stratified": stratified,
    "residual": residual,
}


def get_resampler(name: str) -> Resampler:
    """The resampling function called ``name`` (see :data:`RESAMPLERS`).

    Raises
    ------
    ValueError
        If ``name`` is unknown; the message lists the valid names.
    """
    try:
        return RESAMPLERS[name]
    except (KeyError, TypeError):
        raise ValueError(
            f"unknown resampler {name!r}; valid names are: {', '.join(sorted(RESAMPLERS))}"
        ) from None
