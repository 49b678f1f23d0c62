"""A simulated landmark world and unicycle robot, with known truth.

:func:`simulate_dataset` returns the same :class:`~fastslam_edu.datasets.log.Dataset`
structure as the MR.CLAM reader, so everything downstream (the event stream,
the filters, the metrics) runs unchanged on it, and its errors can be measured
against an exactly known truth. The package tests use it instead of real data.

What is simulated
-----------------
* **World.** ``n_landmarks`` point landmarks (subjects 6, 7, …) placed uniformly
  at random in a rectangular arena centred at the origin, at least
  ``landmark_spacing`` apart and ``margin`` from the walls.
* **True motion.** Each robot drives towards random waypoints with a
  proportional heading controller (``|v| ≤ v_max``, ``|ω| ≤ omega_max``,
  acceleration-limited). The command ``u_i = (v_i, ω_i)`` issued at odometry
  time ``t_i`` is held until ``t_{i+1}`` (zero-order hold), and the pose
  follows the exact circular arc (:func:`fastslam_edu.core.motion.propagate_arc`).
  Odometry times are irregular: intervals ``U(0.5, 1.5) / odometry_rate``.
* **Odometry** reports the true command plus white noise of the given
  *densities* (:class:`~fastslam_edu.core.motion.MotionNoise`, control mode)::

      v̂_i = v_i + σ_v / √Δt_i · ε₁,     ω̂_i = ω_i + σ_ω / √Δt_i · ε₂,

  so that dead reckoning ``Σ v̂_i Δt_i`` drifts by ``σ_v √T`` after ``T``
  seconds, whatever the rate: the filter's motion model with the same
  ``MotionNoise`` is then exactly right.
* **Measurements.** A camera takes frames at irregular times (intervals
  ``U(0.5, 1.5) / measurement_rate``); each frame measures every landmark whose
  true range is in ``[min_range, max_range]`` and true bearing in ``fov``::

      r̂ = r + N(0, range_std²),     φ̂ = wrap(φ + N(0, bearing_std²)),

  and with probability ``outlier_prob`` the range is an outlier,
  ``r̂ + U(0.5, 2)`` m.
* **Groundtruth.** The true pose every ``1 / groundtruth_rate`` seconds.
* **Robots seeing robots** (``see_robots=True``, :func:`simulate_robot_sightings`): each robot's camera also
  measures the centres of the other robots in view, with the same noise, in frames of its own
  (``RobotLog.robot_sightings``, as MR.CLAM's measurement files hold them). Drawn after every robot is
  simulated, so turning it on changes nothing else.

All randomness comes from one ``numpy.random.Generator``; the same seed gives
identical DataFrames. The odometry noise is drawn after the true path, with a
fixed number of draws, so the same seed gives the same true path whatever the
noise settings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np
import pandas as pd

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.datasets.log import Dataset, RobotLog
from fastslam_edu.core.measurement import range_bearing
from fastslam_edu.core.motion import MotionNoise, propagate_arc

#: Controller constants: heading gain [1/s], acceleration limits, waypoint radius [m].
HEADING_GAIN = 1.5
ACCEL_MAX = 0.5  # m/s²
ANGULAR_ACCEL_MAX = 3.0  # rad/s²
WAYPOINT_REACHED = 0.3  # m

FIRST_LANDMARK_SUBJECT = 6
MAX_ROBOTS = FIRST_LANDMARK_SUBJECT - 1


@dataclass(frozen=True)
class SimConfig:
    """Settings of :func:`simulate_dataset` (units: m, rad, s, Hz).

    Attributes
    ----------
    duration : float
        Length of each robot's log [s].
    odometry_rate : float
        Mean odometry rate [Hz] (MR.CLAM: ~67 Hz); intervals are jittered ±50 %.
    n_landmarks : int
        Number of landmarks N; their subjects are ``6 … 5 + N``.
    arena : (float, float)
        Width (x) and height (y) of the arena [m], centred at the origin.
    n_robots : int
        Number of robots (subjects ``1 … n_robots``, at most 5), independent.
    measurement_rate : float
        Camera frames per second [Hz]: each visible landmark is measured at this rate.
    range_std, bearing_std : float
        Measurement noise standard deviations [m], [rad].
    fov : (float, float)
        Field of view: bearings ``fov[0] ≤ φ ≤ fov[1]`` [rad] are visible.
    min_range, max_range : float
        Visible ranges [m].
    outlier_prob : float
        Probability that a measurement's range is an outlier (``+ U(0.5, 2)`` m).
    odometry_noise : MotionNoise
        Densities of the odometry noise (control mode) [m/√s], [rad/√s].
    groundtruth_rate : float
        Groundtruth sampling rate [Hz] (Vicon: 100 Hz).
    t0 : float
        Start time [s] (a Unix time, like MR.CLAM's).
    v_max, omega_max : float
        Bounds of the true commands [m/s], [rad/s].
    landmark_spacing : float
        Minimum distance between two landmarks [m].
    margin : float
        Landmarks and waypoints stay this far inside the walls [m].
    see_robots : bool
        Also simulate each robot's sightings of the other robots (:func:`simulate_robot_sightings`).
    """

    duration: float = 120.0
    odometry_rate: float = 67.0
    n_landmarks: int = 15
    arena: tuple[float, float] = (15.0, 8.0)
    n_robots: int = 1
    measurement_rate: float = 5.0
    range_std: float = 0.05
    bearing_std: float = 0.02
    fov: tuple[float, float] = (-math.pi / 3, math.pi / 3)
    min_range: float = 0.3
    max_range: float = 5.0
    outlier_prob: float = 0.0
    odometry_noise: MotionNoise = MotionNoise(sigma_v=0.01, sigma_omega=0.02)
    groundtruth_rate: float = 100.0
    t0: float = 1248272273.0
    v_max: float = 0.3
    omega_max: float = 1.0
    landmark_spacing: float = 1.0
    margin: float = 1.0
    see_robots: bool = False

    def __post_init__(self) -> None:
        positive = ("duration", "odometry_rate", "measurement_rate", "max_range", "groundtruth_rate",
                    "v_max", "omega_max")
        non_negative = ("range_std", "bearing_std", "min_range", "landmark_spacing", "margin")
        for name in positive + non_negative + ("t0", "outlier_prob"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                    or not math.isfinite(value):
                raise ValueError(f"SimConfig.{name} must be a finite number, got {value!r}")
        for name in positive:
            if getattr(self, name) <= 0:
                raise ValueError(f"SimConfig.{name} must be > 0, got {getattr(self, name)!r}")
        for name in non_negative:
            if getattr(self, name) < 0:
                raise ValueError(f"SimConfig.{name} must be >= 0, got {getattr(self, name)!r}")
        if not 0.0 <= self.outlier_prob <= 1.0:
            raise ValueError(f"SimConfig.outlier_prob must be in [0, 1], got {self.outlier_prob!r}")
        if self.min_range >= self.max_range:
            raise ValueError(f"SimConfig: min_range ({self.min_range}) must be < max_range ({self.max_range})")
        for name, low, high in (("n_landmarks", 0, 90), ("n_robots", 1, MAX_ROBOTS)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not low <= value <= high:
                raise ValueError(f"SimConfig.{name} must be an integer in [{low}, {high}], got {value!r}")
        fov = tuple(float(a) for a in self.fov)
        if len(fov) != 2 or not (-math.pi <= fov[0] < fov[1] <= math.pi):
            raise ValueError(f"SimConfig.fov must be (low, high) with -π <= low < high <= π, got {self.fov!r}")
        object.__setattr__(self, "fov", fov)
        arena = tuple(float(a) for a in self.arena)
        if len(arena) != 2 or not all(math.isfinite(a) and a > 2 * self.margin for a in arena):
            raise ValueError(
                f"SimConfig.arena must be (width, height), each > 2·margin = {2 * self.margin} m, got {self.arena!r}"
            )
        object.__setattr__(self, "arena", arena)
        if not isinstance(self.odometry_noise, MotionNoise) or self.odometry_noise.mode != "control":
            raise ValueError(
                "SimConfig.odometry_noise must be a MotionNoise in mode 'control' (odometry reports "
                f"noisy commands), got {self.odometry_noise!r}"
            )


# --------------------------------------------------------------------------- world


def barcode_of(subject: int) -> int:
    """Barcode number of a subject: ``37 · subject mod 97`` (distinct for subjects 1 … 96).

    A made-up table in the spirit of MR.CLAM's ``Barcodes.dat`` (two-digit codes
    unrelated to subject numbers); it is stored in ``Dataset.barcodes``.
    """
    return (37 * int(subject)) % 97


def place_landmarks(rng: np.random.Generator, config: SimConfig) -> np.ndarray:
    """Uniform random landmark positions, pairwise ≥ ``landmark_spacing`` apart.

    Rejection sampling inside ``[-w/2 + margin, w/2 - margin] × [-h/2 + margin, h/2 - margin]``.

    Returns
    -------
    ndarray, shape (N, 2) [m]
    """
    half = np.array(config.arena) / 2 - config.margin
    placed: list[np.ndarray] = []
    for _ in range(1000 * config.n_landmarks):
        if len(placed) == config.n_landmarks:
            break
        candidate = rng.uniform(-half, half)
        if all(np.hypot(*(candidate - p)) >= config.landmark_spacing for p in placed):
            placed.append(candidate)
    if len(placed) < config.n_landmarks:
        raise ValueError(
            f"cannot place {config.n_landmarks} landmarks {config.landmark_spacing} m apart in an arena "
            f"of {config.arena} m with margin {config.margin} m: lower n_landmarks or landmark_spacing"
        )
    return np.array(placed, dtype=float).reshape(-1, 2)


# --------------------------------------------------------------------------- robot


def irregular_times(rng: np.random.Generator, rate: float, duration: float) -> np.ndarray:
    """Times in ``[0, duration)`` starting at 0, intervals ``U(0.5, 1.5) / rate``."""
    n = int(math.ceil(duration * rate * 2)) + 2
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.5, 1.5, n) / rate)])
    return t[t < duration]


def drive(rng: np.random.Generator, config: SimConfig, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drive one robot among random waypoints: true commands and poses.

    At each odometry time ``t_i`` the controller turns towards the waypoint,
    ``ω = clip(k e, ±ω_max)`` with heading error ``e``, and drives at
    ``v = v_max cos²(e)`` (0 when facing away), both acceleration-limited. The
    command is held until ``t_{i+1}`` (the last one until ``duration``) and the
    pose follows the exact arc.

    Parameters
    ----------
    t : ndarray, shape (T,)
        Odometry times relative to the start [s].

    Returns
    -------
    u : ndarray, shape (T, 2)
        True commands ``(v, ω)``.
    poses : ndarray, shape (T + 1, 3)
        True poses at ``t_0 … t_{T-1}`` and at ``duration``, θ wrapped.
    """
    half = np.array(config.arena) / 2 - config.margin
    px, py = rng.uniform(-half, half)
    th = rng.uniform(-math.pi, math.pi)
    wx, wy = rng.uniform(-half, half)
    ends = np.append(t[1:], config.duration)
    u = np.empty((len(t), 2))
    poses = np.empty((len(t) + 1, 3))
    v = omega = 0.0
    for i, dt in enumerate(ends - t):
        poses[i] = px, py, th
        while math.hypot(wx - px, wy - py) < WAYPOINT_REACHED:
            wx, wy = rng.uniform(-half, half)
        error = math.remainder(math.atan2(wy - py, wx - px) - th, 2 * math.pi)
        omega_cmd = min(max(HEADING_GAIN * error, -config.omega_max), config.omega_max)
        v_cmd = config.v_max * max(math.cos(error), 0.0) ** 2
        v += min(max(v_cmd - v, -ACCEL_MAX * dt), ACCEL_MAX * dt)
        omega += min(max(omega_cmd - omega, -ANGULAR_ACCEL_MAX * dt), ANGULAR_ACCEL_MAX * dt)
        u[i] = v, omega
        # exact arc (as motion.propagate_arc, scalar for speed)
        half_turn = omega * dt / 2
        chord = v * dt * (math.sin(half_turn) / half_turn if half_turn != 0.0 else 1.0)
        px += chord * math.cos(th + half_turn)
        py += chord * math.sin(th + half_turn)
        th += omega * dt
    poses[-1] = px, py, th
    poses[:, 2] = wrap_angle(poses[:, 2])
    return u, poses


def poses_at(times: np.ndarray, t: np.ndarray, u: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """True poses at arbitrary times, by the exact arc from the last odometry time.

    Parameters
    ----------
    times : ndarray, shape (n,)
        Query times in ``[0, duration]`` relative to the start [s].
    t, u, poses
        Odometry times (T,), commands (T, 2) and poses (T + 1, 3) from :func:`drive`.

    Returns
    -------
    ndarray, shape (n, 3)
    """
    i = np.clip(np.searchsorted(t, times, side="right") - 1, 0, len(t) - 1)
    held = times - t[i]
    # the arc depends only on (v Δt, ω Δt): pass u·Δt with a unit step
    return propagate_arc(poses[i], u[i] * held[:, None], 1.0)


def corrupt_odometry(rng: np.random.Generator, u: np.ndarray, dt: np.ndarray, noise: MotionNoise) -> np.ndarray:
    """Odometry readings: ``û_i = u_i + (σ_v, σ_ω) / √Δt_i · ε_i``, ε_i ~ N(0, I₂).

    Always draws (T, 2) normals, so the random stream does not depend on the noise level.
    """
    eps = rng.standard_normal(u.shape)
    return u + eps * np.array([noise.sigma_v, noise.sigma_omega]) / np.sqrt(dt)[:, None]


def measure(
    rng: np.random.Generator,
    config: SimConfig,
    frame_times: np.ndarray,
    frame_poses: np.ndarray,
    landmarks: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Noisy range-bearing measurements of the visible landmarks in each frame.

    Returns
    -------
    time, landmark_index, r, phi : ndarrays, shape (n,)
        Ordered by frame, then landmark index.
    """
    z = range_bearing(frame_poses[:, None, :], landmarks[None, :, :])  # (frames, N, 2)
    r, phi = z[..., 0], z[..., 1]
    visible = (r >= config.min_range) & (r <= config.max_range) & (phi >= config.fov[0]) & (phi <= config.fov[1])
    frame, k = np.nonzero(visible)
    n = len(frame)
    noise = rng.standard_normal((n, 2)) * [config.range_std, config.bearing_std]
    is_outlier = rng.random(n) < config.outlier_prob
    jump = rng.uniform(0.5, 2.0, n)
    r_hat = r[frame, k] + noise[:, 0] + np.where(is_outlier, jump, 0.0)
    phi_hat = wrap_angle(phi[frame, k] + noise[:, 1])
    return frame_times[frame], k, r_hat, phi_hat


def simulate_robot_sightings(rng: np.random.Generator, config: SimConfig, robots: dict[int, RobotLog]) -> dict:
    """Every robot's sightings of the others: ``{robot: DataFrame(time, subject, range, bearing)}``.

    Robot ``a`` takes camera frames at irregular times (``measurement_rate``, as :func:`irregular_times`);
    in each frame it measures every other robot ``b`` whose centre is in view (``min_range ≤ r ≤ max_range``,
    bearing in ``fov``), with the landmarks' noise and outliers (:func:`measure`)::

        (r, φ) = h(x_a(t), p_b(t)) + noise,   p_b = (x_b, y_b),

    the true poses at ``t`` interpolated in the 100 Hz groundtruth (an error of a few µm at the
    simulated speeds). Ordered by time, then by the robot seen.
    """
    from fastslam_edu.core.se2 import interpolate_poses

    numbers = sorted(robots)
    truth = {r: (robots[r].groundtruth["time"].to_numpy(), robots[r].groundtruth[["x", "y", "theta"]].to_numpy())
             for r in numbers}
    out = {}
    for a in numbers:
        frame_t = config.t0 + irregular_times(rng, config.measurement_rate, config.duration)[1:]
        own = interpolate_poses(frame_t, *truth[a])
        others = [b for b in numbers if b != a]
        rows = []
        for j, b in enumerate(others):  # measure() sees fixed points: one robot seen at a time, frame by frame
            pb = interpolate_poses(frame_t, *truth[b])[:, :2]
            z = range_bearing(own, pb)
            visible = ((z[:, 0] >= config.min_range) & (z[:, 0] <= config.max_range)
                       & (z[:, 1] >= config.fov[0]) & (z[:, 1] <= config.fov[1]))
            n = int(visible.sum())
            noise = rng.standard_normal((n, 2)) * [config.range_std, config.bearing_std]
            jump = np.where(rng.random(n) < config.outlier_prob, rng.uniform(0.5, 2.0, n), 0.0)
            rows.append(pd.DataFrame({"time": frame_t[visible], "subject": np.full(n, b, dtype=np.int64),
                                      "range": z[visible, 0] + noise[:, 0] + jump,
                                      "bearing": wrap_angle(z[visible, 1] + noise[:, 1])}))
        table = pd.concat(rows, ignore_index=True) if rows else pd.DataFrame(
            {"time": [], "subject": np.zeros(0, dtype=np.int64), "range": [], "bearing": []})
        out[a] = table.sort_values(["time", "subject"], kind="stable").reset_index(drop=True)
    return out


def simulate_robot(rng: np.random.Generator, config: SimConfig, robot: int, landmarks: np.ndarray) -> RobotLog:
    """One robot's log: odometry, measurements and groundtruth (see the module docstring)."""
    t = irregular_times(rng, config.odometry_rate, config.duration)
    u, poses = drive(rng, config, t)
    dt = np.diff(np.append(t, config.duration))
    u_hat = corrupt_odometry(rng, u, dt, config.odometry_noise)

    frame_t = irregular_times(rng, config.measurement_rate, config.duration)[1:]  # first frame after the start
    time, k, r_hat, phi_hat = measure(rng, config, frame_t, poses_at(frame_t, t, u, poses), landmarks)

    n_gt = int(math.floor(config.duration * config.groundtruth_rate + 1e-9)) + 1
    gt_t = np.arange(n_gt) / config.groundtruth_rate
    gt = poses_at(gt_t, t, u, poses)

    t0 = config.t0
    return RobotLog(
        robot=robot,
        odometry=pd.DataFrame({"time": t0 + t, "v": u_hat[:, 0], "omega": u_hat[:, 1]}),
        measurements=pd.DataFrame(
            {
                "time": t0 + time,
                "subject": (FIRST_LANDMARK_SUBJECT + k).astype(np.int64),
                "range": r_hat,
                "bearing": phi_hat,
            }
        ),
        groundtruth=pd.DataFrame({"time": t0 + gt_t, "x": gt[:, 0], "y": gt[:, 1], "theta": gt[:, 2]}),
        dropped={},
        source="simulation",
    )


def generator_from_seed(seed_or_rng, caller: str = "simulate_dataset") -> np.random.Generator:
    """The ``numpy.random.Generator`` of a seed (int >= 0), or the generator itself; ``caller`` names the error."""
    if isinstance(seed_or_rng, np.random.Generator):
        return seed_or_rng
    if isinstance(seed_or_rng, (int, np.integer)) and not isinstance(seed_or_rng, bool) and seed_or_rng >= 0:
        return np.random.default_rng(int(seed_or_rng))
    raise ValueError(
        f"{caller} needs a seed (int >= 0) or a numpy.random.Generator, got {seed_or_rng!r}"
    )


def simulate_dataset(seed_or_rng: int | np.random.Generator, config: SimConfig | None = None,
                     **overrides) -> Dataset:
    """Simulate a MR.CLAM-style dataset with known truth.

    Parameters
    ----------
    seed_or_rng : int or numpy.random.Generator
        Same seed -> identical DataFrames.
    config : SimConfig, optional
        Settings (default ``SimConfig()``: 120 s, 67 Hz odometry, 15 landmarks in
        15 m × 8 m, one robot).
    **overrides
        Fields of :class:`SimConfig` to change, e.g. ``duration=60.0, outlier_prob=0.05``.

    Returns
    -------
    Dataset
        ``path=None``; ``landmarks`` holds the true landmark positions (index
        ``subject``, columns ``x, y, x_std, y_std``, std 0); ``robots[r]`` holds
        robot ``r``'s odometry (noisy commands), measurements (subjects
        6 … 5 + N) and groundtruth (true poses). Times start at ``config.t0``.

    Examples
    --------
    >>> data = simulate_dataset(0, duration=30.0, odometry_noise=MotionNoise())
    >>> sorted(data.robots), data.landmark_positions.shape
    ([1], (15, 2))
    """
    names = {f.name for f in fields(SimConfig)}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise ValueError(f"simulate_dataset: unknown setting(s) {unknown}; valid: {sorted(names)}")
    config = replace(config or SimConfig(), **overrides)
    rng = generator_from_seed(seed_or_rng)

    positions = place_landmarks(rng, config)
    subjects = FIRST_LANDMARK_SUBJECT + np.arange(config.n_landmarks, dtype=np.int64)
    landmarks = pd.DataFrame(
        {"x": positions[:, 0], "y": positions[:, 1], "x_std": 0.0, "y_std": 0.0},
        index=pd.Index(subjects, name="subject"),
    )
    robots = {r: simulate_robot(rng, config, r, positions) for r in range(1, config.n_robots + 1)}
    if config.see_robots:
        seen = simulate_robot_sightings(rng, config, robots)
        robots = {r: replace(log, robot_sightings=seen[r]) for r, log in robots.items()}
    barcodes = {barcode_of(s): int(s) for s in [*robots, *subjects.tolist()]}
    return Dataset(path=None, barcodes=barcodes, landmarks=landmarks, robots=robots)


__all__ = ["SimConfig", "simulate_dataset", "simulate_robot_sightings", "barcode_of", "place_landmarks",
           "generator_from_seed"]
