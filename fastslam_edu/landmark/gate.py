"""The outlier gate of the filter and its escape, for sightings no particle explains (real data's misread barcodes
and ranges off by metres)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit


# ---------------------------------------------------------------- the compiled kernels (one instant's sightings)


@njit(cache=True)
def gate_escapes(t, j, unexplained_since, escape_s, escape):
    """``escape[i]``: sighting ``i`` (of landmark ``j[i]``, at time ``t``) skips the gate.

    True once the landmark's sightings have been unexplained since
    ``unexplained_since[j]`` for ``escape_s`` seconds or more (``inf`` while explained).
    """
    for i in range(j.shape[0]):
        escape[i] = t - unexplained_since[j[i]] >= escape_s


@njit(cache=True)
def gate_record(t, j, explained, unexplained_since):
    """Note which sightings at ``t`` some particle explained: ``inf`` for those, else the first unexplained time."""
    since = unexplained_since[j]  # read before writing: a landmark may be seen twice in one instant
    for i in range(j.shape[0]):
        unexplained_since[j[i]] = math.inf if explained[i] else min(since[i], t)


# ---------------------------------------------------------------- the gate as an object (the Python loop)


class Gate:
    """The outlier gate (``FastSLAMParams.gate_chi2``) and its escape (``gate_escape_s``), as one object.

    ``chi2``: reject a sighting that every particle puts beyond :math:`d^2 >` ``chi2``
    (None: no gate). Per landmark, the time of the first of its sightings that no
    particle has explained since (``unexplained_since``, ``inf`` while they are
    explained): once that is ``escape_s`` seconds ago, its sightings are applied
    without the gate until one is explained again.
    """

    def __init__(self, chi2: float | None, escape_s: float | None, n_landmarks: int):
        self.chi2 = chi2
        self.escape_s = np.inf if escape_s is None else float(escape_s)
        self.unexplained_since = np.full(n_landmarks, np.inf)

    def escaped(self, t: float, landmarks) -> np.ndarray:
        """Bool (n,): the sightings of ``landmarks`` (n,) at time ``t`` that skip the gate (:func:`gate_escapes`)."""
        j = landmark_indices(landmarks)
        escape = np.empty(len(j), dtype=bool)
        gate_escapes(float(t), j, self.unexplained_since, self.escape_s, escape)
        return escape

    def record(self, t: float, landmarks, explained) -> None:
        """Note which sightings at ``t`` some particle explained (``explained`` (n,) bool; :func:`gate_record`)."""
        gate_record(float(t), landmark_indices(landmarks), np.asarray(explained, dtype=bool).reshape(-1),
                    self.unexplained_since)


def landmark_indices(landmarks) -> np.ndarray:
    """Landmark indices as the compiled kernels take them: int64, shape (n,)."""
    return np.asarray(landmarks, dtype=np.int64).reshape(-1)


__all__ = ["gate_escapes", "gate_record", "Gate", "landmark_indices"]
