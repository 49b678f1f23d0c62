"""Scoring data association: which map landmark each sighting went to, against the barcodes.

The filter with unknown correspondences (:mod:`fastslam_edu.landmark.association`) never
sees a barcode; the barcodes only score it:

* :func:`match_landmarks`: the map's landmarks matched one to one to the surveyed ones
  (``scipy.optimize.linear_sum_assignment`` on the distances, after the SE(2) alignment
  of the matched pairs, starting from the alignment of the path (:func:`path_alignment`);
  a pair further apart than ``max_distance`` is no match);
* :func:`association_accuracy`: the fraction of landmark sightings that the
  highest-weight particle assigned to the map landmark matched to the sighting's
  true subject;
* :func:`association_accuracy_oracle`: the same fraction for maximum-likelihood
  association at the groundtruth pose against the surveyed map, with the filter's
  :math:`R`: the best any association can do with this sensor;
* :func:`association_accuracy_ceiling`: the same at a filter's own path against its own final map (with
  known correspondences): the best an association decided in the filter's frame can do with the map
  the filter can build;
* :class:`OnlineCeiling`: the same rule the filter without barcodes decides by
  (:func:`fastslam_edu.landmark.association.choose_landmarks`), applied by every particle of FastSLAM run *with*
  known correspondences at each instant, before its update: the accuracy a particle reaches while its pose and
  map are those of a filter that never associated wrongly;
* :func:`association_breakdown`: where the landmark sightings went (correct, to a wrong map landmark, to
  an identity no longer in the map, to none);
* :func:`landmarks_in_map` and :func:`landmarks_spurious` (map landmarks matched to no surveyed one).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.optimize import linear_sum_assignment

from fastslam_edu.core.measurement import innovation, range_bearing
from fastslam_edu.evaluation import registration
from fastslam_edu.core.se2 import align_se2, apply_se2
from fastslam_edu.landmark.association import choose_landmarks_kernel
from fastslam_edu.landmark.association_params import AssociationParams, association_workspace, initial_particles
from fastslam_edu.landmark.fastslam import FilterRun
from fastslam_edu.landmark.hooks import Hook
from fastslam_edu.landmark.particle_set import ParticleSet
from fastslam_edu.landmark.fastslam_step import pose_covariance

#: Map landmarks further than this from every surveyed landmark they could be matched to are spurious [m].
MAX_MATCH_DISTANCE = 1.0


def _assign(estimate, truth, max_distance):
    d = np.linalg.norm(estimate[:, None, :] - truth[None, :, :], axis=-1)
    rows, cols = linear_sum_assignment(np.where(d <= max_distance, d, 1e6))
    ok = d[rows, cols] <= max_distance
    out = np.full(len(estimate), -1, dtype=np.int64)
    out[rows[ok]] = cols[ok]
    return out


def match_landmarks(estimate, truth, max_distance: float = MAX_MATCH_DISTANCE, align: bool = True,
                    iterations: int = 3, start=None, register: bool = True) -> np.ndarray:
    """For each map landmark (L, 2), the index of the surveyed landmark (N, 2) it is matched to, or -1.

    The one-to-one assignment that minimises the summed distance
    (``scipy.optimize.linear_sum_assignment``); pairs further apart than ``max_distance`` are unmatched.
    With ``align`` (default) the map is first moved by the SE(2) motion that fits the matched pairs
    (:func:`fastslam_edu.core.se2.align_se2`), and matched again, ``iterations`` times: SLAM
    recovers the map only up to such a motion, and where surveyed landmarks stand a few tenths of a
    metre apart a small offset of the whole map would otherwise match each landmark to its neighbour.

    Where the matching starts: ``start``, ``(R (2, 2), t (2,))``, the motion the map is moved by before the first
    assignment (:func:`path_alignment`: the motion that fits the filter's path to the groundtruth; None: the map
    as it is), and with ``register`` (default) also the motion that lays the map on the survey by itself
    (:func:`fastslam_edu.evaluation.registration.register`): a filter whose heading drifted ends with a map turned
    away from its average path. Of the two, the matching with more pairs is kept (then the smaller summed distance).
    """
    estimate = np.asarray(estimate, dtype=float).reshape(-1, 2)
    truth = np.asarray(truth, dtype=float).reshape(-1, 2)
    if len(estimate) == 0 or len(truth) == 0:
        return np.full(len(estimate), -1, dtype=np.int64)
    starts = [start]
    if register:
        starts.append(registration.register(estimate, truth))
    best, best_key = None, None
    for motion in starts:
        if motion is None and best is not None:
            continue
        out, moved = _match_from(estimate, truth, motion, max_distance, iterations if align else 0)
        ok = out >= 0
        key = (int(ok.sum()), -float(np.linalg.norm(moved[ok] - truth[out[ok]], axis=1).sum()))
        if best_key is None or key > best_key:
            best, best_key = out, key
    return best


def _match_from(estimate, truth, start, max_distance, iterations):
    """:func:`match_landmarks` from one start: ``(match (L,), the map as moved last (L, 2))``."""
    moved = estimate if start is None else apply_se2(estimate, *start)
    out = _assign(moved, truth, max_distance)
    for _ in range(iterations):
        ok = out >= 0
        if ok.sum() < 3:
            break
        R, t, _ = align_se2(estimate[ok], truth[out[ok]])
        moved = apply_se2(estimate, R, t)
        again = _assign(moved, truth, max_distance)
        if np.array_equal(again, out):
            break
        out = again
    return out, moved


def path_alignment(path_xy, truth_xy):
    """``(R, t)``: the SE(2) motion that best maps the filter's positions (n, 2) onto the groundtruth's (n, 2)
    at the same times (:func:`fastslam_edu.core.se2.align_se2`); rows with NaN are left out. The
    map of a SLAM run is placed in the frame of its path, so the same motion brings the map near the survey."""
    path_xy, truth_xy = np.asarray(path_xy, dtype=float), np.asarray(truth_xy, dtype=float)
    ok = np.isfinite(path_xy).all(axis=1) & np.isfinite(truth_xy).all(axis=1)
    R, t, _ = align_se2(path_xy[ok], truth_xy[ok])
    return R, t


def in_survey_order(estimate, match, n_truth: int) -> tuple[np.ndarray, np.ndarray]:
    """The matched map landmarks (L, 2) put in the surveyed order: ``(landmarks (N, 2), observed (N,))``, NaN and
    False where no map landmark is matched (``match`` from :func:`match_landmarks`), so that the scorers of known
    correspondences apply."""
    estimate, match = np.asarray(estimate, dtype=float).reshape(-1, 2), np.asarray(match)
    landmarks, observed = np.full((n_truth, 2), np.nan), np.zeros(n_truth, dtype=bool)
    landmarks[match[match >= 0]] = estimate[match >= 0]
    observed[match[match >= 0]] = True
    return landmarks, observed


def landmarks_in_map(estimate) -> int:
    """How many landmarks the map holds."""
    return int(np.asarray(estimate, dtype=float).reshape(-1, 2).shape[0])


def landmarks_spurious(estimate, truth, max_distance: float = MAX_MATCH_DISTANCE, start=None) -> int:
    """Map landmarks matched to no surveyed landmark (:func:`match_landmarks`, with its ``start``)."""
    return int(np.sum(match_landmarks(estimate, truth, max_distance, start=start) < 0))


def association_accuracy(history, true_index, map_ident, map_match) -> float:
    """Fraction of landmark sightings assigned to the map landmark matched to their true subject.

    ``history`` (n,): the identity of the landmark each sighting was assigned to (-1: none);
    ``true_index`` (n,): the surveyed landmark each sighting is of (-1: clutter, not scored);
    ``map_ident`` (L,): the identities of the map's landmarks; ``map_match`` (L,): the surveyed
    landmark each is matched to (-1: none, :func:`match_landmarks`). NaN if no landmark sighting.
    """
    return association_breakdown(history, true_index, map_ident, map_match)["correct"]


def oracle_association(poses, z, R, landmarks) -> np.ndarray:
    """Maximum-likelihood association at known poses (n, 3) against a known map (N, 2): the index per sighting.

    :math:`\\arg\\max_j \\log\\mathcal N(z \\ominus h(x, \\mathbf l_j); 0, R)` with the sighting's ``R`` (n, 2, 2); rows of
    ``landmarks`` that are NaN (not in a map) are never chosen.
    """
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    z = np.asarray(z, dtype=float).reshape(-1, 2)
    R = np.broadcast_to(np.asarray(R, dtype=float), (len(z), 2, 2))
    landmarks = np.asarray(landmarks, dtype=float).reshape(-1, 2)
    mapped = np.flatnonzero(np.isfinite(landmarks).all(axis=1))  # a landmark at NaN (not in the map) is never chosen
    if len(mapped) == 0:
        raise ValueError("oracle_association: no landmark with a finite position")
    nu = innovation(z[:, None, :], range_bearing(poses[:, None, :], landmarks[None, mapped, :]))  # (n, N, 2)
    Rinv = np.linalg.inv(R)[:, None]
    d2 = np.einsum("nki,nkij,nkj->nk", nu, np.broadcast_to(Rinv, nu.shape[:2] + (2, 2)), nu)
    return mapped[np.argmin(d2, axis=1)].astype(np.int64)  # one R per sighting: the likelihood falls with d²


def association_breakdown(history, true_index, map_ident, map_match) -> dict:
    """Where the landmark sightings went, as fractions that add up to one: ``correct`` (the map landmark matched to
    the sighting's true subject: :func:`association_accuracy`), ``wrong`` (a map landmark matched to another surveyed
    landmark, or to none: a spurious one), ``not_in_map`` (an identity the final map no longer holds: a landmark
    later removed, or still provisional) and ``unassigned`` (no landmark). Arguments as for
    :func:`association_accuracy`; NaN everywhere if there is no landmark sighting."""
    history = np.asarray(history, dtype=np.int64)
    true_index = np.asarray(true_index, dtype=np.int64)
    scored = true_index >= 0
    keys = ("correct", "wrong", "not_in_map", "unassigned")
    if not scored.any():
        return dict.fromkeys(keys, float("nan"))
    h, j = history[scored], true_index[scored]
    truth_of = dict(zip(np.asarray(map_ident).tolist(), np.asarray(map_match).tolist()))
    in_map = np.array([i in truth_of for i in h.tolist()], dtype=bool)
    assigned = np.array([truth_of.get(i, -1) for i in h.tolist()], dtype=np.int64)
    correct = in_map & (assigned == j) & (assigned >= 0)
    return {"correct": float(np.mean(correct)), "wrong": float(np.mean(in_map & ~correct)),
            "not_in_map": float(np.mean(~in_map & (h >= 0))), "unassigned": float(np.mean(h < 0))}


def association_accuracy_oracle(poses, z, R, landmarks, true_index) -> float:
    """The fraction of landmark sightings (``true_index >= 0``) that :func:`oracle_association` gets right."""
    true_index = np.asarray(true_index, dtype=np.int64)
    scored = true_index >= 0
    if not scored.any():
        return float("nan")
    guess = oracle_association(np.asarray(poses)[scored], np.asarray(z)[scored], np.asarray(R)[scored], landmarks)
    return float(np.mean(guess == true_index[scored]))


def association_accuracy_ceiling(t, poses, sighting_t, z, R, landmarks, true_index) -> float:
    """The fraction of landmark sightings that maximum-likelihood association gets right at a filter's own
    poses against its own map: :func:`association_accuracy_oracle` with the pose of the filter's last step at
    or before each sighting, ``poses`` (n, 3) at times ``t`` (n,), and its final map ``landmarks`` (N, 2) in the
    surveyed order (NaN rows: not mapped, never chosen).

    Run on the result of FastSLAM *with* known correspondences, it bounds what any association decided in
    the filter's frame can reach: even told the final map in advance, a sighting goes to the wrong landmark
    when the filter's pose and map disagree, relative to each other, by more than the landmarks' spacing.
    ``sighting_t`` (n,), ``z`` (n, 2), ``R`` (n, 2, 2), ``true_index`` (n,) as for the oracle."""
    t = np.asarray(t, dtype=float)
    k = np.clip(np.searchsorted(t, np.asarray(sighting_t, dtype=float), side="right") - 1, 0, len(t) - 1)
    return association_accuracy_oracle(np.asarray(poses, dtype=float)[k], z, R, landmarks, true_index)


@njit(cache=True)
def particles_right(P, z, R, t, truth, w, rules, work):
    """For each sighting ``z`` (n, 2) of one instant at time ``t``, the weight ``w`` (M,) of the particles of ``P``
    (:class:`~fastslam_edu.landmark.association_params.MapParticles`) whose association
    (:func:`~fastslam_edu.landmark.association.choose_landmarks`, with ``rules``, decided in ``work``: an
    :func:`~fastslam_edu.landmark.association_params.association_workspace` for n sightings) gives it its true
    landmark ``truth`` (n,) (a slot of ``P``): (n,). The pose covariance the rule adds is the filter's:
    ``rules.pose_scale`` times the particles' (:func:`~fastslam_edu.landmark.fastslam_step.pose_covariance`)."""
    right = np.zeros(z.shape[0])
    cloud = pose_covariance(P.poses, w) * rules.pose_scale
    for m in range(P.poses.shape[0]):
        choose_landmarks_kernel(P, m, P.poses[m], (z, R, t), cloud, rules, work)
        for i in range(z.shape[0]):
            if work.slot[i] == truth[i]:
                right[i] += w[m]
    return right


class OnlineCeiling(Hook):
    """What the association of the filter without barcodes would get right, decided inside FastSLAM run *with*
    known correspondences: a :class:`~fastslam_edu.landmark.hooks.Hook` for
    :func:`~fastslam_edu.landmark.fastslam.run_fastslam` (``hooks=(probe,)``) that changes nothing.

    At each measurement instant, after the motion and before the update, every particle decides the instant's
    sightings by :func:`~fastslam_edu.landmark.association.choose_landmarks` (maximum likelihood with the drift
    term and the gate :math:`d_0`, mutual exclusion: the rule and settings of ``params``) against the landmarks it
    has mapped so far; a sighting counts as right, for that particle, when it goes to its true landmark, and the
    particles count by their weights. Sightings of a landmark no particle has mapped yet (a first sighting: any
    association makes it new) are not scored.

    The pose and map each particle decides from are those of a filter that never associated wrongly: the accuracy
    is what a particle of the filter without barcodes reaches while it has made no mistake, before any mistake
    compounds. ``accuracy`` (after the run): the weighted fraction over the scored sightings; ``scored``: their
    number; ``first_sightings``: those left out. Either particle set (arrays, or the landmark trees) is read.
    """

    def __init__(self, params: AssociationParams = AssociationParams()):
        self.rules = params.rules()
        self.right = 0.0
        self.scored = 0
        self.first_sightings = 0
        self._work = None

    def workspace(self, n: int, N: int):
        """The :func:`~fastslam_edu.landmark.association_params.association_workspace` the probe decides in, made
        again only when an instant has more sightings (``n``) or the set other landmarks (``N``) than it holds."""
        work = self._work
        if work is None or work.slot.shape[0] < n or work.ll.shape[1] != N:
            self._work = work = association_workspace(n, N)
        return work

    @property
    def accuracy(self) -> float:
        return self.right / self.scored if self.scored else float("nan")

    def after_motion(self, run: FilterRun, s: int, e: int) -> None:
        stream = run.stream
        a, b = int(stream.offsets[e]), int(stream.offsets[e + 1])
        if b <= a:
            return
        parts = run.particles
        if not isinstance(parts, ParticleSet):  # the landmark trees: read as arrays
            parts = parts.to_particle_set()
        M, N = parts.seen.shape
        truth = np.asarray(stream.landmark[a:b], dtype=np.int64)
        mapped = parts.seen[:, truth].any(axis=0)
        self.first_sightings += int(np.sum(~mapped))
        if not mapped.any():
            return
        P = initial_particles(M, N, np.zeros(3))  # slot k holds landmark k, every landmark confirmed
        P.poses[:], P.sigma[:], P.n[:], P.ident[:] = parts.poses, parts.sigma, N, np.arange(N)
        P.mu[:] = np.where(parts.seen[..., None], parts.mu, np.nan)  # a landmark a particle has not mapped: never chosen
        P.evidence[:], P.last_t[:] = self.rules.n_confirm, run.last_seen
        w = np.asarray(run.w, dtype=float)
        right = particles_right(P, np.ascontiguousarray(stream.z[a:b], dtype=float),
                                np.ascontiguousarray(run.R[a:b]), float(stream.t[e]), truth, w / w.sum(), self.rules,
                                self.workspace(b - a, N))
        self.right += float(right[mapped].sum())
        self.scored += int(mapped.sum())


def association_table(history, true_index, map_ident, n_landmarks: int) -> np.ndarray:
    """Counts (L, N + 1): how many sightings of surveyed landmark ``j`` (column ``j``; the last column: clutter)
    went to map landmark ``l`` (row, in the order of ``map_ident``). Sightings assigned to no map landmark
    (a landmark later removed, or still provisional) are not counted.

    A row with several large entries is a **merged** landmark (one map landmark for several surveyed ones);
    a column with several large entries a **split** one (several map landmarks for one surveyed landmark).
    """
    history = np.asarray(history, dtype=np.int64)
    true_index = np.asarray(true_index, dtype=np.int64)
    row = {int(i): r for r, i in enumerate(np.asarray(map_ident).tolist())}
    table = np.zeros((len(row), n_landmarks + 1), dtype=np.int64)
    for h, j in zip(history.tolist(), true_index.tolist()):
        if h in row:
            table[row[h], j if j >= 0 else n_landmarks] += 1
    return table


def merged_and_split(table, share: float = 0.2) -> tuple[int, int]:
    """From :func:`association_table`: map landmarks whose sightings come from two or more surveyed landmarks
    (each at least ``share`` of the row: merged), and surveyed landmarks spread over two or more map landmarks
    (each at least ``share`` of the column: split)."""
    t = np.asarray(table, dtype=float)[:, :-1]
    rows = t / np.maximum(t.sum(axis=1, keepdims=True), 1)
    cols = t / np.maximum(t.sum(axis=0, keepdims=True), 1)
    return int(np.sum((rows >= share).sum(axis=1) >= 2)), int(np.sum((cols >= share).sum(axis=0) >= 2))


__all__ = ["association_table", "in_survey_order", "merged_and_split", "MAX_MATCH_DISTANCE", "match_landmarks", "path_alignment",
           "landmarks_in_map", "landmarks_spurious", "association_accuracy", "association_breakdown",
           "oracle_association", "association_accuracy_oracle", "association_accuracy_ceiling",
           "particles_right", "OnlineCeiling"]
