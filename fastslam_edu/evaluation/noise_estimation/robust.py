"""Robust spread: the scaled median absolute deviation, which a few gross outliers barely move."""

from __future__ import annotations

import numpy as np
from scipy.stats import median_abs_deviation

__all__ = ["robust_std", "finite_values"]


def robust_std(e) -> float:
    """Robust standard deviation ``σ̂ = 1.4826 · median |e − median e|`` (scaled MAD).

    ``scipy.stats.median_abs_deviation(e, scale="normal")`` (the factor is
    ``1/Φ⁻¹(3/4) = 1.482602…``), after checking that ``e`` is non-empty and
    finite, with an error that says which (SciPy returns NaN for an empty
    input or one with a NaN in it).

    For Gaussian data it estimates the standard deviation (relative standard
    error ≈ 0.78/√n, against 0.71/√n for the sample std); each gross outlier
    moves it by about as much as one ordinary point, not by its size.

    Parameters
    ----------
    e : array_like, shape (n,)
        Finite values, n ≥ 1.

    Returns
    -------
    float
    """
    return float(median_abs_deviation(finite_values(e, "robust_std"), scale="normal"))


def finite_values(e, caller: str) -> np.ndarray:
    """``e`` flattened to a non-empty 1-D float array of finite values, or a ValueError naming ``caller``."""
    e = np.asarray(e, dtype=float).ravel()
    if e.size == 0:
        raise ValueError(f"{caller}: no values (empty input)")
    if not np.isfinite(e).all():
        raise ValueError(f"{caller}: {int(np.count_nonzero(~np.isfinite(e)))} NaN or inf value(s) in the input")
    return e
