"""Registration without correspondences: the rigid motion that lays a SLAM map on the surveyed landmarks.

To score a map whose landmarks carry no names (unknown correspondences), each map landmark is matched to a surveyed
one (:func:`fastslam_edu.evaluation.association.match_landmarks`). SLAM recovers the map only up to a rigid motion
of the plane, :math:`T(p) = R(\\varphi)\\,p + \\tau`, so the map is first moved by the motion that best fits it to the
survey, and that motion needs correspondences to be fitted (:func:`fastslam_edu.core.se2.align_se2`).
The motion that fits the filter's *path* to the groundtruth gives a start, but a filter whose heading drifted
while it mapped ends with a map turned away from its average path (on MR.CLAM by up to a radian and more): from
that start every landmark is matched to a neighbour of its own, or to nothing.

:func:`consensus_motion` finds the motion from the two point sets alone. Any two map landmarks :math:`a_1, a_2` and
two surveyed landmarks :math:`b_1, b_2` the same distance apart (within ``2 radius``) propose the motion that turns
:math:`a_2 - a_1` onto :math:`b_2 - b_1` and lays the midpoint of the first pair on that of the second
(:func:`motion_of_two`). Each map landmark proposes with its ``PARTNERS`` nearest (one right pair is enough), every
proposal is tried, and the motion that brings the most map landmarks within ``radius`` of a surveyed one wins, the smaller sum of those distances breaking ties:
a consensus, as in RANSAC (Fischler and Bolles 1981), without the random draws. Pairs closer than ``min_baseline``
propose nothing: the direction between two close landmarks is noise (MR.CLAM's stand in clusters 0.2 m apart).

The search never looks at what a landmark is of, only where it is: a wrong motion cannot make the association
scores better, only the matching's start. The kernels are numba ``njit(cache=True)`` (they run as plain Python
with ``NUMBA_DISABLE_JIT=1``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from fastslam_edu.core.checks import finite_array
from fastslam_edu.core.se2 import align_se2


@njit(cache=True, _nrt=False)
def motion_of_two(a1, a2, b1, b2):
    """The rigid motion :math:`(\\varphi, \\tau_x, \\tau_y)` [rad, m, m] that turns :math:`a_2 - a_1` onto the
    direction of :math:`b_2 - b_1` and moves the midpoint of :math:`a_1, a_2` onto that of :math:`b_1, b_2`."""
    phi = math.atan2(b2[1] - b1[1], b2[0] - b1[0]) - math.atan2(a2[1] - a1[1], a2[0] - a1[0])
    c, s = math.cos(phi), math.sin(phi)
    ax, ay = 0.5 * (a1[0] + a2[0]), 0.5 * (a1[1] + a2[1])
    bx, by = 0.5 * (b1[0] + b2[0]), 0.5 * (b1[1] + b2[1])
    return phi, bx - (c * ax - s * ay), by - (s * ax + c * ay)


def point_grid(B, cell):
    """The points ``B`` (nb, 2) filed in square cells of side ``cell`` [m] (at least ``cell``; larger if the points
    span more than 1,000 cells): ``(x0, y0, side, nx, ny, start, items)``, the points of cell ``(cx, cy)`` being
    ``items[start[c]:start[c + 1]]`` with ``c = cx * ny + cy``. A point within ``side`` of a position is in the 3×3
    cells around it, so :func:`count_inliers` looks at a few points, not all of ``B``. (numpy: it runs once per
    registration; the order of the points within a cell does not matter, the nearest of them is looked for.)"""
    B = np.asarray(B, dtype=float)
    lo, hi = B.min(axis=0), B.max(axis=0)
    x0, y0 = lo - cell
    side = float(max(cell, (hi[0] - x0 + cell) / 1000.0, (hi[1] - y0 + cell) / 1000.0))
    nx, ny = int((hi[0] - x0) / side) + 2, int((hi[1] - y0) / side) + 2
    key = ((B[:, 0] - x0) / side).astype(np.int64) * ny + ((B[:, 1] - y0) / side).astype(np.int64)
    items = np.argsort(key, kind="stable")
    start = np.concatenate([[0], np.cumsum(np.bincount(key, minlength=nx * ny))]).astype(np.int64)
    return float(x0), float(y0), side, nx, ny, start, items


@njit(cache=True, _nrt=False)
def count_inliers(A, B, grid, motion, radius, enough=0):
    """``(count, cost)``: how many points of ``A`` (na, 2), moved by ``motion`` :math:`= (\\varphi, \\tau_x, \\tau_y)`,
    lie within ``radius`` of some point of ``B`` (nb, 2) (filed in ``grid``, :func:`point_grid` with a side of at
    least ``radius``), and the sum of those nearest distances [m]. The count stops, returning ``(-1, inf)``, as soon
    as it cannot reach ``enough`` any more."""
    x0, y0, side, nx, ny, start, items = grid
    c, s = math.cos(motion[0]), math.sin(motion[0])
    count, cost = 0, 0.0
    na = A.shape[0]
    for i in range(na):
        if count + (na - i) < enough:
            return -1, math.inf
        x, y = c * A[i, 0] - s * A[i, 1] + motion[1], s * A[i, 0] + c * A[i, 1] + motion[2]
        gx, gy = int(math.floor((x - x0) / side)), int(math.floor((y - y0) / side))
        nearest = math.inf
        for cx in range(max(gx - 1, 0), min(gx + 2, nx)):
            for cy in range(max(gy - 1, 0), min(gy + 2, ny)):
                cell = cx * ny + cy
                for q in range(start[cell], start[cell + 1]):
                    j = items[q]
                    nearest = min(nearest, math.hypot(x - B[j, 0], y - B[j, 1]))
        if nearest <= radius:
            count += 1
            cost += nearest
    if count < enough:
        return -1, math.inf
    return count, cost


def pairs_by_distance(B):
    """Every ordered pair ``(j1, j2)`` of ``B`` (nb, 2), ``j1 != j2``, sorted by their distance: ``(distance (P,),
    j1 (P,), j2 (P,))``, so that the pairs at a given distance are found by bisection."""
    B = np.asarray(B, dtype=float)
    first, second = np.nonzero(~np.eye(len(B), dtype=bool))
    dist = np.hypot(B[second, 0] - B[first, 0], B[second, 1] - B[first, 1])
    order = np.argsort(dist, kind="stable")
    return dist[order], first[order], second[order]


#: Each map landmark proposes motions with this many others: its nearest ones at least ``min_baseline`` away. With
#: every pair, a map of L landmarks would make of the order of L² × N² proposals (N surveyed); one right pair is
#: enough, so a few partners per landmark keep the proposals linear in L (a map full of spurious landmarks is scored
#: too).
PARTNERS = 4


def nearest_partners(A, min_baseline):
    """``(na, PARTNERS)``: for each point of ``A`` (na, 2), its ``PARTNERS`` nearest other points at least
    ``min_baseline`` [m] away, nearest first (``-1`` where there are fewer)."""
    A = np.asarray(A, dtype=float)
    d = np.hypot(A[:, None, 0] - A[None, :, 0], A[:, None, 1] - A[None, :, 1])
    d[(d < min_baseline) | np.eye(len(A), dtype=bool)] = np.inf
    order = np.argsort(d, axis=1, kind="stable")[:, :PARTNERS]
    partners = np.full((len(A), PARTNERS), -1, dtype=np.int64)
    partners[:, :order.shape[1]] = np.where(np.take_along_axis(d, order, axis=1) < np.inf, order, -1)
    return partners


def pair_windows(A, partners, b_dist, radius):
    """``(na, PARTNERS, 2)``: for each point ``i1`` of ``A`` and each of its ``partners``, the range ``[start, stop)``
    of the pairs of ``B`` (their distances ``b_dist`` sorted, :func:`pairs_by_distance`) as far apart as ``i1`` and
    its partner within ``2 radius`` (empty where the partner is -1): found by bisection."""
    A = np.asarray(A, dtype=float)
    other = A[np.maximum(partners, 0)]
    da = np.hypot(other[..., 0] - A[:, None, 0], other[..., 1] - A[:, None, 1])
    windows = np.stack([np.searchsorted(b_dist, da - 2.0 * radius), np.searchsorted(b_dist, da + 2.0 * radius,
                                                                                     side="right")], axis=-1)
    windows[partners < 0] = 0
    return windows.astype(np.int64)


@njit(cache=True, _nrt=False)
def best_motion(A, B, partners, pairs, windows, grid, radius):
    """The search of :func:`consensus_motion`: every point ``i1`` of ``A`` with each of its ``partners``, against
    the ordered pairs of ``B`` (``pairs``, :func:`pairs_by_distance`) in its ``windows`` (:func:`pair_windows`: the
    pairs as far apart within ``2 radius``); each proposal is scored by :func:`count_inliers` on ``grid``
    (:func:`point_grid`). ``(count, φ, τx, τy)`` of the best."""
    _, b_first, b_second = pairs
    best_count, best_cost = np.int64(0), math.inf  # (not 0: a literal would make numba compile count_inliers twice)
    best_phi = best_tx = best_ty = 0.0
    for i1 in range(A.shape[0]):
        for q in range(partners.shape[1]):
            i2 = partners[i1, q]
            for p in range(windows[i1, q, 0], windows[i1, q, 1]):
                phi, tx, ty = motion_of_two(A[i1], A[i2], B[b_first[p]], B[b_second[p]])
                count, cost = count_inliers(A, B, grid, (phi, tx, ty), radius, best_count)
                if count > best_count or (count == best_count and cost < best_cost):
                    best_count, best_cost = count, cost
                    best_phi, best_tx, best_ty = phi, tx, ty
    return best_count, best_phi, best_tx, best_ty


def consensus_motion(A, B, radius, min_baseline):
    """The motion that lays the most points of ``A`` (na, 2) within ``radius`` of points of ``B`` (nb, 2) (module
    docstring): ``(count, φ, τx, τy)``; ``count`` 0 when no two points of ``A`` are ``min_baseline`` apart with a
    pair of ``B`` at the same distance. Each point of ``A`` proposes with its ``PARTNERS`` nearest points at least
    ``min_baseline`` away (:func:`nearest_partners`), against every ordered pair of ``B`` at the same distance within
    ``2 radius`` (:func:`pairs_by_distance`, :func:`pair_windows`); the search itself is compiled
    (:func:`best_motion`), the sorting and bisection done here in numpy."""
    A, B = np.ascontiguousarray(A, dtype=float), np.ascontiguousarray(B, dtype=float)
    if len(A) < 2 or len(B) < 2:
        return 0, 0.0, 0.0, 0.0
    radius = float(radius)
    partners, pairs = nearest_partners(A, min_baseline), pairs_by_distance(B)
    windows = pair_windows(A, partners, pairs[0], radius)
    return best_motion(A, B, partners, pairs, windows, point_grid(B, radius), radius)


def register(estimate, truth, radius: float = 0.5, min_baseline: float = 1.0):
    """``(R (2, 2), t (2,))``: the motion :math:`p \\mapsto R p + t` that lays the map ``estimate`` (L, 2) [m] on the
    surveyed landmarks ``truth`` (N, 2) [m], or None if no two map landmarks propose one: :func:`consensus_motion`,
    refitted by least squares (:func:`fastslam_edu.core.se2.align_se2`) to the map landmarks it lays
    within ``radius`` of a surveyed one, each paired with the nearest."""
    A = np.ascontiguousarray(finite_array("estimate", estimate, "register", (2,)).reshape(-1, 2))
    B = np.ascontiguousarray(finite_array("truth", truth, "register", (2,)).reshape(-1, 2))
    if not (radius > 0 and min_baseline >= 0):
        raise ValueError(f"register: need radius > 0 and min_baseline >= 0, got {radius!r}, {min_baseline!r}")
    count, phi, tx, ty = consensus_motion(A, B, float(radius), float(min_baseline))
    if count == 0:
        return None
    c, s = math.cos(phi), math.sin(phi)
    R, t = np.array([[c, -s], [s, c]]), np.array([tx, ty])
    # two landmarks fix the motion only to their noise: refit it by least squares on the landmarks it lays on the
    # survey, each with its nearest surveyed landmark
    d = np.linalg.norm((A @ R.T + t)[:, None, :] - B[None, :, :], axis=-1)
    near = d.argmin(axis=1)
    inside = d[np.arange(len(A)), near] <= radius
    if inside.sum() >= 2:
        R, t, _ = align_se2(A[inside], B[near[inside]])
    return R, t


__all__ = ["PARTNERS", "motion_of_two", "point_grid", "count_inliers", "pairs_by_distance", "nearest_partners",
           "pair_windows", "best_motion", "consensus_motion", "register"]
