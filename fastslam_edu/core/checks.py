"""Checking array arguments, with messages that name the function, the argument and the bad entry.

Every public function of the package that takes arrays from a user checks them
here, so that a NaN, a wrong shape or a string gives one clear line instead of a
traceback from deep inside numpy.
"""

from __future__ import annotations

import numpy as np


def finite_array(name: str, a, caller: str, trailing: tuple[int, ...] = (), dtype=float) -> np.ndarray:
    """``a`` as an array of shape ``(..., *trailing)`` with only finite values.

    Raises a ValueError that starts with ``caller`` and names the argument
    ``name``: not numeric, the wrong trailing shape, or the first NaN / inf
    (its value and index). Integer arrays (``dtype=int``) are not checked for
    finiteness (they are).
    """
    try:
        a = np.asarray(a, dtype=dtype)
    except (TypeError, ValueError):
        raise ValueError(f"{caller}: {name} must be numeric, got {a!r}") from None
    n = len(trailing)
    if n and (a.ndim < n or a.shape[a.ndim - n :] != tuple(trailing)):
        want = "(..., " + ", ".join(str(t) for t in trailing) + ")"
        raise ValueError(f"{caller}: {name} must have shape {want}, got shape {a.shape}")
    if a.dtype.kind in "fc" and not np.isfinite(a).all():
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0])
        raise ValueError(f"{caller}: {name} contains a non-finite value ({a[bad]}) at index {bad}")
    return a


def array_summary(a) -> str:
    """A short printable form of an array for error messages (at most 12 entries shown, 6 digits)."""
    return np.array2string(np.asarray(a), threshold=12, edgeitems=3, precision=6)


def float_array(a, name: str) -> np.ndarray:
    """``a`` as a float array; a ValueError naming ``name`` if it is not numeric."""
    try:
        return np.asarray(a, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be an array of real numbers, got {a!r}") from exc


def point_rows(a, name: str, *, allow_nan: bool = False) -> np.ndarray:
    """An (n, 2) array of finite points (NaN rows allowed on request)."""
    p = float_array(a, name)
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f"{name} must have shape (n, 2) (x, y in metres), got shape {p.shape}")
    bad = ~np.isfinite(p).all(axis=1)
    if allow_nan:
        bad &= ~np.isnan(p).any(axis=1)
    if np.any(bad):
        rows = np.flatnonzero(bad)
        raise ValueError(f"{name} has {rows.size} row(s) with NaN or inf values, e.g. row(s) {rows[:5].tolist()}")
    return p
