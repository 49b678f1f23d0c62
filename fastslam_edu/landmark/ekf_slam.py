"""EKF-SLAM with known or unknown correspondences: one Gaussian over the pose and the whole map.

The baseline FastSLAM was designed to beat (*Probabilistic Robotics*, table 10.1; with
unknown correspondences, table 10.2: see "Unknown correspondences" below).
The state is the pose and all :math:`N` landmarks stacked,

.. math::

    \\mathbf y = (x, y, \\theta, l_{1,x}, l_{1,y}, \\dots, l_{N,x}, l_{N,y})^\\top, \\qquad
    \\mathbf y \\sim \\mathcal N(\\mu, \\Sigma),

with :math:`\\mu` of shape (3 + 2K,) [m, m, rad, m, ...] and :math:`\\Sigma` (3 + 2K, 3 + 2K).
Landmark :math:`k` occupies rows ``3 + 2k`` and ``4 + 2k`` (:func:`landmark_slice`).
The off-diagonal blocks are what FastSLAM does without: how the error of one
landmark is tied to the pose's and to every other landmark's.

The filter, for each step of an event stream
(:func:`fastslam_edu.datasets.events.event_stream`):

1. **Prediction** (table 10.1, lines 2–5; :func:`predict`): the pose moves by the
   unicycle of :mod:`fastslam_edu.core.motion` (Euler step, heading at the start),
   the map stays. With the Jacobian :math:`G_t = \\partial g / \\partial x` and the
   motion noise :math:`V_t M_t V_t^\\top` in pose space (noise densities per √s, as
   FastSLAM's :class:`~fastslam_edu.core.motion.MotionNoise`),

   .. math::

       \\Sigma_{xx} \\leftarrow G_t \\Sigma_{xx} G_t^\\top + V_t M_t V_t^\\top, \\qquad
       \\Sigma_{xm} \\leftarrow G_t \\Sigma_{xm} .

   Only the pose's rows and columns change: :math:`O(N)`. Between two sightings the
   steps are composed in one (:func:`predict_segment`, equal to the step-by-step
   prediction to rounding).
2. **A landmark seen for the first time** is initialised from the inverse model
   :math:`m = h^{-1}(x, z)` (:func:`add_landmark`) with its cross-covariances:
   :math:`\\Sigma_{mm} = J_x \\Sigma_{xx} J_x^\\top + G R G^\\top`, :math:`\\Sigma_{m\\cdot} = J_x \\Sigma_{x\\cdot}`
   (:math:`J_x = \\partial h^{-1}/\\partial x`, :math:`G = \\partial h^{-1}/\\partial z`), not table 10.1's
   "infinite prior".
3. **Update** (table 10.1, the loop over the sightings; :func:`update`) for each sighting
   :math:`z = (r, \\phi)` of landmark :math:`k`: :math:`\\hat z = h(\\mu_x, \\mu_k)`, the
   Jacobian :math:`H_t = \\partial h/\\partial \\mathbf y`, non-zero only in the pose's columns
   (:math:`G_x = \\partial h/\\partial x`) and landmark :math:`k`'s (:math:`H = \\partial h/\\partial m`),
   the innovation :math:`\\nu = z \\ominus \\hat z` (bearing wrapped), its covariance
   :math:`Q = H_t \\Sigma H_t^\\top + R`, the gain :math:`K = \\Sigma H_t^\\top Q^{-1}`, and

   .. math::

       \\mu \\leftarrow \\mu + K \\nu, \\qquad
       \\Sigma \\leftarrow (I - K H_t) \\Sigma (I - K H_t)^\\top + K R K^\\top

   (Joseph form: symmetric and positive semi-definite for any gain, and first-order
   insensitive to errors in :math:`K`). Every entry of :math:`\\Sigma` changes:
   :math:`O(N^2)` per sighting, the cost FastSLAM avoids (:func:`joseph_update`).
4. **The gate**: a sighting whose squared Mahalanobis distance
   :math:`d^2 = \\nu^\\top Q^{-1} \\nu` exceeds ``gate_chi2`` is set aside, with the
   escape of FastSLAM's :class:`~fastslam_edu.landmark.fastslam.Gate` (after
   ``gate_escape_s`` seconds of rejections of one landmark, its sightings are applied).

**Unknown correspondences** (``correspondences="unknown"``, table 10.2): the filter never
reads ``stream.landmark``. The map grows one landmark at a time (the state's size is
:math:`3 + 2N_t`, :math:`N_t` the landmarks made so far). For each sighting the squared
Mahalanobis distance :math:`d_k^2 = \\nu_k^\\top Q_k^{-1}\\nu_k` to every map landmark is computed
(:func:`association_distances`); the nearest one (smallest :math:`d^2`) is updated as above if
:math:`d^2 \\le \\min(` ``gate_chi2``, ``new_landmark_chi2`` :math:`)`; if :math:`d^2 >`
``new_landmark_chi2`` for *every* map landmark the sighting starts a new landmark; in between it is
set aside (too far to update, too near to be new). With ``mutual_exclusion`` the sightings of one
instant are associated jointly (:func:`associate`, an assignment problem): two sightings of one
instant never go to the same map landmark. The gate's escape does not apply (a sighting far from
everything makes a new landmark instead). The barcodes are used only after the run, to score it
as FastSLAM's associations are (:mod:`fastslam_edu.evaluation.association`): the map's landmarks
are matched one-to-one to the surveyed ones; unmatched map landmarks are *spurious*.

The noise settings are FastSLAM's (:class:`EKFSLAMParams`, defaults taken from
:class:`~fastslam_edu.landmark.fastslam.FastSLAMParams`), so that the two filters
are compared on the same model. The filter is deterministic: no random numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.checks import finite_array
from fastslam_edu.core.measurement import jacobian_inverse, jacobian_pose, landmark_from_measurement, range_bearing
from fastslam_edu.core.motion import MotionNoise, dead_reckon, propagate
from fastslam_edu.core.params import Params
from fastslam_edu.core.timing import RunTimer
from fastslam_edu.datasets.log import EventStream
from fastslam_edu.landmark.fastslam import FastSLAMParams, Gate, stream_commands
from fastslam_edu.landmark.proposal import motion_prediction, segment_motion

__all__ = [
    "EKFSLAMParams",
    "EKFSLAMState",
    "EKFSLAMResult",
    "landmark_slice",
    "motion_jacobian",
    "motion_noise_covariance",
    "predict",
    "predict_segment",
    "jacobian_inverse_pose",
    "add_landmark",
    "measurement_jacobian",
    "full_measurement_jacobian",
    "joseph_update",
    "subtract_symmetric_product",
    "update",
    "correlation_matrix",
    "association_distances",
    "associate",
    "add_new_landmark",
    "run_ekf_slam",
]

#: What :func:`update` did with a sighting.
INITIALISED, UPDATED, REJECTED = "initialised", "updated", "rejected"

#: :func:`associate`'s codes for a sighting that starts a new landmark, and one set aside.
NEW, SET_ASIDE = -1, -2

#: Default ``new_landmark_chi2``: a sighting starts a new landmark when its squared Mahalanobis distance to
#: every map landmark exceeds this (χ² with 2 degrees of freedom: a tail of 2.5e-8). Above the gate (27.6), so a
#: sighting between the two is set aside. Chosen for the mean association accuracy over MR.CLAM Dataset 1 robot 2
#: and Dataset 6 robots 1–5 (9.2 … 60 tried, one value for all robots); the differences near it are small.
NEW_LANDMARK_CHI2 = 35.0


def _fastslam_default(name: str):
    """A default factory reading FastSLAMParams()'s field ``name`` (one source for the shared defaults)."""
    return lambda: getattr(FastSLAMParams(), name)


@dataclass(frozen=True, eq=False)
class EKFSLAMParams(Params):
    """Settings of EKF-SLAM: FastSLAM's noise model and gate, with FastSLAM's defaults.

    Attributes
    ----------
    motion_noise : MotionNoise
        Noise densities per √s (control mode: on :math:`(v, \\omega)`; state mode: on the pose).
    measurement_cov : ndarray (2, 2)
        :math:`R = \\mathrm{diag}(\\sigma_r^2, \\sigma_\\phi^2)` [m², rad²] at range 0.
    range_std_slope : float
        :math:`\\sigma_r(r) = \\sqrt{R_{00}} + \\text{slope}\\cdot r` [m/m] (:meth:`measurement_covariance`).
    gate_chi2 : float or None
        Reject a sighting with :math:`d^2 = \\nu^\\top Q^{-1}\\nu >` ``gate_chi2``; None: no gate.
    gate_escape_s : float or None
        After this many seconds [s] of rejections of one landmark, apply its sightings
        (:class:`fastslam_edu.landmark.fastslam.Gate`); None: never.
    odometry_scale : (float, float)
        The filter moves with :math:`(k_v v, k_\\omega \\omega)`.
    correspondences : "known" or "unknown"
        "known": ``stream.landmark`` says which landmark each sighting sees (table 10.1). "unknown":
        the filter associates by Mahalanobis nearest neighbour (table 10.2) and never reads it.
    new_landmark_chi2 : float
        Unknown correspondences: a sighting whose :math:`d^2` to every map landmark exceeds this
        starts a new landmark (table 10.2's :math:`\\alpha`).
    mutual_exclusion : bool
        Unknown correspondences: the sightings of one instant go to distinct map landmarks.
    new_landmark_max_range : float or None
        Unknown correspondences: a sighting farther than this [m] never starts a landmark (it is set
        aside: far sightings place a landmark too loosely to tell it from its neighbours); None: no limit
        (the default: limits of 2.5 m and 4 m lowered the association accuracy on MR.CLAM).

    FastSLAM's tempering (``measurement_correlation_s``) acts on particle weights, which
    EKF-SLAM does not have; its particle and resampling settings do not apply either.
    """

    motion_noise: MotionNoise = field(default_factory=_fastslam_default("motion_noise"))
    measurement_cov: np.ndarray = field(default_factory=_fastslam_default("measurement_cov"))
    range_std_slope: float = field(default_factory=_fastslam_default("range_std_slope"))
    gate_chi2: float | None = field(default_factory=_fastslam_default("gate_chi2"))
    gate_escape_s: float | None = field(default_factory=_fastslam_default("gate_escape_s"))
    odometry_scale: tuple[float, float] = field(default_factory=_fastslam_default("odometry_scale"))
    correspondences: str = "known"
    new_landmark_chi2: float = NEW_LANDMARK_CHI2
    mutual_exclusion: bool = True
    new_landmark_max_range: float | None = None

    def __post_init__(self):
        # FastSLAMParams checks the shared fields, with the same messages
        as_fastslam = self.to_fastslam()
        object.__setattr__(self, "measurement_cov", as_fastslam.measurement_cov)
        scale = np.asarray(self.odometry_scale, dtype=float)
        if scale.shape != (2,) or not np.isfinite(scale).all():
            raise ValueError(f"odometry_scale must be two finite numbers (k_v, k_omega), got {self.odometry_scale!r}")
        if self.correspondences not in ("known", "unknown"):
            raise ValueError(f'correspondences must be "known" or "unknown", got {self.correspondences!r}')
        a = self.new_landmark_chi2
        if isinstance(a, bool) or not isinstance(a, (int, float, np.integer, np.floating)) or not np.isfinite(a) \
                or a <= 0:
            raise ValueError(f"new_landmark_chi2 must be a finite number > 0, got {a!r}")
        r = self.new_landmark_max_range
        if r is not None and (isinstance(r, bool) or not isinstance(r, (int, float, np.integer, np.floating))
                              or not np.isfinite(r) or r <= 0):
            raise ValueError(f"new_landmark_max_range must be a finite number > 0 or None, got {r!r}")
        if not isinstance(self.mutual_exclusion, (bool, np.bool_)):
            raise ValueError(f"mutual_exclusion must be True or False, got {self.mutual_exclusion!r}")

    @classmethod
    def from_fastslam(cls, params: FastSLAMParams) -> "EKFSLAMParams":
        """The EKF-SLAM settings that share ``params``' noise model, gate and odometry scale."""
        if not isinstance(params, FastSLAMParams):
            raise ValueError(f"from_fastslam expects FastSLAMParams, got {type(params).__name__}")
        return cls(motion_noise=params.motion_noise, measurement_cov=params.measurement_cov,
                   range_std_slope=params.range_std_slope, gate_chi2=params.gate_chi2,
                   gate_escape_s=params.gate_escape_s, odometry_scale=params.odometry_scale)

    def to_fastslam(self) -> FastSLAMParams:
        """FastSLAMParams() with this noise model, gate and odometry scale (validates them)."""
        return FastSLAMParams().replace(motion_noise=self.motion_noise, measurement_cov=self.measurement_cov,
                                        range_std_slope=self.range_std_slope, gate_chi2=self.gate_chi2,
                                        gate_escape_s=self.gate_escape_s, odometry_scale=self.odometry_scale)

    def measurement_covariance(self, z) -> np.ndarray:
        """:math:`R` for each measurement ``z`` (n, 2): shape (n, 2, 2), as FastSLAM's."""
        return self.to_fastslam().measurement_covariance(z)


# ---------------------------------------------------------------- the state


def landmark_slice(k: int) -> slice:
    """Rows of landmark ``k`` in the state: ``3 + 2k`` and ``4 + 2k``."""
    return slice(3 + 2 * k, 5 + 2 * k)


@dataclass
class EKFSLAMState:
    """The joint Gaussian :math:`\\mathcal N(\\mu, \\Sigma)` over pose and map.

    Attributes
    ----------
    mu : ndarray (3 + 2K,)
        :math:`\\mu`: pose ``(x, y, θ)`` [m, m, rad] then ``(m_x, m_y)`` [m] per landmark.
    sigma : ndarray (3 + 2K, 3 + 2K)
        :math:`\\Sigma`; the rows and columns of landmarks not yet seen are zero.
    seen : ndarray (N,) bool
        Landmark ``k`` has been initialised.
    """

    mu: np.ndarray
    sigma: np.ndarray
    seen: np.ndarray

    @classmethod
    def initial(cls, n_landmarks: int, x0, pose_cov=None) -> "EKFSLAMState":
        """Pose ``x0`` (3,), covariance ``pose_cov`` (3, 3) (default 0: the start defines the frame), no landmark."""
        if isinstance(n_landmarks, bool) or not isinstance(n_landmarks, (int, np.integer)) or n_landmarks < 0:
            raise ValueError(f"n_landmarks must be an integer >= 0, got {n_landmarks!r}")
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (3,) or not np.isfinite(x0).all():
            raise ValueError(f"initial pose must be 3 finite numbers (x, y, theta), got {x0!r}")
        n = 3 + 2 * int(n_landmarks)
        mu, sigma = np.zeros(n), np.zeros((n, n))
        mu[:3] = x0[0], x0[1], wrap_angle(x0[2])
        if pose_cov is not None:
            P0 = np.asarray(pose_cov, dtype=float)
            if P0.shape != (3, 3) or not np.isfinite(P0).all() or not np.allclose(P0, P0.T) \
                    or np.linalg.eigvalsh(P0).min() < 0:
                raise ValueError(f"pose_cov must be a symmetric positive semi-definite 3x3 matrix, got {pose_cov!r}")
            sigma[:3, :3] = P0
        return cls(mu=mu, sigma=sigma, seen=np.zeros(int(n_landmarks), dtype=bool))

    @property
    def n_landmarks(self) -> int:
        return len(self.seen)

    @property
    def pose(self) -> np.ndarray:
        """:math:`\\mu_x` (3,) [m, m, rad] (a copy)."""
        return self.mu[:3].copy()

    @property
    def pose_cov(self) -> np.ndarray:
        """:math:`\\Sigma_{xx}` (3, 3) (a copy)."""
        return self.sigma[:3, :3].copy()

    def landmarks(self) -> tuple[np.ndarray, np.ndarray]:
        """Means (N, 2) [m] and marginal covariances (N, 2, 2) [m²]; NaN for landmarks not seen."""
        N = self.n_landmarks
        mu = self.mu[3:].reshape(N, 2).copy()
        idx = 3 + 2 * np.arange(N)
        cov = np.empty((N, 2, 2))
        for a in range(2):
            for b in range(2):
                cov[:, a, b] = self.sigma[idx + a, idx + b]
        mu[~self.seen] = np.nan
        cov[~self.seen] = np.nan
        return mu, cov

    def copy(self) -> "EKFSLAMState":
        return EKFSLAMState(self.mu.copy(), self.sigma.copy(), self.seen.copy())


# ---------------------------------------------------------------- 1. prediction


def motion_jacobian(x, u, dt: float) -> np.ndarray:
    """:math:`G_t = \\partial g / \\partial x` of the Euler step at pose ``x`` (3,) with ``u = (v, ω)`` over ``dt`` s.

    ::

        G_t = [[1, 0, -v Δt sin θ],
               [0, 1,  v Δt cos θ],
               [0, 0,  1         ]]

    Returns (3, 3); the third column is in m/rad.
    """
    theta, ds = float(x[2]), float(u[0]) * float(dt)
    return np.array([[1.0, 0.0, -ds * np.sin(theta)], [0.0, 1.0, ds * np.cos(theta)], [0.0, 0.0, 1.0]])


def motion_noise_covariance(x, dt: float, noise: MotionNoise) -> np.ndarray:
    """The motion noise of one step in pose space, :math:`V_t M_t V_t^\\top` (3, 3).

    Control mode (noise on the distance :math:`\\Delta s` and turn :math:`\\Delta\\theta`):
    :math:`M_t = \\mathrm{diag}(\\sigma_v^2 \\Delta t, \\sigma_\\omega^2 \\Delta t)` [m², rad²] and
    :math:`V_t = \\partial g/\\partial(\\Delta s, \\Delta\\theta) = [[\\cos\\theta, 0], [\\sin\\theta, 0], [0, 1]]`.
    State mode: :math:`\\mathrm{diag}(\\sigma_{xy}^2, \\sigma_{xy}^2, \\sigma_\\theta^2)\\,\\Delta t`.
    """
    if noise.mode == "control":
        theta = float(x[2])
        V = np.array([[np.cos(theta), 0.0], [np.sin(theta), 0.0], [0.0, 1.0]])
        return V @ np.diag([noise.sigma_v**2 * dt, noise.sigma_omega**2 * dt]) @ V.T
    return np.diag([noise.sigma_xy**2, noise.sigma_xy**2, noise.sigma_theta**2]) * dt


def _move_pose_block(state: EKFSLAMState, G: np.ndarray, Q: np.ndarray) -> None:
    """:math:`\\Sigma_{xx} \\leftarrow G\\Sigma_{xx}G^\\top + Q`, :math:`\\Sigma_{xm} \\leftarrow G\\Sigma_{xm}` (in place).

    ``G``, ``Q`` (3, 3); :math:`\\Sigma_{mx}` is set to the transpose, :math:`\\Sigma_{xx}` made exactly symmetric.
    """
    S = state.sigma
    S[:3, :3] = _symmetric(G @ S[:3, :3] @ G.T + Q)
    S[:3, 3:] = G @ S[:3, 3:]
    S[3:, :3] = S[:3, 3:].T


def _symmetric(A: np.ndarray) -> np.ndarray:
    """:math:`(A + A^\\top)/2`: exactly symmetric in floating point (rounding leaves products slightly off)."""
    return 0.5 * (A + A.T)


def predict(state: EKFSLAMState, u, dt: float, noise: MotionNoise) -> EKFSLAMState:
    """Table 10.1, lines 2–5: one step of the motion model, in place (returns ``state``).

    :math:`\\mu_x \\leftarrow g(\\mu_x, u)` (:func:`fastslam_edu.core.motion.propagate`, heading wrapped),
    then :func:`motion_jacobian` and :func:`motion_noise_covariance` on the pose's rows and columns.

    Parameters
    ----------
    u : (2,) command ``(v [m/s], ω [rad/s])``; dt : step [s], >= 0; noise : MotionNoise.
    """
    if not isinstance(noise, MotionNoise):
        raise ValueError(f"noise must be a MotionNoise, got {type(noise).__name__}")
    x = state.mu[:3].copy()
    state.mu[:3] = propagate(x, u, dt)  # checks u and dt
    _move_pose_block(state, motion_jacobian(x, u, dt), motion_noise_covariance(x, dt, noise))
    return state


def predict_segment(state: EKFSLAMState, u, dt, noise: MotionNoise) -> np.ndarray:
    """:func:`predict` through ``L`` steps at once, in place; returns the mean pose after each step (L, 3).

    The product of the steps' Jacobians is :math:`[[1, 0, -(y_L - y_0)], [0, 1, x_L - x_0], [0, 0, 1]]`
    (the whole path turns about its start), and their noises add up as
    :func:`fastslam_edu.landmark.proposal.segment_motion` computes: the result equals ``L`` calls of
    :func:`predict` to rounding, at the cost of one.

    Parameters
    ----------
    u : (L, 2) commands; dt : (L,) steps [s]; noise : MotionNoise.
    """
    if not isinstance(noise, MotionNoise):
        raise ValueError(f"noise must be a MotionNoise, got {type(noise).__name__}")
    u = finite_array("u", u, "predict_segment", (2,)).reshape(-1, 2)
    dt = finite_array("dt", dt, "predict_segment").reshape(-1)
    if len(dt) != len(u) or len(dt) == 0 or (dt < 0).any():
        raise ValueError(f"predict_segment: u (L, 2) and dt (L,) with L >= 1 and dt >= 0, got {u.shape}, {dt.shape}")
    x0 = state.mu[:3].copy()
    path = dead_reckon(x0, u, dt)
    x_end = path[-1]
    G = np.array([[1.0, 0.0, -(x_end[1] - x0[1])], [0.0, 1.0, x_end[0] - x0[0]], [0.0, 0.0, 1.0]])
    _, Q = motion_prediction(x0[None], *segment_motion(u, dt, noise))
    state.mu[:3] = x_end[0], x_end[1], wrap_angle(x_end[2])
    _move_pose_block(state, G, Q[0])
    path[:, 2] = wrap_angle(path[:, 2])
    return path


# ---------------------------------------------------------------- 2. a new landmark


def jacobian_inverse_pose(x, z) -> np.ndarray:
    """:math:`J_x = \\partial h^{-1}/\\partial x` (2, 3) of the inverse model with respect to the pose.

    ::

        J_x = [[1, 0, -r sin(φ + θ)],
               [0, 1,  r cos(φ + θ)]]
    """
    x = finite_array("x", x, "jacobian_inverse_pose", (3,))
    z = finite_array("z", z, "jacobian_inverse_pose", (2,))
    angle = z[..., 1] + x[..., 2]
    r = z[..., 0]
    one, zero = np.ones_like(r), np.zeros_like(r)
    return np.stack((np.stack((one, zero, -r * np.sin(angle)), axis=-1),
                     np.stack((zero, one, r * np.cos(angle)), axis=-1)), axis=-2)


def add_landmark(state: EKFSLAMState, z, k: int, R) -> EKFSLAMState:
    """Initialise landmark ``k`` from sighting ``z = (r, φ)`` (2,) with noise ``R`` (2, 2), in place.

    :math:`\\mu_k = h^{-1}(\\mu_x, z)`; :math:`\\Sigma_{kk} = J_x \\Sigma_{xx} J_x^\\top + G R G^\\top`
    and :math:`\\Sigma_{k\\cdot} = J_x \\Sigma_{x\\cdot}` (the landmark inherits the pose's error).
    Cost :math:`O(N)`.
    """
    _check_landmark(state, k, "add_landmark")
    x = state.mu[:3]
    Jx, G = jacobian_inverse_pose(x, z), jacobian_inverse(x, z)
    s = landmark_slice(k)
    S = state.sigma
    state.mu[s] = landmark_from_measurement(x, z)
    S[s, :] = Jx @ S[:3, :]
    S[:, s] = S[s, :].T
    S[s, s] = _symmetric(Jx @ S[:3, :3] @ Jx.T + G @ R @ G.T)
    state.seen[k] = True
    return state


# ---------------------------------------------------------------- 3. the update


def measurement_jacobian(state: EKFSLAMState, k: int):
    """:math:`\\hat z = h(\\mu_x, \\mu_k)` (2,) and the non-zero blocks of :math:`H_t`: :math:`G_x` (2, 3), :math:`H` (2, 2).

    The full :math:`H_t` (2, 3 + 2K) is :math:`G_x` in the pose's columns, :math:`H` in landmark
    ``k``'s, zero elsewhere (:func:`full_measurement_jacobian`).
    """
    x, m = state.mu[:3], state.mu[landmark_slice(k)]
    Gx = jacobian_pose(x, m)
    return range_bearing(x, m), Gx, -Gx[:, :2]  # ∂h/∂m = −∂h/∂(x, y): only the offset m − (x, y) counts


def full_measurement_jacobian(state: EKFSLAMState, k: int) -> np.ndarray:
    """:math:`H_t = \\partial h / \\partial y` (2, 3 + 2K) as a dense matrix (for teaching and checks)."""
    _, Gx, H = measurement_jacobian(state, k)
    Ht = np.zeros((2, len(state.mu)))
    Ht[:, :3], Ht[:, landmark_slice(k)] = Gx, H
    return Ht


def joseph_update(sigma: np.ndarray, gain: np.ndarray, sigma_Ht: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """Joseph form :math:`\\Sigma \\leftarrow (I - KH_t)\\Sigma(I - KH_t)^\\top + KRK^\\top` in place, in O(n²).

    With :math:`C = \\Sigma H_t^\\top` (n, 2) and :math:`Q = H_t\\Sigma H_t^\\top + R` (2, 2) the Joseph
    form expands to :math:`\\Sigma - K C^\\top - C K^\\top + K Q K^\\top
    = \\Sigma - (A B^\\top + B A^\\top)` with :math:`A = K`, :math:`B = C - \\tfrac12 K Q`: a symmetric
    rank-4 change, applied entry by entry in one pass (:func:`subtract_symmetric_product`).
    :math:`H_t` (2, n) is never formed; every entry of :math:`\\Sigma` is read and written once —
    the :math:`O(N^2)` memory traffic of an EKF-SLAM update.

    Parameters
    ----------
    sigma : (n, n) symmetric, updated in place; gain : (n, 2) :math:`K`; sigma_Ht : (n, 2) :math:`C`; Q : (2, 2).
    """
    B = sigma_Ht - 0.5 * gain @ Q
    subtract_symmetric_product(sigma, np.ascontiguousarray(gain), np.ascontiguousarray(B))
    return sigma


@njit(cache=True)
def subtract_symmetric_product(sigma, A, B):
    """:math:`\\Sigma_{ij} \\leftarrow \\Sigma_{ij} - (a_i \\cdot b_j + b_i \\cdot a_j)` for all i, j, in place.

    ``sigma`` (n, n), ``A``, ``B`` (n, r). Entry (j, i) adds the same two products in the other
    order, and floating-point addition commutes: a symmetric :math:`\\Sigma` stays exactly symmetric.
    """
    n, r = A.shape
    for i in range(n):
        for j in range(n):
            ab = 0.0
            ba = 0.0
            for c in range(r):
                ab += A[i, c] * B[j, c]
                ba += B[i, c] * A[j, c]
            sigma[i, j] -= ab + ba


def update(state: EKFSLAMState, z, k: int, R, *, gate_chi2: float | None = None, escape: bool = False) -> str:
    """Table 10.1's loop body for one sighting ``z = (r, φ)`` (2,) of landmark ``k`` with noise ``R`` (2, 2).

    A landmark not seen yet is initialised (:func:`add_landmark`). Otherwise
    :math:`\\nu = z \\ominus h(\\mu_x, \\mu_k)`, :math:`Q = H_t\\Sigma H_t^\\top + R`,
    :math:`K = \\Sigma H_t^\\top Q^{-1}`, :math:`\\mu \\leftarrow \\mu + K\\nu` (heading wrapped),
    and :func:`joseph_update`; unless :math:`d^2 = \\nu^\\top Q^{-1}\\nu >` ``gate_chi2`` and not
    ``escape``: then nothing changes.

    Returns ``"initialised"``, ``"updated"`` or ``"rejected"``.
    """
    _check_landmark(state, k, "update")
    z = finite_array("z", z, "update", (2,)).reshape(2)
    R = finite_array("R", R, "update", (2, 2)).reshape(2, 2)
    if z[0] < 0:
        raise ValueError(f"update: negative range r = {z[0]} m in z = {z.tolist()} (z must be (r, φ))")
    return _update(state, z, k, R, gate_chi2, escape)


def _update(state: EKFSLAMState, z: np.ndarray, k: int, R: np.ndarray, gate_chi2, escape: bool) -> str:
    """:func:`update` without the checks of its arguments (the run checks the stream once)."""
    if not state.seen[k]:
        add_landmark(state, z, k, R)
        return INITIALISED
    z_hat, Gx, H = measurement_jacobian(state, k)
    s, S = landmark_slice(k), state.sigma
    sigma_Ht = S[:, :3] @ Gx.T + S[:, s] @ H.T  # C = Σ H_tᵀ, (n, 2)
    Q = Gx @ sigma_Ht[:3] + H @ sigma_Ht[s] + R
    nu = z - z_hat  # ν = z ⊖ ẑ (fastslam_edu.core.measurement.innovation, without its checks)
    nu[1] = wrap_angle(nu[1])
    Q_inv = np.linalg.inv(Q)
    if gate_chi2 is not None and not escape and float(nu @ Q_inv @ nu) > gate_chi2:
        return REJECTED
    gain = sigma_Ht @ Q_inv
    state.mu += gain @ nu
    state.mu[2] = wrap_angle(state.mu[2])
    joseph_update(S, gain, sigma_Ht, Q)
    return UPDATED


def _check_landmark(state: EKFSLAMState, k, caller: str) -> None:
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k < state.n_landmarks:
        raise ValueError(f"{caller}: landmark index k must be an integer in [0, {state.n_landmarks}), got {k!r}")


def correlation_matrix(sigma) -> np.ndarray:
    """:math:`\\rho_{ij} = \\Sigma_{ij} / \\sqrt{\\Sigma_{ii}\\Sigma_{jj}}` (n, n); rows of zero variance give NaN."""
    sigma = np.asarray(sigma, dtype=float)
    sd = np.sqrt(np.clip(np.diag(sigma), 0.0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = sigma / np.outer(sd, sd)
    rho[(sd == 0)[:, None] | (sd == 0)[None, :]] = np.nan
    return rho


# ---------------------------------------------------------------- 5. unknown correspondences (table 10.2)


def association_distances(state: EKFSLAMState, z, R) -> np.ndarray:
    """Squared Mahalanobis distances :math:`d_k^2 = \\nu_k^\\top Q_k^{-1}\\nu_k` of sighting ``z`` (2,) to every map landmark.

    :math:`\\nu_k = z \\ominus h(\\mu_x, \\mu_k)` and :math:`Q_k = H_t^k \\Sigma H_t^{k\\top} + R` as in
    :func:`update`, for all seen landmarks at once (only the pose's and landmark :math:`k`'s blocks of
    :math:`\\Sigma` enter: :math:`O(N)`). Returns (N,); ``inf`` for landmarks not seen (and for one the
    robot stands on).
    """
    z = finite_array("z", z, "association_distances", (2,)).reshape(2)
    R = finite_array("R", R, "association_distances", (2, 2)).reshape(2, 2)
    N = state.n_landmarks
    d2 = np.full(N, np.inf)
    idx = np.flatnonzero(state.seen)
    if idx.size == 0:
        return d2
    x = state.mu[:3]
    m = state.mu[3:].reshape(N, 2)[idx]
    dx, dy = m[:, 0] - x[0], m[:, 1] - x[1]
    q = dx * dx + dy * dy
    ok = q > 0
    idx, dx, dy, q = idx[ok], dx[ok], dy[ok], q[ok]
    r = np.sqrt(q)
    zero, one = np.zeros_like(r), np.ones_like(r)
    # J = [G_x | H] (n, 2, 5): the pose's columns, then the landmark's (H = -G_x[:, :2])
    J = np.stack((np.stack((-dx / r, -dy / r, zero, dx / r, dy / r), axis=-1),
                  np.stack((dy / q, -dx / q, -one, -dy / q, dx / q), axis=-1)), axis=-2)
    rows = np.concatenate((np.broadcast_to([0, 1, 2], (len(idx), 3)),
                           np.stack((3 + 2 * idx, 4 + 2 * idx), axis=-1)), axis=1)  # (n, 5)
    S = state.sigma[rows[:, :, None], rows[:, None, :]]  # (n, 5, 5)
    Q = J @ S @ np.swapaxes(J, -1, -2) + R
    nu = np.stack((z[0] - r, wrap_angle(z[1] - (np.arctan2(dy, dx) - x[2]))), axis=-1)
    d2[idx] = np.einsum("ni,ni->n", nu, np.linalg.solve(Q, nu[..., None])[..., 0])
    return d2


def associate(d2: np.ndarray, new_landmark_chi2: float, gate_chi2: float | None = None,
              mutual_exclusion: bool = True) -> np.ndarray:
    """Table 10.2's choice for each sighting of one instant, from their distances ``d2`` (n, N).

    For each sighting: the map landmark ``k`` it updates (>= 0), :data:`NEW` (-1: its :math:`d^2` to
    every map landmark exceeds ``new_landmark_chi2``) or :data:`SET_ASIDE` (-2: no landmark within
    :math:`\\min(` ``gate_chi2``, ``new_landmark_chi2`` :math:`)`, but one within ``new_landmark_chi2``).
    Without ``mutual_exclusion``: the nearest landmark of each sighting. With it: the assignment of
    sightings to distinct landmarks (or "new") that minimises the summed :math:`d^2`, a new landmark
    costing ``new_landmark_chi2`` (:func:`scipy.optimize.linear_sum_assignment`). Returns (n,) int.
    """
    d2 = np.atleast_2d(np.asarray(d2, dtype=float))
    n, N = d2.shape
    limit = new_landmark_chi2 if gate_chi2 is None else min(gate_chi2, new_landmark_chi2)
    nearest = d2.min(axis=1) if N else np.full(n, np.inf)
    out = np.where(nearest > new_landmark_chi2, NEW, SET_ASIDE)
    if not mutual_exclusion or n == 1:
        k = d2.argmin(axis=1) if N else np.zeros(n, dtype=int)
        return np.where(nearest <= limit, k, out)
    from scipy.optimize import linear_sum_assignment

    big = 1e6 * (new_landmark_chi2 + 1.0)
    cost = np.full((n, N + n), big)
    cost[:, :N] = np.where(d2 <= limit, d2, big)
    cost[np.arange(n), N + np.arange(n)] = new_landmark_chi2  # sighting i's own "new landmark" slot
    rows, cols = linear_sum_assignment(cost)
    for i, c in zip(rows, cols):
        if c < N and cost[i, c] < big:
            out[i] = c
    return out


def add_new_landmark(state: EKFSLAMState, z, R) -> int:
    """Grow the state by one landmark (two rows and columns) and initialise it from ``z`` (:func:`add_landmark`).

    Returns its index. The copy costs :math:`O(N^2)`, paid once per landmark.
    """
    N = state.n_landmarks
    n = len(state.mu)
    mu, sigma = np.zeros(n + 2), np.zeros((n + 2, n + 2))
    mu[:n], sigma[:n, :n] = state.mu, state.sigma
    state.mu, state.sigma, state.seen = mu, sigma, np.append(state.seen, False)
    add_landmark(state, z, N, R)
    return N


# ---------------------------------------------------------------- the run


@dataclass
class EKFSLAMResult:
    """What :func:`run_ekf_slam` produces (the fields the scorers of FastSLAM's result read, and the joint Gaussian).

    Attributes
    ----------
    t : (T,) step times [s]
    pose_mean : (T, 3) :math:`\\mu_x` after each step (after the update at a measurement step)
    landmarks_mean, landmarks_cov, observed : (N, 2), (N, 2, 2), (N,) the map at the end (NaN where not seen)
    mean, cov : (3 + 2K,), (3 + 2K, 3 + 2K) the final joint :math:`\\mu`, :math:`\\Sigma`
    update_t, pose_cov : (n,), (n, 3, 3) time and :math:`\\Sigma_{xx}` after each measurement step
    measurements_used, measurements_rejected : counts (initialisations count as used)
    filter_seconds : wall time of the filter loop, without ``compile_seconds``
    compile_seconds : wall time numba spent compiling (or loading from its cache) the loop's kernels
    params, landmark_subjects : the settings; the subject of each landmark index
    correspondences : "known" or "unknown"
    sighting_map : (n,) int, the map landmark each sighting of the stream updated or started (< 0: set aside)
    map_mean, map_cov : (n, 2), (n, 2, 2) the filter's own map, in the order its landmarks were made

    With unknown correspondences ``landmarks_mean``, ``landmarks_cov`` are the filter's own map
    (``map_mean``, ``map_cov``, all ``observed``): which surveyed landmark each one is, is for a
    scorer to find (:func:`fastslam_edu.evaluation.association.match_landmarks`). ``history``,
    ``landmarks`` and ``landmark_ident`` name them as FastSLAM's result with unknown correspondences
    does (:class:`fastslam_edu.landmark.association.AssociationResult`).
    """

    t: np.ndarray
    pose_mean: np.ndarray
    landmarks_mean: np.ndarray
    landmarks_cov: np.ndarray
    observed: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    update_t: np.ndarray
    pose_cov: np.ndarray
    measurements_used: int
    measurements_rejected: int
    filter_seconds: float
    params: EKFSLAMParams
    landmark_subjects: np.ndarray
    correspondences: str = "known"
    sighting_map: np.ndarray | None = None
    map_mean: np.ndarray | None = None
    map_cov: np.ndarray | None = None
    compile_seconds: float = 0.0

    @property
    def history(self) -> np.ndarray:
        """The map landmark each sighting went to (< 0: set aside): ``sighting_map``."""
        return self.sighting_map

    @property
    def landmarks(self) -> np.ndarray:
        """The filter's map (n, 2), in the order its landmarks were made: ``map_mean``."""
        return self.map_mean

    @property
    def landmark_ident(self) -> np.ndarray:
        """The identity of each map landmark: its index."""
        return np.arange(len(self.map_mean))


def _measurement_steps(stream: EventStream):
    """Segments ``(s, e, measured)``: steps ``s..e`` end at a measurement step (or at the stream's end)."""
    ends = np.flatnonzero(np.diff(stream.offsets) > 0).tolist()
    if not ends or ends[-1] != len(stream) - 1:
        ends.append(len(stream) - 1)
    start = 0
    for e in ends:
        yield start, e, bool(stream.offsets[e + 1] > stream.offsets[e])
        start = e + 1


def _check_stream(stream: EventStream, unknown: bool) -> None:
    if not isinstance(stream, EventStream):
        raise ValueError(f"run_ekf_slam expects an EventStream, got {type(stream).__name__}")
    if len(stream) == 0:
        raise ValueError("the event stream is empty")
    lm = np.asarray(stream.landmark)
    if not unknown and lm.size and (lm.min() < 0 or lm.max() >= stream.n_landmarks):
        raise ValueError(f"the event stream sees landmark indices outside [0, {stream.n_landmarks})")
    z = finite_array("z", stream.z, "run_ekf_slam", (2,))
    if (z[:, 0] < 0).any():
        raise ValueError(f"run_ekf_slam: the event stream has negative ranges (row {int(np.argmax(z[:, 0] < 0))})")


def run_ekf_slam(stream: EventStream, params: EKFSLAMParams | FastSLAMParams = EKFSLAMParams(), *, x0=None,
                 pose_cov0=None, correspondences: str | None = None) -> EKFSLAMResult:
    """Run EKF-SLAM over an event stream, with known (table 10.1) or unknown (table 10.2) correspondences.

    For each segment of steps ending at a measurement step: :func:`predict_segment`,
    then for each sighting of the step in order, with :math:`R` = ``params.measurement_covariance(z)``:

    * known correspondences: :func:`update` of landmark ``stream.landmark[j]``, with the gate;
    * unknown: :func:`associate` (the sightings of the step jointly if ``params.mutual_exclusion``,
      on the distances before the step's updates; otherwise one by one, each after the previous
      update), then :func:`update` of the chosen landmark or :func:`add_new_landmark`.
      ``stream.landmark`` is not read (:mod:`fastslam_edu.evaluation.association` scores the run).

    Parameters
    ----------
    stream : EventStream
        From :func:`fastslam_edu.datasets.events.event_stream`; ``stream.landmark`` are the correspondences
        (known) or the truth used only to score (unknown).
    params : EKFSLAMParams, or FastSLAMParams (its noise model and gate are used: :meth:`EKFSLAMParams.from_fastslam`)
    x0 : (3,) initial pose; default ``stream.x0``.
    pose_cov0 : (3, 3) its covariance; default 0.
    correspondences : "known", "unknown" or None (default: ``params.correspondences``).
    """
    if isinstance(params, FastSLAMParams):
        params = EKFSLAMParams.from_fastslam(params)
    if not isinstance(params, EKFSLAMParams):
        raise ValueError(f"params must be EKFSLAMParams (or FastSLAMParams), got {type(params).__name__}")
    if correspondences is not None:
        params = params.replace(correspondences=correspondences)  # checks the value
    unknown = params.correspondences == "unknown"
    _check_stream(stream, unknown)
    x0 = stream.x0 if x0 is None else x0
    if x0 is None:
        raise ValueError("no initial pose: the stream has no groundtruth; pass x0=(x, y, theta)")
    state = EKFSLAMState.initial(0 if unknown else stream.n_landmarks, x0, pose_cov0)
    u, dt = stream_commands(stream, params)
    z_all = np.asarray(stream.z, dtype=float)
    R_all = params.measurement_covariance(z_all)
    gate = Gate(params.gate_chi2, params.gate_escape_s, stream.n_landmarks)
    T = len(stream)
    pose_mean = np.empty((T, 3))
    sighting_map = np.full(len(z_all), SET_ASIDE)
    update_t, pose_cov, counts = [], [], {INITIALISED: 0, UPDATED: 0, REJECTED: 0}
    with RunTimer() as timer:  # filter_seconds without numba's compiling (compile_seconds)
        _filter_loop(state, stream, u, dt, z_all, R_all, params, gate, unknown, pose_mean, sighting_map, update_t,
                     pose_cov, counts)
    map_mean, map_cov = state.landmarks()
    mu, cov, observed = map_mean, map_cov, state.seen.copy()
    return EKFSLAMResult(
        t=np.asarray(stream.t, dtype=float), pose_mean=pose_mean, landmarks_mean=mu, landmarks_cov=cov,
        observed=observed, mean=state.mu, cov=state.sigma, update_t=np.asarray(update_t),
        pose_cov=np.asarray(pose_cov).reshape(-1, 3, 3), measurements_used=counts[INITIALISED] + counts[UPDATED],
        measurements_rejected=counts[REJECTED], filter_seconds=timer.filter_seconds, params=params,
        compile_seconds=timer.compile_seconds,
        landmark_subjects=np.asarray(stream.landmark_subjects), correspondences=params.correspondences,
        sighting_map=sighting_map, map_mean=map_mean, map_cov=map_cov,
    )


def _filter_loop(state, stream, u, dt, z_all, R_all, params, gate, unknown, pose_mean, sighting_map, update_t,
                 pose_cov, counts):
    """Prediction and update over the whole stream (in place on ``state`` and the record arrays)."""
    for s, e, measured in _measurement_steps(stream):
        pose_mean[s : e + 1] = predict_segment(state, u[s : e + 1], dt[s : e + 1], params.motion_noise)
        if not measured:
            continue
        t = float(stream.t[e])
        if unknown:
            _associate_and_update(state, z_all, R_all, range(stream.offsets[e], stream.offsets[e + 1]), params,
                                  sighting_map, counts)
        else:
            for j in range(stream.offsets[e], stream.offsets[e + 1]):
                k = int(stream.landmark[j])
                outcome = _update(state, z_all[j], k, R_all[j], gate.chi2, bool(gate.escaped(t, [k])[0]))
                gate.record(t, [k], [outcome != REJECTED])
                counts[outcome] += 1
                if outcome != REJECTED:
                    sighting_map[j] = k
        pose_mean[e] = state.mu[:3]
        update_t.append(t)
        pose_cov.append(state.sigma[:3, :3].copy())


def _associate_and_update(state: EKFSLAMState, z_all, R_all, rows, params: EKFSLAMParams, sighting_map, counts):
    """Table 10.2 for the sightings ``rows`` of one instant (in place; fills ``sighting_map`` and ``counts``)."""
    rows = list(rows)
    joint = params.mutual_exclusion and len(rows) > 1
    if joint:
        d2 = np.stack([association_distances(state, z_all[j], R_all[j]) for j in rows])
        choice = associate(d2, params.new_landmark_chi2, params.gate_chi2, True)
    for i, j in enumerate(rows):
        if joint:
            c = int(choice[i])
        else:
            c = int(associate(association_distances(state, z_all[j], R_all[j])[None], params.new_landmark_chi2,
                              params.gate_chi2, False)[0])
        if c == NEW and params.new_landmark_max_range is not None and z_all[j, 0] > params.new_landmark_max_range:
            c = SET_ASIDE
        if c == NEW:
            sighting_map[j] = add_new_landmark(state, z_all[j], R_all[j])
            counts[INITIALISED] += 1
        elif c == SET_ASIDE:
            counts[REJECTED] += 1
        else:
            _update(state, z_all[j], c, R_all[j], None, True)
            sighting_map[j] = c
            counts[UPDATED] += 1
