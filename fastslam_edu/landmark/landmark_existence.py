"""Existence and retirement of landmarks with unknown correspondences: adding and removing a particle's landmarks,
negative evidence (the log odds that a landmark is real), and the hand-over of a retired landmark's identity.
See :mod:`fastslam_edu.landmark.association`, step 3.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from fastslam_edu.core.ekf import initialise_landmark_kernel


@njit(cache=True, _nrt=False)
def add_landmark(P, m, z, R, ident, t):
    """A new landmark in particle ``m`` from sighting ``z`` (lines 7–9 of table 13.1); its slot, or -1 if full."""
    k = P.n[m]
    if k >= P.mu.shape[1]:
        return -1
    initialise_landmark_kernel(P.poses[m], z, R, P.mu[m, k], P.sigma[m, k])
    P.ident[m, k] = ident
    P.seen[m, k] = 1
    P.missed[m, k] = 0
    P.evidence[m, k] = 1.0
    P.last_t[m, k] = t
    P.first_t[m, k] = t
    P.committed[m, k] = True  # (apply_associations clears it for a far sighting under deferred commitment)
    P.n[m] = k + 1
    return k


@njit(cache=True, _nrt=False)
def remove_landmark(P, m, k):
    """Remove landmark ``k`` of particle ``m``: the last landmark takes its slot."""
    last = P.n[m] - 1
    if k != last:
        for a in range(2):  # (number by number: an array assignment compiles numba's shape check, see copy_row)
            P.mu[m, k, a] = P.mu[m, last, a]
            for b in range(2):
                P.sigma[m, k, a, b] = P.sigma[m, last, a, b]
        P.ident[m, k] = P.ident[m, last]
        P.seen[m, k] = P.seen[m, last]
        P.missed[m, k] = P.missed[m, last]
        P.evidence[m, k] = P.evidence[m, last]
        P.log_odds[m, k] = P.log_odds[m, last]
        P.last_t[m, k] = P.last_t[m, last]
        P.first_t[m, k] = P.first_t[m, last]
        P.committed[m, k] = P.committed[m, last]
    P.ident[m, last] = -1
    P.n[m] = last


@njit(cache=True, _nrt=False)
def in_view(pose, mu, rules):
    """Whether a landmark at ``mu`` (2,) is inside the camera's range and field of view from ``pose`` (3,): its range
    :math:`r = |\\delta|`, :math:`\\delta = \\mu - (x, y)` [m], within ``[rules.min_range, rules.max_range]`` and
    its bearing :math:`\\phi = \\operatorname{atan2}(\\delta_y, \\delta_x) - \\theta` (wrapped) within
    :math:`\\pm` ``rules.fov`` = :math:`\\phi_{\\max}` [rad] (the range first: a landmark out of range needs no
    bearing).

    The bearing without its arctangent: :math:`\\cos\\phi` is the dot product of the unit heading
    :math:`(\\cos\\theta, \\sin\\theta)` and the unit vector :math:`\\delta / r` to the landmark, and
    :math:`\\cos` decreases on :math:`[0, \\pi]`, so :math:`|\\phi| \\le \\phi_{\\max} \\iff
    \\delta_x\\cos\\theta + \\delta_y\\sin\\theta \\ge r\\cos\\phi_{\\max}` for any
    :math:`\\phi_{\\max} \\in [0, \\pi]`, beyond :math:`\\pi/2` too (:math:`\\cos\\phi_{\\max} < 0`: a landmark
    behind the robot's sideways line may be in view); :math:`\\phi_{\\max} \\ge \\pi` lets every bearing in. At
    :math:`r = 0` the direction is that of :math:`\\operatorname{atan2}(0, 0) = 0`, :math:`\\delta / r = (1, 0)`.
    """
    return in_view_along(pose[0], pose[1], math.cos(pose[2]), math.sin(pose[2]), math.cos(rules.fov), mu, rules)


@njit(cache=True, _nrt=False)
def in_view_along(x, y, cos_theta, sin_theta, cos_fov, mu, rules):
    """:func:`in_view` from the position ``(x, y)`` [m] with the heading's unit vector :math:`(\\cos\\theta,
    \\sin\\theta)` and :math:`\\cos\\phi_{\\max}` given, for a loop over a particle's landmarks that computes them
    once (:func:`negative_evidence`)."""
    dx, dy = mu[0] - x, mu[1] - y
    r = math.sqrt(dx * dx + dy * dy)
    if not rules.min_range <= r <= rules.max_range:
        return False
    if rules.fov >= math.pi:
        return True
    if r == 0.0:
        dx, r = 1.0, 1.0  # atan2(0, 0) = 0: the direction of the x axis
    return dx * cos_theta + dy * sin_theta >= r * cos_fov


@njit(cache=True, _nrt=False)
def existence_log_odds(log_odds, seen, rules):
    """The existence log odds of a landmark after one instant in view: seen (``True``) or missed.

    :math:`L \\mathrel{+}= \\log\\frac{p_D}{p_F}` for a sighting, :math:`\\log\\frac{1-p_D}{1-p_F}` (< 0) for a miss,
    from :math:`L = 0` (even odds) before the first sighting; clamped above at ``log_odds_cap_sightings``' worth,
    so that a landmark seen for a long time is still removed after a few dozen misses once it has gone (a
    copy that a newer landmark has replaced): :math:`p_D` = 0.3, :math:`p_F` = 0.05 give +1.79 and -0.31.
    """
    if seen:
        return min(log_odds + rules.log_odds_seen, rules.log_odds_cap)
    return log_odds + rules.log_odds_missed


@njit(cache=True, _nrt=False)
def negative_evidence(P, m, taken, rules):
    """Count a miss for every landmark of particle ``m`` in view but not taken at this instant; remove the
    provisional ones whose existence log odds (:func:`existence_log_odds`) fall below zero: more likely clutter than
    real. A confirmed landmark whose log odds fall below zero is retired by :func:`retire_landmarks`."""
    x, y, cos_fov = P.poses[m, 0], P.poses[m, 1], math.cos(rules.fov)  # (in_view's, once for all the landmarks)
    c, s = math.cos(P.poses[m, 2]), math.sin(P.poses[m, 2])
    k = np.int64(0)  # (not 0: see retire_landmarks)
    while k < P.n[m]:
        if not taken[k] and in_view_along(x, y, c, s, cos_fov, P.mu[m, k], rules):
            P.missed[m, k] += 1
            P.log_odds[m, k] = existence_log_odds(P.log_odds[m, k], False, rules)
            if P.log_odds[m, k] < 0.0 and P.evidence[m, k] < rules.n_confirm:
                taken[k] = taken[P.n[m] - 1]  # the last landmark moves into slot k
                remove_landmark(P, m, k)
                continue
        k += 1


@njit(cache=True, _nrt=False)
def heir_of(P, m, a, rules):
    """The landmark of particle ``m`` that continues the identity of landmark ``a``: the nearest one made after
    ``a``, within ``rules.inherit_radius`` metres; -1 if there is none."""
    best, best_d = -1, rules.inherit_radius
    for b in range(P.n[m]):
        if b == a or P.first_t[m, b] <= P.first_t[m, a]:
            continue  # older than a: another landmark
        d = math.hypot(P.mu[m, a, 0] - P.mu[m, b, 0], P.mu[m, a, 1] - P.mu[m, b, 1])
        if d <= best_d:
            best, best_d = b, d
    return best


#: The columns of the record of hand-overs (:func:`retire_landmarks`): the instant, the particle, the heir's old
#: identity, the identity it takes.
RENAME_INSTANT, RENAME_PARTICLE, RENAME_HEIR, RENAME_TAKEN = 0, 1, 2, 3


@njit(cache=True, _nrt=False)
def retire_landmarks(P, m, rules, renames, n_renames, q):
    """Remove the confirmed landmarks of particle ``m`` whose existence log odds fell below zero; each passes
    its identity to its heir (:func:`heir_of`), if it has one.

    A landmark stops being seen where the particle expects it when its pose drifted while the landmark was out of
    view: the sightings, further than :math:`d_0` from it, start a copy nearby, which takes them, and the
    original collects misses. The copy is the same landmark seen again: it continues the original's identity
    (and counts its sightings), so that the particle's association history reads one landmark, not two. It keeps
    its own evidence: a copy still provisional stays out of the map until its own sightings confirm it. Each
    hand-over is written to row ``n_renames[0]`` of ``renames`` (C, 4), columns :data:`RENAME_INSTANT`
    (``q``), :data:`RENAME_PARTICLE` (``m``), :data:`RENAME_HEIR` (the heir's old identity) and
    :data:`RENAME_TAKEN` (the identity it takes), and ``n_renames`` (1,) counts the rows
    (:func:`fastslam_edu.landmark.association_history.best_history` reads them).
    """
    k = np.int64(0)  # (not 0: a literal would make numba compile heir_of and remove_landmark twice)
    while k < P.n[m]:
        if P.log_odds[m, k] >= 0.0:
            k += 1
            continue
        b = heir_of(P, m, k, rules)
        if b >= 0:
            row = n_renames[0]
            renames[row, RENAME_INSTANT], renames[row, RENAME_PARTICLE] = q, m
            renames[row, RENAME_HEIR], renames[row, RENAME_TAKEN] = P.ident[m, b], P.ident[m, k]
            n_renames[0] = row + 1
            P.ident[m, b] = P.ident[m, k]
            P.seen[m, b] += P.seen[m, k]
        remove_landmark(P, m, k)


__all__ = ["add_landmark", "remove_landmark", "in_view", "in_view_along", "existence_log_odds", "negative_evidence",
           "heir_of", "RENAME_INSTANT", "RENAME_PARTICLE", "RENAME_HEIR", "RENAME_TAKEN", "retire_landmarks"]
