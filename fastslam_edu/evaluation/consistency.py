"""Is a filter's uncertainty honest? The normalised estimation error squared (NEES).

A filter reports an estimate :math:`\\hat x` and a covariance :math:`P`. If it is
*consistent* — its errors are what its covariance says — then for the true
state :math:`x` the normalised estimation error squared

.. math::

    \\epsilon = (\\hat x - x)^\\top P^{-1} (\\hat x - x)

is :math:`\\chi^2`-distributed with :math:`d = \\dim x` degrees of freedom: its mean is
:math:`d`. Averaged over :math:`n` independent runs, :math:`n \\bar\\epsilon \\sim \\chi^2_{nd}`, which
gives the two-sided interval of :func:`nees_interval` (Bar-Shalom, Li and
Kirubarajan, *Estimation with Applications to Tracking and Navigation*, §5.4).
A mean above the interval means the filter is **overconfident**: its errors
are larger than it believes.

For FastSLAM the pose estimate and its covariance are those of the particle
cloud (:func:`pose_mean_and_covariance`: the weighted mean and covariance of the
particles' poses, headings averaged on the circle); the map's are those of the
mixture of the particles' landmark EKFs
(:func:`fastslam_edu.landmark.particle_set.combined_map`). :class:`SpreadRecorder` collects
the cloud during a run through ``run_fastslam(..., hooks=[Monitor(callback)])`` without
changing it. :func:`align_pose` moves a pose and its covariance by the rigid
motion that fits the estimated map to the true one: the NEES of the aligned
pose asks whether the filter knows where it is *relative to its own map*, the
plain NEES whether it knows where it is in the world.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.landmark.fastslam import FastSLAMParams
from fastslam_edu.landmark.particle_set import combined_map
from fastslam_edu.landmark.fastslam_step import combined_pose_kernel, pose_covariance as compiled_pose_covariance
from fastslam_edu.datasets.sim import SimConfig

__all__ = [
    "nees",
    "nees_interval",
    "pose_error",
    "pose_mean_and_covariance",
    "align_pose",
    "SpreadRecorder",
    "simulator_params",
]


def nees(error, cov) -> np.ndarray:
    """Normalised estimation error squared :math:`\\epsilon = e^\\top P^{-1} e`.

    Parameters
    ----------
    error : array_like, shape (..., d)
        Estimate minus truth :math:`e` (angles wrapped: :func:`pose_error`).
    cov : array_like, shape (..., d, d)
        The covariance :math:`P` the estimator reports; symmetric positive definite.

    Returns
    -------
    ndarray, shape (...)
        :math:`\\epsilon` per estimate; :math:`\\chi^2_d` if the estimator is consistent.

    Raises
    ------
    ValueError
        On mismatched shapes, non-finite values or a covariance that is not
        positive definite (naming the first such estimate).
    """
    e = np.asarray(error, dtype=float)
    P = np.asarray(cov, dtype=float)
    if e.ndim < 1 or P.shape != e.shape + e.shape[-1:]:
        raise ValueError(f"nees: error (..., d) and cov (..., d, d) do not match: {e.shape} and {P.shape}")
    for name, a in (("error", e), ("cov", P)):
        if not np.isfinite(a).all():
            raise ValueError(f"nees: {name} has NaN or infinite values")
    d = e.shape[-1]
    flat_e, flat_P = e.reshape(-1, d), P.reshape(-1, d, d)
    try:
        L = np.linalg.cholesky(flat_P)
    except np.linalg.LinAlgError:
        ok = np.array([np.all(np.linalg.eigvalsh(p) > 0) for p in flat_P])
        bad = int(np.flatnonzero(~ok)[0])
        raise ValueError(f"nees: covariance {bad} is not positive definite "
                         f"(eigenvalues {np.linalg.eigvalsh(flat_P[bad]).tolist()})") from None
    # e^T P^{-1} e = |L^{-1} e|^2 with P = L L^T
    y = np.linalg.solve(L, flat_e[..., None])[..., 0]
    return np.einsum("ni,ni->n", y, y).reshape(e.shape[:-1])


def nees_interval(dof: int, n_runs: int, confidence: float = 0.95) -> tuple[float, float]:
    """Two-sided interval for the mean NEES of ``n_runs`` independent runs of a consistent estimator.

    :math:`n \\bar\\epsilon \\sim \\chi^2_{n d}`, so
    :math:`\\bar\\epsilon \\in [\\chi^2_{nd}(\\alpha/2),\\ \\chi^2_{nd}(1-\\alpha/2)] / n` with
    probability ``confidence`` :math:`= 1 - \\alpha`. One run, three degrees of
    freedom, 95 %: [0.22, 9.35]; ten runs: [1.68, 4.70].
    """
    if int(dof) != dof or dof < 1 or int(n_runs) != n_runs or n_runs < 1:
        raise ValueError(f"nees_interval: dof and n_runs must be whole numbers >= 1, got {dof!r}, {n_runs!r}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"nees_interval: confidence must be in (0, 1), got {confidence!r}")
    nd, alpha = int(dof) * int(n_runs), 1.0 - confidence
    lo, hi = chi2.ppf([alpha / 2, 1 - alpha / 2], nd) / int(n_runs)
    return float(lo), float(hi)


def pose_error(estimate, truth) -> np.ndarray:
    """Pose error ``estimate − truth`` (..., 3) [m, m, rad], heading wrapped to (−π, π]."""
    e = np.asarray(estimate, dtype=float) - np.asarray(truth, dtype=float)
    if e.shape[-1:] != (3,):
        raise ValueError(f"pose_error: poses must be (..., 3) (x, y, theta), got shape {e.shape}")
    e[..., 2] = wrap_angle(e[..., 2])
    return e


def pose_mean_and_covariance(poses, w) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean and covariance of a particle cloud of poses.

    :math:`\\bar x = \\sum_m w^{[m]} x^{[m]}` with the circular mean for the heading
    (:func:`fastslam_edu.landmark.fastslam_step.combined_pose_kernel`), and
    :math:`P = \\sum_m w^{[m]} \\delta^{[m]} \\delta^{[m]\\top}` with
    :math:`\\delta^{[m]} = x^{[m]} - \\bar x`, its heading wrapped: a cloud that
    straddles θ = ±π has a small variance, not one of π². The inputs are checked here; the sums are
    :func:`fastslam_edu.landmark.fastslam_step.pose_covariance`'s, the covariance the association adds to
    its innovations.

    Parameters
    ----------
    poses : array_like, shape (M, 3)
    w : array_like, shape (M,)
        Normalised weights.

    Returns
    -------
    mean : ndarray (3,), cov : ndarray (3, 3)
    """
    x = np.asarray(poses, dtype=float)
    w = np.asarray(w, dtype=float)
    if x.ndim != 2 or x.shape[1] != 3 or w.shape != (x.shape[0],):
        raise ValueError(f"pose_mean_and_covariance: poses (M, 3) and w (M,) expected, got {x.shape} and {w.shape}")
    if not abs(w.sum() - 1.0) < 1e-9 or (w < 0).any():
        raise ValueError(f"pose_mean_and_covariance: w must be non-negative and sum to 1, sum is {w.sum()!r}")
    x, w = np.ascontiguousarray(x), np.ascontiguousarray(w)
    mean = np.empty(3)
    combined_pose_kernel(x, w, mean)
    return mean, compiled_pose_covariance(x, w)


def align_pose(pose, cov, R, t, angle) -> tuple[np.ndarray, np.ndarray]:
    """A pose and its covariance moved by the rigid motion ``p ↦ R p + t`` (rotation ``angle``).

    ``(R, t, angle)`` as returned by :func:`fastslam_edu.core.se2.align_se2`:
    position :math:`R p + t`, heading :math:`\\theta + \\alpha`; the covariance becomes
    :math:`J P J^\\top` with :math:`J = \\mathrm{diag}(R, 1)`.
    """
    pose = np.asarray(pose, dtype=float)
    P = np.asarray(cov, dtype=float)
    R = np.asarray(R, dtype=float)
    J = np.eye(3)
    J[:2, :2] = R
    moved = np.empty(3)
    moved[:2] = R @ pose[:2] + np.asarray(t, dtype=float)
    moved[2] = wrap_angle(pose[2] + float(angle))
    return moved, J @ P @ J.T


class SpreadRecorder:
    """A ``monitor`` for :func:`fastslam_edu.landmark.fastslam.run_fastslam` that keeps the particle cloud's spread.

    With ``times=None`` it records every measurement step. With ``times`` it
    records, for each of them, the first measurement step at or after it: one
    record per time, so runs over different logs line up (two times with no
    sighting between them get the same step; times after the last measurement
    step get none). A record is the step's time, the cloud's mean pose and
    covariance (:func:`pose_mean_and_covariance`) and, with ``maps=True``, the combined
    map (:func:`fastslam_edu.landmark.particle_set.combined_map`: means (N, 2), covariances
    (N, 2, 2), observed (N,)). It reads the particles and never writes them.

    Attributes (lists, one entry per record): ``t``, ``mean``, ``cov``, ``maps``.
    """

    def __init__(self, times=None, *, maps: bool = False):
        self._pending = None if times is None else sorted(float(t) for t in np.atleast_1d(times))
        self._maps = bool(maps)
        self.t, self.mean, self.cov, self.maps = [], [], [], []

    def __call__(self, t, particles, w) -> None:
        copies = 1
        if self._pending is not None:
            copies = 0
            while self._pending and self._pending[0] <= t:
                self._pending.pop(0)
                copies += 1
            if copies == 0:
                return
        mean, cov = pose_mean_and_covariance(particles.poses, w)
        spread = combined_map(particles.to_particle_set()) if self._maps else None  # dense, also for tree maps
        for _ in range(copies):
            self.t.append(float(t))
            self.mean.append(mean)
            self.cov.append(cov)
            if self._maps:
                self.maps.append(spread)


def simulator_params(config: SimConfig | None = None, **changes) -> FastSLAMParams:
    """Filter settings whose model *is* the simulator's: the test of consistency with no model error.

    The odometry noise densities of ``config`` (default ``SimConfig()``), its
    constant measurement noise :math:`R = \\mathrm{diag}(\\sigma_r^2, \\sigma_\\phi^2)` (no
    range-dependent growth), and independent sightings (no tempering: the
    simulator's errors are white). ``changes`` set other fields
    (``n_particles=1000``, ``mode="localize"``, ...).
    """
    c = SimConfig() if config is None else config
    return FastSLAMParams().replace(motion_noise=c.odometry_noise,
                       measurement_cov=np.diag([c.range_std**2, c.bearing_std**2]), range_std_slope=0.0,
                       measurement_correlation_s=None, **changes)
