"""Re-association after a gap (fastslam_edu.landmark.gap_window, AssociationParams.gap_window_sightings), on
constructed frames with known truth and on simulated logs."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from fastslam_edu.core.measurement import range_bearing
from fastslam_edu.datasets.events import event_stream
from fastslam_edu.datasets.sim import simulate_dataset
from fastslam_edu.landmark.association import AssociationRecord, choose_landmarks, run_unknown
from fastslam_edu.landmark.association_params import JOINT, AssociationParams, association_workspace, initial_particles
from fastslam_edu.landmark.fastslam import FastSLAMParams
from fastslam_edu.landmark.gap_window import (decide_window, gap_covariance, gap_window, hold_frame, holds_frame,
                                              moved_pose, window_correction)
from fastslam_edu.landmark.joint_compatibility import N_PAIR_SLOTS, best_joint_hypothesis
from fastslam_edu.landmark.step_records import Log

R = np.diag([0.05**2, 0.02**2])
#: Joint compatibility, the motion noise's drift (2 cm and 0.05 rad per √s, counted for 5 s), a camera seeing all
#: around; windows of two sightings.
RULES = AssociationParams(filter=FastSLAMParams(n_particles=1, measurement_cov=R, range_std_slope=0.0,
                                                measurement_correlation_s=None),
                          fov=math.pi, min_range=0.3, max_range=8.0, drift_xy=0.02, drift_theta=0.05, drift_cap_s=5.0,
                          gap_window_sightings=2).rules()
assert RULES.association == JOINT


def particle_with(landmarks, pose=(0.0, 0.0, 0.0)):
    """One particle at ``pose`` holding ``landmarks`` (Σ = (3 cm)² I), confirmed (10 sightings), last seen at t = 0:
    identities 100, 101, ..."""
    P = initial_particles(1, 8, list(pose))
    for k, m in enumerate(landmarks):
        P.mu[0, k] = m
        P.sigma[0, k] = np.eye(2) * 0.03**2
        P.ident[0, k] = 100 + k
        P.seen[0, k] = 10
        P.evidence[0, k] = 10.0
        P.log_odds[0, k] = 5.0
    P.n[0] = len(landmarks)
    return P


def held_window(P, believed, seen, times, gap_s):
    """The frames of ``seen`` (a list of (n_i, 2) sightings) held in a window, the particle at the ``believed``
    poses (one per frame), after a gap of ``gap_s`` seconds: ``(L, win)`` with ``L`` the stream of those frames."""
    z = np.concatenate(seen)
    offsets = np.concatenate([[0], np.cumsum([len(s) for s in seen])]).astype(np.int64)
    n = len(seen)
    L = Log(t=np.asarray(times, dtype=float), u=np.zeros((n, 2)), dt=np.zeros(n), offsets=offsets, z=z,
            j=np.full(len(z), -1, dtype=np.int64), R=np.repeat(R[None], len(z), axis=0))
    win = gap_window(1, P.mu.shape[1], len(z), max(len(s) for s in seen))  # (room for every frame given)
    win.clock[0] = times[0] - gap_s  # the last sighting before the gap
    for w, pose in enumerate(believed):
        assert holds_frame(win, times[w], RULES)
        P.poses[0] = pose
        hold_frame(win, P.poses, np.zeros((3, 3)), (offsets[w], offsets[w + 1], w, w))
    return L, win


def record_for(n_sightings):
    """An empty :class:`AssociationRecord` for one particle."""
    return AssociationRecord(w=np.ones(1), pose_mean=np.zeros((1, 3)), pose_best=np.zeros((1, 3)),
                             assoc=np.full((1, n_sightings), -1, dtype=np.int64), parents=np.zeros((4, 1), dtype=np.int64),
                             instant_of=np.zeros(n_sightings, dtype=np.int64), next_ident=np.array([7]),
                             totals=np.zeros(3, dtype=np.int64), renames=np.zeros((64, 4), dtype=np.int64),
                             n_renames=np.zeros(1, dtype=np.int64))


def rigidly_moved(poses, delta):
    """``poses`` (W, 3) moved by the rigid motion ``delta`` = (dx, dy, dθ) about the first (exactly)."""
    poses = np.asarray(poses, dtype=float)
    c, s = math.cos(delta[2]), math.sin(delta[2])
    d = poses[:, :2] - poses[0, :2]
    out = poses.copy()
    out[:, 0] = poses[0, 0] + delta[0] + c * d[:, 0] - s * d[:, 1]
    out[:, 1] = poses[0, 1] + delta[1] + s * d[:, 0] + c * d[:, 1]
    out[:, 2] = poses[:, 2] + delta[2]
    return out


LANDMARKS = np.array([[3.0, 0.0], [2.0, 2.5], [-1.0, 3.0], [4.0, -2.0], [0.5, -3.0]])


def test_the_window_correction_recovers_a_rigid_motion_of_the_path():
    """Noise-free sightings from three frames of a true path; the particle believes that path moved rigidly by
    (0.15 m, -0.1 m, 0.25 rad). Given the right landmarks and a wide prior, Gauss-Newton moves it back: the
    corrected poses are the true ones to 1e-6."""
    true = np.array([[0.0, 0.0, 0.0], [0.3, 0.05, 0.15], [0.55, 0.2, 0.35]])
    believed = rigidly_moved(true, (0.15, -0.1, 0.25))
    seen_ks = [[0, 1], [2, 3], [0, 4]]
    seen = [range_bearing(true[w], LANDMARKS[ks]) for w, ks in enumerate(seen_ks)]
    P = particle_with(LANDMARKS)
    L, win = held_window(P, believed, seen, [40.0, 40.5, 41.0], gap_s=40.0)
    win.prior[:] = np.eye(3) * 1e4  # (so wide that the sightings alone decide)
    slot = np.array([k for ks in seen_ks for k in ks])
    e = window_correction(P, 0, L, win, slot, RULES)
    for w in range(3):
        out = np.zeros(3)
        moved_pose(win, 0, w, *e, out)
        np.testing.assert_allclose(out, true[w], atol=1e-6)


def test_the_gap_prior_is_the_whole_gaps_drift():
    """gap_covariance adds the drift beyond the association's cap; with the cap's own drift it is the motion
    noise's density times the whole gap."""
    out = np.zeros((3, 3))
    cloud = np.diag([1e-4, 2e-4, 3e-4])
    gap_covariance(cloud, 40.0, RULES, out)
    expected = cloud + np.diag([0.02**2, 0.02**2, 0.05**2]) * (40.0 - 5.0)
    np.testing.assert_allclose(out, expected, rtol=1e-12)


def aliased_frames():
    """The heading drifted 0.32 rad across a 40 s gap: landmark A's sighting lands exactly on its neighbour B's place.
    A second frame sees C, which only the same rotation explains. Returns ``(P, L, win, true_pose)``."""
    true_pose = np.array([0.0, 0.0, 0.0])
    believed = true_pose + [0.0, 0.0, 0.32]
    A, C = np.array([3.0, 0.0]), np.array([0.0, 3.0])
    B = 3.0 * np.array([math.cos(0.32), math.sin(0.32)])  # where the believed heading puts A's sighting
    P = particle_with([A, B, C])
    seen = [range_bearing(true_pose, A[None]), range_bearing(true_pose, C[None])]
    L, win = held_window(P, [believed, believed], seen, [40.0, 40.2], gap_s=40.0)
    return P, L, win, true_pose


def test_one_sighting_after_a_gap_takes_the_neighbour():
    """The failure the window is for: decided alone, even with the whole gap's drift in the pose covariance, the
    first sighting goes to B (slot 1), whose place it lands on."""
    P, L, win, _ = aliased_frames()
    prior = np.zeros((3, 3))
    gap_covariance(np.zeros((3, 3)), 40.0, RULES, prior)
    slot, _ = choose_landmarks(P, 0, P.poses[0], L.z[:1], L.R[:1], prior, 40.0, RULES)
    assert slot.tolist() == [1]


def test_the_window_decides_both_sightings_by_one_rotation():
    """Decided as a window, the two sightings go to A and C (identities 100 and 102): one rotation of -0.32 rad
    explains both, and the particle's heading is put right to 0.01 rad."""
    P, L, win, true_pose = aliased_frames()
    out = record_for(len(L.z))
    work = association_workspace(1, P.mu.shape[1])
    e = decide_window(P, 0, L, RULES, win, work, out)
    assert out.assoc[0].tolist() == [100, 102]
    assert e[2] == pytest.approx(-0.32, abs=0.01)
    assert P.poses[0, 2] == pytest.approx(true_pose[2], abs=0.01)


def test_one_landmark_alone_never_moves_the_path():
    """A window whose sightings all go to one landmark leaves the particle's poses where they were (one range and
    bearing cannot fix three unknowns): zero motion, the frames decided as usual."""
    P = particle_with(LANDMARKS)
    pose = np.array([0.0, 0.0, 0.1])
    seen = [range_bearing(np.zeros(3), LANDMARKS[:1]), range_bearing(np.zeros(3), LANDMARKS[:1])]
    L, win = held_window(P, [pose, pose], seen, [40.0, 40.2], gap_s=40.0)
    e = decide_window(P, 0, L, RULES, win, association_workspace(1, P.mu.shape[1]), record_for(2))
    assert e == (0.0, 0.0, 0.0)
    np.testing.assert_array_equal(P.poses[0], pose)


def test_a_landmark_takes_sightings_of_two_frames_but_not_two_of_one():
    """best_joint_hypothesis with frames: two sightings that both fit landmark 0 both take it when they come from two
    frames, and only one does when they come from one (the other is new)."""
    info = np.zeros((2, 1, N_PAIR_SLOTS))
    info[:, 0, 0] = 0.1  # ν'D⁻¹ν: both fit well
    ll = np.zeros((2, 1))
    p0 = np.full(2, -20.0)
    for group, expected in (([0, 1], [0, 0]), ([0, 0], None)):
        slot = np.full(2, -2, dtype=np.int64)
        best_joint_hypothesis(info, ll, p0, np.eye(3) * 1e-3, slot,
                              (np.full(2, -1, dtype=np.int64), np.zeros((3, N_PAIR_SLOTS)),
                               np.array(group, dtype=np.int64), np.zeros(3)))
        if expected is not None:
            assert slot.tolist() == expected
        else:
            assert sorted(slot.tolist()) == [-1, 0]


def gappy_stream(seed, start=40.0, length=20.0):
    """Robot 1 of a simulation with its sightings from ``start`` to ``start + length`` seconds removed: a gap."""
    data = simulate_dataset(seed, duration=120.0)
    log = data.robots[1]
    m = log.measurements
    t = m["time"].to_numpy()
    kept = m[(t < t[0] + start) | (t > t[0] + start + length)].reset_index(drop=True)
    return event_stream(dataclasses.replace(log, measurements=kept), data.landmark_subjects)


SIM = AssociationParams(filter=FastSLAMParams(n_particles=20, measurement_cov=R, range_std_slope=0.0), max_range=5.0,
                        fov=1.0, gap_window_sightings=4)


def test_a_run_with_windows_is_reproducible_and_decides_every_held_frame():
    """On a simulated log with a 20 s gap: windows are decided (moves recorded, at the gap's end), the same seed gives
    the same numbers, and every sighting held in a window was given a landmark or left out as any other."""
    stream = gappy_stream(0)
    a = run_unknown(stream, SIM, 3)
    b = run_unknown(stream, SIM, 3)
    np.testing.assert_array_equal(a.history, b.history)
    np.testing.assert_array_equal(a.pose_mean, b.pose_mean)
    np.testing.assert_array_equal(a.gap_moves, b.gap_moves)
    assert len(a.gap_moves) >= SIM.filter.n_particles  # one row per particle and window
    t0 = stream.t[0]
    assert np.all(a.gap_moves[:, 0] - t0 > 60.0 - 1e-9)  # the first frame after the gap
    off = run_unknown(stream, dataclasses.replace(SIM, gap_window_sightings=0), 3)
    assert len(off.gap_moves) == 0
    assigned = np.mean(a.history >= 0)
    assert assigned >= np.mean(off.history >= 0) - 0.05  # holding frames loses no sightings


@pytest.mark.parametrize("kwargs, message", [({"gap_window_sightings": -1}, "gap_window_sightings"),
                                             ({"gap_window_s": 0.0}, "gap_window_s"),
                                             ({"gap_window_sightings": 3,
                                               "filter": FastSLAMParams(proposal="fastslam2")}, "FastSLAM 1.0")])
def test_bad_window_settings_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        AssociationParams(**kwargs)


def test_a_log_that_ends_inside_a_window_decides_it():
    """Sightings stop from 100 s to 117 s of a 120 s log, and a window holds up to 1000 sightings or 10 s: the window
    the last frames open is still open when the log ends, and run_unknown decides it then (a move recorded for every
    particle after 117 s, most of those frames' sightings given landmarks)."""
    stream = gappy_stream(1, start=100.0, length=17.0)
    result = run_unknown(stream, dataclasses.replace(SIM, gap_window_sightings=1000), 5)
    t0 = stream.t[0]
    last = result.gap_moves[result.gap_moves[:, 0] - t0 > 117.0 - 1e-9]
    assert len(last) == SIM.filter.n_particles  # one window, every particle decided it
    step_of = np.repeat(np.arange(len(stream)), np.diff(stream.offsets))
    tail = stream.t[step_of] - t0 > 117.0
    assert tail.any() and np.mean(result.history[tail] >= 0) > 0.5
