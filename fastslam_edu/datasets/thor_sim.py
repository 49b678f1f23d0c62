"""A simulated THOR sequence: the humanoid walks through rooms, its head moved by the real joint log.

The THOR LiDAR logs are not public any more (see the THOR README); the joint
log of training sequence 0 is. This module builds the missing half: a LiDAR
sequence of the same shape, with known truth, whose head motion is the real one.

What is simulated
-----------------
* **World.** A :class:`~fastslam_edu.datasets.floor_plan.FloorPlan`: vertical walls of height ``H`` (2.5 m)
  standing on 2D segments, and the floor ``z = 0``. The default
  (:func:`~fastslam_edu.datasets.floor_plan.default_floor_plan`) is four rooms joined by 1 m doors, with a pillar
  and a cabinet, 20 m × 12 m.
* **Walk.** The body follows a polyline of waypoints (:func:`walking_path`):
  it turns in place at each waypoint (rate ``turn_rate``), then walks straight
  at the constant speed that makes the tour last the whole sequence. It stands
  still while the head pitch exceeds ``stop_above_pitch`` (15°): THOR stops to
  look at the floor. The world frame is the body's start frame: the first
  pose is ``(0, 0, 0)``.
* **Head.** Scans are taken at ``scan_rate`` (40 Hz) on the joint log's clock;
  each takes the neck yaw and head pitch of the joint sample nearest in time
  (:func:`fastslam_edu.datasets.thor_geometry.joints_at`), exactly what a reader of the real
  logs does.
* **LiDAR.** 1081 beams, −135° … +135° in 0.25° steps, from the LiDAR origin
  ``T_WL (0, 0, 0)`` at 1.41 m along ``d_b = T_WL α_b``
  (:func:`fastslam_edu.datasets.thor_geometry.beam_directions_world`). Each beam returns the
  nearer of its wall hit and its floor hit (:func:`~fastslam_edu.datasets.floor_plan.cast_rays`), plus Gaussian
  noise ``N(0, range_std²)``; beyond 30 m or over the walls (no ceiling)
  it returns nothing, written as ``no_return`` (0 m, below the 0.1 m minimum).
* **Odometry** with drift (:func:`drifting_odometry`): each true increment
  ``u_k = x_{k−1}⁻¹ ⊕ x_k`` is scaled by ``1 + odom_scale``, its yaw gets a
  bias ``odom_yaw_drift`` per metre walked, and white noise whose variance
  grows with the motion; dead reckoning of these increments is the odometry
  pose (variant 1's ``pose``), whose world-frame differences are variant 2's
  ``delta_pose``.

:func:`write_sequence` writes it with
:func:`fastslam_edu.datasets.thor_lidar.write_thor_lidar` in either THOR variant, so
that :func:`fastslam_edu.datasets.thor_lidar.read_thor_lidar` reads it back like a
real file. All randomness comes from one ``numpy.random.Generator``: the
odometry noise is drawn first, then the range noise scan by scan, so the same
seed gives the same sequence.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.datasets.floor_plan import (  # noqa: F401 (the world, re-exported for chapter 18)
    DEFAULT_WAYPOINTS, FLOOR, NO_HIT, WALL, FloorPlan, cast_rays, default_floor_plan)
from fastslam_edu.datasets.thor_lidar import read_thor_joints, thor_angles, write_thor_lidar
from fastslam_edu.core.se2 import compose_increments, path_increments
from fastslam_edu.datasets.thor_geometry import MAX_RANGE, beam_directions_world, nearest_sample

__all__ = [
    "NO_HIT",
    "WALL",
    "FLOOR",
    "FloorPlan",
    "default_floor_plan",
    "DEFAULT_WAYPOINTS",
    "ThorSimConfig",
    "ThorSequence",
    "walking_path",
    "drifting_odometry",
    "cast_rays",
    "scan_times",
    "simulate_thor",
    "write_sequence",
    "real_thor_joints",
]

#: Scans ray-cast at once (bounds the memory: CHUNK × 1081 beams × walls).
CHUNK = 64


# --------------------------------------------------------------------------- settings and result


@dataclass(frozen=True)
class ThorSimConfig:
    """Settings of :func:`simulate_thor` (units: m, rad, s, Hz).

    Attributes
    ----------
    scan_rate : float
        LiDAR scan rate [Hz] (Hokuyo UTM-30LX: 40).
    t_start : float
        Start of the simulated window, seconds after the joint log's first sample.
    duration : float or None
        Length of the window [s]; None: to the end of the joint log.
    n_beams : int
        Beams per scan (1081: −135° … +135°, 0.25°).
    range_std : float
        Standard deviation of the Gaussian range noise [m].
    max_range : float
        Longer returns are "no return" [m].
    no_return : float
        Range written for "no return" (0: below the valid 0.1 m, like the Hokuyo's error codes).
    turn_rate : float
        Turning-in-place rate at the waypoints [rad/s].
    stop_above_pitch : float or None
        The body stands still while the head pitch exceeds this [rad] (THOR
        stops to look at the floor); None: it never stops.
    odom_scale : float
        Systematic relative error of the odometry increments (0.03: 3 % too long).
    odom_yaw_drift : float
        Systematic yaw error [rad per metre walked].
    odom_trans_noise : float
        Translation noise density [m/√m]: each increment's x and y get
        ``N(0, odom_trans_noise² · d_k)``, ``d_k`` its length.
    odom_rot_noise : float
        Rotation noise density [rad/√rad]: the yaw increment gets
        ``N(0, odom_rot_noise² · |Δθ_k|)``.
    """

    scan_rate: float = 40.0
    t_start: float = 0.0
    duration: float | None = None
    n_beams: int = 1081
    range_std: float = 0.01
    max_range: float = MAX_RANGE
    no_return: float = 0.0
    turn_rate: float = 0.5
    stop_above_pitch: float | None = math.radians(15.0)
    odom_scale: float = 0.03
    odom_yaw_drift: float = 0.01
    odom_trans_noise: float = 0.01
    odom_rot_noise: float = 0.02

    def __post_init__(self) -> None:
        positive = {"scan_rate": self.scan_rate, "max_range": self.max_range, "turn_rate": self.turn_rate}
        for name, v in positive.items():
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"ThorSimConfig: {name} must be positive, got {v}")
        nonneg = {
            "t_start": self.t_start, "range_std": self.range_std, "odom_trans_noise": self.odom_trans_noise,
            "odom_rot_noise": self.odom_rot_noise,
        }
        for name, v in nonneg.items():
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"ThorSimConfig: {name} must be ≥ 0, got {v}")
        for name, v in {"odom_scale": self.odom_scale, "odom_yaw_drift": self.odom_yaw_drift,
                        "no_return": self.no_return}.items():
            if not math.isfinite(v):
                raise ValueError(f"ThorSimConfig: {name} must be finite, got {v}")
        if self.stop_above_pitch is not None and not math.isfinite(self.stop_above_pitch):
            raise ValueError(f"ThorSimConfig: stop_above_pitch must be finite or None, got {self.stop_above_pitch}")
        if self.duration is not None and not (math.isfinite(self.duration) and self.duration > 0):
            raise ValueError(f"ThorSimConfig: duration must be positive or None, got {self.duration}")
        if int(self.n_beams) != self.n_beams or self.n_beams < 1:
            raise ValueError(f"ThorSimConfig: n_beams must be a positive integer, got {self.n_beams}")


@dataclass
class ThorSequence:
    """A simulated THOR sequence with its truth.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Scan times [s], on the joint log's clock (Unix time for the real log).
    angles : ndarray, shape (B,)
        Beam angles [rad].
    ranges : ndarray, shape (N, B)
        Measured ranges [m] as written to the file (``no_return`` where nothing was hit).
    kind : ndarray of int8, shape (N, B)
        What each beam hit: :data:`NO_HIT`, :data:`WALL` or :data:`FLOOR`.
    true_range : ndarray, shape (N, B)
        Noise-free range to the hit [m] (``inf`` where :attr:`kind` is :data:`NO_HIT`).
    true_pose : ndarray, shape (N, 3)
        Body pose ``(x, y, θ)`` [m, m, rad] at each scan.
    odom_pose : ndarray, shape (N, 3)
        Drifting odometry pose (variant 1's ``pose``); ``odom_pose[0] = true_pose[0]``.
    delta_pose : ndarray, shape (N, 3)
        World-frame differences of ``odom_pose`` (variant 2's ``delta_pose``):
        row 0 is ``odom_pose[0]``, so their running sum is ``odom_pose``.
    neck, head : ndarray, shape (N,)
        Neck yaw and head pitch at each scan [rad] (nearest joint sample).
    joint_index : ndarray of int64, shape (N,)
        Index of that joint sample in the joint log.
    plan : FloorPlan
    config : ThorSimConfig
    """

    t: np.ndarray
    angles: np.ndarray
    ranges: np.ndarray
    kind: np.ndarray
    true_range: np.ndarray
    true_pose: np.ndarray
    odom_pose: np.ndarray
    delta_pose: np.ndarray
    neck: np.ndarray
    head: np.ndarray
    joint_index: np.ndarray
    plan: FloorPlan
    config: ThorSimConfig = field(default_factory=ThorSimConfig)

    def __len__(self) -> int:
        return len(self.t)

    def counts(self) -> dict[str, int]:
        """Number of beams per :attr:`kind`: ``{"wall": …, "floor": …, "none": …}``."""
        return {
            "wall": int((self.kind == WALL).sum()),
            "floor": int((self.kind == FLOOR).sum()),
            "none": int((self.kind == NO_HIT).sum()),
        }


# --------------------------------------------------------------------------- motion


def walking_path(waypoints, t, *, turn_rate: float = 0.5, moving=None) -> np.ndarray:
    """Body poses along a polyline: turn in place at each waypoint, then walk straight.

    The body starts at ``waypoints[0]`` facing ``waypoints[1]``; at waypoint
    ``i`` it turns by ``wrap(ψ_i − ψ_{i−1})`` at ``turn_rate``, ``ψ_i`` the
    heading of segment ``i``, then walks the segment. Its clock ``τ`` runs only
    while it moves: ``τ_k = Σ_{j ≤ k, moving_j} (t_j − t_{j−1})``. It walks at the
    constant speed ``v = L / (τ_N − Σ_i |Δψ_i| / turn_rate)`` that ends the tour
    at the last scan (``L`` the polyline's length). Between the knots (turned,
    walked) ``x``, ``y`` and the unwrapped yaw are linear in ``τ``.

    Parameters
    ----------
    waypoints : array_like, shape (n, 2)
        ``n ≥ 2`` points [m]; consecutive points distinct.
    t : array_like, shape (N,)
        Increasing times [s].
    turn_rate : float
        [rad/s].
    moving : array_like of bool, shape (N,), optional
        False where the body stands still (between scan ``k − 1`` and ``k``);
        default: always moving.

    Returns
    -------
    ndarray, shape (N, 3)
        ``(x, y, θ)``, ``θ`` wrapped to (−π, π].
    """
    w = np.asarray(waypoints, dtype=float)
    t = np.asarray(t, dtype=float)
    if w.ndim != 2 or w.shape[1] != 2 or len(w) < 2 or not np.isfinite(w).all():
        raise ValueError(f"walking_path: waypoints must be finite (n, 2) with n ≥ 2, got shape {w.shape}")
    if t.ndim != 1 or t.size < 2 or not np.isfinite(t).all() or (np.diff(t) <= 0).any():
        raise ValueError("walking_path: t must be finite, increasing, with at least 2 times")
    if not (math.isfinite(turn_rate) and turn_rate > 0):
        raise ValueError(f"walking_path: turn_rate must be positive, got {turn_rate}")
    moving = np.ones(t.shape, dtype=bool) if moving is None else np.asarray(moving, dtype=bool)
    if moving.shape != t.shape:
        raise ValueError(f"walking_path: moving must have shape {t.shape}, got {moving.shape}")
    seg = np.diff(w, axis=0)
    length = np.hypot(seg[:, 0], seg[:, 1])
    if (length == 0).any():
        raise ValueError(f"walking_path: waypoints {int(np.argmax(length == 0))} and the next coincide")
    heading = np.arctan2(seg[:, 1], seg[:, 0])
    turn = np.concatenate([[0.0], wrap_angle(np.diff(heading))])  # turn before segment i
    yaw = heading[0] + np.cumsum(turn)  # unwrapped heading of each segment
    turn_time = np.abs(turn) / turn_rate
    tau = np.concatenate([[0.0], np.cumsum(np.diff(t) * moving[1:])])  # the body's clock
    walk_time = tau[-1] - turn_time.sum()
    if walk_time <= 0:
        raise ValueError(
            f"walking_path: {tau[-1]:.1f} s of motion is too short for the turns "
            f"({turn_time.sum():.1f} s at {turn_rate} rad/s)"
        )
    speed = length.sum() / walk_time
    # knots: the start, then per segment "turned at its start" and "walked to its end"
    kt, kx, ky, kyaw = [0.0], [w[0, 0]], [w[0, 1]], [yaw[0]]
    for i in range(len(seg)):  # one iteration per waypoint (a handful), not per scan
        kt.append(kt[-1] + turn_time[i])
        kx.append(w[i, 0]), ky.append(w[i, 1]), kyaw.append(yaw[i])
        kt.append(kt[-1] + length[i] / speed)
        kx.append(w[i + 1, 0]), ky.append(w[i + 1, 1]), kyaw.append(yaw[i])
    kt = np.array(kt)
    kt[-1] = max(kt[-1], tau[-1])  # rounding
    x, y, th = (np.interp(tau, kt, np.array(v)) for v in (kx, ky, kyaw))
    return np.column_stack([x, y, wrap_angle(th)])


def drifting_odometry(true_pose, rng: np.random.Generator, config: ThorSimConfig | None = None) -> np.ndarray:
    """Dead reckoning from corrupted increments: odometry that drifts.

    With ``u_k = (Δx, Δy, Δθ) = x_{k−1}⁻¹ ⊕ x_k`` (robot frame) and
    ``d_k = ‖(Δx, Δy)‖``::

        Δx̂ = (1 + s) Δx + N(0, σ_t² d_k),   Δŷ = (1 + s) Δy + N(0, σ_t² d_k),
        Δθ̂ = Δθ + β d_k + N(0, σ_r² |Δθ|),

    ``s = odom_scale``, ``β = odom_yaw_drift``, ``σ_t = odom_trans_noise``,
    ``σ_r = odom_rot_noise``; ``x̂_0 = x_0`` and ``x̂_k = x̂_{k−1} ⊕ û_k``.
    The variances grow with the motion, so the noise does not depend on the
    scan rate, and a body standing still has exact odometry.

    Parameters
    ----------
    true_pose : array_like, shape (N, 3)
    rng : numpy.random.Generator
        Draws ``3 (N − 1)`` standard normals.
    config : ThorSimConfig, optional

    Returns
    -------
    ndarray, shape (N, 3)
    """
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"drifting_odometry: rng must be a numpy.random.Generator, got {type(rng).__name__}")
    cfg = ThorSimConfig() if config is None else config
    x = np.asarray(true_pose, dtype=float)
    if x.ndim != 2 or x.shape[1] != 3 or len(x) < 1 or not np.isfinite(x).all():
        raise ValueError(f"drifting_odometry: true_pose must be finite (N, 3), got shape {x.shape}")
    if len(x) == 1:
        return x.copy()
    u = path_increments(x)
    d = np.hypot(u[:, 0], u[:, 1])
    eps = rng.standard_normal((len(u), 3))
    noisy = np.empty_like(u)
    noisy[:, :2] = (1 + cfg.odom_scale) * u[:, :2] + cfg.odom_trans_noise * np.sqrt(d)[:, None] * eps[:, :2]
    noisy[:, 2] = u[:, 2] + cfg.odom_yaw_drift * d + cfg.odom_rot_noise * np.sqrt(np.abs(u[:, 2])) * eps[:, 2]
    return compose_increments(x[0], noisy)


# --------------------------------------------------------------------------- the sequence


def _joint_arrays(t_joints, neck, head) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    arrays = []
    for name, a in (("t_joints", t_joints), ("neck", neck), ("head", head)):
        a = np.asarray(a, dtype=float)
        if a.ndim != 1 or a.size < 2:
            raise ValueError(f"simulate_thor: {name} must be a 1-D array of at least 2 samples, got shape {a.shape}")
        if not np.isfinite(a).all():
            k = int(np.argmax(~np.isfinite(a)))
            raise ValueError(f"simulate_thor: {name}[{k}] = {a[k]} is not finite")
        arrays.append(a)
    t, n, h = arrays
    if not (t.shape == n.shape == h.shape):
        raise ValueError(f"simulate_thor: t_joints, neck, head must have equal lengths, got {t.size}, {n.size}, {h.size}")
    if (np.diff(t) <= 0).any():
        k = int(np.argmax(np.diff(t) <= 0))
        raise ValueError(f"simulate_thor: joint times must increase; t_joints[{k + 1}] = {t[k + 1]} ≤ t_joints[{k}] = {t[k]}")
    return t, n, h


def scan_times(t_joints, config: ThorSimConfig) -> np.ndarray:
    """Scan times ``t_0 + k / scan_rate`` inside the window of the joint log.

    ``t_0 = t_joints[0] + t_start``; the window ends ``duration`` seconds later
    (or at the joint log's end).
    """
    t0 = t_joints[0] + config.t_start
    end = t_joints[-1] if config.duration is None else t0 + config.duration
    if end > t_joints[-1] + 1e-9 or t0 >= t_joints[-1]:
        raise ValueError(
            f"simulate_thor: window [{config.t_start}, {config.t_start + (end - t0):.3f}] s is outside the joint log "
            f"(0 … {t_joints[-1] - t_joints[0]:.3f} s)"
        )
    n = int(math.floor((end - t0) * config.scan_rate + 1e-9)) + 1
    if n < 2:
        raise ValueError("simulate_thor: the window holds fewer than 2 scans")
    return t0 + np.arange(n) / config.scan_rate


def simulate_thor(
    t_joints,
    neck,
    head,
    rng: np.random.Generator,
    config: ThorSimConfig | None = None,
    *,
    plan: FloorPlan | None = None,
    waypoints=None,
) -> ThorSequence:
    """Simulate a THOR LiDAR sequence whose head follows a joint log.

    Parameters
    ----------
    t_joints, neck, head : array_like, shape (n,)
        The joint log: times [s] (increasing), neck yaw and head pitch [rad] —
        the real one from :func:`real_thor_joints`, or any arrays (tests).
    rng : numpy.random.Generator
    config : ThorSimConfig, optional
    plan : FloorPlan, optional
        Default :func:`default_floor_plan`.
    waypoints : array_like (n, 2), optional
        The tour, default :data:`DEFAULT_WAYPOINTS`.

    Returns
    -------
    ThorSequence
    """
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"simulate_thor: rng must be a numpy.random.Generator, got {type(rng).__name__}")
    cfg = ThorSimConfig() if config is None else config
    plan = default_floor_plan() if plan is None else plan
    waypoints = DEFAULT_WAYPOINTS if waypoints is None else waypoints
    tj, nj, hj = _joint_arrays(t_joints, neck, head)
    t = scan_times(tj, cfg)
    idx = nearest_sample(t, tj)  # the joint sample nearest to each scan, as joints_at() picks it
    neck_k, head_k = nj[idx], hj[idx]
    moving = None if cfg.stop_above_pitch is None else head_k <= cfg.stop_above_pitch
    true_pose = walking_path(waypoints, t, turn_rate=cfg.turn_rate, moving=moving)
    odom = drifting_odometry(true_pose, rng, cfg)
    angles = thor_angles(cfg.n_beams)
    n, b = len(t), angles.size
    true_range = np.empty((n, b))
    kind = np.empty((n, b), dtype=np.int8)
    ranges = np.empty((n, b))
    for k0 in range(0, n, CHUNK):  # chunks of scans bound the memory; each chunk is vectorised
        sl = slice(k0, min(k0 + CHUNK, n))
        origin, dirs = beam_directions_world(angles, neck_k[sl], head_k[sl], true_pose[sl])
        r, kd = cast_rays(origin, dirs, plan)
        noisy = r + cfg.range_std * rng.standard_normal(r.shape)
        seen = (kd != NO_HIT) & (noisy <= cfg.max_range)
        kd[~seen] = NO_HIT
        true_range[sl], kind[sl] = np.where(seen, r, np.inf), kd
        ranges[sl] = np.where(seen, noisy, cfg.no_return)
    delta = np.diff(odom, axis=0, prepend=np.zeros((1, 3)))
    delta[:, 2] = wrap_angle(delta[:, 2])
    return ThorSequence(
        t=t, angles=angles, ranges=ranges, kind=kind, true_range=true_range, true_pose=true_pose, odom_pose=odom,
        delta_pose=delta, neck=neck_k, head=head_k, joint_index=idx, plan=plan, config=cfg,
    )


def write_sequence(seq: ThorSequence, path, *, variant: int = 1) -> Path:
    """Write a simulated sequence as a THOR LiDAR ``.mat`` file.

    Variant 1 (Penn 2018): ``t``, ``pose`` = :attr:`ThorSequence.odom_pose`,
    ``res`` = 0.25°, ``rpy`` = zeros (the simulated body stays upright),
    ``scan``. Variant 2 (UCSD 2020): ``t``, ``scan``, ``delta_pose`` =
    :attr:`ThorSequence.delta_pose`. Read it back with
    :func:`fastslam_edu.datasets.thor_lidar.read_thor_lidar`.

    Returns
    -------
    Path
    """
    path = Path(path)
    if variant == 1:
        write_thor_lidar(path, seq.t, seq.ranges, pose=seq.odom_pose, variant=1,
                         res=float(seq.angles[1] - seq.angles[0]) if seq.angles.size > 1 else None)
    elif variant == 2:
        write_thor_lidar(path, seq.t, seq.ranges, delta_pose=seq.delta_pose, variant=2)
    else:
        raise ValueError(f"write_sequence: variant must be 1 or 2, got {variant}")
    return path


def real_thor_joints(*, download: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The real joint log of THOR training sequence 0: ``t``, ``neck``, ``head`` (shape (38318,) each).

    Read from ``<data_root>/thor/train_joint0.mat`` (the registry's ``thor`` dataset,
    :func:`fastslam_edu.datasets.dataset_path`) with
    :func:`fastslam_edu.datasets.thor_lidar.read_thor_joints`. With ``download=True`` a
    missing or altered file is fetched from its pinned source and checked first.
    """
    from fastslam_edu.datasets import dataset_path

    return read_thor_joints(dataset_path("thor", download=download) / "train_joint0.mat")
