"""Deferred commitment in FastSLAM with unknown correspondences (``AssociationParams.deferred``,
``split_tentative``): the confirmation range r* against its closed form and the filter's own gate, and two
landmarks 0.2 m apart first seen from far, on a hand-made event stream."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fastslam_edu.core.ekf import initialise_landmark_kernel
from fastslam_edu.core.motion import MotionNoise
from fastslam_edu.core.measurement import range_bearing
from fastslam_edu.datasets.log import EventStream
from fastslam_edu.landmark.association import run_unknown
from fastslam_edu.landmark.association_likelihood import association_loglik
from fastslam_edu.landmark.association_params import AssociationParams, confirmation_range
from fastslam_edu.landmark.fastslam import FastSLAMParams

#: σ_r 5 cm, σ_φ 0.02 rad, constant: r* = 0.2 / (0.02 √32) = 1.77 m at d0² = 16.
FILTER = FastSLAMParams(n_particles=20, measurement_cov=np.diag([0.05**2, 0.02**2]), range_std_slope=0.0,
                        measurement_correlation_s=None)
PAIR = np.array([[8.0, 0.1], [8.0, -0.1]])  # two landmarks 0.2 m apart, side by side seen from the x axis


def test_confirmation_range_closed_form():
    """r* = d / (σ_φ √(2 d0²)): it grows with d and shrinks with σ_φ and the gate; the range noise does not
    enter."""
    R = np.diag([0.07**2, 0.02**2])
    assert confirmation_range(R, 0.2, 16.0) == pytest.approx(0.2 / (0.02 * math.sqrt(32.0)))
    assert confirmation_range(R, 0.2, 16.0) == pytest.approx(1.7678, abs=1e-4)
    assert confirmation_range(np.diag([0.5**2, 0.02**2]), 0.2, 16.0) == confirmation_range(R, 0.2, 16.0)
    assert confirmation_range(R, 0.4, 16.0) == pytest.approx(2 * confirmation_range(R, 0.2, 16.0))
    assert confirmation_range(R, 0.2, 4.0) == pytest.approx(2 * confirmation_range(R, 0.2, 16.0))
    assert AssociationParams().confirm_range == math.inf  # off by default
    assert AssociationParams(deferred=True).confirm_range == pytest.approx(0.2 / (0.02 * math.sqrt(32.0)))
    with pytest.raises(ValueError, match="separation_m"):
        AssociationParams(separation_m=0.0)


@pytest.mark.parametrize("factor, outside", [(0.9, True), (1.1, False)])
def test_confirmation_range_is_where_the_filter_gate_parts_a_pair(factor, outside):
    """Independent check with the filter's own likelihood: a landmark made from one sighting at range r (Q = 2R),
    and the noise-free sighting of its neighbour 0.2 m across the line of sight: its d² is about d0² = 16 at r*,
    beyond the gate inside r*, inside the gate beyond r*."""
    R = np.diag([0.05**2, 0.02**2])
    rules = AssociationParams(filter=FILTER, drift_xy=0.0, drift_theta=0.0).rules()
    r_star = confirmation_range(R, 0.2, 16.0)
    pose = np.zeros(3)
    d2 = []
    for r in (r_star, factor * r_star):
        mu, sigma = np.zeros(2), np.zeros((2, 2))
        initialise_landmark_kernel(pose, np.array([r, 0.0]), R, mu, sigma)
        z = range_bearing(pose, np.array([[r, 0.2]]))[0]
        d2.append(association_loglik(pose, z, R, mu, sigma, np.zeros((3, 3)), 0.0, rules)[1])
    assert d2[0] == pytest.approx(16.0, rel=0.02)
    assert (d2[1] > 16.0) == outside


def approach_stream(stop_x: float, both=()) -> EventStream:
    """A robot at the origin facing +x sees :data:`PAIR` from 8 m for 20 s, drives at 0.5 m/s to ``stop_x`` and sees
    it from there for 60 s: one noise-free sighting per camera frame (5 Hz), A and B in turn (both in the frames
    ``both``)."""
    dt = 0.2
    drive = int(round(stop_x / 0.5 / dt))
    n = int(20 / dt) + drive + int(60 / dt)
    u = np.zeros((n, 2))
    u[int(20 / dt) + 1:int(20 / dt) + 1 + drive] = (0.5, 0.0)
    x = np.concatenate([[0.0], np.cumsum(u[1:, 0] * dt)])
    seen = [[0, 1] if k in both else [k % 2] for k in range(n)]
    z = np.vstack([range_bearing(np.array([x[k], 0.0, 0.0]), PAIR[seen[k]]) for k in range(n)])
    t = np.arange(n) * dt
    return EventStream(t=t, dt=np.concatenate([[0.0], np.diff(t)]), u=u,
                       offsets=np.concatenate([[0], np.cumsum([len(s) for s in seen])]), z=z,
                       landmark=np.concatenate(seen), landmark_subjects=np.array([1, 2]), x0=np.zeros(3))


#: One particle and no motion noise: the run is deterministic, its map the decisions' alone. No drift in the
#: association's Q, no merging of the final map's copies.
ONE = AssociationParams(filter=FILTER.replace(n_particles=1, motion_noise=MotionNoise()), drift_xy=0.0,
                        drift_theta=0.0, merge_radius=0.0, max_range=5.0, fov=1.0)


def near_pair(result) -> list[int]:
    """How many map landmarks lie within 0.03 m of each of :data:`PAIR`, and within 0.03 m of its midpoint."""
    d = np.linalg.norm(result.landmarks[:, None, :] - np.vstack([PAIR, PAIR.mean(0)])[None], axis=2)
    return [int(np.sum(d[:, j] < 0.03)) for j in range(3)]


def test_pair_first_seen_from_far_kept_apart_only_with_deferred_commitment():
    """Seen from 8 m the pair is one landmark (lateral σ 0.16 m); the robot then stops 1.5 m away, inside r* = 1.77 m
    but where the merged landmark, well known by then, still takes both (0.1 m off it: d² ≈ 11 < 16). Without
    deferral the map ends with the merged landmark between them; with it, the first sighting within r*
    re-initialises the landmark on one of them and the other's sightings (0.2 m off: d² ≈ 17) start a second."""
    stream = approach_stream(6.5)
    merged = run_unknown(stream, ONE, 0)
    apart = run_unknown(stream, ONE.replace(deferred=True), 0)
    assert near_pair(merged) == [0, 0, 1] and len(merged.landmarks) == 1, merged.landmarks
    assert near_pair(apart) == [1, 1, 0] and len(apart.landmarks) == 2, apart.landmarks
    far = run_unknown(approach_stream(6.0), ONE.replace(deferred=True), 0)  # stops 2 m away: beyond r*, merged
    assert near_pair(far) == [0, 0, 1], far.landmarks


def test_a_provisional_landmark_seen_twice_in_one_frame_splits():
    """From 8 m the pair is one provisional landmark, until a frame (the 4th, before n_confirm sightings) sees both
    A and B: both fit it. Without ``split_tentative`` the joint rule gives it one of them and starts a landmark at
    the other, which starves: the old landmark (Σ shrunk by 3 sightings) explains B's sightings better than the
    fresh one (its smaller det Q outweighs its 0.1 m offset), and negative evidence removes it; the merged landmark
    stays. With it, the landmark is re-initialised from its own sighting: two fresh landmarks, one on each, and
    each keeps its own."""
    stream = approach_stream(0.0, both=(3,))
    merged = run_unknown(stream, ONE, 0)
    split = run_unknown(stream, ONE.replace(split_tentative=True), 0)
    assert near_pair(merged)[:2] == [0, 0] and len(merged.landmarks) == 1, merged.landmarks
    assert near_pair(split) == [1, 1, 0], split.landmarks
