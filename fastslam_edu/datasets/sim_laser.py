"""A simulated laser world: a 2D floor plan seen by a planar laser scanner, with known truth.

Grid SLAM (:mod:`fastslam_edu.grid.gridslam`) is tested against it without real data. The robot drives a route
through a small office (:func:`floor_plan`), the scanner's ranges are exact ray casts (:func:`ray_cast`) plus
``N(0, range_std²)``, and the odometry is the true path with noise (:func:`noisy_odometry`).
:func:`simulate_laser_world` returns the log as :class:`~fastslam_edu.datasets.laser.LaserLog` with the truth.
The landmark world is :mod:`fastslam_edu.datasets.sim`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.params import Params
from fastslam_edu.datasets.laser import LaserLog
from fastslam_edu.datasets.sim import generator_from_seed

__all__ = ["LaserWorld", "LaserSimSettings", "floor_plan", "ray_cast", "drive_route", "noisy_odometry",
           "simulate_laser_world"]


@dataclass(frozen=True)
class LaserWorld:
    """A simulated laser log with its truth (returned by :func:`simulate_laser_world`).

    Attributes
    ----------
    log : fastslam_edu.datasets.laser.LaserLog
        What a robot would record: scan times ``t`` [s], ``ranges`` (N, B) [m]
        (NaN = no return), beam ``angles`` (B,) [rad], and the **odometry**
        pose of each scan in both ``poses`` and ``odometry`` (like
        ``intel_gfs.json``), so ``odometry_increments(log)`` gives the noisy
        increments.
    truth : ndarray, shape (N, 3)
        True pose ``(x, y, θ)`` of each scan [m, m, rad].
    walls : ndarray, shape (S, 2, 2)
        Wall segments ``[[x_a, y_a], [x_b, y_b]]`` [m].
    """

    log: object
    truth: np.ndarray
    walls: np.ndarray


def floor_plan(width: float = 16.0, height: float = 10.0, door: float = 1.2) -> np.ndarray:
    """Wall segments of a small office: an outer rectangle, a corridor and four rooms.

    The rectangle ``[0, width] × [0, height]`` is split by two horizontal walls
    at ``y = 0.4 h`` and ``y = 0.6 h`` into a lower row of rooms, a corridor
    and an upper row of rooms; a vertical wall at ``x = w/2`` splits each row
    into two rooms. Every room opens onto the corridor through a door gap of
    width ``door`` [m], and one box-shaped pillar stands in each room, so that
    scans are not all made of long straight walls.

    Returns
    -------
    ndarray, shape (S, 2, 2)
        Segments ``[[x_a, y_a], [x_b, y_b]]`` [m].
    """
    w, h, d = float(width), float(height), float(door)
    if not (w > 4 * d and h > 4 * d and d > 0):
        raise ValueError(f"floor_plan: need width, height > 4·door > 0, got {width}, {height}, {door}")
    y1, y2, xm = 0.4 * h, 0.6 * h, 0.5 * w
    segs = [
        ((0, 0), (w, 0)), ((w, 0), (w, h)), ((w, h), (0, h)), ((0, h), (0, 0)),  # outer walls
        ((xm, 0), (xm, y1)), ((xm, y2), (xm, h)),  # walls between rooms
    ]
    for y in (y1, y2):  # corridor walls, with a door into each room (centred in the room)
        for x0, x1 in ((0.0, xm), (xm, w)):
            c = 0.5 * (x0 + x1)
            segs += [((x0, y), (c - d / 2, y)), ((c + d / 2, y), (x1, y))]
    boxes = []
    for cx, cy in ((0.25 * w, 0.2 * h), (0.75 * w, 0.2 * h), (0.25 * w, 0.8 * h), (0.75 * w, 0.8 * h)):
        # pillars 0.5 m × 0.5 m, off-centre so that rooms are not symmetric
        boxes.append((cx + 0.6, cy - 0.3 if cy < h / 2 else cy + 0.3, 0.25, 0.25))
    for fx, below in ((0.14, True), (0.37, False), (0.6, True), (0.9, False)):
        # cabinets against the corridor walls: without them a corridor looks the same all along
        boxes.append((fx * w, y1 + 0.2 if below else y2 - 0.2, 0.3, 0.2))
    for cx, cy, sx, sy in boxes:
        corners = [(cx - sx, cy - sy), (cx + sx, cy - sy), (cx + sx, cy + sy), (cx - sx, cy + sy)]
        segs += [(corners[i], corners[(i + 1) % 4]) for i in range(4)]
    return np.array(segs, dtype=float)


def ray_cast(pose, angles, walls, max_range: float) -> np.ndarray:
    """Exact ranges of beams from ``pose`` to the nearest wall (NaN if none within ``max_range``).

    Beam ``b`` leaves the sensor at ``p = (x, y)`` in direction
    ``d_b = (cos(θ + α_b), sin(θ + α_b))``; wall ``s`` is ``a_s + u (e_s − a_s)``,
    ``u ∈ [0, 1]``. Solving ``p + r d_b = a_s + u (e_s − a_s)`` by Cramer's rule
    for all beams × walls at once gives ``r`` and ``u``; the range is the
    smallest ``r > 0`` with ``0 ≤ u ≤ 1``.

    Parameters
    ----------
    pose : array_like, shape (3,)
    angles : array_like, shape (B,)
        Beam angles in the sensor frame [rad].
    walls : array_like, shape (S, 2, 2)
    max_range : float
        [m].

    Returns
    -------
    ndarray, shape (B,)
        Ranges [m], NaN where the nearest wall is farther than ``max_range``.
    """
    x, y, th = (float(v) for v in np.asarray(pose, dtype=float))
    phi = th + np.asarray(angles, dtype=float)
    d = np.stack([np.cos(phi), np.sin(phi)], axis=-1)[:, None, :]  # (B, 1, 2)
    a = walls[None, :, 0, :]  # (1, S, 2)
    e = walls[None, :, 1, :] - a  # wall direction (1, S, 2)
    w = a - np.array([x, y])  # from the sensor to the wall start
    # p + r d = a + u e  <=>  r d − u e = w ; det = d × (−e) = −(d_x e_y − d_y e_x)
    det = -(d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0])  # (B, S)
    ok = np.abs(det) > 1e-12
    safe = np.where(ok, det, 1.0)
    r = (w[..., 0] * -e[..., 1] - w[..., 1] * -e[..., 0]) / safe
    u = (d[..., 0] * w[..., 1] - d[..., 1] * w[..., 0]) / safe
    hit = ok & (r > 1e-9) & (u >= 0.0) & (u <= 1.0)
    r = np.where(hit, r, np.inf).min(axis=1)
    return np.where(r <= max_range, r, np.nan)


def _loop_waypoints(width: float, height: float) -> np.ndarray:
    """A route through the corridor and into each room (through its door) and back."""
    w, h = width, height
    yc = 0.5 * h  # corridor centre line
    route = [(1.0, yc)]
    for cx, down in ((0.25 * w, True), (0.75 * w, True), (0.75 * w, False), (0.25 * w, False)):
        ry = 0.2 * h if down else 0.8 * h
        route += [(cx, yc), (cx, ry), (cx - 1.5, ry), (cx, ry), (cx, yc)]
    route.append((1.0, yc))
    return np.array(route, dtype=float)


@dataclass(frozen=True, eq=False)
class LaserSimSettings(Params):
    """The simulated office, laser, route and odometry of :func:`simulate_laser_world`.

    ``width, height`` floor size [m]; ``n_beams`` beams spread evenly over
    ``[−fov/2, fov/2]`` [rad] (181 over 180°); ``max_range``, ``range_std`` [m];
    ``step`` [m] and ``turn_step`` [rad]: scan spacing on straight legs and in
    turns; ``laps``: times the route is driven; ``trans_noise, rot_noise,
    rot_per_metre, rot_bias``: odometry noise [m/m, rad/rad, rad/m, rad/m]
    (:func:`noisy_odometry`).
    """

    width: float = 16.0
    height: float = 10.0
    n_beams: int = 181
    fov: float = math.pi
    max_range: float = 12.0
    range_std: float = 0.01
    step: float = 0.4
    turn_step: float = 0.35
    laps: int = 1
    trans_noise: float = 0.05
    rot_noise: float = 0.03
    rot_per_metre: float = 0.02
    rot_bias: float = 0.01

    def __post_init__(self):
        for name in ("step", "turn_step", "max_range"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"simulate_laser_world: {name} must be > 0, got {v}")
        if int(self.laps) < 1 or int(self.n_beams) < 2:
            raise ValueError(f"simulate_laser_world: need laps ≥ 1 and n_beams ≥ 2, got {self.laps}, {self.n_beams}")


def drive_route(route, step: float, turn_step: float) -> np.ndarray:
    """Poses (N, 3) along ``route`` (W, 2): turn in place at each waypoint, then drive the leg straight.

    A pose every ``turn_step`` radians while turning and every ``step`` metres on
    a leg, so that consecutive poses differ by a translation *or* a turn, like
    GMapping's processed scans.
    """
    poses = []
    heading = math.atan2(route[1, 1] - route[0, 1], route[1, 0] - route[0, 0])
    for a, b in zip(route[:-1], route[1:]):
        leg = b - a
        length = float(np.hypot(*leg))
        if length < 1e-9:
            continue
        target = math.atan2(leg[1], leg[0])
        turn = float(wrap_angle(target - heading))
        n_turn = int(math.ceil(abs(turn) / turn_step))
        for i in range(1, n_turn + 1):  # turn in place at a
            poses.append((a[0], a[1], float(wrap_angle(heading + turn * i / n_turn))))
        heading = target
        n = max(1, int(math.ceil(length / step)))
        for i in range(0 if not poses else 1, n + 1):
            p = a + leg * i / n
            poses.append((p[0], p[1], heading))
    return np.array(poses)


def noisy_odometry(truth, settings: LaserSimSettings, rng: np.random.Generator) -> np.ndarray:
    """Odometry poses (N, 3) from the true poses, with noise that grows with the increment.

    With the true increment ``u_k = x_{k−1}⁻¹ ⊕ x_k`` (``d_k = ‖(Δx, Δy)‖``), the
    recorded increment is::

        û_k = u_k + (σ_t ε₁, σ_t ε₂, σ_θ ε₃ + b d_k),
        σ_t = trans_noise · d_k,  σ_θ = rot_noise · |Δθ_k| + rot_per_metre · d_k,

    with ``ε ~ N(0, I)`` and a systematic heading drift ``b = rot_bias`` [rad/m]
    (real odometry drifts one way); the odometry poses are
    ``o_k = o_{k−1} ⊕ û_k`` from ``o_0 = x_0``.
    """
    from fastslam_edu.core.se2 import compose_increments, path_increments

    u = path_increments(truth)
    d = np.hypot(u[:, 0], u[:, 1])
    eps = rng.standard_normal(u.shape)
    u_hat = u + np.column_stack([
        settings.trans_noise * d * eps[:, 0],
        settings.trans_noise * d * eps[:, 1],
        (settings.rot_noise * np.abs(u[:, 2]) + settings.rot_per_metre * d) * eps[:, 2] + settings.rot_bias * d,
    ])
    return compose_increments(truth[0], u_hat)


def simulate_laser_world(seed_or_rng: int | np.random.Generator, settings: LaserSimSettings | None = None,
                         **changes) -> LaserWorld:
    """Simulate a robot with a planar laser driving around a small office (known truth).

    World: :func:`floor_plan` (outer walls, corridor, four rooms with doors and
    pillars). True path: the route of :func:`_loop_waypoints` driven ``laps``
    times (:func:`drive_route`). Ranges: exact ray casting (:func:`ray_cast`)
    plus ``N(0, range_std²)``. Odometry: :func:`noisy_odometry`.

    Parameters
    ----------
    seed_or_rng : int or numpy.random.Generator
        Same seed → same world, path and noise.
    settings : LaserSimSettings, optional
        Default ``LaserSimSettings()``.
    **changes
        Settings to change, by name (``simulate_laser_world(0, laps=2)``).

    Returns
    -------
    LaserWorld
        ``log`` (a :class:`~fastslam_edu.datasets.laser.LaserLog`, scans 1 s
        apart), ``truth`` (N, 3), ``walls`` (S, 2, 2).
    """
    rng = generator_from_seed(seed_or_rng, "simulate_laser_world")
    s = (LaserSimSettings() if settings is None else settings).replace(**changes)
    walls = floor_plan(s.width, s.height)
    waypoints = _loop_waypoints(s.width, s.height)
    truth = drive_route(np.concatenate([waypoints[:-1]] * int(s.laps) + [waypoints[-1:]]), s.step, s.turn_step)
    angles = np.linspace(-s.fov / 2, s.fov / 2, int(s.n_beams))
    ranges = np.array([ray_cast(p, angles, walls, s.max_range) for p in truth])
    ranges = ranges + s.range_std * rng.standard_normal(ranges.shape)
    odo = noisy_odometry(truth, s, rng)
    log = LaserLog(
        t=np.arange(len(truth), dtype=float), ranges=ranges, angles=angles, poses=odo, odometry=odo.copy(),
        source="simulate_laser_world", max_range=float(s.max_range),
    )
    return LaserWorld(log=log, truth=truth, walls=walls)
