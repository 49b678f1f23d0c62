"""FastSLAM 1.0 with each particle's landmarks in a :class:`~fastslam_edu.landmark_tree.LandmarkTree`.

The array engine (:mod:`fastslam_edu.fastslam`) keeps the map of all particles
in dense arrays ``mu (M, K, 2)``, ``sigma (M, K, 2, 2)``; resampling copies
them with fancy indexing — :math:`O(MK)` per resampling step, whatever the
number of landmarks seen. Here (Montemerlo et al. 2002, section 4):

=========  ======================  ==========================================
poses      (M, 3) array            :math:`x^{[m]}`, as in the array engine
trees      list of M LandmarkTree  :math:`(\\mu_k^{[m]}, \\Sigma_k^{[m]})` for the landmarks seen
logw       (M,) array              :math:`\\log w^{[m]}`
=========  ======================  ==========================================

* **resampling** copies tree *references*: :math:`O(M)`;
* **updating** landmark :math:`k` in particle :math:`m` path-copies
  :math:`\\lceil \\log_2 K \\rceil + 1` nodes: :math:`O(M \\log K)` per measurement;
* the EKF arithmetic itself is the array engine's: the few landmarks measured
  at an instant are read out of the trees (:func:`~fastslam_edu.landmark_tree.gather`),
  updated by :func:`fastslam_edu.fastslam.update_with_measurements`, vectorised
  over the M particles, and written back into new trees
  (:func:`~fastslam_edu.landmark_tree.set_each`).

The filter consumes the random numbers in the same order as
:func:`fastslam_edu.fastslam.run_fastslam` (it calls the same ``propagate`` and
``resample_if_needed``) and applies the measurements of one instant with the
same function (batched distinct landmarks, a landmark seen twice in a second
round, range-dependent :math:`R`, the robust gate), so for the same seed it
gives the same path and map.

In Python it is *slower* than the array engine for MR.CLAM's 15 landmarks —
numpy copies a particle's 15 × 7 numbers in one C call, while the tree walks
Python objects — and faster only once :math:`K` reaches the thousands
(:func:`step_cost` measures both; see the chapter "Why FastSLAM is O(M log K)").
"""

from __future__ import annotations

import gc
import time
import tracemalloc
from dataclasses import dataclass, fields

import numpy as np

from .datasets.log import EventStream
from .fastslam import (
    FastSLAMParams,
    FastSLAMResult,
    ParticleSet,
    run_fastslam,
    update_with_measurements,
)
from .landmark_tree import LandmarkTree, count_new_nodes, gather, set_each, tree_depth, trees_to_arrays
from .resampling import systematic
from .weights import weights_from_log

__all__ = [
    "TreeParticleSet",
    "FastSLAMTreeResult",
    "update_trees_with_measurements",
    "run_fastslam_tree",
    "step_particles",
    "step_cost",
    "crossover_k",
]


@dataclass
class TreeParticleSet:
    """The M particles of FastSLAM 1.0, each map a :class:`LandmarkTree` (see the module docstring)."""

    poses: np.ndarray
    trees: list[LandmarkTree]
    logw: np.ndarray

    @classmethod
    def initial(cls, n_particles: int, n_landmarks: int, x0) -> "TreeParticleSet":
        """All particles at pose ``x0`` (3,), sharing one empty tree, uniform weights."""
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (3,) or not np.all(np.isfinite(x0)):
            raise ValueError(f"initial pose must be 3 finite numbers (x, y, theta), got {x0!r}")
        if isinstance(n_particles, bool) or not isinstance(n_particles, (int, np.integer)) or n_particles < 1:
            raise ValueError(f"n_particles must be an integer >= 1, got {n_particles!r}")
        M = int(n_particles)
        empty = LandmarkTree.empty(n_landmarks)
        return cls(poses=np.tile(x0, (M, 1)), trees=[empty] * M, logw=np.zeros(M))

    def __len__(self) -> int:
        return self.poses.shape[0]

    @property
    def n_landmarks(self) -> int:
        return self.trees[0].n_landmarks

    @property
    def weights(self) -> np.ndarray:
        """Normalised weights :math:`w^{[m]}`, shape (M,)."""
        return weights_from_log(self.logw)

    def select(self, indices) -> "TreeParticleSet":
        """Particles ``indices`` as a new set, uniform weights: the **trees are shared, not copied**.

        :math:`O(M)` whatever :math:`K`: offspring of one parent hold the same
        tree object, which is safe because a tree is never modified — an
        update builds a new tree (:meth:`LandmarkTree.set`).
        """
        idx = np.asarray(indices)
        return TreeParticleSet(
            poses=self.poses[idx], trees=[self.trees[i] for i in idx.tolist()], logw=np.zeros(len(idx))
        )

    def with_known_map(self, landmarks) -> "TreeParticleSet":
        """Every particle holding one shared tree of the known landmarks ``(K, 2)`` (localisation)."""
        K = len(landmarks)
        known = LandmarkTree.from_arrays(landmarks, np.tile(np.eye(2) * 1e-6, (K, 1, 1)), count=np.ones(K, int))
        self.trees = [known] * len(self)
        return self

    def update(self, z, k, R, *, update_map: bool = True, gate_chi2: float | None = None, escape=None,
               power=None, proposal_loglik=None) -> np.ndarray:
        """Step 2 for the measurements of one instant: :func:`update_trees_with_measurements`."""
        return update_trees_with_measurements(self, z, k, R, update_map=update_map, gate_chi2=gate_chi2,
                                              escape=escape, power=power, proposal_loglik=proposal_loglik)

    def to_particle_set(self) -> ParticleSet:
        """The same particles as a dense :class:`~fastslam_edu.fastslam.ParticleSet` (:math:`O(MK)`)."""
        mu, sigma, seen, count = trees_to_arrays(self.trees)
        return ParticleSet(poses=self.poses.copy(), mu=mu, sigma=sigma, seen=seen, logw=self.logw.copy(),
                           count=count)


# ---------------------------------------------------------------- step 2 on trees


def update_trees_with_measurements(
    particles: TreeParticleSet, z, k, R, *, update_map: bool = True, gate_chi2: float | None = None, escape=None,
    power=None, proposal_loglik=None,
) -> np.ndarray:
    """Step 2 for all the measurements of one instant: ``z`` (n, 2) of landmarks ``k`` (n,).

    1. **Read** the :math:`n' \\le n` distinct landmarks measured out of every
       particle's tree (:func:`~fastslam_edu.landmark_tree.gather`,
       :math:`O(M n' \\log K)`) into a small :class:`~fastslam_edu.fastslam.ParticleSet`
       of :math:`n'` landmarks, which shares ``poses`` and ``logw`` with ``particles``.
    2. **Update** it with the array engine's own
       :func:`~fastslam_edu.fastslam.update_with_measurements` — initialisation,
       EKF update, weights, robust gate: the same numbers, by construction.
    3. **Write back** each landmark that changed in a particle (mean, covariance,
       seen or count) by path copying (:func:`~fastslam_edu.landmark_tree.set_each`,
       :math:`O(\\log K)` each); a particle whose landmark did not change (an
       outlier for it, or a known map) keeps its tree.

    ``R`` is (2, 2) or one per measurement (n, 2, 2). Returns a bool (n,):
    False where no particle explains the measurement (rejected by the gate, unless escaped).
    """
    k = np.asarray(k, dtype=int).reshape(-1)
    keys, local = np.unique(k, return_inverse=True)  # local index of each measurement's landmark
    mu, sigma, seen, count = gather(particles.trees, keys)
    mu[~seen], sigma[~seen] = 0.0, np.eye(2)  # the array engine's values for a landmark not seen yet
    before = mu.copy(), sigma.copy(), seen.copy(), count.copy()
    measured = ParticleSet(poses=particles.poses, mu=mu, sigma=sigma, seen=seen, logw=particles.logw, count=count)
    explained = update_with_measurements(measured, z, local, R, update_map=update_map, gate_chi2=gate_chi2,
                                        escape=escape, power=power, proposal_loglik=proposal_loglik)
    particles.logw = measured.logw
    changed = ((mu != before[0]).any(axis=-1) | (sigma != before[1]).any(axis=(-2, -1))
               | (seen != before[2]) | (count != before[3]))  # (M, n')
    for j, key in enumerate(keys.tolist()):
        if changed[:, j].any():
            particles.trees = set_each(particles.trees, key, mu[:, j], sigma[:, j], count[:, j], which=changed[:, j])
    return explained


# ---------------------------------------------------------------- the whole run


@dataclass
class FastSLAMTreeResult(FastSLAMResult):
    """:class:`~fastslam_edu.fastslam.FastSLAMResult` of the tree filter.

    ``particles`` is the final set converted to dense arrays (so every tool
    made for the array engine applies); ``trees`` is the final set itself.
    """

    trees: TreeParticleSet | None = None


def run_fastslam_tree(
    stream: EventStream,
    params: FastSLAMParams = FastSLAMParams(),
    rng: np.random.Generator | int | None = 0,
    **options,
) -> FastSLAMTreeResult:
    """Run FastSLAM 1.0 with tree maps over an event stream.

    The array engine's run loop (:func:`fastslam_edu.fastslam.run_fastslam`, whose
    keyword options it takes) with particles that store their maps in trees
    (:class:`TreeParticleSet`): the same random numbers, the same result to
    rounding; ``filter_seconds`` is this filter's time and ``trees`` the final
    tree-backed set.
    """
    result = run_fastslam(stream, params, rng, particle_class=TreeParticleSet, **options)
    return FastSLAMTreeResult(**{f.name: getattr(result, f.name) for f in fields(result)}, trees=result.final)


# ---------------------------------------------------------------- the cost of one step, measured


def _step_world(n_landmarks: int, n_particles: int, n_updates: int, seed: int):
    """A full map of K landmarks held by M particles (dense and tree), poses, measurements, resampling indices.

    Landmarks uniform in a 100 m square, every particle near the origin,
    ``n_updates`` distinct landmarks measured (exact range and bearing from
    the origin); indices from systematic resampling of uniform random weights.
    """
    rng = np.random.default_rng(seed)
    K, M = int(n_landmarks), int(n_particles)
    if K < n_updates:
        raise ValueError(f"need K >= {n_updates} landmarks, got K = {K}")
    lm = rng.uniform(-50.0, 50.0, (K, 2))
    sigma = np.tile(np.eye(2) * 0.01, (K, 1, 1))
    poses = np.column_stack([rng.normal(0.0, 0.05, (M, 2)), rng.normal(0.0, 0.01, M)])
    keys = rng.choice(K, size=n_updates, replace=False)
    d = lm[keys]
    z = np.column_stack([np.hypot(d[:, 0], d[:, 1]), np.arctan2(d[:, 1], d[:, 0])])
    w = rng.random(M)
    indices = systematic(w / w.sum(), rng)
    dense = ParticleSet(
        poses=poses, mu=np.broadcast_to(lm, (M, K, 2)).copy(), sigma=np.broadcast_to(sigma, (M, K, 2, 2)).copy(),
        seen=np.ones((M, K), dtype=bool), logw=np.zeros(M),
    )
    tree = TreeParticleSet(poses=poses.copy(), trees=[LandmarkTree.from_arrays(lm, sigma)] * M, logw=np.zeros(M))
    return dense, tree, indices, keys, z


def step_particles(
    particles: ParticleSet | TreeParticleSet, indices, keys, z, R=None
) -> ParticleSet | TreeParticleSet:
    """One filter step on either representation: resample ``indices``, then update landmarks ``keys`` with ``z``.

    ``particles`` is a :class:`~fastslam_edu.fastslam.ParticleSet` (dense: ``select``
    copies :math:`M \\times K` landmark filters) or a :class:`TreeParticleSet`
    (``select`` copies M references, the update path-copies
    :math:`M \\cdot n (\\lceil \\log_2 K\\rceil + 1)` nodes). ``indices`` (M,), ``keys`` (n,),
    ``z`` (n, 2); ``R`` (2, 2), default ``diag(0.1², 0.02²)``. No gate. Returns the
    new set; the input is unchanged.
    """
    R = np.diag([0.1**2, 0.02**2]) if R is None else R
    new = particles.select(indices)
    if isinstance(new, TreeParticleSet):
        update_trees_with_measurements(new, z, keys, R)
    else:
        update_with_measurements(new, z, keys, R)
    return new


def _seconds_per_step(particles, indices, keys, z, n_steps: int) -> float:
    """Mean wall time of ``n_steps`` calls of :func:`step_particles` (each result dropped at once)."""
    gc.collect()
    t0 = time.perf_counter()
    for _ in range(n_steps):
        step_particles(particles, indices, keys, z)
    return (time.perf_counter() - t0) / n_steps


def step_cost(n_landmarks: int, n_particles: int = 100, *, n_updates: int = 2, repeats: int = 5,
              seed: int = 0, min_block_seconds: float = 0.02) -> dict:
    """Measure one filter step (resample all M particles, update ``n_updates`` landmarks) on trees and dense arrays.

    Timing, like :mod:`timeit`: a *block* runs the step ``n`` times in a row
    (``n`` chosen so that a block lasts at least ``min_block_seconds``) and
    gives the mean time per step; ``repeats`` blocks alternate between the two
    representations (so a busy machine slows both alike), and the median and
    the minimum over the blocks are reported. Memory is measured with
    :mod:`tracemalloc` in a separate run (tracing slows Python code down).

    Returns
    -------
    dict
        ``K, M, n_updates, depth, repeats``;
        ``tree_seconds, dense_seconds`` (median), ``tree_seconds_min, dense_seconds_min``,
        ``speedup`` (dense / tree, medians);
        ``tree_bytes_peak, dense_bytes_peak``: the most allocated at once during the step;
        ``tree_bytes_retained, dense_bytes_retained``: what the new particle set holds beyond the old one;
        ``tree_nodes_created``: distinct nodes of the new trees that are in none of the old ones — per
        particle the union of the ``n`` root-to-leaf paths, at most ``tree_nodes_bound``
        :math:`= M n (\\lceil\\log_2 K\\rceil + 1)` (the first update's copy of a node on both paths,
        the root at least, is replaced by the second's);
        ``dense_bytes_copied``: the landmark arrays ``select`` copies (:math:`\\propto MK`).
    """
    if int(repeats) < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats!r}")
    dense, tree, indices, keys, z = _step_world(n_landmarks, n_particles, n_updates, seed)
    out: dict = {"K": int(n_landmarks), "M": int(n_particles), "n_updates": int(n_updates),
                 "depth": tree_depth(n_landmarks), "repeats": int(repeats)}
    sets = {"tree": tree, "dense": dense}
    block = {name: max(1, int(np.ceil(min_block_seconds / _seconds_per_step(p, indices, keys, z, 1))))
             for name, p in sets.items()}  # the first call is also a warm-up
    times: dict[str, list[float]] = {name: [] for name in sets}
    for _ in range(int(repeats)):
        for name, p in sets.items():
            times[name].append(_seconds_per_step(p, indices, keys, z, block[name]))
    for name, p in sets.items():
        out[f"{name}_seconds"] = float(np.median(times[name]))
        out[f"{name}_seconds_min"] = float(min(times[name]))
        out[f"{name}_steps_per_block"] = block[name]
        gc.collect()
        started = not tracemalloc.is_tracing()
        if started:
            tracemalloc.start()
        try:
            before = tracemalloc.get_traced_memory()[0]
            tracemalloc.reset_peak()
            new = step_particles(p, indices, keys, z)
            current, peak = tracemalloc.get_traced_memory()
        finally:
            if started:
                tracemalloc.stop()
        out[f"{name}_bytes_peak"] = int(peak - before)
        out[f"{name}_bytes_retained"] = int(current - before)
        if name == "tree":
            out["tree_nodes_created"] = count_new_nodes(new.trees, tree.trees)
        del new
    out["tree_nodes_bound"] = int(n_particles) * int(n_updates) * (out["depth"] + 1)
    out["dense_bytes_copied"] = int(sum(a.nbytes for a in (dense.mu, dense.sigma, dense.seen, dense.count)))
    out["speedup"] = out["dense_seconds"] / out["tree_seconds"]
    return out


def crossover_k(rows: list[dict], stat: str = "seconds") -> float | None:
    """The K from which the tree is faster, from :func:`step_cost` results sorted by K.

    Where :math:`g(K) = \\log(t_\\text{dense} / t_\\text{tree})` crosses 0 for the last time,
    interpolated linearly in :math:`\\log K` between the two measured K around it;
    ``rows[0]["K"]`` if the tree wins everywhere measured, None if it never
    wins at the largest K. ``stat``: ``"seconds"`` (medians) or ``"seconds_min"`` (minima).
    """
    K = np.array([r["K"] for r in rows], dtype=float)
    if len(K) == 0 or np.any(np.diff(K) <= 0):
        raise ValueError(f"crossover_k needs step_cost rows sorted by increasing K, got K = {K.tolist()}")
    gain = np.log(np.array([r[f"dense_{stat}"] / r[f"tree_{stat}"] for r in rows]))
    if gain[-1] <= 0:
        return None
    losing = np.flatnonzero(gain <= 0)
    if len(losing) == 0:
        return float(K[0])
    i = losing[-1]  # the last K where dense arrays still win; the tree wins from i + 1 on
    a, b = np.log(K[i]), np.log(K[i + 1])
    return float(np.exp(a + (b - a) * gain[i] / (gain[i] - gain[i + 1])))
