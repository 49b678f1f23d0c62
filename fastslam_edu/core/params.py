"""Parameter sets: immutable, comparable, hashable, copied and serialised one way.

:class:`Params` is the base of the package's frozen dataclasses of settings
(:class:`fastslam_edu.landmark.fastslam.FastSLAMParams`, :class:`fastslam_edu.grid.gridslam.GridSLAMParams`,
:class:`fastslam_edu.core.motion.MotionNoise`):

* ``a == b`` compares every field by value (arrays element by element), and
  ``hash(a)`` agrees with it, so a parameter set can key a dict of results;
* array fields are stored read-only, so the default instance cannot be changed in place;
* ``a.replace(**changes)`` is the one way to copy with changes (validated again);
* ``a.to_dict()`` the one way to serialise: plain JSON values, nested parameter sets as dicts.
"""

from __future__ import annotations

import dataclasses

import numpy as np


def _frozen(value):
    """A hashable stand-in for a field value: arrays and lists as nested tuples."""
    if isinstance(value, np.ndarray):
        return ("array", value.shape, tuple(value.ravel().tolist()))
    if isinstance(value, (list, tuple)):
        return tuple(_frozen(v) for v in value)
    return value


def _plain(value):
    """A field value as JSON: arrays and tuples as lists, parameter sets as dicts, numpy scalars as Python numbers."""
    if isinstance(value, Params):
        return value.to_dict()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


class Params:
    """Base of the parameter dataclasses (declare them ``@dataclass(frozen=True, eq=False)``)."""

    def _key(self) -> tuple:
        return tuple(_frozen(getattr(self, f.name)) for f in dataclasses.fields(self))

    def __eq__(self, other) -> bool:
        return type(self) is type(other) and self._key() == other._key()

    def __hash__(self) -> int:
        return hash((type(self).__name__,) + self._key())

    def replace(self, **changes):
        """A copy with some fields changed, validated again; an unknown name raises ValueError."""
        names = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(changes) - names)
        if unknown:
            raise ValueError(f"{type(self).__name__}: unknown setting(s) {unknown}; valid: {sorted(names)}")
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """Every field as plain JSON values (arrays as nested lists, nested parameter sets as dicts)."""
        return {f.name: _plain(getattr(self, f.name)) for f in dataclasses.fields(self)}

    @staticmethod
    def read_only(a) -> np.ndarray:
        """``a`` as a float array that cannot be written (for array fields, in ``__post_init__``)."""
        a = np.array(a, dtype=float)
        a.setflags(write=False)
        return a
