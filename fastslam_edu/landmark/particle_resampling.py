"""Step 3 of FastSLAM, compiled: which particles are drawn, and the set replaced by them in place.

*Probabilistic Robotics* table 13.1 ends each step by drawing :math:`M` particles with probability proportional to
their weights (with replacement) and copying their poses and maps. Resampling is done only when the set has
degenerated, :math:`N_\\text{eff} < \\text{threshold} \\times M` (:func:`draw_if_degenerate`). The resamplers draw
the indices in increasing order (:func:`resampling_indices`), so the set can be overwritten in place, each particle
that changes written once, none read after it is written (:func:`copy_order`, :func:`select_in_place`), without a
second copy of the maps.

The run with barcodes (:mod:`fastslam_edu.landmark.fastslam_step`) and the run without
(:mod:`fastslam_edu.landmark.association`, whose particles hold maps of variable size and copy them with
``select_maps``) share the draw and the copy order.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from fastslam_edu.core.resampling import (in_increasing_order, inverse_cdf_kernel, roulette_kernel,
                                         stratified_positions, systematic_positions)


@njit(cache=True)
def resampling_indices(w, rng, code):
    """The particles drawn by resampler ``code`` (:data:`~fastslam_edu.landmark.step_records.RESAMPLER_CODES`),
    with the kernels of :mod:`fastslam_edu.core.resampling`: positions ``u_j`` (systematic ``(j + U) / M``;
    stratified ``(j + U_j) / M``; roulette ``U_j`` sorted), then the inverse CDF, ``min{i : c_i > u_j}``
    (roulette: :func:`fastslam_edu.core.resampling.roulette_kernel`, the same indices without a sort)."""
    m = w.shape[0]
    if code == 2:  # the same indices, counted instead of sorted (no sort to compile)
        return roulette_kernel(w / np.sum(w), rng)
    u = systematic_positions(m, rng) if code == 0 else stratified_positions(m, rng)
    return inverse_cdf_kernel(u, w / np.sum(w))


@njit(cache=True, _nrt=False)
def copy_particle(src, i, dst, m):
    """Particle ``i`` of ``src``: its pose and map written over particle ``m`` of ``dst`` (both
    :class:`~fastslam_edu.landmark.step_records.Particles`). Without reference counts
    (:mod:`fastslam_edu.landmark.fastslam_step`'s docstring): reading ``src.mu`` at every landmark would count one."""
    for a in range(3):
        dst.poses[m, a] = src.poses[i, a]
    for k in range(src.mu.shape[1]):
        dst.mu[m, k, 0], dst.mu[m, k, 1] = src.mu[i, k, 0], src.mu[i, k, 1]
        dst.sigma[m, k, 0, 0], dst.sigma[m, k, 0, 1] = src.sigma[i, k, 0, 0], src.sigma[i, k, 0, 1]
        dst.sigma[m, k, 1, 0], dst.sigma[m, k, 1, 1] = src.sigma[i, k, 1, 0], src.sigma[i, k, 1, 1]
        dst.seen[m, k], dst.count[m, k] = src.seen[i, k], src.count[i, k]


@njit(cache=True, _nrt=False)
def is_increasing(idx):
    """Whether ``idx`` (M,) never decreases (as the resamplers draw it)."""
    for m in range(1, idx.shape[0]):
        if idx[m - 1] > idx[m]:
            return False
    return True


@njit(cache=True)
def copy_order(idx):
    """The particles ``m`` that resampling to ``idx`` (M,) overwrites (``idx[m] != m``), in an order that never
    reads a particle after overwriting it, for ``idx`` increasing (:func:`is_increasing`): those that move down
    (``idx[m] > m``) in increasing ``m``, then those that move up (``idx[m] < m``) in decreasing ``m``; a particle
    ``p`` read by the second pass has ``idx[p] <= p``, so the first did not write it."""
    order = np.empty(idx.shape[0], dtype=np.int64)
    n = 0
    for m in range(idx.shape[0]):
        if idx[m] > m:
            order[n] = m
            n += 1
    for m in range(idx.shape[0] - 1, -1, -1):
        if idx[m] < m:
            order[n] = m
            n += 1
    return order[:n]


@njit(cache=True)
def select_in_place(P, idx):
    """The particles ``idx`` (M,) replace the set ``P``, their maps copied (no two offspring share memory); log
    weights 0.

    The resamplers draw ``idx`` in increasing order: each particle that changes is then copied once, in the order
    of :func:`copy_order`, with no second copy of the set. Indices in another order are first put in increasing
    order (:func:`fastslam_edu.core.resampling.in_increasing_order`: the same particles drawn).
    """
    if not is_increasing(idx):
        idx = in_increasing_order(idx)
    for m in copy_order(idx):
        copy_particle(P, idx[m], P, m)
    P.logw[:] = 0.0


@njit(cache=True)
def draw_if_degenerate(w, n_eff, s, rng):
    """Step 3's decision and draw: when :math:`N_\\text{eff}` (``n_eff``) is below ``s.resample_threshold`` × M
    (always, with a threshold of 1 or more), the indices (M,) of the particles drawn with weights ``w`` (M,) by
    resampler ``s.resampler`` (:func:`resampling_indices`), the weights then set uniform; else an empty array
    (the set is kept, with its weights)."""
    m = w.shape[0]
    if s.resample_threshold >= 1.0 or n_eff < s.resample_threshold * m:
        idx = resampling_indices(w, rng, s.resampler)
        w[:] = 1.0 / m
        return idx
    return np.empty(0, dtype=np.int64)


__all__ = ["resampling_indices", "copy_particle", "is_increasing", "copy_order", "select_in_place",
           "draw_if_degenerate"]
