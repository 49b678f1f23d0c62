"""Step (c) of the smoother's data association (:mod:`fastslam_edu.landmark.smoother_association`): split, merge
and prune moves on landmarks, scored by the penalised cost, and loop closures between groups of landmarks
accepted by pairwise consistency (a maximum clique)."""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from fastslam_edu.core.measurement import innovation_unchecked, landmark_from_measurement, range_bearing_unchecked
from fastslam_edu.landmark.smoother_association_model import (OUTLIER, SightingLog, SmootherAssociationParams,
                                                              fit_landmark, frames_of, sighting_poses)


# --------------------------------------------------------------------------- (c) split, merge, prune


def two_clusters(poses, z, Rinv, iterations: int = 10) -> np.ndarray:
    """Hard EM of two landmarks for sightings ``z`` (s, 2) from fixed ``poses`` (s, 3): each sighting goes to the
    landmark it fits better (:math:`d^2`, measurement space), each landmark is fitted to its sightings
    (:func:`fit_landmark`); started from the two ends of the principal axis of the inverse measurements.
    Returns a bool (s,): the second cluster."""
    points = landmark_from_measurement(poses, z)
    centred = points - points.mean(axis=0)
    proj = centred @ np.linalg.svd(centred, full_matrices=False)[2][0]
    side = proj > np.median(proj)
    for _ in range(iterations):
        if side.sum() < 2 or (~side).sum() < 2:
            break
        d2 = []
        for part in (~side, side):
            l = fit_landmark(poses[part], z[part], Rinv[part])[0]
            nu = innovation_unchecked(z, range_bearing_unchecked(poses, l))
            d2.append(np.einsum("ni,nij,nj->n", nu, Rinv, nu))
        new = d2[1] < d2[0]
        if np.array_equal(new, side):
            break
        side = new
    return side


def split_moves(log: SightingLog, poses, labels, beta, settings: SmootherAssociationParams) -> tuple[np.ndarray, int]:
    """Split every landmark whose sightings form two clusters (:func:`two_clusters` of their inverse measurements)
    when the two fit them better by more than the penalty :math:`\\lambda` of the second:
    :math:`\\sum \\beta_i d^2_i` (one) :math:`> \\sum \\beta_i d^2_i` (two) :math:`+ \\lambda`, and the two are never
    seen in one frame... by construction, or if they are (a landmark seen twice in one frame), all the more.
    Returns ``(labels, splits)``."""
    labels = labels.copy()
    xs = sighting_poses(log, poses)
    splits = 0
    for j in range(int(labels.max(initial=-1)) + 1):
        i = np.flatnonzero(labels == j)
        if len(i) < 4:
            continue
        _, _, d2_one = fit_landmark(xs[i], log.stream.z[i], log.Rinv[i])
        side = two_clusters(xs[i], log.stream.z[i], log.Rinv[i])
        if side.sum() < 2 or (~side).sum() < 2:
            continue
        _, _, d2_a = fit_landmark(xs[i[~side]], log.stream.z[i[~side]], log.Rinv[i[~side]])
        _, _, d2_b = fit_landmark(xs[i[side]], log.stream.z[i[side]], log.Rinv[i[side]])
        one = np.sum(beta[i] * np.minimum(d2_one, settings.gate))
        two = np.sum(beta[i[~side]] * np.minimum(d2_a, settings.gate)) \
            + np.sum(beta[i[side]] * np.minimum(d2_b, settings.gate))
        if two + settings.penalty < one:
            labels[i[side]] = labels.max() + 1
            splits += 1
    return labels, splits


def merge_moves(log: SightingLog, poses, labels, landmarks, cov, beta, *, settings: SmootherAssociationParams):
    """Merge landmarks ``a, b`` never seen in one frame whose positions agree within their covariances
    (:math:`(l_a - l_b)^\\top (\\Sigma_a + \\Sigma_b)^{-1} (l_a - l_b) \\le g`) when one landmark fits the sightings of
    both for less than the penalty :math:`\\lambda` it saves. Nearest pairs first. Returns ``(labels, merges)``."""
    labels = labels.copy()
    xs = sighting_poses(log, poses)
    N = len(landmarks)
    ok = np.isfinite(landmarks).all(axis=1)
    pairs = []
    for a in range(N):
        for b in range(a + 1, N):
            if ok[a] and ok[b]:
                e = landmarks[a] - landmarks[b]
                d2 = e @ np.linalg.solve(cov[a] + cov[b], e)
                if d2 <= settings.gate:
                    pairs.append((d2, a, b))
    merged, gone = 0, set()
    frames = {j: frames_of(log, labels, j) for j in {a for _, a, _ in pairs} | {b for _, _, b in pairs}}
    for _, a, b in sorted(pairs):
        if a in gone or b in gone or frames[a] & frames[b]:
            continue
        i = np.flatnonzero((labels == a) | (labels == b))
        _, _, d2_one = fit_landmark(xs[i], log.stream.z[i], log.Rinv[i])
        ia, ib = np.flatnonzero(labels == a), np.flatnonzero(labels == b)
        two = sum(np.sum(beta[k] * np.minimum(fit_landmark(xs[k], log.stream.z[k], log.Rinv[k])[2], settings.gate))
                  for k in (ia, ib))
        one = np.sum(beta[i] * np.minimum(d2_one, settings.gate))
        if one < two + settings.penalty:
            labels[ib] = a
            frames[a] |= frames[b]
            gone.add(b)
            merged += 1
    return labels, merged


def views_and_sightings(log: SightingLog, poses, labels, landmarks) -> tuple[np.ndarray, np.ndarray]:
    """Two bool (F, N) matrices over the camera frames (steps with sightings) and the landmarks: ``view``, the landmark
    in view from the frame's pose (within the field of view and the range of the filter's ``AssociationParams``), and
    ``seen``, given a sighting of that frame."""
    fov, r_min, r_max, _, _ = log.camera
    steps = np.flatnonzero(np.diff(log.stream.offsets))
    x = poses[np.searchsorted(log.keys, steps)]
    N = len(landmarks)
    placed = np.isfinite(landmarks).all(axis=1)  # a landmark without a sighting used is nowhere: never in view
    landmarks = np.where(placed[:, None], landmarks, 1e6)
    z_hat = range_bearing_unchecked(x[:, None], landmarks[None])  # (F, N, 2): every frame against every landmark
    view = placed[None] & (z_hat[..., 0] >= r_min) & (z_hat[..., 0] <= r_max) & (np.abs(z_hat[..., 1]) <= fov)
    seen = np.zeros((len(steps), N), dtype=bool)
    ok = labels >= 0
    seen[np.searchsorted(steps, log.frame[ok]), labels[ok]] = True
    return view, seen


def whole_log_existence_log_odds(log: SightingLog, poses, labels, landmarks) -> np.ndarray:
    """The log odds (N,) that each landmark is real rather than clutter, as the filter's negative evidence
    (:func:`fastslam_edu.landmark.landmark_existence.existence_log_odds`, over the whole log, unclamped):
    :math:`n_{hit} \\log(p_D/p_F) + n_{miss} \\log((1-p_D)/(1-p_F))`, with :math:`n_{hit}` the camera frames that
    see it and :math:`n_{miss}` those that see something but not it while it is in view
    (:func:`views_and_sightings`). Another robot standing somewhere for a while is seen there, and then missed
    whenever the camera looks there again."""
    _, _, _, log_hit, log_miss = log.camera
    view, seen = views_and_sightings(log, poses, labels, landmarks)
    return seen.sum(axis=0) * log_hit + (view & ~seen).sum(axis=0) * log_miss


def static_against_transient(log: SightingLog, poses, labels, landmarks) -> np.ndarray:
    """The log likelihood ratio (N,) of each landmark being *static* (there all the log, seen with probability
    :math:`p_D` whenever in view) against *transient* (there only from its first sighting to its last: another
    robot standing still, then gone), with the transient's :math:`k = 2` extra parameters (when it came, when it
    left) charged the BIC's :math:`\\tfrac{k}{2} \\ln n = \\ln n`:

    .. math::

        \\Lambda = n_{out} \\log\\frac{1 - p_D}{1 - p_F} + \\ln n_{view},

    :math:`n_{out}` the frames that have it in view but before its first sighting or after its last (a miss that
    the static landmark must explain by :math:`1 - p_D` and the transient one by :math:`1 - p_F`: it was not there),
    :math:`n_{view}` the frames that have it in view or see it. Frames between its first and last sighting count
    alike under both and cancel. :math:`\\Lambda \\le 0`: transient."""
    _, _, _, _, log_miss = log.camera
    view, seen = views_and_sightings(log, poses, labels, landmarks)
    frame = np.arange(len(view))[:, None]
    first = np.where(seen, frame, len(view)).min(axis=0)  # (a landmark never seen: no frame is inside)
    last = np.where(seen, frame, -1).max(axis=0)
    outside = view & ~seen & ((frame < first) | (frame > last))
    return outside.sum(axis=0) * log_miss + np.log(np.maximum((view | seen).sum(axis=0), 1))


def prune_landmarks(log: SightingLog, poses, labels, landmarks, d2, beta, *, settings: SmootherAssociationParams):
    """Landmarks whose sightings, left out, cost less than the landmark, :math:`\\sum_i \\beta_i (g - d^2_i) \\le
    \\lambda`, or whose existence log odds (:func:`whole_log_existence_log_odds`) are not positive: their
    sightings become outliers. Returns ``(labels, pruned)``."""
    labels = labels.copy()
    odds = whole_log_existence_log_odds(log, poses, labels, landmarks)
    pruned = 0
    for j in range(int(labels.max(initial=-1)) + 1):
        i = np.flatnonzero(labels == j)
        support = np.sum(beta[i] * (settings.gate - np.minimum(d2[i], settings.gate)))
        if len(i) and (support <= settings.penalty or not odds[j] > 0):
            labels[i] = OUTLIER
            pruned += 1
    return labels, pruned


def transient_outliers(log: SightingLog, poses, labels, landmarks) -> np.ndarray:
    """``labels`` with the sightings of every landmark more likely transient than static
    (:func:`static_against_transient` :math:`\\le 0`) made outliers: the map reports static landmarks only."""
    static = static_against_transient(log, poses, labels, landmarks)
    transient = np.flatnonzero(static <= 0)
    return np.where(np.isin(labels, transient), OUTLIER, labels)


# --------------------------------------------------------------------------- loop closures between groups


def maximum_clique(adjacent: np.ndarray) -> list[int]:
    """The largest set of vertices all pairwise adjacent (``adjacent`` (V, V) bool, symmetric): Bron–Kerbosch with
    pivoting. Exponential in the worst case; the candidate graphs here have tens of vertices."""
    V = len(adjacent)
    neighbours = [set(np.flatnonzero(adjacent[v]).tolist()) - {v} for v in range(V)]
    best: list[int] = []

    def expand(clique, candidates, excluded):
        nonlocal best
        if not candidates and not excluded:
            if len(clique) > len(best):
                best = list(clique)
            return
        if len(clique) + len(candidates) <= len(best):
            return
        pivot = max(candidates | excluded, key=lambda u: len(neighbours[u] & candidates))
        for v in sorted(candidates - neighbours[pivot]):
            expand(clique + [v], candidates & neighbours[v], excluded & neighbours[v])
            candidates = candidates - {v}
            excluded = excluded | {v}

    expand([], set(range(V)), set())
    return sorted(best)


def loop_candidates(log: SightingLog, labels, landmarks, cov,
                    settings: SmootherAssociationParams) -> list[tuple[int, int]]:
    """Pairs ``(a, b)`` of landmarks never seen in one frame, too far apart to be merged by :func:`merge_moves`
    (:math:`d^2 > g`) but within the drift the odometry allows between the two visits: the motion noise's
    :math:`\\sigma_v^2 \\Delta t` on each coordinate, :math:`\\Delta t` [s] the time between the last sighting of the
    older and the first of the newer, plus the landmarks' own covariances, at :math:`\\sqrt g` standard deviations."""
    noise = log.params.motion_noise
    rate = noise.sigma_v ** 2 if noise.mode == "control" else noise.sigma_xy ** 2  # [m²/s]
    t = log.stream.t[log.frame]
    N = len(landmarks)
    first = np.array([t[labels == j].min() if np.any(labels == j) else np.inf for j in range(N)])
    last = np.array([t[labels == j].max() if np.any(labels == j) else -np.inf for j in range(N)])
    frames = [frames_of(log, labels, j) for j in range(N)]
    out = []
    for a in range(N):
        for b in range(N):
            if a == b or not first[a] <= first[b] or not np.isfinite(landmarks[[a, b]]).all():
                continue
            if first[a] == first[b] and a > b:
                continue
            e = landmarks[a] - landmarks[b]
            C = cov[a] + cov[b]
            if e @ np.linalg.solve(C, e) <= settings.gate or frames[a] & frames[b]:
                continue
            drift = rate * max(first[b] - last[a], 0.0) * 2.0 + np.trace(C)
            if e @ e <= settings.gate * drift:
                out.append((a, b))
    return out


def consistent_pairs(pairs, landmarks, cov, settings: SmootherAssociationParams) -> np.ndarray:
    """The consistency graph (P, P) of candidate pairs: ``(a, b)`` and ``(c, e)`` (four distinct landmarks) agree
    when :math:`(\\|l_a - l_c\\| - \\|l_b - l_e\\|)^2 \\le \\chi^2_1(p)\\,\\sigma^2`, :math:`\\sigma^2` half the
    trace of the four landmarks' covariances summed (the variance of a distance, to first order, for round
    covariances)."""
    k = float(chi2.ppf(settings.loop_probability, 1))
    P = len(pairs)
    adjacent = np.zeros((P, P), dtype=bool)
    for p in range(P):
        a, b = pairs[p]
        for q in range(p + 1, P):
            c, e = pairs[q]
            if len({a, b, c, e}) < 4:
                continue
            diff = np.linalg.norm(landmarks[a] - landmarks[c]) - np.linalg.norm(landmarks[b] - landmarks[e])
            var = 0.5 * np.trace(cov[a] + cov[b] + cov[c] + cov[e])
            adjacent[p, q] = adjacent[q, p] = diff * diff <= k * var
    return adjacent


def loop_closures(log: SightingLog, labels, landmarks, cov, settings: SmootherAssociationParams):
    """A group of landmark pairs to merge at once: the maximum clique of the consistency graph of the loop
    candidates (:func:`loop_candidates`, :func:`consistent_pairs`), if it holds at least ``min_loop_landmarks``
    pairs; else none. Returns the merged labels, or None."""
    pairs = loop_candidates(log, labels, landmarks, cov, settings)
    if len(pairs) < settings.min_loop_landmarks:
        return None
    clique = maximum_clique(consistent_pairs(pairs, landmarks, cov, settings))
    if len(clique) < settings.min_loop_landmarks:
        return None
    labels = labels.copy()
    for p in clique:
        a, b = pairs[p]
        labels[labels == b] = a
    return labels


__all__ = ["two_clusters", "split_moves", "merge_moves", "views_and_sightings", "whole_log_existence_log_odds",
           "static_against_transient", "prune_landmarks", "transient_outliers",
           "maximum_clique", "loop_candidates", "consistent_pairs", "loop_closures"]
