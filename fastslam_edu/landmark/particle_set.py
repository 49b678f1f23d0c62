"""The particle set of FastSLAM 1.0 and the four steps on it (Montemerlo et al. 2002; table 13.1 of *Probabilistic
Robotics*): propagate (step 1), update (step 2, in the compiled kernels of :mod:`fastslam_edu.landmark.fastslam_step`),
resample (step 3) and combine (step 4).

State of the filter (:class:`ParticleSet`), for :math:`M` particles and :math:`N` landmarks:

=========  ==============  ==========================================
poses      (M, 3)          :math:`x^{[m]} = (x, y, \\theta)` [m, m, rad]
mu         (M, N, 2)       :math:`\\mu_n^{[m]}` [m]
sigma      (M, N, 2, 2)    :math:`\\Sigma_n^{[m]}` [m²]
seen       (M, N) bool     landmark n initialised in particle m
logw       (M,)            :math:`\\log w^{[m]}` (unnormalised)
=========  ==============  ==========================================

The driver that runs these steps over a log is :func:`fastslam_edu.landmark.fastslam.run_fastslam`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.motion import MotionNoise, move_segment
from fastslam_edu.core.resampling import get_resampler
from fastslam_edu.landmark.fastslam_step import (normalise_weights, propagate_segment_kernel, standard_normals,
                                                 update_particles)
from fastslam_edu.landmark.step_records import Particles, Sightings


@dataclass
class ParticleSet:
    """The M particles of FastSLAM 1.0 (arrays, see the module docstring)."""

    poses: np.ndarray
    mu: np.ndarray
    sigma: np.ndarray
    seen: np.ndarray
    logw: np.ndarray
    count: np.ndarray | None = None  # (M, N) sightings used per landmark (default: 1 where seen)

    def __post_init__(self):
        if self.count is None:
            self.count = np.asarray(self.seen, dtype=np.int64).copy()

    @classmethod
    def initial(cls, n_particles: int, n_landmarks: int, x0) -> "ParticleSet":
        """All particles at pose ``x0`` (3,), no landmark seen, uniform weights."""
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (3,) or not np.all(np.isfinite(x0)):
            raise ValueError(f"initial pose must be 3 finite numbers (x, y, theta), got {x0!r}")
        M, N = int(n_particles), int(n_landmarks)
        return cls(
            poses=np.tile(x0, (M, 1)),
            mu=np.zeros((M, N, 2)),
            sigma=np.tile(np.eye(2), (M, N, 1, 1)),
            seen=np.zeros((M, N), dtype=bool),
            logw=np.zeros(M),
        )

    def __len__(self) -> int:
        return self.poses.shape[0]

    @property
    def weights(self) -> np.ndarray:
        """Normalised weights :math:`w^{[m]}`, shape (M,) (all log weights :math:`-\\infty`: uniform)."""
        w = np.empty(len(self.logw))
        normalise_weights(np.asarray(self.logw, dtype=float), w)
        return w

    def with_known_map(self, landmarks) -> "ParticleSet":
        """Every particle holding the known landmarks ``(N, 2)`` (localisation), Σ = 10⁻⁶ I."""
        self.mu[:] = landmarks
        self.sigma[:] = np.eye(2) * 1e-6
        self.seen[:] = True
        self.count[:] = 1
        return self

    def arrays(self) -> Particles:
        """The arrays as the step's kernels take them (:class:`fastslam_edu.landmark.fastslam_step.Particles`), shared."""
        return Particles(self.poses, self.mu, self.sigma, self.seen, self.count, self.logw)

    def update(self, z, k, R, *, update_map: bool = True, gate_chi2: float | None = None, escape=None,
               beta=None, proposal_loglik=None) -> np.ndarray:
        """Step 2 for the measurements of one instant: :func:`update_with_sightings`."""
        sightings = make_sightings(z, k, R, len(self), escape=escape, beta=beta, proposal_loglik=proposal_loglik)
        return update_with_sightings(self, sightings, gate_chi2=gate_chi2, update_map=update_map)

    def to_particle_set(self) -> "ParticleSet":
        """The set as dense arrays: itself (see the tree storage of :mod:`fastslam_edu.landmark.fastslam_tree`)."""
        return self

    def select(self, indices) -> "ParticleSet":
        """Particles ``indices`` as a new set with **copied** arrays and uniform weights.

        Fancy indexing copies, so two offspring of one parent never share memory:
        updating a landmark in one cannot change the other (the bug a shallow
        ``copy.copy`` of a particle object has).
        """
        idx = np.asarray(indices)
        return ParticleSet(
            poses=np.take(self.poses, idx, axis=0),  # = self.poses[idx], with less overhead
            mu=np.take(self.mu, idx, axis=0),
            sigma=np.take(self.sigma, idx, axis=0),
            seen=np.take(self.seen, idx, axis=0),
            logw=np.zeros(len(idx)),
            count=np.take(self.count, idx, axis=0),
        )


# ---------------------------------------------------------------- the four steps


def propagate(particles: ParticleSet, u, dt, noise: MotionNoise, rng: np.random.Generator):
    """Step 1: sample the motion model for every particle through L odometry steps.

    Parameters
    ----------
    u : ndarray (L, 2)
        Commands ``(v, ω)`` of the steps.
    dt : ndarray (L,)
        Step lengths [s].

    Returns
    -------
    path : ndarray (M, L, 3)
        Every particle's pose after each step (:func:`fastslam_edu.core.motion.move_segment`,
        the same random numbers as :func:`propagate_segment`); ``particles.poses`` is
        set to the poses after the last step.
    """
    u, dt = np.atleast_2d(np.asarray(u, dtype=float)), np.atleast_1d(np.asarray(dt, dtype=float))
    eps = draw_normals(rng, len(particles), len(dt), noise.n_draws)
    path = move_segment(particles.poses, u, dt, noise, eps.transpose(2, 0, 1))
    particles.poses = path[:, -1].copy()
    return path


def draw_normals(rng: np.random.Generator, m: int, n_steps: int, k: int) -> np.ndarray:
    """The numbers of ``rng.standard_normal((m, n_steps, k))``, stored step by step: (n_steps, k, m), as
    :func:`fastslam_edu.landmark.fastslam_step.propagate_segment_kernel` reads them (drawn by the compiled loop
    when there are many)."""
    if m * n_steps * k < 4096:
        return np.ascontiguousarray(rng.standard_normal((m, n_steps, k)).transpose(1, 2, 0))
    out = np.empty((n_steps, k, m))
    standard_normals(rng, out)
    return out


def propagate_segment(particles: ParticleSet, u, dt, noise: MotionNoise, rng: np.random.Generator, w, *,
                      n_record: int | None = None):
    """Step 1 as the filter runs it: line 4 of table 13.1 for each particle, recording the estimates.

    The same random numbers as :func:`propagate`, but instead of every
    particle's path (M, L, 3) it returns what the filter records at each step:
    the weighted-mean pose and the pose of the highest-weight particle
    (:func:`fastslam_edu.landmark.fastslam_step.propagate_segment_kernel`).

    Parameters
    ----------
    u, dt, noise, rng : as :func:`propagate`.
    w : ndarray (M,)
        Normalised weights (constant along the segment: no measurement in it).
    n_record : int, optional
        Estimates for the first ``n_record`` steps only (default all ``L``): at a
        measurement step the filter records its estimate after the update instead.

    Returns
    -------
    mean, best : ndarray (n_record, 3)
        Weighted-mean pose (:func:`combined_pose`) and best particle's pose after each step.
    """
    u, dt = np.asarray(u, dtype=float).reshape(-1, 2), np.asarray(dt, dtype=float).reshape(-1)
    n = len(dt) if n_record is None else n_record
    mean, best = np.empty((n, 3)), np.empty((n, 3))
    particles.poses = np.array(particles.poses, dtype=float)  # a private copy, moved in place
    propagate_segment_kernel(particles.poses, u, dt, noise.densities,
                             draw_normals(rng, len(particles), len(dt), noise.n_draws), w, mean, best)
    return mean, best


def update_with_measurement(particles: ParticleSet, z, k: int, R, **options) -> bool:
    """Step 2 for one measurement ``z = (r, φ)`` of landmark ``k``: :func:`update_with_measurements` with n = 1."""
    return bool(update_with_measurements(particles, np.reshape(z, (1, 2)), [k], np.reshape(R, (1, 2, 2)),
                                         **options)[0])


def make_sightings(z, k, R, n_particles: int, *, escape=None, beta=None, proposal_loglik=None) -> Sightings:
    """The sightings of one instant as the step's kernels take them (:class:`fastslam_edu.landmark.fastslam_step.Sightings`).

    ``z`` (n, 2), ``k`` (n,), ``R`` (n, 2, 2) or (2, 2); ``escape`` (n,) bool
    (default none escapes the gate), ``beta`` (n,) the likelihoods' exponents β
    (default 1), ``proposal_loglik`` (M, n) log weights that replace FastSLAM
    1.0's where not NaN (default all NaN).
    """
    z = np.asarray(z, dtype=float).reshape(-1, 2)
    n = len(z)
    k = np.asarray(k, dtype=np.int64).reshape(-1)
    R = np.asarray(R, dtype=float)
    if R.shape != (n, 2, 2):
        R = np.broadcast_to(R, (n, 2, 2)).copy()
    escape = np.zeros(n, dtype=bool) if escape is None else _per_sighting(escape, bool, n)
    beta = np.ones(n) if beta is None else _per_sighting(beta, float, n)
    loglik = (np.full((n_particles, n), np.nan) if proposal_loglik is None
              else np.asarray(proposal_loglik, float).reshape(n_particles, n))
    return Sightings(z, k, R, escape, beta, loglik)


def _per_sighting(values, dtype, n: int) -> np.ndarray:
    """``values`` as an (n,) array of ``dtype`` (one value is repeated)."""
    values = np.asarray(values, dtype=dtype).reshape(-1)
    return values if len(values) == n else np.broadcast_to(values, (n,)).copy()


def update_with_sightings(particles: ParticleSet, sightings: Sightings, *, gate_chi2: float | None = None,
                          update_map: bool = True) -> np.ndarray:
    """Step 2 for the sightings of one instant (:func:`make_sightings`); see :func:`update_with_measurements`."""
    explained = np.ones(len(sightings.j), dtype=bool)
    update_particles(particles.arrays(), sightings, np.inf if gate_chi2 is None else float(gate_chi2),
                     bool(update_map), explained)
    return explained


def update_with_measurements(particles: ParticleSet, z, k, R, *, update_map: bool = True,
                             gate_chi2: float | None = None, escape=None, beta=None) -> np.ndarray:
    """Step 2 for all the measurements of one instant: ``z`` (n, 2) of landmarks ``k`` (n,), in order.

    Lines 5–18 of table 13.1 for every particle
    (:func:`fastslam_edu.landmark.fastslam_step.update_particles`): particles that have not
    seen a landmark initialise it (:math:`\\mu = h^{-1}(x, z)`, :math:`\\Sigma = G R G^\\top`) and
    keep their weight; the others update its EKF and add
    :math:`\\beta \\log \\mathcal N(\\nu; 0, Q)` to their log weight. With
    ``update_map=False`` (localisation with a known map) only the weights change.

    The gate sets aside a measurement that *no* particle explains
    (:math:`d^2 = \\nu^\\top Q^{-1} \\nu >` ``gate_chi2`` for every particle that has seen
    the landmark): it changes neither weights nor maps of those particles. A
    particle for which it is an outlier, while others explain it, keeps the
    log-likelihood but leaves its landmark alone (a landmark seen only once is
    re-initialised instead, at no cost in weight).

    Parameters
    ----------
    R : (n, 2, 2) or (2, 2)
        Measurement noise covariances.
    gate_chi2 : float or None
        None: no gate.
    escape : (n,) bool, optional
        Measurements applied without the gate (:class:`Gate`).
    beta : (n,), optional
        Exponents :math:`\\beta` of their likelihoods (:func:`tempering_exponents`; default 1).

    FastSLAM 2.0 weighs with its own log weights: :func:`make_sightings` (``proposal_loglik``)
    and :func:`update_with_sightings`.

    Returns
    -------
    explained : (n,) bool
        False where no particle explains the measurement (rejected by the gate, unless escaped).
    """
    sightings = make_sightings(z, k, R, len(particles), escape=escape, beta=beta)
    return update_with_sightings(particles, sightings, gate_chi2=gate_chi2, update_map=update_map)


def resample_if_needed(
    particles: ParticleSet, resampler: str, threshold: float, rng: np.random.Generator
) -> tuple[ParticleSet, float, bool]:
    """Step 3: resample when :math:`N_\\text{eff} < \\text{threshold}\\cdot M`.

    Returns ``(particles, N_eff before, resampled?)``; after resampling the
    weights are uniform (the evidence is now in the particle counts — keeping
    the old weights as well would count it twice).
    """
    parents, n_eff, _ = draw_parents(particles, resampler, threshold, rng)
    if parents is None:
        return particles, n_eff, False
    return particles.select(parents), n_eff, True


def draw_parents(particles: ParticleSet, resampler: str, threshold: float, rng: np.random.Generator):
    """The decision of step 3: ``(parents, N_eff, w)``, the indices the resampler draws (M,), or None when
    :math:`N_\\text{eff} \\ge \\text{threshold}\\cdot M` (``threshold`` 1.0: always draw); ``w`` the
    normalised weights it drew them with."""
    w = np.empty(len(particles))
    n_eff = normalise_weights(np.asarray(particles.logw, dtype=float), w)  # and N_eff = 1 / Σ w²
    if threshold >= 1.0 or n_eff < threshold * len(particles):  # 1.0: at every call (the write-up)
        return get_resampler(resampler)(w, rng), n_eff, w
    return None, n_eff, w


def combined_pose(poses, w) -> np.ndarray:
    """Weighted mean pose: :math:`\\bar x = \\sum_m w^{[m]} x^{[m]}`, with the circular mean for θ.

    ``poses`` (M, ..., 3), ``w`` (M,) normalised; returns (..., 3), heading
    wrapped (:func:`combined_heading`).
    """
    poses = np.asarray(poses, dtype=float)
    out = np.empty(poses.shape[1:])
    if poses.ndim == 2:  # one pose per particle (M, 3): x and y in one product
        out[:2] = w @ poses[:, :2]
    else:
        out[..., 0] = w @ poses[..., 0]
        out[..., 1] = w @ poses[..., 1]
    out[..., 2] = combined_heading(poses[..., 2], w)
    return out


def combined_heading(theta, w) -> np.ndarray:
    """Circular weighted mean :math:`\\bar\\theta = \\operatorname{atan2}(\\sum_m w^{[m]} \\sin\\theta^{[m]}, \\sum_m w^{[m]} \\cos\\theta^{[m]})`.

    ``theta`` (M, ...) [rad], ``w`` (M,) normalised; returns (...), wrapped.
    """
    theta = np.asarray(theta, dtype=float)
    return wrap_angle(np.arctan2(w @ np.sin(theta), w @ np.cos(theta)))


def combined_map(particles: ParticleSet):
    """Step 4 for the map: weighted mean landmarks and their mixture covariance.

    :math:`\\bar\\mu_k = \\sum_m w^{[m]} \\mu_k^{[m]}` over the particles that have seen
    ``k`` (weights renormalised among them), and
    :math:`\\bar\\Sigma_k = \\sum_m w^{[m]} (\\Sigma_k^{[m]} + (\\mu_k^{[m]}-\\bar\\mu_k)(\\mu_k^{[m]}-\\bar\\mu_k)^\\top)`,
    the covariance of the Gaussian mixture (the write-up's "weighted sum of squared
    covariances" is not a covariance: see the chapter on putting it together).

    Returns ``mu (N, 2)``, ``sigma (N, 2, 2)``, ``observed (N,)``; NaN for unseen landmarks.
    """
    w = particles.weights[:, None] * particles.seen  # (M, N)
    tot = w.sum(axis=0)
    observed = tot > 0
    wn = np.divide(w, tot, out=np.zeros_like(w), where=observed)
    mu = np.einsum("mk,mkd->kd", wn, particles.mu)
    d = particles.mu - mu[None]
    sigma = np.einsum("mk,mkij->kij", wn, particles.sigma + d[..., :, None] * d[..., None, :])
    mu[~observed] = np.nan
    sigma[~observed] = np.nan
    return mu, sigma, observed


__all__ = ["ParticleSet", "propagate", "draw_normals", "propagate_segment", "update_with_measurement", "make_sightings",
           "update_with_sightings", "update_with_measurements", "resample_if_needed", "draw_parents", "combined_pose",
           "combined_heading", "combined_map"]
