"""Simulated runs and event streams made for tests (shared by the test files that need them)."""

from __future__ import annotations

import dataclasses

import numpy as np

from fastslam_edu.datasets.events import event_stream
from fastslam_edu.datasets.log import EventStream
from fastslam_edu.evaluation.metrics import trajectory_errors
from fastslam_edu.datasets.sim import simulate_dataset


def simulate(seed: int, duration: float = 40.0, **overrides):
    """(dataset, robot-1 log, full-rate event stream) of a simulation of ``duration`` seconds."""
    data = simulate_dataset(seed, duration=duration, **overrides)
    log = data.robots[1]
    return data, log, event_stream(log, data.landmark_subjects)


def path_rmse(t, poses, log) -> float:
    """RMSE [m] of the positions ``poses`` (n, 3) at times ``t`` against the log's groundtruth."""
    gt = log.groundtruth
    return trajectory_errors(t, poses, gt["time"].to_numpy(), gt[["x", "y", "theta"]].to_numpy())["rmse"]


def with_repeated_measurements(stream: EventStream, every: int) -> EventStream:
    """Every ``every``-th measurement step gets a second reading of its first landmark (r + 2 cm)."""
    z, lm, offsets, steps_with = [], [], [0], 0
    for k in range(len(stream)):
        zk, lk = (list(a) for a in stream.measurements_at(k))
        if zk:
            if steps_with % every == 0:
                zk.append(zk[0] + [0.02, 0.0])
                lk.append(lk[0])
            steps_with += 1
        z += zk
        lm += lk
        offsets.append(offsets[-1] + len(zk))
    return dataclasses.replace(stream, z=np.array(z, dtype=float).reshape(-1, 2),
                               landmark=np.array(lm, dtype=np.int64), offsets=np.array(offsets, dtype=np.int64))


def with_landmark_moved(stream: EventStream, landmark: int, after: float, extra_range: float) -> EventStream:
    """Sightings of ``landmark`` from time ``after`` [s] on read ``extra_range`` metres further.

    As if the landmark had been moved away from the robot: every later
    sighting disagrees with every particle's map, again and again — the case
    the gate's escape (``gate_escape_s``) is for.
    """
    step = np.repeat(np.arange(len(stream)), np.diff(stream.offsets))
    moved = (stream.landmark == landmark) & (np.asarray(stream.t)[step] >= after)
    z = np.array(stream.z, dtype=float)
    z[moved, 0] += extra_range
    return dataclasses.replace(stream, z=z)
