"""The event stream cut into segments: runs of odometry steps that end at a measurement step.

Step 1 of FastSLAM moves the particles through a whole segment at once; steps 2–4 run at its last step, when it
has sightings. Used by the filter with known correspondences (:mod:`fastslam_edu.landmark.fastslam`) and with
unknown ones (:mod:`fastslam_edu.landmark.association`).
"""

from __future__ import annotations

import numpy as np

from fastslam_edu.datasets.log import EventStream

#: Longest run of odometry steps propagated at once (bounds memory: M × L × 3 floats).
MAX_SEGMENT = 512


def measurement_segments(stream: EventStream, cut_times=()):
    """``(s, e)``: the steps split into runs ending at a measurement step (or MAX_SEGMENT, or a cut time)."""
    n_meas = np.diff(stream.offsets)
    ends = set(np.flatnonzero(n_meas > 0).tolist())
    for tc in cut_times:
        k = int(np.searchsorted(stream.t, tc, side="left"))
        if k < len(stream):
            ends.add(k)  # the step at or just after tc ends a segment
    ends.add(len(stream) - 1)
    start = 0
    for end in sorted(ends):
        while end - start + 1 > MAX_SEGMENT:
            yield start, start + MAX_SEGMENT - 1
            start += MAX_SEGMENT
        if end >= start:
            yield start, end
        start = end + 1


def segment_chunks(segments: np.ndarray, max_steps: int):
    """``(a, b)``: runs ``segments[a:b]`` of whole segments (S, 2) covering at most ``max_steps`` steps each
    (a longer segment alone), in order: what the compiled run does between two calls to the hooks."""
    a = 0
    while a < len(segments):
        b = a + 1
        while b < len(segments) and segments[b, 1] - segments[a, 0] + 1 <= max_steps:
            b += 1
        yield a, b
        a = b


def stream_commands(stream: EventStream, params):
    """The stream's commands times ``params.odometry_scale`` (a :class:`fastslam_edu.landmark.fastslam.FastSLAMParams`),
    and its time steps, checked: ``(u (N, 2), dt (N,))``."""
    u = np.asarray(stream.u, dtype=float) * np.asarray(params.odometry_scale, dtype=float)
    dt = np.asarray(stream.dt, dtype=float)
    if not (np.isfinite(u).all() and np.isfinite(dt).all()) or (dt < 0).any():
        bad = np.flatnonzero(~np.isfinite(u).all(axis=1) | ~np.isfinite(dt) | (dt < 0))
        raise ValueError(f"the event stream has non-finite commands or negative time steps ({len(bad)} step(s), "
                         f"the first at step {bad[0]}, t = {stream.t[bad[0]]!r})")
    return u, dt


__all__ = ["MAX_SEGMENT", "measurement_segments", "segment_chunks", "stream_commands"]
