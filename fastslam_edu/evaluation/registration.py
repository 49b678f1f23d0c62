"""Registration without correspondences: the rigid motion that lays a SLAM map on the surveyed landmarks.

To score a map whose landmarks carry no names (unknown correspondences), each map landmark is matched to a surveyed
one (:func:`fastslam_edu.evaluation.association.match_landmarks`). SLAM recovers the map only up to a rigid motion
of the plane, :math:`T(p) = R(\\varphi)\\,p + \\tau`, so the map is first moved by the motion that best fits it to the
survey, and that motion needs correspondences to be fitted (:func:`fastslam_edu.evaluation.metrics.align_se2`).
The motion that fits the filter's *path* to the groundtruth gives a start, but a filter whose heading drifted
while it mapped ends with a map turned away from its average path (on MR.CLAM by up to a radian and more): from
that start every landmark is matched to a neighbour of its own, or to nothing.

:func:`consensus_motion` finds the motion from the two point sets alone. Any two map landmarks :math:`a_1, a_2` and
two surveyed landmarks :math:`b_1, b_2` the same distance apart (within ``2 radius``) propose the motion that turns
:math:`a_2 - a_1` onto :math:`b_2 - b_1` and lays the midpoint of the first pair on that of the second
(:func:`motion_of_two`). Every proposal is tried (a map holds a few dozen landmarks), and the motion that brings the
most map landmarks within ``radius`` of a surveyed one wins, the smaller sum of those distances breaking ties:
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
from fastslam_edu.evaluation.metrics import align_se2


@njit(cache=True)
def motion_of_two(a1, a2, b1, b2):
    """The rigid motion :math:`(\\varphi, \\tau_x, \\tau_y)` [rad, m, m] that turns :math:`a_2 - a_1` onto the
    direction of :math:`b_2 - b_1` and moves the midpoint of :math:`a_1, a_2` onto that of :math:`b_1, b_2`."""
    phi = math.atan2(b2[1] - b1[1], b2[0] - b1[0]) - math.atan2(a2[1] - a1[1], a2[0] - a1[0])
    c, s = math.cos(phi), math.sin(phi)
    ax, ay = 0.5 * (a1[0] + a2[0]), 0.5 * (a1[1] + a2[1])
    bx, by = 0.5 * (b1[0] + b2[0]), 0.5 * (b1[1] + b2[1])
    return phi, bx - (c * ax - s * ay), by - (s * ax + c * ay)


@njit(cache=True)
def count_inliers(A, B, phi, tx, ty, radius):
    """``(count, cost)``: how many points of ``A`` (na, 2), moved by :math:`(\\varphi, \\tau)`, lie within ``radius``
    of some point of ``B`` (nb, 2), and the sum of those nearest distances [m]."""
    c, s = math.cos(phi), math.sin(phi)
    count, cost = 0, 0.0
    for i in range(A.shape[0]):
        x, y = c * A[i, 0] - s * A[i, 1] + tx, s * A[i, 0] + c * A[i, 1] + ty
        nearest = math.inf
        for j in range(B.shape[0]):
            nearest = min(nearest, math.hypot(x - B[j, 0], y - B[j, 1]))
        if nearest <= radius:
            count += 1
            cost += nearest
    return count, cost


@njit(cache=True)
def consensus_motion(A, B, radius, min_baseline):
    """The motion that lays the most points of ``A`` (na, 2) within ``radius`` of points of ``B`` (nb, 2) (module
    docstring): ``(count, φ, τx, τy)``; ``count`` 0 when no two points of ``A`` are ``min_baseline`` apart with a
    pair of ``B`` at the same distance."""
    best_count, best_cost = 0, math.inf
    best_phi = best_tx = best_ty = 0.0
    na, nb = A.shape[0], B.shape[0]
    for i1 in range(na):
        for i2 in range(i1 + 1, na):
            da = math.hypot(A[i2, 0] - A[i1, 0], A[i2, 1] - A[i1, 1])
            if da < min_baseline:
                continue
            for j1 in range(nb):
                for j2 in range(nb):
                    if j2 == j1:
                        continue
                    db = math.hypot(B[j2, 0] - B[j1, 0], B[j2, 1] - B[j1, 1])
                    if abs(da - db) > 2.0 * radius:
                        continue
                    phi, tx, ty = motion_of_two(A[i1], A[i2], B[j1], B[j2])
                    count, cost = count_inliers(A, B, phi, tx, ty, radius)
                    if count > best_count or (count == best_count and cost < best_cost):
                        best_count, best_cost = count, cost
                        best_phi, best_tx, best_ty = phi, tx, ty
    return best_count, best_phi, best_tx, best_ty


def register(estimate, truth, radius: float = 0.5, min_baseline: float = 1.0):
    """``(R (2, 2), t (2,))``: the motion :math:`p \\mapsto R p + t` that lays the map ``estimate`` (L, 2) [m] on the
    surveyed landmarks ``truth`` (K, 2) [m], or None if no two map landmarks propose one: :func:`consensus_motion`,
    refitted by least squares (:func:`fastslam_edu.evaluation.metrics.align_se2`) to the map landmarks it lays
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


__all__ = ["motion_of_two", "count_inliers", "consensus_motion", "register"]
