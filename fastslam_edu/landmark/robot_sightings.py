"""The robot-robot sightings as factors: each robot's pose at the sighting's instant and the tempering weights.

At time :math:`t_s` robot :math:`a` measures range and bearing :math:`z_s` to the centre of robot :math:`b`. A
sighting time is rarely a keyframe of both robots, so each robot's pose at :math:`t_s` is its last keyframe
composed with the dead-reckoned motion from it, :math:`x_k \\oplus \\delta` (:func:`keyframe_offsets`); the
residual's Jacobian with respect to the keyframe goes through :func:`compose_jacobian`. Used by
:func:`fastslam_edu.landmark.multi_robot.smooth_robots` and its GTSAM twin
(:func:`fastslam_edu.landmark.smoother_gtsam.robots_factor_graph`).
"""

from __future__ import annotations

import numpy as np

from fastslam_edu.core.se2 import relative
from fastslam_edu.datasets.log import EventStream
from fastslam_edu.landmark.evidence import tempering_exponents


def compose_jacobian(x: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """:math:`\\partial (x \\oplus \\delta) / \\partial x`, shape (n, 3, 3), for poses ``x`` (n, 3) and motions
    ``delta`` (n, 3) in the frame of ``x``: the translation :math:`R(\\theta)\\delta_{xy}` swings with
    :math:`\\theta`, so column 3 is :math:`(-(R\\delta)_y, (R\\delta)_x, 1)`."""
    c, s = np.cos(x[:, 2]), np.sin(x[:, 2])
    J = np.broadcast_to(np.eye(3), (len(x), 3, 3)).copy()
    J[:, 0, 2] = -(s * delta[:, 0] + c * delta[:, 1])
    J[:, 1, 2] = c * delta[:, 0] - s * delta[:, 1]
    return J


def compose_unwrapped(x: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """:math:`x \\oplus \\delta`: ``(x + R(θ) δ_xy, θ + δ_θ)``, shapes (n, 3); θ not wrapped (as the
    residuals' Jacobians assume; :func:`fastslam_edu.core.se2.compose` wraps it)."""
    c, s = np.cos(x[:, 2]), np.sin(x[:, 2])
    return np.stack([x[:, 0] + c * delta[:, 0] - s * delta[:, 1], x[:, 1] + s * delta[:, 0] + c * delta[:, 1],
                     x[:, 2] + delta[:, 2]], axis=1)


def keyframe_offsets(stream: EventStream, path: np.ndarray, keys: np.ndarray, t: np.ndarray):
    """For times ``t`` (n,) inside the stream's span: the keyframe at or before each (index into ``keys``, (n,))
    and the dead-reckoned motion :math:`\\delta` from it to ``t`` in its frame, (n, 3).

    ``path`` (len(stream), 3) is the dead-reckoned pose at every step; between steps it is interpolated linearly
    (steps are 15 ms apart at MR.CLAM's full rate).
    """
    st = np.asarray(stream.t, dtype=float)
    j = np.clip(np.searchsorted(st, t, side="right") - 1, 0, len(st) - 1)
    nxt = np.minimum(j + 1, len(st) - 1)
    span = st[nxt] - st[j]
    w = np.where(span > 0, (t - st[j]) / np.where(span > 0, span, 1.0), 0.0)[:, None]
    pose_t = (1 - w) * path[j] + w * path[nxt]
    k = np.searchsorted(keys, j, side="right") - 1
    return k, relative(path[keys[k]], pose_t)


def robot_sighting_table(robot_sightings: dict, streams: dict):
    """The robot-robot sightings between the robots of ``streams``, as arrays, and how many are left out.

    ``robot_sightings``: robot → DataFrame ``time, subject, range, bearing`` (its sightings of other robots,
    :func:`fastslam_edu.datasets.mrclam.robot_sightings`). Kept: sightings of a robot being solved, at a time inside
    both robots' streams. Returns ``(observer (n,), seen (n,), t (n,), z (n, 2), skipped)``, in time order per observer.
    """
    robots = list(streams)
    unknown = sorted(set(robot_sightings) - set(robots))
    if unknown:
        raise ValueError(f"robot sightings given for robot(s) {unknown}, which are not among the robots solved {robots}")
    parts, skipped = [], 0
    for a in robots:
        df = robot_sightings.get(a)
        if df is None or len(df) == 0:
            continue
        missing = [c for c in ("time", "subject", "range", "bearing") if c not in df.columns]
        if missing:
            raise ValueError(f"robot {a} sightings of robots: missing column(s) {missing}")
        t = df["time"].to_numpy(dtype=float)
        b = df["subject"].to_numpy(dtype=np.int64)
        z = df[["range", "bearing"]].to_numpy(dtype=float)
        if not (np.isfinite(t).all() and np.isfinite(z).all()):
            row = int(np.flatnonzero(~(np.isfinite(t) & np.isfinite(z).all(axis=1)))[0])
            raise ValueError(f"robot {a} sightings of robots, row {row}: NaN or inf in time {t[row]!r}, z {z[row].tolist()}")
        if np.any(b == a):
            row = int(np.flatnonzero(b == a)[0])
            raise ValueError(f"robot {a} sightings of robots, row {row}: robot {a} sees itself")
        keep = np.isin(b, robots)
        inside = np.zeros(len(t), dtype=bool)
        for other in np.unique(b[keep]):
            sa, sb = streams[a], streams[int(other)]
            lo, hi = max(sa.t[0], sb.t[0]), min(sa.t[-1], sb.t[-1])
            inside |= (b == other) & (t >= lo) & (t <= hi)
        skipped += int(np.sum(~inside))
        parts.append((np.full(int(inside.sum()), a), b[inside], t[inside], z[inside]))
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 2)), skipped
    return (*(np.concatenate([p[i] for p in parts]) for i in range(4)), skipped)


def robot_sighting_weights(observer, seen, t, tau: float | None) -> np.ndarray:
    """Tempering :math:`\\beta_s` of the robot-robot sightings: per observer, each robot seen counts as a landmark
    (:func:`~fastslam_edu.landmark.evidence.tempering_exponents`); ``tau`` None: all 1."""
    beta = np.ones(len(t))
    if tau is None:
        return beta
    for a in np.unique(observer):
        rows = np.flatnonzero(observer == a)
        last_seen = np.full(int(np.max(seen)) + 1, -np.inf)  # indexed by robot number
        times, starts = np.unique(t[rows], return_index=True)
        ends = np.append(starts[1:], len(rows))
        for ti, s, e in zip(times, starts, ends):
            idx = rows[s:e]
            beta[idx] = tempering_exponents(ti, seen[idx], last_seen, tau)
    return beta


__all__ = ["compose_jacobian", "compose_unwrapped", "keyframe_offsets", "robot_sighting_table",
           "robot_sighting_weights"]
