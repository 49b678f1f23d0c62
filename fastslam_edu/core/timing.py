"""Timing a run: its wall time, and the part of it numba spent compiling.

The first call of a compiled kernel in a process compiles it, or loads it from numba's
cache (``njit(cache=True)``): tens of seconds on a first run (an empty cache: a fresh
install, Colab), a fraction of a second later. ``filter_seconds`` should say how fast the
filter is, not how fast the compiler is: :class:`RunTimer` keeps the two apart, from
numba's own events (``numba:compiler_lock`` is held while numba compiles a kernel or
loads it from its cache; nested holds count once).

    with RunTimer() as timer:
        ...  # the run
    timer.filter_seconds, timer.compile_seconds  # wall time without, and spent in, compilation [s]
"""

from __future__ import annotations

import time

from numba.core import event

#: The numba event that spans compiling a kernel, or loading it from the cache.
COMPILE_EVENT = "numba:compiler_lock"


class RunTimer:
    """Context manager: ``total_seconds`` of the block, ``compile_seconds`` of it in numba's compiler, and
    ``filter_seconds`` = total − compile (with ``NUMBA_DISABLE_JIT=1`` nothing compiles: compile 0)."""

    def __enter__(self) -> "RunTimer":
        self._compiling = event.TimingListener()
        event.register(COMPILE_EVENT, self._compiling)
        self._start = time.perf_counter()
        return self

    def __exit__(self, *exc) -> None:
        self.total_seconds = time.perf_counter() - self._start
        event.unregister(COMPILE_EVENT, self._compiling)

    @property
    def compile_seconds(self) -> float:
        """Seconds spent compiling kernels (or loading them from numba's cache) inside the block."""
        return self._compiling.duration if self._compiling.done else 0.0

    @property
    def filter_seconds(self) -> float:
        """Seconds of the block without those of compilation."""
        return self.total_seconds - self.compile_seconds
