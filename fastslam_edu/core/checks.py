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
