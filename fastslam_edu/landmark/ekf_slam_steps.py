"""EKF-SLAM's joint Gaussian over pose and map, and its steps (*Probabilistic Robotics*, table 10.1).

The state :class:`EKFSLAMState` is :math:`\\mathcal N(\\mu, \\Sigma)` over
:math:`\\mathbf y = (x, y, \\theta, l_{1,x}, l_{1,y}, \\dots)`, landmark :math:`k` in rows ``3 + 2k`` and
``4 + 2k`` (:func:`landmark_slice`). The steps, each in place on the state:

1. **Prediction** (lines 2–5): :func:`predict` one step, :func:`predict_segment` many at once, with the
   Jacobian :func:`motion_jacobian` and the noise :func:`motion_noise_covariance`; only the pose's rows and
   columns change, :math:`O(N)`.
2. **A new landmark** from the inverse model, with its cross-covariances (:func:`augment_state`).
3. **The update** for one sighting (:func:`update`): innovation, gain, Joseph form (:func:`joseph_update`),
   :math:`O(N^2)`; with the gate on the squared Mahalanobis distance.

The run over a log is :func:`fastslam_edu.landmark.ekf_slam.run_ekf_slam`; table 10.2's data association is
:mod:`fastslam_edu.landmark.ekf_slam_association`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.checks import finite_array
from fastslam_edu.core.measurement import jacobian_inverse, jacobian_pose, landmark_from_measurement, range_bearing
from fastslam_edu.core.motion import MotionNoise, dead_reckon, propagate
from fastslam_edu.landmark.proposal import motion_prediction, segment_motion

__all__ = ["INITIALISED", "UPDATED", "REJECTED", "EKFSLAMState", "landmark_slice", "motion_jacobian",
           "motion_noise_covariance", "predict", "predict_segment", "jacobian_inverse_pose", "augment_state",
           "measurement_jacobian", "full_measurement_jacobian", "joseph_update", "subtract_symmetric_product",
           "update", "update_unchecked", "correlation_matrix"]


#: What :func:`update` did with a sighting.
INITIALISED, UPDATED, REJECTED = "initialised", "updated", "rejected"


# ---------------------------------------------------------------- the state


def landmark_slice(k: int) -> slice:
    """Rows of landmark ``k`` in the state: ``3 + 2k`` and ``4 + 2k``."""
    return slice(3 + 2 * k, 5 + 2 * k)


@dataclass
class EKFSLAMState:
    """The joint Gaussian :math:`\\mathcal N(\\mu, \\Sigma)` over pose and map.

    Attributes
    ----------
    mu : ndarray (3 + 2N,)
        :math:`\\mu`: pose ``(x, y, θ)`` [m, m, rad] then ``(m_x, m_y)`` [m] per landmark.
    sigma : ndarray (3 + 2N, 3 + 2N)
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


def augment_state(state: EKFSLAMState, z, k: int, R) -> EKFSLAMState:
    """Initialise landmark ``k`` from sighting ``z = (r, φ)`` (2,) with noise ``R`` (2, 2), in place.

    :math:`\\mu_k = h^{-1}(\\mu_x, z)`; :math:`\\Sigma_{kk} = J_x \\Sigma_{xx} J_x^\\top + G R G^\\top`
    and :math:`\\Sigma_{k\\cdot} = J_x \\Sigma_{x\\cdot}` (the landmark inherits the pose's error).
    Cost :math:`O(N)`.
    """
    _check_landmark(state, k, "augment_state")
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

    The full :math:`H_t` (2, 3 + 2N) is :math:`G_x` in the pose's columns, :math:`H` in landmark
    ``k``'s, zero elsewhere (:func:`full_measurement_jacobian`).
    """
    x, m = state.mu[:3], state.mu[landmark_slice(k)]
    Gx = jacobian_pose(x, m)
    return range_bearing(x, m), Gx, -Gx[:, :2]  # ∂h/∂m = −∂h/∂(x, y): only the offset m − (x, y) counts


def full_measurement_jacobian(state: EKFSLAMState, k: int) -> np.ndarray:
    """:math:`H_t = \\partial h / \\partial y` (2, 3 + 2N) as a dense matrix (for teaching and checks)."""
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

    A landmark not seen yet is initialised (:func:`augment_state`). Otherwise
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
    return update_unchecked(state, z, k, R, gate_chi2, escape)


def update_unchecked(state: EKFSLAMState, z: np.ndarray, k: int, R: np.ndarray, gate_chi2, escape: bool) -> str:
    """:func:`update` without the checks of its arguments (the run checks the stream once)."""
    if not state.seen[k]:
        augment_state(state, z, k, R)
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
