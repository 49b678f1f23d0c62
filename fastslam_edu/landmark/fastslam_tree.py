"""FastSLAM 1.0 with each particle's landmarks in a :class:`~fastslam_edu.landmark.tree.LandmarkTree`.

The array engine (:mod:`fastslam_edu.landmark.fastslam`) keeps the map of all particles
in dense arrays ``mu (M, N, 2)``, ``sigma (M, N, 2, 2)``; resampling copies
them with fancy indexing — :math:`O(MN)` per resampling step, whatever the
number of landmarks seen. Here (Montemerlo et al. 2002, section 4):

=========  ======================  ==========================================
poses      (M, 3) array            :math:`x^{[m]}`, as in the array engine
trees      list of M LandmarkTree  :math:`(\\mu_k^{[m]}, \\Sigma_k^{[m]})` for the landmarks seen
logw       (M,) array              :math:`\\log w^{[m]}`
=========  ======================  ==========================================

* **resampling** copies tree *references*: :math:`O(M)`;
* **updating** landmark :math:`k` in particle :math:`m` path-copies
  :math:`\\lceil \\log_2 N \\rceil + 1` nodes: :math:`O(M \\log N)` per measurement;
* the EKF arithmetic itself is the array engine's: the few landmarks measured
  at an instant are read out of the trees (:func:`~fastslam_edu.landmark.tree.gather`),
  updated by :func:`fastslam_edu.landmark.particle_set.update_with_sightings` (the compiled
  per-particle step), and written back into new trees
  (:func:`~fastslam_edu.landmark.tree.set_each`).

The filter consumes the random numbers in the same order as
:func:`fastslam_edu.landmark.fastslam.run_fastslam` (it calls the same ``propagate`` and
``resample_if_needed``) and applies the measurements of one instant with the
same function (batched distinct landmarks, a landmark seen twice in a second
round, range-dependent :math:`R`, the robust gate), so for the same seed it
gives the same path and map.

The constants differ in kind: resampling dense arrays copies :math:`MN`
landmark filters in a few C calls, while the tree creates and walks Python
objects, one per node. So for a small map such as MR.CLAM's 15 landmarks the
array engine is faster, and the tree wins only from some :math:`N` on that
depends on the machine; ``benchmarks/landmark_tree.py`` measures both (see
the chapter "Why FastSLAM is O(M log N)").
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from fastslam_edu.datasets.log import EventStream
from fastslam_edu.landmark.fastslam import FastSLAMParams, FastSLAMResult, run_fastslam
from fastslam_edu.landmark.particle_set import ParticleSet, make_sightings, update_with_sightings
from fastslam_edu.landmark.tree import LandmarkTree, gather, set_each, trees_to_arrays
from fastslam_edu.core.weights import weights_from_log

__all__ = [
    "TreeParticleSet",
    "FastSLAMTreeResult",
    "update_trees_with_sightings",
    "run_fastslam_tree",
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

        :math:`O(M)` whatever :math:`N`: offspring of one parent hold the same
        tree object, which is safe because a tree is never modified — an
        update builds a new tree (:meth:`LandmarkTree.set`).
        """
        idx = np.asarray(indices)
        return TreeParticleSet(
            poses=self.poses[idx], trees=[self.trees[i] for i in idx.tolist()], logw=np.zeros(len(idx))
        )

    def with_known_map(self, landmarks) -> "TreeParticleSet":
        """Every particle holding one shared tree of the known landmarks ``(N, 2)`` (localisation)."""
        N = len(landmarks)
        known = LandmarkTree.from_arrays(landmarks, np.tile(np.eye(2) * 1e-6, (N, 1, 1)), count=np.ones(N, int))
        self.trees = [known] * len(self)
        return self

    def update(self, z, k, R, *, update_map: bool = True, gate_chi2: float | None = None, escape=None,
               beta=None, proposal_loglik=None) -> np.ndarray:
        """Step 2 for the measurements of one instant: :func:`update_trees_with_sightings`."""
        sightings = make_sightings(z, k, R, len(self), escape=escape, beta=beta, proposal_loglik=proposal_loglik)
        return update_trees_with_sightings(self, sightings, gate_chi2=gate_chi2, update_map=update_map)

    def to_particle_set(self) -> ParticleSet:
        """The same particles as a dense :class:`~fastslam_edu.landmark.particle_set.ParticleSet` (:math:`O(MN)`)."""
        mu, sigma, seen, count = trees_to_arrays(self.trees)
        return ParticleSet(poses=self.poses.copy(), mu=mu, sigma=sigma, seen=seen, logw=self.logw.copy(),
                           count=count)


# ---------------------------------------------------------------- step 2 on trees


def update_trees_with_sightings(particles: TreeParticleSet, sightings, *, gate_chi2: float | None = None,
                                update_map: bool = True) -> np.ndarray:
    """Step 2 for the sightings of one instant (:func:`~fastslam_edu.landmark.particle_set.make_sightings`).

    1. **Read** the :math:`n' \\le n` distinct landmarks measured out of every
       particle's tree (:func:`~fastslam_edu.landmark.tree.gather`,
       :math:`O(M n' \\log N)`) into a small :class:`~fastslam_edu.landmark.particle_set.ParticleSet`
       of :math:`n'` landmarks, which shares ``poses`` and ``logw`` with ``particles``.
    2. **Update** it with the array engine's own
       :func:`~fastslam_edu.landmark.particle_set.update_with_sightings` — initialisation,
       EKF update, weights, robust gate: the same numbers, by construction.
    3. **Write back** each landmark that changed in a particle (mean, covariance,
       seen or count) by path copying (:func:`~fastslam_edu.landmark.tree.set_each`,
       :math:`O(\\log N)` each); a particle whose landmark did not change (an
       outlier for it, or a known map) keeps its tree.

    Returns a bool (n,): False where no particle explains the measurement
    (rejected by the gate, unless escaped).
    """
    keys, local = np.unique(sightings.j, return_inverse=True)  # local index of each measurement's landmark
    mu, sigma, seen, count = gather(particles.trees, keys)
    mu[~seen], sigma[~seen] = 0.0, np.eye(2)  # the array engine's values for a landmark not seen yet
    before = mu.copy(), sigma.copy(), seen.copy(), count.copy()
    measured = ParticleSet(poses=particles.poses, mu=mu, sigma=sigma, seen=seen, logw=particles.logw, count=count)
    explained = update_with_sightings(measured, sightings._replace(j=local.astype(np.int64).reshape(-1)),
                                      gate_chi2=gate_chi2, update_map=update_map)
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
    """:class:`~fastslam_edu.landmark.fastslam.FastSLAMResult` of the tree filter.

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

    The array engine's run loop (:func:`fastslam_edu.landmark.fastslam.run_fastslam`, whose
    keyword options it takes) with particles that store their maps in trees
    (:class:`TreeParticleSet`): the same random numbers, the same result to
    rounding; ``filter_seconds`` is this filter's time and ``trees`` the final
    tree-backed set.
    """
    result = run_fastslam(stream, params, rng, particle_class=TreeParticleSet, **options)
    return FastSLAMTreeResult(**{f.name: getattr(result, f.name) for f in fields(result)}, trees=result.final)
