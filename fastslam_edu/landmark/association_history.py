"""The association history of the final best particle, read back through its ancestors, and the merging of
landmark copies that history shows never seen together. See :mod:`fastslam_edu.landmark.association`.
"""

from __future__ import annotations

import numpy as np

from fastslam_edu.landmark.landmark_existence import RENAME_HEIR, RENAME_INSTANT, RENAME_PARTICLE, RENAME_TAKEN


def best_history(assoc: np.ndarray, parents: np.ndarray, instant_of: np.ndarray, m: int,
                 renames: np.ndarray | None = None) -> np.ndarray:
    """The association history of final particle ``m``: the identity its ancestors gave each sighting (n,).

    ``renames`` (C, 4), the rows of hand-overs written
    (:func:`fastslam_edu.landmark.landmark_existence.retire_landmarks`): an identity that one of its ancestors
    handed over is read as the identity it took, for the sightings before and after."""
    out = np.full(assoc.shape[1], -1, dtype=np.int64)
    order = np.argsort(instant_of, kind="stable")
    bounds = np.searchsorted(instant_of[order], np.arange(parents.shape[0] + 1))
    ancestor = np.empty(parents.shape[0], dtype=np.int64)
    for q in range(parents.shape[0] - 1, -1, -1):
        m = int(parents[q, m])
        ancestor[q] = m
        rows = order[bounds[q]:bounds[q + 1]]
        out[rows] = assoc[m, rows]
    if renames is None or len(renames) == 0:
        return out
    rows = np.asarray(renames)
    ours = rows[ancestor[rows[:, RENAME_INSTANT]] == rows[:, RENAME_PARTICLE]]
    taken = dict(zip(ours[:, RENAME_HEIR].tolist(), ours[:, RENAME_TAKEN].tolist()))
    for old in list(taken):  # a chain a -> b -> c ends at c (an identity is only ever handed to a newer landmark)
        new = taken[old]
        while new in taken:
            new = taken[new]
        taken[old] = new
    return np.array([taken.get(i, i) for i in out.tolist()], dtype=np.int64)


def seen_together(history: np.ndarray, instant_of: np.ndarray) -> set[tuple[int, int]]:
    """The pairs of identities ``(a, b)``, ``a < b``, that ``history`` (n,) gives sightings of one instant
    (``instant_of`` (n,)): two things the camera saw at once, so two landmarks."""
    pairs: set[tuple[int, int]] = set()
    given = history >= 0
    order = np.argsort(instant_of[given], kind="stable")
    h, q = history[given][order], instant_of[given][order]
    for chunk in np.split(h, np.flatnonzero(np.diff(q)) + 1):
        ids = sorted(set(chunk.tolist()))
        pairs.update((a, b) for i, a in enumerate(ids) for b in ids[i + 1:])
    return pairs


def merge_copies(landmarks, cov, ident, history, instant_of, radius: float):
    """The final map with its copies merged: ``(landmarks (L', 2), cov (L', 2, 2), ident (L',), history (n,))``.

    A map landmark within ``radius`` metres of an older one (a smaller identity) that ``history`` never gives a
    sighting of the same instant (:func:`seen_together`) is a copy of it, kept apart because the pose had
    drifted between the two: the two Gaussians become one (information form,
    :math:`\\Sigma = (\\Sigma_a^{-1} + \\Sigma_b^{-1})^{-1}`), under the older identity, which its sightings take in
    the history. The nearest older landmark is taken first; ``radius`` 0 merges nothing.
    """
    landmarks, cov = np.array(landmarks, dtype=float), np.array(cov, dtype=float)
    ident, history = np.array(ident, dtype=np.int64), np.array(history, dtype=np.int64)
    if radius <= 0 or len(ident) < 2:
        return landmarks, cov, ident, history
    together = seen_together(history, np.asarray(instant_of))
    alive = np.ones(len(ident), dtype=bool)
    for b in np.argsort(ident):
        d = np.linalg.norm(landmarks - landmarks[b], axis=1)
        older = alive & (ident < ident[b]) & (d <= radius)
        older &= np.array([(int(ident[a]), int(ident[b])) not in together for a in range(len(ident))])
        if not older.any():
            continue
        a = int(np.flatnonzero(older)[np.argmin(d[older])])
        info_a, info_b = np.linalg.inv(cov[a]), np.linalg.inv(cov[b])
        cov[a] = np.linalg.inv(info_a + info_b)
        landmarks[a] = cov[a] @ (info_a @ landmarks[a] + info_b @ landmarks[b])
        ia, ib = int(ident[a]), int(ident[b])
        partners = {j if i == ib else i for i, j in together if ib in (i, j)}
        together |= {(min(ia, o), max(ia, o)) for o in partners if o != ia}  # what b was seen with, a now is
        history[history == ident[b]] = ident[a]
        alive[b] = False
    return landmarks[alive], cov[alive], ident[alive], history


__all__ = ["best_history", "seen_together", "merge_copies"]
