"""Importance weights in log space: normalisation and effective sample size.

Why log space
-------------
In FastSLAM the importance weight of particle ``m`` is the product of the
likelihoods of every measurement it has explained since the last resampling,

.. math::

    w^{[m]} \\propto \\prod_{j} p(z_j \\mid s^{t,[m]}, z^{t-1}, u^t, n^t).

Each factor is a probability *density*, often much smaller than one. A product
of 200 measurements with likelihood ``1e-3`` each is ``1e-600``, far below the
smallest positive double (``~4.9e-324``; ``~2.2e-308`` for normal numbers): it
underflows to exactly ``0.0`` for *every* particle, and normalising
``w / Σw`` then computes ``0 / 0 = NaN``. Only the *ratios* between
particles matter, and those are perfectly representable.

So we keep ``ℓ^{[m]} = log w^{[m]}`` and **add** log-likelihoods
(``200 · log 1e-3 ≈ -1381.6`` is an ordinary float). Normalising subtracts
the log of the total,

.. math::

    \\tilde ℓ^{[m]} = ℓ^{[m]} - \\log \\sum_{k} e^{ℓ^{[k]}},

computed with the log-sum-exp trick (shift by the maximum ``a* = max_k ℓ^{[k]}``
so the largest exponent is ``e^0 = 1``):

.. math::

    \\log \\sum_k e^{ℓ^{[k]}} = a^* + \\log \\sum_k e^{ℓ^{[k]} - a^*}.

SciPy has both: ``scipy.special.logsumexp`` (the left side) and
``scipy.special.log_softmax`` (``ℓ - logsumexp(ℓ)``, shifted as above).
:func:`normalise_log_weights` is ``log_softmax`` with the checks a filter
needs (NaN, ``+inf``, no particles, every weight zero).

Degenerate case: if every ``ℓ^{[m]} = -∞`` (every particle has likelihood
exactly zero, e.g. a gate rejected the measurement for all of them), the
weights are ``0/0``: :func:`normalise_log_weights` returns uniform weights by
default (the particles are equally implausible) or raises on request;
:func:`is_degenerate` tells the caller which case happened.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from scipy.special import log_softmax, logsumexp

from fastslam_edu.core.checks import array_summary

__all__ = [
    "is_degenerate",
    "normalise_log_weights",
    "weights_from_log",
    "effective_sample_size",
    "effective_sample_size_from_log",
]

OnDegenerate = Literal["uniform", "raise"]


def _reject_nan(a: np.ndarray, name: str) -> None:
    n_nan = int(np.count_nonzero(np.isnan(a)))
    if n_nan:
        raise ValueError(
            f"{name} contains {n_nan} NaN value(s) out of {a.size} "
            f"(a log-likelihood was NaN: check the measurement, the innovation "
            f"covariance and the particle states); {name} = {array_summary(a)}"
        )


def _as_log_weights(logw, name: str = "logw") -> np.ndarray:
    """Validate log-weights: real, at least 1-D, non-empty, no NaN, no +inf."""
    try:
        a = np.asarray(logw, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be an array of real numbers, got {logw!r}") from exc
    if a.ndim == 0:
        raise ValueError(f"{name} must have at least one axis (the particles), got the scalar {a}")
    if a.shape[-1] == 0:
        raise ValueError(f"{name} is empty (shape {a.shape}): there are no particles to weight")
    _reject_nan(a, name)
    n_posinf = int(np.count_nonzero(np.isposinf(a)))
    if n_posinf:
        raise ValueError(
            f"{name} contains {n_posinf} value(s) equal to +inf (an infinite "
            f"likelihood, e.g. a zero-variance density); {name} = {array_summary(a)}"
        )
    return a


def is_degenerate(logw) -> np.ndarray | bool:
    """True where every log-weight is ``-inf`` (all likelihoods are zero).

    Parameters
    ----------
    logw : array_like, shape (..., M)
        Log-weights of ``M`` particles (leading batch dims allowed).

    Returns
    -------
    bool or ndarray of bool, shape (...)
    """
    a = _as_log_weights(logw)
    out = np.all(np.isneginf(a), axis=-1)
    return out if out.ndim else bool(out)


def normalise_log_weights(logw, *, on_degenerate: OnDegenerate = "uniform") -> np.ndarray:
    """Normalised log-weights ``ℓ̃ = ℓ - log Σ_k exp(ℓ^{[k]})``, so that ``Σ_m exp(ℓ̃^{[m]}) = 1``.

    ``scipy.special.log_softmax`` along the last axis, after checking the input.

    Parameters
    ----------
    logw : array_like, shape (..., M)
        Unnormalised log-weights ``ℓ^{[m]} = log w^{[m]}`` of ``M`` particles
        along the last axis (leading batch dims allowed). ``-inf`` (weight
        zero) is allowed; NaN and ``+inf`` are not.
    on_degenerate : {"uniform", "raise"}, default "uniform"
        What to do when *every* entry of a row is ``-inf``, so the weights are
        ``0/0``. ``"uniform"``: return ``-log M`` for every particle (all are
        equally implausible; call :func:`is_degenerate` first to find out
        whether this happened). ``"raise"``: raise a ValueError.

    Returns
    -------
    ndarray, shape (..., M)
        Normalised log-weights (``≤ 0``; ``-inf`` stays ``-inf``).

    Raises
    ------
    ValueError
        On NaN or ``+inf`` in ``logw`` (the message counts them), on an empty
        particle axis, on an unknown ``on_degenerate``, and on a degenerate row
        when ``on_degenerate="raise"`` (the message shows the values).

    Examples
    --------
    200 measurements of likelihood 1e-3 for one particle, 1e-3·2 for another:
    the products underflow to 0, the logs do not.

    >>> ell = [200 * np.log(1e-3), 200 * np.log(1e-3) + np.log(2.0)]
    >>> np.exp(normalise_log_weights(ell)).round(4)
    array([0.3333, 0.6667])
    """
    if on_degenerate not in ("uniform", "raise"):
        raise ValueError(f"on_degenerate must be 'uniform' or 'raise', got {on_degenerate!r}")
    a = _as_log_weights(logw)
    m = a.shape[-1]
    degenerate = np.all(np.isneginf(a), axis=-1, keepdims=True)
    if np.any(degenerate):
        if on_degenerate == "raise":
            n_bad = int(np.count_nonzero(degenerate))
            raise ValueError(
                f"all {m} log-weights are -inf in {n_bad} row(s) (every particle's "
                f"likelihood underflowed or is exactly zero), so the weights are 0/0; "
                f"logw = {array_summary(a)}"
            )
    # a degenerate row becomes all zeros, whose log-softmax is -log M (uniform)
    return log_softmax(np.where(degenerate, 0.0, a), axis=-1)


def weights_from_log(logw, *, on_degenerate: OnDegenerate = "uniform") -> np.ndarray:
    """Normalised weights ``w^{[m]} = exp(ℓ̃^{[m]})``, summing to 1 along the last axis.

    Parameters
    ----------
    logw : array_like, shape (..., M)
        Unnormalised log-weights (see :func:`normalise_log_weights`).
    on_degenerate : {"uniform", "raise"}, default "uniform"
        Passed to :func:`normalise_log_weights`.

    Returns
    -------
    ndarray, shape (..., M)
        Non-negative weights, each row summing to 1 (to round-off).
    """
    a = logw if isinstance(logw, np.ndarray) and logw.dtype == float else None
    if a is not None and a.ndim == 1 and a.size:
        # Fast path for the filter's inner loop: NaN and +inf make the maximum
        # non-finite, and so does a row of all -inf; those go to the checked path.
        top = a.max()
        if np.isfinite(top):
            w = np.exp(a - top)
            return w / w.sum()
    w = np.exp(normalise_log_weights(logw, on_degenerate=on_degenerate))
    # exp of normalised logs already sums to 1 within a few ulps; divide once
    # more so the sum is as close to 1 as floating point allows.
    return w / np.sum(w, axis=-1, keepdims=True)


def effective_sample_size(w) -> np.ndarray | float:
    """Effective sample size ``N_eff = 1 / Σ_m (w^{[m]})²`` of normalised weights.

    Computed as ``(Σ w)² / Σ w²``, which equals ``1 / Σ w²`` when ``Σ w = 1``
    and does not depend on the normalisation. ``N_eff = M`` for uniform
    weights and ``1`` when one particle carries all the weight; a common rule
    resamples only when ``N_eff < M / 2``.

    Parameters
    ----------
    w : array_like, shape (..., M)
        Non-negative, finite weights of ``M`` particles (leading batch dims allowed).

    Returns
    -------
    float or ndarray, shape (...)
        ``N_eff`` in ``[1, M]``.

    Raises
    ------
    ValueError
        On NaN, ``inf``, negative weights, an empty particle axis, or a row of all zeros.
    """
    try:
        w = np.asarray(w, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"w must be an array of real numbers, got {w!r}") from exc
    if w.ndim == 0 or w.shape[-1] == 0:
        raise ValueError(f"w must have a non-empty particle axis, got shape {w.shape}")
    _reject_nan(w, "w")
    if not np.all(np.isfinite(w)):
        raise ValueError(f"w contains infinite values: w = {array_summary(w)}")
    if np.any(w < 0):
        raise ValueError(f"w contains {int(np.count_nonzero(w < 0))} negative weight(s): w = {array_summary(w)}")
    total = np.sum(w, axis=-1)
    if np.any(total <= 0):
        raise ValueError(f"all weights are zero in at least one row: N_eff is undefined; w = {array_summary(w)}")
    w = w / total[..., None]  # scale first: avoids overflow/underflow of Σw²
    out = 1.0 / np.sum(w * w, axis=-1)
    return out if out.ndim else float(out)


def effective_sample_size_from_log(logw, *, on_degenerate: OnDegenerate = "uniform") -> np.ndarray | float:
    """Effective sample size from (unnormalised) log-weights, computed in log space.

    .. math::

        N_\\mathrm{eff} = \\frac{(\\sum_m w^{[m]})^2}{\\sum_m (w^{[m]})^2}
                        = \\exp\\big(2\\,\\mathrm{LSE}(ℓ) - \\mathrm{LSE}(2ℓ)\\big)
                        = \\exp\\big(-\\mathrm{LSE}(2\\tilde ℓ)\\big),

    with ``LSE = scipy.special.logsumexp``.

    Parameters
    ----------
    logw : array_like, shape (..., M)
        Log-weights (see :func:`normalise_log_weights`).
    on_degenerate : {"uniform", "raise"}, default "uniform"
        For a row of all ``-inf``: treat as uniform (``N_eff = M``) or raise.

    Returns
    -------
    float or ndarray, shape (...)
        ``N_eff`` in ``[1, M]``.
    """
    ell = normalise_log_weights(logw, on_degenerate=on_degenerate)
    out = np.exp(-logsumexp(2.0 * ell, axis=-1))
    return out if out.ndim else float(out)
