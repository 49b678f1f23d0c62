"""The unicycle motion model, sampled for M particles.

The robot's pose is ``x = (x, y, θ)`` [m, m, rad]; its odometry reports the
command ``u = (v, ω)``: forward velocity [m/s] and angular velocity [rad/s],
held for ``Δt`` seconds. FastSLAM's proposal (Montemerlo et al. 2002, step 1
of the algorithm) draws each particle's new pose from
``p(x_t | x_{t-1}, u_t)``; this module writes that distribution as a
deterministic step plus Gaussian noise.

Deterministic step (Euler, as ``propagate_all_states`` in the MR.CLAM
write-up of Chen, Iwasa et al.), with the heading **at the start** of the step::

    x_t = x_{t-1} + v Δt cos θ_{t-1}
    y_t = y_{t-1} + v Δt sin θ_{t-1}
    θ_t = θ_{t-1} + ω Δt                      (wrapped to (-π, π])

Its error over a fixed time is O(Δt) (see :func:`propagate_arc` for the exact
circular arc; at MR.CLAM's 67 Hz the two differ by millimetres).

Noise as densities
------------------
The write-up adds noise of a fixed standard deviation (0.05) to ``v`` and ``ω``
at every step. Then the spread of the pose after one second depends on how
many steps that second was cut into: at 67 Hz the per-step errors average out
and the filter becomes 67 times over-confident (variances). Here the noise is
a *density* (a random walk): over a step of ``Δt`` seconds the integrated
control is perturbed by ``σ √Δt ε`` with ``ε ~ N(0, 1)``, so that ``n`` steps
of ``Δt = T/n`` add up to a variance ``σ² T`` whatever ``n`` is.
See :class:`MotionNoise` for the two ways of adding it.

Shapes: a pose array ``x`` is ``(..., 3)`` (one pose ``(3,)`` or M particles
``(M, 3)``); a command ``u`` is ``(2,)`` (the same for all) or ``(..., 2)``
(one per particle). Leading dimensions broadcast.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.checks import finite_array
from fastslam_edu.core.params import Params

_MODES = ("control", "state")


@dataclass(frozen=True, eq=False)
class MotionNoise(Params):
    """Noise of the motion model, as densities (standard deviation per √second).

    Two modes, as the two options of the write-up's ``propagate_all_states``:

    ``mode="control"`` — noise on the command, before propagating. Over a step
    of ``Δt`` seconds the distance and the turn are::

        Δs = v Δt + σ_v √Δt ε₁,      Δθ = ω Δt + σ_ω √Δt ε₂,

    i.e. noise of standard deviation ``σ_v / √Δt`` on ``v`` and ``σ_ω / √Δt``
    on ``ω``. Var(Δs) = σ_v² Δt and Var(Δθ) = σ_ω² Δt.

    ``mode="state"`` — noise on the pose, after deterministic propagation::

        x_t = f(x_{t-1}, u_t) + (σ_xy √Δt ε₁, σ_xy √Δt ε₂, σ_θ √Δt ε₃).

    Attributes
    ----------
    mode : {"control", "state"}
    sigma_v : float
        Control mode: density of the distance noise [m/√s].
    sigma_omega : float
        Control mode: density of the heading noise [rad/√s].
    sigma_xy : float
        State mode: density of the noise on x and on y [m/√s].
    sigma_theta : float
        State mode: density of the noise on θ [rad/√s].

    The two densities of the other mode must stay 0 (a ValueError otherwise, so
    that a misplaced value is not silently ignored). ``MotionNoise()`` is no
    noise at all.

    Examples
    --------
    The write-up's "std 0.05 on v and ω" at its 1 Hz steps:

    >>> MotionNoise.from_per_step_std(1.0, v_std=0.05, omega_std=0.05)
    MotionNoise(mode='control', sigma_v=0.05, sigma_omega=0.05, sigma_xy=0.0, sigma_theta=0.0)
    """

    mode: str = "control"
    sigma_v: float = 0.0
    sigma_omega: float = 0.0
    sigma_xy: float = 0.0
    sigma_theta: float = 0.0

    def __post_init__(self) -> None:
        if self.mode not in _MODES:
            raise ValueError(f"MotionNoise.mode must be 'control' or 'state', got {self.mode!r}")
        for name in ("sigma_v", "sigma_omega", "sigma_xy", "sigma_theta"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise ValueError(f"MotionNoise.{name} must be a number, got {value!r}")
            if not math.isfinite(value) or value < 0:
                raise ValueError(f"MotionNoise.{name} must be finite and >= 0, got {value!r}")
            object.__setattr__(self, name, float(value))
        unused = ("sigma_xy", "sigma_theta") if self.mode == "control" else ("sigma_v", "sigma_omega")
        for name in unused:
            if getattr(self, name) != 0.0:
                raise ValueError(
                    f"MotionNoise.{name} is used only in mode="
                    f"{'state' if self.mode == 'control' else 'control'!r}, but mode={self.mode!r} "
                    f"and {name}={getattr(self, name)!r}; set it to 0 or change the mode"
                )

    @property
    def densities(self) -> np.ndarray:
        """``(σ_v, σ_ω, σ_xy, σ_θ)`` as an array (what :func:`fastslam_edu.landmark.fastslam_step.sample_pose` takes)."""
        return np.array([self.sigma_v, self.sigma_omega, self.sigma_xy, self.sigma_theta])

    @property
    def n_draws(self) -> int:
        """Standard normals used per particle per step: 2 (control) or 3 (state)."""
        return 2 if self.mode == "control" else 3

    def step_std(self, dt: float) -> np.ndarray:
        """Standard deviations of the noise over one step of ``dt`` seconds.

        Control mode: those of ``(Δs, Δθ)``, ``(σ_v √dt, σ_ω √dt)``.
        State mode: those of the kick on ``(x, y, θ)``, ``(σ_xy √dt, σ_xy √dt, σ_θ √dt)``.

        Returns
        -------
        ndarray, shape (n_draws,)
        """
        root_dt = math.sqrt(_check_dt(dt))
        if self.mode == "control":
            return np.array([self.sigma_v, self.sigma_omega]) * root_dt
        return np.array([self.sigma_xy, self.sigma_xy, self.sigma_theta]) * root_dt

    @classmethod
    def from_per_step_std(
        cls,
        step: float,
        *,
        v_std: float | None = None,
        omega_std: float | None = None,
        xy_std: float | None = None,
        theta_std: float | None = None,
    ) -> MotionNoise:
        """Densities equivalent to a per-step standard deviation at a fixed step.

        Control mode (give ``v_std`` [m/s], ``omega_std`` [rad/s]: noise added to
        ``v`` and ``ω`` at every step of ``step`` seconds): the distance then
        varies by ``v_std · step`` per step, so ``σ_v = v_std · √step``
        (likewise ``σ_ω``).

        State mode (give ``xy_std`` [m], ``theta_std`` [rad]: noise added to the
        pose at every step): ``σ_xy = xy_std / √step`` (likewise ``σ_θ``).

        The result reproduces the per-step model exactly at ``step``, and keeps
        the same spread per second at any other step.

        Parameters
        ----------
        step : float
            The step the per-step standard deviations were meant for [s], > 0.
        """
        step = _check_dt(step)
        if step == 0:
            raise ValueError("from_per_step_std: step must be > 0 seconds, got 0")
        control = {"v_std": v_std, "omega_std": omega_std}
        state = {"xy_std": xy_std, "theta_std": theta_std}
        given_control = any(v is not None for v in control.values())
        given_state = any(v is not None for v in state.values())
        if given_control == given_state:
            raise ValueError(
                "from_per_step_std: give either v_std/omega_std (control mode) or "
                "xy_std/theta_std (state mode), not both and not neither"
            )
        root = math.sqrt(step)
        if given_control:
            return cls("control", sigma_v=(v_std or 0.0) * root, sigma_omega=(omega_std or 0.0) * root)
        return cls("state", sigma_xy=(xy_std or 0.0) / root, sigma_theta=(theta_std or 0.0) / root)


# --------------------------------------------------------------------------- checks


def _check_dt(dt: float) -> float:
    try:
        value = float(dt)
    except (TypeError, ValueError):
        raise ValueError(f"dt must be a number of seconds, got {dt!r}") from None
    if not math.isfinite(value) or value < 0:
        raise ValueError(f"dt must be finite and >= 0 seconds, got {dt!r}")
    return value


def _check_poses(x, caller: str) -> np.ndarray:
    return finite_array("x (poses x, y, θ)", x, caller, (3,))


def _check_controls(u, caller: str) -> np.ndarray:
    return finite_array("u (commands v, ω)", u, caller, (2,))


# --------------------------------------------------------------------------- model


def advance(x: np.ndarray, delta_s, delta_theta) -> np.ndarray:
    """Euler step by a distance and a turn, heading taken at the start of the step.

    ``x_t = x + Δs cos θ``, ``y_t = y + Δs sin θ``, ``θ_t = wrap(θ + Δθ)``.

    Parameters
    ----------
    x : ndarray, shape (..., 3)
        Poses ``(x, y, θ)`` [m, m, rad] (not checked).
    delta_s, delta_theta : float or ndarray broadcastable to ``x[..., 0]``
        Distance travelled [m] and turn [rad].

    Returns
    -------
    ndarray, shape broadcast of ``x`` with the increments, (..., 3)
    """
    theta = x[..., 2]
    return np.stack(
        [
            x[..., 0] + delta_s * np.cos(theta),
            x[..., 1] + delta_s * np.sin(theta),
            wrap_angle(theta + delta_theta),
        ],
        axis=-1,
    )


def propagate(x, u, dt: float) -> np.ndarray:
    """Deterministic unicycle step ``f(x, u)`` (Euler, heading at the start of the step).

    ``x_t = x + v Δt cos θ``, ``y_t = y + v Δt sin θ``, ``θ_t = wrap(θ + ω Δt)``.

    This is the write-up's ``propagate_all_states`` without noise. Its error
    against the exact arc (:func:`propagate_arc`) is O(v ω Δt²) per step,
    O(Δt) over a fixed time.

    Parameters
    ----------
    x : array_like, shape (3,) or (M, 3) or (..., 3)
        Poses ``(x, y, θ)`` [m, m, rad].
    u : array_like, shape (2,) or (..., 2)
        Command ``(v [m/s], ω [rad/s])``, one for all or one per pose.
    dt : float
        Duration of the step [s], >= 0. ``dt = 0`` leaves the pose unchanged
        (θ wrapped).

    Returns
    -------
    ndarray, shape (..., 3)
        The new poses; leading dimensions are those of ``x`` and ``u`` broadcast.

    Raises
    ------
    ValueError
        Wrong shapes, NaN/inf, or a negative ``dt``.
    """
    x, u, dt = _check_poses(x, "propagate"), _check_controls(u, "propagate"), _check_dt(dt)
    return advance(x, u[..., 0] * dt, u[..., 1] * dt)


def propagate_arc(x, u, dt: float) -> np.ndarray:
    """Exact unicycle motion: a circular arc of constant ``(v, ω)`` for ``dt`` seconds.

    The robot moves along the chord of the arc, of length ``v Δt sinc(ω Δt / 2)``
    (with ``sinc(a) = sin(a)/a``, ``sinc(0) = 1``), in the direction of the
    heading at mid-step ``θ + ω Δt / 2``::

        x_t = x + v Δt sinc(ω Δt/2) cos(θ + ω Δt/2)
        y_t = y + v Δt sinc(ω Δt/2) sin(θ + ω Δt/2)
        θ_t = wrap(θ + ω Δt)

    which equals the textbook ``x + (v/ω)(sin(θ + ω Δt) - sin θ)`` but has no
    division by ``ω`` (a straight line when ``ω = 0``). Used by the simulator
    for the true motion; the filter uses the Euler form, :func:`propagate`.

    Parameters and returns as :func:`propagate`.
    """
    x, u, dt = _check_poses(x, "propagate_arc"), _check_controls(u, "propagate_arc"), _check_dt(dt)
    v, omega = u[..., 0], u[..., 1]
    half_turn = omega * dt / 2.0
    chord = v * dt * np.sinc(half_turn / np.pi)  # numpy's sinc is sin(πa)/(πa)
    theta = x[..., 2]
    return np.stack(
        [
            x[..., 0] + chord * np.cos(theta + half_turn),
            x[..., 1] + chord * np.sin(theta + half_turn),
            wrap_angle(theta + omega * dt),
        ],
        axis=-1,
    )


def move(x, u, dt: float, noise: MotionNoise, eps) -> np.ndarray:
    """One noisy step with given standard normals ``eps`` (the sampler without its RNG).

    Control mode (:class:`MotionNoise`)::

        Δs = v Δt + σ_v √Δt ε₁,   Δθ = ω Δt + σ_ω √Δt ε₂,   then the Euler step by (Δs, Δθ).

    State mode::

        x_t = propagate(x, u, Δt) + (σ_xy √Δt ε₁, σ_xy √Δt ε₂, σ_θ √Δt ε₃),   θ wrapped.

    Taking ``eps`` as an argument lets this function, the loop reference of the tests and
    the filter's compiled step consume the very same random numbers.

    Parameters
    ----------
    x : array_like, shape (M, 3) or (..., 3)
        Poses [m, m, rad].
    u : array_like, shape (2,) or (..., 2)
        Command ``(v [m/s], ω [rad/s])``.
    dt : float
        Step [s], >= 0 (``dt = 0``: no motion, no noise).
    noise : MotionNoise
    eps : array_like, shape (M, noise.n_draws) or (..., noise.n_draws)
        Standard normal draws, one row per output pose.

    Returns
    -------
    ndarray, shape (M, 3) or (..., 3)
    """
    x, u, dt = _check_poses(x, "move"), _check_controls(u, "move"), _check_dt(dt)
    if not isinstance(noise, MotionNoise):
        raise ValueError(f"noise must be a MotionNoise, got {type(noise).__name__}")
    batch = np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
    eps = np.asarray(eps, dtype=float)
    if eps.shape != batch + (noise.n_draws,):
        raise ValueError(
            f"eps must have shape {batch + (noise.n_draws,)} (one row of {noise.n_draws} standard "
            f"normals per pose, mode={noise.mode!r}), got {eps.shape}"
        )
    if not np.isfinite(eps).all():
        raise ValueError("eps contains NaN or inf")
    std = noise.step_std(dt)
    if noise.mode == "control":
        delta_s = u[..., 0] * dt + std[0] * eps[..., 0]
        delta_theta = u[..., 1] * dt + std[1] * eps[..., 1]
        return advance(x, delta_s, delta_theta)
    moved = advance(x, u[..., 0] * dt, u[..., 1] * dt) + std * eps
    moved[..., 2] = wrap_angle(moved[..., 2])
    return moved


def _check_segment(x, u, dt, noise, eps) -> None:
    x = _check_poses(x, "move_segment")
    u = np.asarray(u, dtype=float)
    dt = np.asarray(dt, dtype=float)
    if x.ndim != 2 or u.ndim != 2 or u.shape[1] != 2 or dt.shape != (u.shape[0],):
        raise ValueError(
            f"move_segment expects x (M, 3), u (L, 2), dt (L,); got {x.shape}, {u.shape}, {dt.shape}"
        )
    if not (np.isfinite(u).all() and np.isfinite(dt).all()) or (dt < 0).any():
        raise ValueError("move_segment: u and dt must be finite and dt >= 0")
    if not isinstance(noise, MotionNoise):
        raise ValueError(f"noise must be a MotionNoise, got {type(noise).__name__}")
    shape = (x.shape[0], u.shape[0], noise.n_draws)
    if np.shape(eps) != shape or not np.isfinite(eps).all():
        raise ValueError(f"eps must be finite with shape {shape}, got {np.shape(eps)}")


def segment_increments(x, u, dt, noise: MotionNoise, eps):
    """The pieces of :func:`move_segment`: each step's displacement, and the headings.

    With the per-step increments ``Δs_j`` and ``Δθ_j`` (command plus noise, as in
    :func:`move`), the heading before step ``j`` is ``θ_j = θ_0 + Σ_{i<j} Δθ_i``
    and the step moves the robot by ``Δs_j (cos θ_j, sin θ_j)`` (plus, for noise
    on the state, ``σ_xy √Δt (ε₁, ε₂)``). The poses are running sums of these
    displacements: :func:`move_segment` takes them; the filter, which needs only
    weighted means, runs the same steps one particle at a time
    (:func:`fastslam_edu.landmark.fastslam_step.propagate_segment_kernel`).

    Parameters are those of :func:`move_segment` (unchecked: ``x`` (M, 3),
    ``u`` (L, 2), ``dt`` (L,), ``eps`` (M, L, noise.n_draws)).

    Returns
    -------
    dx, dy : ndarray, shape (M, L)
        Displacement of each particle in each step [m].
    theta : ndarray, shape (M, L)
        Heading after each step [rad], not wrapped (continuous from ``x[:, 2]``).
    """
    x, u, dt = np.asarray(x, dtype=float), np.asarray(u, dtype=float), np.asarray(dt, dtype=float)
    sq = np.sqrt(dt)
    ds = u[:, 0] * dt
    dth = u[:, 1] * dt
    if noise.mode == "control":
        ds = ds + noise.sigma_v * sq * eps[..., 0]  # (M, L)
        dth = dth + noise.sigma_omega * sq * eps[..., 1]
    else:
        dth = dth + noise.sigma_theta * sq * eps[..., 2]
    # heading after each step, (M, L); a running sum of one step is that step
    theta_end = x[:, 2:3] + (np.cumsum(dth, axis=1) if dth.shape[-1] > 1 else dth)
    heading = theta_end - dth  # the heading at the start of each step
    dx = ds * np.cos(heading)
    dy = ds * np.sin(heading)
    if noise.mode != "control":
        dx = dx + noise.sigma_xy * sq * eps[..., 0]
        dy = dy + noise.sigma_xy * sq * eps[..., 1]
    return dx, dy, theta_end


def move_segment(x, u, dt, noise: MotionNoise, eps, *, check: bool = True) -> np.ndarray:
    """:func:`move` through ``L`` consecutive steps at once, for ``M`` particles.

    Applying :func:`move` ``L`` times is a running sum: with the per-step
    increments ``Δs_j`` and ``Δθ_j`` (command plus noise, as in :func:`move`),
    the heading before step ``j`` is ``θ_j = θ_0 + Σ_{i<j} Δθ_i`` and the position
    after it is ``x_0 + Σ_{i≤j} Δs_i (cos θ_i, sin θ_i)`` (:func:`segment_increments`).
    Cumulative sums replace a Python loop over the ``L`` steps, which is what
    makes full-rate odometry (~65 Hz) cheap for the filter. The result equals
    ``L`` calls of :func:`move` with ``eps[:, j]`` to rounding (tested).

    Parameters
    ----------
    x : array_like, shape (M, 3)
        Poses before the first step [m, m, rad].
    u : array_like, shape (L, 2)
        Commands ``(v, ω)`` of the steps.
    dt : array_like, shape (L,)
        Step durations [s], >= 0.
    noise : MotionNoise
    eps : array_like, shape (M, L, noise.n_draws)
        Standard normal draws.
    check : bool
        Validate the inputs (callers that validated their stream once pass False).

    Returns
    -------
    ndarray, shape (M, L, 3)
        Every pose after each step (heading wrapped).
    """
    x = np.asarray(x, dtype=float)
    if check:
        _check_segment(x, u, dt, noise, eps)
    return path_from_increments(x, *segment_increments(x, u, dt, noise, eps))


def path_from_increments(x, dx, dy, theta, *, wrap: bool = True) -> np.ndarray:
    """Poses (M, L, 3) after each step from :func:`segment_increments`: ``x_0`` plus running sums.

    ``wrap=False`` leaves the headings continuous from ``x[:, 2]`` (the filter wraps only what it keeps).
    """
    path = np.empty(np.shape(dx) + (3,))
    path[..., 0] = x[:, 0:1] + np.cumsum(dx, axis=1)
    path[..., 1] = x[:, 1:2] + np.cumsum(dy, axis=1)
    path[..., 2] = wrap_angle(theta) if wrap else theta
    return path


def dead_reckon(x0, u, dt) -> np.ndarray:
    """The path of the commands alone: the motion model's Euler steps without noise, shape (L, 3).

    ``x0`` (3,) the start, ``u`` (L, 2) the commands ``(v, ω)``, ``dt`` (L,) the
    step lengths [s]; row ``i`` is the pose after step ``i``. θ is **not**
    wrapped (a continuous heading, so that differences count whole turns).
    """
    x0 = np.asarray(x0, dtype=float).reshape(1, 3)
    dx, dy, theta = segment_increments(x0, u, dt, MotionNoise(), np.zeros((1, len(dt), 2)))
    return path_from_increments(x0, dx, dy, theta, wrap=False)[0]


def dead_reckon_at(odometry, times, x0=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Integrate the odometry with the filter's motion model, without noise.

    The command ``(v_i, ω_i)`` of row ``i`` is held from ``t_i`` until the
    next row (zero before the first row); the path is a chain of Euler steps
    (:func:`dead_reckon`) between the
    sorted union of the odometry times and ``times``, starting at ``x0`` at
    ``min(times[0], t_0)``.

    Parameters
    ----------
    odometry : DataFrame
        Columns ``time, v, omega`` (a log's odometry table,
        :attr:`fastslam_edu.datasets.log.RobotLog.odometry`), time non-decreasing.
    times : array_like, shape (n,)
        Non-decreasing times [s] at which the pose is wanted.
    x0 : array_like, shape (3,)
        Pose at the start.

    Returns
    -------
    ndarray, shape (n, 3)
        Poses ``(x, y, θ)`` at ``times``; θ is **not** wrapped (a continuous
        heading, so that differences count whole turns).
    """
    odo = odometry[["time", "v", "omega"]].to_numpy(dtype=float)
    q = np.asarray(times, dtype=float)
    if odo.shape[0] == 0 or not np.isfinite(odo).all():
        raise ValueError("dead_reckon_at: odometry must be non-empty and finite")
    if q.ndim != 1 or q.size == 0 or not np.isfinite(q).all() or np.any(np.diff(q) < 0):
        raise ValueError("dead_reckon_at: times must be a non-empty, finite, non-decreasing 1-D array")
    if np.any(np.diff(odo[:, 0]) < 0):
        raise ValueError("dead_reckon_at: odometry time goes backwards")
    knots = np.unique(np.concatenate([odo[:, 0], q]))
    knots = knots[knots <= q[-1]]
    row = np.searchsorted(odo[:, 0], knots[:-1], side="right") - 1
    u = np.where(row[:, None] >= 0, odo[np.maximum(row, 0), 1:3], 0.0)
    x0 = np.asarray(x0, dtype=float)
    path = np.vstack([x0, dead_reckon(x0, u, np.diff(knots))])
    return path[np.searchsorted(knots, q)]


def sample_motion(x, u, dt: float, noise: MotionNoise, rng: np.random.Generator) -> np.ndarray:
    """Draw new poses from ``p(x_t | x_{t-1}, u_t)``: :func:`move` with fresh normals.

    ``eps = rng.standard_normal(batch + (noise.n_draws,))`` is drawn even when the
    noise is zero, so that the random stream does not depend on the noise level.

    Parameters
    ----------
    x, u, dt, noise
        As :func:`move`.
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (M, 3) or (..., 3)
    """
    if not isinstance(rng, np.random.Generator):
        raise ValueError(
            f"rng must be a numpy.random.Generator (np.random.default_rng(seed)), got {type(rng).__name__}"
        )
    x, u = _check_poses(x, "sample_motion"), _check_controls(u, "sample_motion")
    if not isinstance(noise, MotionNoise):
        raise ValueError(f"noise must be a MotionNoise, got {type(noise).__name__}")
    batch = np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
    eps = rng.standard_normal(batch + (noise.n_draws,))
    return move(x, u, dt, noise, eps)


__all__ = ["MotionNoise", "advance", "propagate", "propagate_arc", "move", "move_segment", "segment_increments",
           "path_from_increments", "dead_reckon", "dead_reckon_at",
           "sample_motion"]
