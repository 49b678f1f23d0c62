"""Data association re-decided in the smoother (fastslam_edu.landmark.smoother_association), on simulated data."""

from __future__ import annotations

import numpy as np
import pytest

from fastslam_edu.datasets.events import event_stream
from fastslam_edu.datasets.sim import SimConfig, simulate_dataset
from fastslam_edu.evaluation import association as score
from fastslam_edu.landmark import smoother_association as sa
from fastslam_edu.landmark.association import AssociationParams, run_unknown
from fastslam_edu.landmark.fastslam import FastSLAMParams

SIM_FILTER = FastSLAMParams(n_particles=30, measurement_cov=np.diag([0.05**2, 0.02**2]), range_std_slope=0.0)
SIM_PARAMS = AssociationParams(filter=SIM_FILTER, max_range=5.0, fov=1.0)


@pytest.fixture(scope="module")
def sim():
    data = simulate_dataset(0, SimConfig(duration=120.0))
    stream = event_stream(data.robots[1], data.landmark_subjects)
    return data, stream, run_unknown(stream, SIM_PARAMS, 0)


def accuracy(history, ident, landmarks, data, truth):
    return score.association_accuracy(history, truth, ident, score.match_landmarks(landmarks, data.landmark_positions))


def test_smoother_beats_the_filter_and_reaches_the_truth(sim):
    data, stream, filt = sim
    truth = stream.landmark
    s = sa.smooth_association(stream, filt)
    a_filter = accuracy(filt.history, filt.landmark_ident, filt.landmarks, data, truth)
    a_smooth = accuracy(s.history, s.landmark_ident, s.landmarks, data, truth)
    assert a_smooth >= a_filter and a_smooth >= 0.99
    assert np.sum(score.match_landmarks(s.landmarks, data.landmark_positions) < 0) == 0
    again = sa.smooth_association(stream, filt)  # no random step: same numbers
    assert np.array_equal(again.history, s.history) and again.cost == s.cost


def test_assignment_never_gives_one_landmark_two_sightings_of_a_frame():
    rng = np.random.default_rng(0)
    for _ in range(200):
        s, N = rng.integers(1, 6), rng.integers(0, 6)
        d2 = rng.uniform(0, 10, (s, N))
        chosen = sa.assign_frame(d2, 13.8, 13.8)
        used = chosen[(chosen >= 0) & (chosen < N)]
        assert len(used) == len(set(used.tolist()))
        # every sighting fits every landmark: all go to distinct landmarks while any is left
        assert np.sum((chosen >= 0) & (chosen < N)) == min(s, N)


def _log_and_truth(sim):
    data, stream, filt = sim
    log = sa._prepare(stream, SIM_FILTER, None, SIM_PARAMS)
    return data, stream, filt, log, sa.SmootherAssociationParams()


def test_a_planted_merge_is_split(sim):
    data, stream, filt, log, settings = _log_and_truth(sim)
    truth = stream.landmark.copy()
    moved = data.landmark_positions.copy()
    k, j = 0, 1  # plant: landmark j moved 0.2 m from k, and both given one label
    counts = np.bincount(truth, minlength=len(moved))
    k, j = np.argsort(-counts)[:2]
    labels = np.where(truth == j, k, truth)
    state = sa.alternate(log, filt.pose_mean[log.keys], labels, moved, settings)
    table = score.association_table(state.labels, truth, np.arange(len(state.landmarks)), len(moved))
    assert int(np.sum(table[:, k] > 0.8 * counts[k])) == 1 and int(np.sum(table[:, j] > 0.8 * counts[j])) == 1
    assert np.argmax(table[:, k]) != np.argmax(table[:, j])


def test_a_planted_split_is_merged(sim):
    data, stream, filt, log, settings = _log_and_truth(sim)
    truth = stream.landmark.copy()
    k = int(np.argmax(np.bincount(truth)))
    i = np.flatnonzero(truth == k)
    labels = truth.copy()
    labels[i[len(i) // 2:]] = truth.max() + 1  # the second half of its sightings as another landmark
    lms = np.vstack([data.landmark_positions, data.landmark_positions[k] + [0.05, 0.0]])
    state = sa.alternate(log, filt.pose_mean[log.keys], labels, lms, settings)
    assert len(np.unique(state.labels[i])) == 1 and state.labels[i[0]] >= 0
