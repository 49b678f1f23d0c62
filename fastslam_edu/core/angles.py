"""Angles: wrapping to the half-open interval (-π, π].

Every bearing residual and heading difference in the package goes through
:func:`wrap_angle`, so that an error of 359° is read as -1°.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


def wrap_angle(a):
    """Wrap angle(s) ``a`` [rad] to (-π, π].

    ``wrap(a) = a - 2π·ceil((a - π) / 2π)``, which maps π to π and -π to π.

    Parameters
    ----------
    a : float or ndarray, any shape

    Returns
    -------
    float or ndarray of the same shape, values in (-π, π].
    """
    a = np.asarray(a, dtype=float)
    out = a - 2.0 * np.pi * np.ceil((a - np.pi) / (2.0 * np.pi))
    return out if out.ndim else float(out)


@njit(cache=True, inline="always")
def wrap_angle_kernel(a):
    """:func:`wrap_angle` of one angle ``a`` [rad], compiled (for the filter's per-particle kernels)."""
    return a - 2.0 * math.pi * math.ceil((a - math.pi) / (2.0 * math.pi))
