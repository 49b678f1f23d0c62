"""EKF-SLAM with unknown correspondences: which map landmark a sighting sees (*Probabilistic Robotics*, table 10.2).

For each sighting, the squared Mahalanobis distance :math:`d_k^2 = \\nu_k^\\top Q_k^{-1}\\nu_k` to every map landmark
(:func:`association_distances`); the choice (:func:`associate`): the nearest landmark within the gate, a new
landmark (:data:`NEW`, :func:`add_new_landmark`) when every :math:`d_k^2` exceeds ``new_landmark_chi2``, or set
aside (:data:`SET_ASIDE`) in between; with mutual exclusion, the sightings of one instant jointly, as an
assignment problem. The run that uses it is :func:`fastslam_edu.landmark.ekf_slam.run_ekf_slam`.
"""

from __future__ import annotations

import numpy as np

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.checks import finite_array
from fastslam_edu.landmark.ekf_slam_steps import EKFSLAMState, augment_state

__all__ = ["NEW", "SET_ASIDE", "association_distances", "associate", "add_new_landmark"]


#: :func:`associate`'s codes for a sighting that starts a new landmark, and one set aside.
NEW, SET_ASIDE = -1, -2


def association_distances(state: EKFSLAMState, z, R) -> np.ndarray:
    """Squared Mahalanobis distances :math:`d_k^2 = \\nu_k^\\top Q_k^{-1}\\nu_k` of sighting ``z`` (2,) to every map landmark.

    :math:`\\nu_k = z \\ominus h(\\mu_x, \\mu_k)` and :math:`Q_k = H_t^k \\Sigma H_t^{k\\top} + R` as in
    :func:`~.ekf_slam_steps.update`, for all seen landmarks at once (only the pose's and landmark :math:`k`'s blocks of
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
    """Grow the state by one landmark (two rows and columns) and initialise it from ``z``
    (:func:`~.ekf_slam_steps.augment_state`).

    Returns its index. The copy costs :math:`O(N^2)`, paid once per landmark.
    """
    N = state.n_landmarks
    n = len(state.mu)
    mu, sigma = np.zeros(n + 2), np.zeros((n + 2, n + 2))
    mu[:n], sigma[:n, :n] = state.mu, state.sigma
    state.mu, state.sigma, state.seen = mu, sigma, np.append(state.seen, False)
    augment_state(state, z, N, R)
    return N
