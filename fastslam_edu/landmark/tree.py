"""A persistent balanced binary tree of landmark filters: FastSLAM's O(M log N) map.

Why a tree
----------
A FastSLAM particle carries one 2×2 EKF :math:`(\\mu_k^{[m]}, \\Sigma_k^{[m]})` per
landmark, :math:`k = 0 \\dots N-1`. Resampling draws :math:`M` particles with
replacement, so a parent with several offspring must be *copied*: each offspring
will update its own landmarks afterwards. Copying dense arrays costs
:math:`O(N)` per particle, :math:`O(MN)` per step, although a measurement step
changes only the few landmarks it sees. Montemerlo et al. (2002, section 4)
store each particle's landmarks in a balanced binary tree instead and copy
**only the path** to a changed leaf:

* resampling copies a *reference* to the parent's tree: :math:`O(1)` per particle;
* updating landmark :math:`k` builds a new leaf and new copies of the
  :math:`\\lceil \\log_2 N \\rceil` internal nodes above it; every subtree off the
  path is shared with the old tree: :math:`O(\\log N)` per particle;
* reading landmark :math:`k` walks :math:`\\lceil \\log_2 N \\rceil` levels.

One step then costs :math:`O(M \\log N)` instead of :math:`O(MN)`, and memory
grows by :math:`O(M \\log N)` nodes per step instead of :math:`O(MN)` floats.

Shape of the tree
-----------------
Landmark indices are known in advance (``0 … N-1``), so no rebalancing is
needed (the notes' C++ used a red–black tree because their keys arrive in any
order): the tree is the *complete* binary tree over ``0 … 2^d - 1`` with
depth :math:`d = \\lceil \\log_2 N \\rceil`. The path to key ``k`` is spelled by
its binary digits, most significant first: 0 = left, 1 = right. For ``N = 8``
and ``k = 5 = 101₂``: right, left, right.

Representation (immutable, so sharing is safe)
-----------------------------------------------
* an internal node is a tuple ``(left, right)``;
* a leaf is a :class:`Landmark`, the named tuple ``(mu, sigma, count)``: the
  landmark's EKF — mean and covariance as **read-only** arrays, shapes (2,)
  and (2, 2), so that an accidental ``mu[0] = …`` raises ``ValueError:
  assignment destination is read-only`` instead of silently changing every
  particle that shares the leaf — and the number of sightings it has used
  (the array engine's ``count``, which its robust gate needs);
* an empty subtree (no landmark stored below) is ``None``.

Whether a tuple is a node or a leaf follows from its depth. Nodes are never
mutated — :meth:`LandmarkTree.set` returns a new tree — so two trees that
share a node agree on every landmark below it, forever.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

__all__ = [
    "Landmark",
    "LandmarkTree",
    "tree_depth",
    "count_nodes",
    "shared_nodes",
    "count_new_nodes",
    "gather",
    "set_each",
    "trees_to_arrays",
]


def tree_depth(n_landmarks: int) -> int:
    """Depth :math:`d = \\lceil \\log_2 N \\rceil` of the complete tree over ``0 … N-1`` (0 for N = 1)."""
    return (int(n_landmarks) - 1).bit_length()


def _check_n_landmarks(n_landmarks) -> int:
    if isinstance(n_landmarks, bool) or not isinstance(n_landmarks, (int, np.integer)) or n_landmarks < 1:
        raise ValueError(f"the number of landmarks N must be an integer >= 1, got {n_landmarks!r}")
    return int(n_landmarks)


def _path_bits(k: int, depth: int) -> list[int]:
    """The branch :math:`b_i = \\lfloor k / 2^{d-1-i} \\rfloor \\bmod 2` (0 left, 1 right) at level ``i < d``."""
    return [k >> shift & 1 for shift in range(depth - 1, -1, -1)]


def _read_only(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


_FLOAT = np.dtype(float)


def _is_frozen(a) -> bool:
    """True for a float64 ndarray that is read-only, and so is every array it is a view of.

    Such an array can be stored in a leaf as it is: no copy is needed, since
    nothing writes to it by accident (a read-only view of a *writable* array
    is not frozen: the array it views could still change it).
    """
    if type(a) is not np.ndarray or a.dtype is not _FLOAT:
        return False
    while type(a) is np.ndarray:
        if a.flags.writeable:
            return False
        a = a.base
    return a is None


def _frozen_or_copy(a):
    """``a`` itself if :func:`_is_frozen`, else a read-only float copy (None when ``a`` is not numeric)."""
    if _is_frozen(a):
        return a
    try:
        return _read_only(np.array(a, dtype=float))
    except (TypeError, ValueError):
        return None


class Landmark(NamedTuple):
    """A leaf of the tree: the EKF of one landmark in one particle.

    Attributes
    ----------
    mu : ndarray, shape (2,), read-only
        Mean :math:`\\mu_k^{[m]}` [m].
    sigma : ndarray, shape (2, 2), read-only
        Covariance :math:`\\Sigma_k^{[m]}` [m²].
    count : int
        Sightings used so far (1 after the initialisation; the array engine's ``count``).
    """

    mu: np.ndarray
    sigma: np.ndarray
    count: int = 1


def _leaf_arrays(mu, sigma, count, *, batch: bool, caller: str):
    """Copies of ``mu (…, 2)``, ``sigma (…, 2, 2)`` as finite read-only float arrays, ``count`` as int(s) >= 1."""
    lead = "(M, " if batch else "("
    try:
        mu = np.array(mu, dtype=float)
        sigma = np.array(sigma, dtype=float)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{caller}: mu and sigma must be numeric arrays ({err})") from None
    want_mu, want_sigma = (mu.shape[:1] + (2,), mu.shape[:1] + (2, 2)) if batch else ((2,), (2, 2))
    if mu.ndim != len(want_mu) or mu.shape != want_mu:
        raise ValueError(f"{caller}: mu must have shape {lead}2), got {mu.shape}")
    if sigma.shape != want_sigma:
        raise ValueError(f"{caller}: sigma must have shape {lead}2, 2), got {sigma.shape}")
    for name, a in (("mu", mu), ("sigma", sigma)):
        if not np.isfinite(a).all():
            where = tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0])
            raise ValueError(f"{caller}: {name} has a non-finite value {a[where]} at index {where}")
    c = np.asarray(count)
    if c.dtype == bool or not np.issubdtype(c.dtype, np.integer) or c.shape not in ((), mu.shape[:-1]) \
            or (c < 1).any():
        raise ValueError(f"{caller}: count must be an integer >= 1 (one per landmark), got {count!r}")
    count = np.broadcast_to(c, mu.shape[:-1]).tolist()
    return _read_only(mu), _read_only(sigma), count


def _leaf(mu, sigma, count, caller: str) -> Landmark:
    """The checked leaf ``Landmark(mu, sigma, count)`` for one key: the fast path of :func:`_leaf_arrays`.

    ``mu`` (2,) and ``sigma`` (2, 2) are kept by reference when already
    frozen (:func:`_is_frozen`, e.g. another leaf's arrays) and copied once
    otherwise; finiteness is tested on the plain sum
    :math:`\\sum_i \\mu_i + \\sum_{ij} \\Sigma_{ij}` (NaN or ±inf whenever an entry is).
    Anything unusual — a wrong shape, a non-finite sum, a count that is not
    a Python int >= 1 — goes to :func:`_leaf_arrays`, which raises its clear
    error or converts the rare valid case (a NumPy integer count, a sum that
    overflows).
    """
    m, s = _frozen_or_copy(mu), _frozen_or_copy(sigma)
    if (m is not None and s is not None and m.shape == (2,) and s.shape == (2, 2)
            and type(count) is int and count >= 1 and math.isfinite(sum(m.tolist()) + sum(s.ravel().tolist()))):
        return Landmark(m, s, count)
    return Landmark(*_leaf_arrays(mu, sigma, count, batch=False, caller=caller))


@dataclass(frozen=True, slots=True, eq=False)
class LandmarkTree:
    """The landmarks of one particle: a persistent complete binary tree keyed by ``0 … N-1``.

    Build one with :meth:`empty` or :meth:`from_arrays`; :meth:`set` returns a
    *new* tree and leaves this one unchanged. All operations on one key cost
    :math:`O(\\log N)`.

    Attributes
    ----------
    root : tuple or None
        The root node (see the module docstring), None when no landmark is stored.
    n_landmarks : int
        :math:`N`, the number of valid keys.
    depth : int
        :math:`d = \\lceil \\log_2 N \\rceil`: a leaf is ``depth`` steps below the root.
    size : int
        Number of landmarks stored (``len(tree)``).
    """

    root: tuple | None
    n_landmarks: int
    depth: int
    size: int

    # ------------------------------------------------------------ construction

    @classmethod
    def empty(cls, n_landmarks: int) -> "LandmarkTree":
        """A tree for keys ``0 … N-1`` holding no landmark (root None): :math:`O(1)`."""
        N = _check_n_landmarks(n_landmarks)
        return cls(None, N, tree_depth(N), 0)

    @classmethod
    def from_arrays(cls, mu, sigma, seen=None, count=None) -> "LandmarkTree":
        """A tree holding landmark ``k`` for every ``k`` with ``seen[k]``, built bottom-up in :math:`O(N)`.

        Parameters
        ----------
        mu : array_like, shape (N, 2)
            Landmark means :math:`\\mu_k` [m].
        sigma : array_like, shape (N, 2, 2)
            Landmark covariances :math:`\\Sigma_k` [m²].
        seen : array_like of bool, shape (N,), optional
            Which landmarks to store (default: all).
        count : array_like of int, shape (N,), optional
            Sightings used per landmark (default 1).
        """
        mu, sigma, count = _leaf_arrays(mu, sigma, 1 if count is None else count, batch=True,
                                        caller="LandmarkTree.from_arrays")
        N = _check_n_landmarks(len(mu))
        seen = np.ones(N, dtype=bool) if seen is None else np.asarray(seen)
        if seen.shape != (N,) or seen.dtype != bool:
            raise ValueError(f"LandmarkTree.from_arrays: seen must be a bool array of shape ({N},), got "
                             f"{seen.dtype} {seen.shape}")
        depth = tree_depth(N)
        level: list = [Landmark(mu[k], sigma[k], count[k]) if seen[k] else None for k in range(N)]
        level += [None] * ((1 << depth) - N)
        for _ in range(depth):  # pair up children into parents, one level at a time
            level = [None if a is None and b is None else (a, b) for a, b in zip(level[0::2], level[1::2])]
        return cls(level[0], N, depth, int(seen.sum()))

    # ------------------------------------------------------------ queries

    def _check_key(self, k) -> int:
        if type(k) is not int:
            if isinstance(k, bool) or not isinstance(k, (int, np.integer)):
                raise ValueError(f"landmark index must be an integer, got {k!r} ({type(k).__name__})")
            k = int(k)
        if not 0 <= k < self.n_landmarks:
            raise ValueError(f"landmark index {k} outside 0 … {self.n_landmarks - 1} (N = {self.n_landmarks})")
        return k

    def get(self, k: int) -> Landmark | None:
        """The :class:`Landmark` ``(mu, sigma, count)`` stored at ``k`` (read-only arrays), or None.

        Walks :math:`d = \\lceil \\log_2 N \\rceil` levels: :math:`O(\\log N)`.
        """
        node = self.root
        for bit in _path_bits(self._check_key(k), self.depth):
            if node is None:
                return None
            node = node[bit]
        return node

    def __contains__(self, k) -> bool:
        return self.get(k) is not None

    def __len__(self) -> int:
        return self.size

    def items(self) -> Iterator[tuple[int, Landmark]]:
        """``(k, landmark)`` for every stored landmark, in index order: :math:`O(N)`."""

        def walk(node, first: int, level: int):
            if node is None:
                return
            if level == 0:
                yield first, node
                return
            half = 1 << (level - 1)
            yield from walk(node[0], first, level - 1)
            yield from walk(node[1], first + half, level - 1)

        yield from walk(self.root, 0, self.depth)

    def keys(self) -> list[int]:
        """Indices of the stored landmarks, sorted."""
        return [k for k, _ in self.items()]

    def nodes(self) -> Iterator[tuple[int, int, tuple]]:
        """Every stored node as ``(level, position, node)``, breadth first.

        ``level`` 0 is the root and ``level == depth`` the leaves; ``position``
        counts from the left within a level (so a leaf's position is its key).
        For drawing the tree and counting shared nodes.
        """
        current = [(0, self.root)] if self.root is not None else []
        for level in range(self.depth + 1):
            for position, node in current:
                yield level, position, node
            if level < self.depth:
                current = [(2 * p + b, child) for p, node in current for b, child in enumerate(node)
                           if child is not None]

    # ------------------------------------------------------------ the persistent update

    def set(self, k: int, mu, sigma, count: int = 1) -> "LandmarkTree":
        """A new tree in which landmark ``k`` holds ``Landmark(mu, sigma, count)``; this tree is unchanged.

        Path copying: the new tree gets a new leaf and new copies of the
        :math:`d` internal nodes from the root down to it (:math:`d + 1` new
        nodes); every other subtree is the *same object* as in this tree.
        Time and memory :math:`O(\\log N)`. ``mu`` and ``sigma`` are stored as
        read-only arrays: copied, unless they already are read-only float
        arrays (such as another leaf's), which are stored by reference.

        Raises
        ------
        ValueError
            On a key that is not an integer in ``0 … N-1``, ``mu``/``sigma``
            of the wrong shape or with NaN/inf, or a count < 1.
        """
        bits = _path_bits(self._check_key(k), self.depth)
        return self._with_leaf(bits, _leaf(mu, sigma, count, "LandmarkTree.set"))

    def _with_leaf(self, bits: list[int], leaf: Landmark) -> "LandmarkTree":
        """Path copy for a key given by its branch ``bits`` (no checks: inputs are checked by the caller).

        Walking down, keep the sibling :math:`s_i` of the path at each level
        :math:`i` (None below an empty subtree); walking up, the new node at
        level :math:`i` is ``(new, s_i)`` if :math:`b_i = 0`, else ``(s_i, new)``.
        """
        siblings = []
        node = self.root
        for bit in bits:
            if node is None:
                siblings.append(None)
            elif bit:
                siblings.append(node[0])
                node = node[1]
            else:
                siblings.append(node[1])
                node = node[0]
        new = leaf
        for bit, sibling in zip(reversed(bits), reversed(siblings)):  # rebuild the path bottom-up
            new = (sibling, new) if bit else (new, sibling)
        return LandmarkTree(new, self.n_landmarks, self.depth, self.size + (node is None))

    def __repr__(self) -> str:
        return f"LandmarkTree(N={self.n_landmarks}, depth={self.depth}, stored={self.size})"


# ---------------------------------------------------------------- node sharing


def _node_ids(tree: LandmarkTree, into: set[int]) -> int:
    """Add the ids of the nodes of ``tree`` not yet in ``into``; return how many were added.

    A node already in ``into`` is not descended into: its whole subtree is
    already there (nodes are immutable), which makes counting the distinct
    nodes of M trees that share most of their nodes cheap.
    """
    added = 0
    stack = [(tree.root, 0)]
    while stack:
        node, level = stack.pop()
        if node is None or id(node) in into:
            continue
        into.add(id(node))
        added += 1
        if level < tree.depth:
            stack.append((node[0], level + 1))
            stack.append((node[1], level + 1))
    return added


def count_nodes(*trees: LandmarkTree) -> int:
    """Number of *distinct* nodes (internal nodes and leaves) in the given trees, by identity.

    For one tree holding every key of ``N = 2^d`` this is :math:`2N - 1`; for
    :math:`M` trees that share subtrees it is far less than :math:`M(2N-1)`.
    """
    seen: set[int] = set()
    return sum(_node_ids(t, seen) for t in trees)


def shared_nodes(a: LandmarkTree, b: LandmarkTree) -> int:
    """Number of nodes of ``b`` that are also nodes of ``a`` (the same objects).

    After ``b = a.set(k, …)`` it is ``count_nodes(b) − (depth + 1)``: all but the path.
    """
    ids: set[int] = set()
    _node_ids(a, ids)
    return count_nodes(b) - _node_ids(b, ids)


def count_new_nodes(new: Sequence[LandmarkTree], old: Sequence[LandmarkTree]) -> int:
    """Number of distinct nodes of the trees ``new`` that are in none of the trees ``old``.

    The nodes a filter step created and kept: after M particles each update
    one landmark, :math:`M (\\lceil \\log_2 N \\rceil + 1)`.
    """
    ids: set[int] = set()
    for t in old:
        _node_ids(t, ids)
    return sum(_node_ids(t, ids) for t in new)


# ---------------------------------------------------------------- one key, M particles


def _check_trees(trees: Sequence[LandmarkTree], caller: str) -> tuple[int, int]:
    if len(trees) == 0:
        raise ValueError(f"{caller}: no trees given")
    N, depth = trees[0].n_landmarks, trees[0].depth
    for m, t in enumerate(trees):
        if not isinstance(t, LandmarkTree) or t.n_landmarks != N:
            raise ValueError(f"{caller}: trees[{m}] is {t!r}; expected a LandmarkTree with N = {N}")
    return N, depth


def gather(trees: Sequence[LandmarkTree], keys) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Landmarks ``keys`` (n,) of each of the M particles' trees, as arrays: :math:`O(M n \\log N)`.

    Returns
    -------
    mu : ndarray, shape (M, n, 2)
        :math:`\\mu_{k_j}^{[m]}` [m]; NaN where particle ``m`` has not stored ``k_j``.
    sigma : ndarray, shape (M, n, 2, 2)
        :math:`\\Sigma_{k_j}^{[m]}` [m²]; NaN where not stored.
    seen : ndarray of bool, shape (M, n)
    count : ndarray of int64, shape (M, n)
        Sightings used; 0 where not stored.
    """
    N, depth = _check_trees(trees, "gather")
    paths = [_path_bits(trees[0]._check_key(k), depth) for k in np.atleast_1d(np.asarray(keys)).tolist()]
    leaves = []
    for t in trees:
        for bits in paths:
            node = t.root
            for bit in bits:
                if node is None:
                    break
                node = node[bit]
            leaves.append(node)
    M, n = len(trees), len(paths)
    if all(leaf is not None for leaf in leaves):  # the common case: one C call per array
        mu = np.array([leaf[0] for leaf in leaves]).reshape(M, n, 2)
        sigma = np.array([leaf[1] for leaf in leaves]).reshape(M, n, 2, 2)
        count = np.array([leaf[2] for leaf in leaves], dtype=np.int64).reshape(M, n)
        return mu, sigma, np.ones((M, n), dtype=bool), count
    seen = np.array([leaf is not None for leaf in leaves])
    mu = np.full((M * n, 2), np.nan)
    sigma = np.full((M * n, 2, 2), np.nan)
    count = np.zeros(M * n, dtype=np.int64)
    if seen.any():
        stored = [leaf for leaf in leaves if leaf is not None]
        mu[seen] = [leaf[0] for leaf in stored]
        sigma[seen] = [leaf[1] for leaf in stored]
        count[seen] = [leaf[2] for leaf in stored]
    return mu.reshape(M, n, 2), sigma.reshape(M, n, 2, 2), seen.reshape(M, n), count.reshape(M, n)


def set_each(trees: Sequence[LandmarkTree], k: int, mu, sigma, count=1, which=None) -> list[LandmarkTree]:
    """``[trees[m].set(k, mu[m], sigma[m], count[m]) …]`` for the M particles: :math:`O(M \\log N)`.

    Parameters
    ----------
    trees : sequence of M LandmarkTree
    k : int
        Landmark index.
    mu : array_like, shape (M, 2)
    sigma : array_like, shape (M, 2, 2)
    count : int or array_like of int, shape (M,)
        Sightings used (default 1).
    which : array_like of bool, shape (M,), optional
        Only particles with ``which[m]`` get a new tree; the others keep theirs
        (the same object: nothing is copied). Default: all.

    Returns
    -------
    list of M LandmarkTree
        New trees; the input trees are unchanged. ``mu`` and ``sigma`` are
        validated and copied once, and the leaves hold read-only rows of the copy.
    """
    N, depth = _check_trees(trees, "set_each")
    bits = _path_bits(trees[0]._check_key(k), depth)
    mu, sigma, count = _leaf_arrays(mu, sigma, count, batch=True, caller="set_each")
    M = len(trees)
    if len(mu) != M:
        raise ValueError(f"set_each: mu has {len(mu)} rows for {M} trees")
    if which is None:
        return [t._with_leaf(bits, Landmark(mu[m], sigma[m], count[m])) for m, t in enumerate(trees)]
    which = np.asarray(which)
    if which.shape != (M,) or which.dtype != bool:
        raise ValueError(f"set_each: which must be a bool array of shape ({M},), got {which.dtype} {which.shape}")
    return [t._with_leaf(bits, Landmark(mu[m], sigma[m], count[m])) if w else t
            for m, (t, w) in enumerate(zip(trees, which.tolist()))]


def trees_to_arrays(trees: Sequence[LandmarkTree]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Dense ``mu (M, N, 2)``, ``sigma (M, N, 2, 2)``, ``seen (M, N)``, ``count (M, N)`` of M trees: :math:`O(MN)`.

    Unstored landmarks get ``mu = 0``, ``sigma = I``, ``count = 0`` (the array
    engine's initial values), so the result is a valid
    :class:`fastslam_edu.landmark.particle_set.ParticleSet` map.
    """
    N, _ = _check_trees(trees, "trees_to_arrays")
    M = len(trees)
    mu = np.zeros((M, N, 2))
    sigma = np.tile(np.eye(2), (M, N, 1, 1))
    seen = np.zeros((M, N), dtype=bool)
    count = np.zeros((M, N), dtype=np.int64)
    for m, t in enumerate(trees):
        for k, leaf in t.items():
            mu[m, k], sigma[m, k], count[m, k] = leaf
            seen[m, k] = True
    return mu, sigma, seen, count
