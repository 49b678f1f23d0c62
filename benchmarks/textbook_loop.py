"""FastSLAM 1.0 as plain Python over particle objects: an independent reference, for tests and benchmarks.

This is the algorithm ``FastSLAM_1`` of the FastSLAM notes (Montemerlo et al. 2002;
Thrun, Burgard, Fox, *Probabilistic Robotics*, table 13.1) written with plain
Python loops over particles and landmarks, one :class:`Particle` object each::

    for each particle m:
        x^[m] ~ p(x_t | x_{t-1}^[m], u_t)                    # propagate
        for each measurement z of landmark j:
            if j never seen:  μ_j = h⁻¹(x, z),  Σ_j = G R Gᵀ   # initialise
            else:             EKF update of (μ_j, Σ_j), w *= N(ν; 0, Q)
    resample if N_eff < threshold · M

It consumes the random numbers in the same order as the package's filter
(:mod:`fastslam_edu.landmark.fastslam`, whose step is the compiled per-particle kernel of
:mod:`fastslam_edu.landmark.fastslam_step`), so both give the same result for the same
seed: ``tests/test_fastslam_loop.py`` checks the kernel against this code, which
uses the textbook numpy EKF (:func:`fastslam_edu.core.ekf.update_landmark_textbook`, itself
checked against filterpy) and the vectorised motion model. The speed benchmark
uses it as a yardstick of the machine (``benchmarks/fastslam_mrclam.py``).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from fastslam_edu.datasets.log import EventStream
from fastslam_edu.core.ekf import initialise_landmark, innovation_statistics, update_landmark_textbook
from fastslam_edu.landmark.evidence import tempering_exponents
from fastslam_edu.landmark.fastslam import FastSLAMParams
from fastslam_edu.landmark.gate import Gate
from fastslam_edu.landmark.segments import measurement_segments
from fastslam_edu.core.motion import move
from fastslam_edu.core.resampling import get_resampler
from fastslam_edu.core.weights import effective_sample_size, weights_from_log


@dataclass
class Particle:
    """One FastSLAM particle: a pose, a log weight and one EKF per landmark seen."""

    pose: np.ndarray
    logw: float = 0.0
    landmarks: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    count: dict[int, int] = field(default_factory=dict)  # sightings used per landmark

    def copy(self) -> "Particle":
        """A deep copy: offspring of one parent must not share landmark arrays."""
        return copy.deepcopy(self)


def update_particle(p: Particle, z, j: int, R, *, update_map: bool = True, gate_chi2=None, beta: float = 1.0) -> None:
    """Lines 6–18 of FastSLAM_1 for one particle and one measurement.

    With a gate, if ``d² = νᵀQ⁻¹ν > gate_chi2`` the measurement is an outlier for
    this particle: its log weight still gets the log-likelihood, but its
    landmark is left alone — unless the landmark was seen only once, which is
    then re-initialised from the new sighting at no cost in weight (one of its
    two sightings is wrong). The measurements no particle explains never get
    here (:func:`is_explained`). ``beta`` β: the weight grows by β · log N(ν; 0, Q)
    (:func:`fastslam_edu.landmark.evidence.tempering_exponents`).
    """
    if j not in p.landmarks:
        p.landmarks[j] = initialise_landmark(p.pose, z, R)
        p.count[j] = 1
        return
    mu, sigma = p.landmarks[j]
    mu_new, sigma_new, loglik = update_landmark_textbook(mu, sigma, p.pose, z, R)
    loglik *= beta
    if gate_chi2 is not None:
        _, d2 = innovation_statistics(mu, sigma, p.pose, z, R)
        if d2 > gate_chi2:
            if p.count[j] == 1 and update_map:
                p.landmarks[j] = initialise_landmark(p.pose, z, R)
            else:
                p.logw += loglik
            return
    p.logw += loglik
    p.count[j] += 1
    if update_map:
        p.landmarks[j] = (mu_new, sigma_new)


def is_explained(particles: list[Particle], z, j: int, R, gate_chi2) -> bool:
    """False if *every* particle that has seen landmark ``j`` puts ``z`` beyond the gate.

    Such a measurement fits no hypothesis (a misread barcode, a range off by
    metres) and the filter sets it aside, unless it escapes the gate.
    """
    if gate_chi2 is None:
        return True
    d2 = [innovation_statistics(*p.landmarks[j], p.pose, z, R)[1] for p in particles if j in p.landmarks]
    return not d2 or min(d2) <= gate_chi2


def run_fastslam_loop(
    stream: EventStream,
    params: FastSLAMParams = FastSLAMParams(),
    rng: np.random.Generator | int | None = 0,
    *,
    x0=None,
    landmarks=None,
) -> tuple[list[Particle], np.ndarray]:
    """Run the textbook filter; returns the final particles and the weighted-mean path (N, 3).

    Supports modes ``"slam"`` and ``"localize"`` (the engine's other options are
    bookkeeping around the same four steps).
    """
    if params.mode not in ("slam", "localize"):
        raise ValueError('the loop reference runs mode "slam" or "localize"')
    if params.proposal != "motion":
        raise ValueError("the loop reference is FastSLAM 1.0 only (proposal=\"motion\"); "
                         "FastSLAM 2.0's one-particle form is "
                         "fastslam_edu.landmark.proposal.improved_pose_information_form")
    rng = np.random.default_rng(rng) if not isinstance(rng, np.random.Generator) else rng
    x0 = np.asarray(stream.x0 if x0 is None else x0, dtype=float)
    M = params.n_particles
    particles = [Particle(pose=x0.copy()) for _ in range(M)]
    if params.mode == "localize":
        for p in particles:
            p.landmarks = {k: (np.array(m, dtype=float), np.eye(2) * 1e-6) for k, m in enumerate(landmarks)}
            p.count = {k: 1 for k in range(len(landmarks))}
    u = np.asarray(stream.u, dtype=float) * np.asarray(params.odometry_scale, dtype=float)  # as the engine
    path = np.empty((len(stream), 3))
    escapes = Gate(params.gate_chi2, params.gate_escape_s, stream.n_landmarks)  # the escape from the gate, as the engine
    last_seen = np.full(stream.n_landmarks, -np.inf)
    for s, e in measurement_segments(stream):
        eps = rng.standard_normal((M, e - s + 1, params.motion_noise.n_draws))
        w = weights_from_log(np.array([p.logw for p in particles]))
        for i, k in enumerate(range(s, e + 1)):
            for m, p in enumerate(particles):
                p.pose = move(p.pose, u[k], stream.dt[k], params.motion_noise, eps[m, i])
            path[k] = _combined_pose(particles, w)
        z, lm = stream.measurements_at(e)
        if len(z) == 0:
            continue
        escape = escapes.escaped(stream.t[e], lm)
        betas = tempering_exponents(stream.t[e], lm, last_seen, params.measurement_correlation_s)
        explained = np.ones(len(lm), dtype=bool)
        for i, (zi, j, R, beta) in enumerate(zip(z, lm, params.measurement_covariance(z), betas)):
            explained[i] = is_explained(particles, zi, int(j), R, params.gate_chi2)
            if not (explained[i] or escape[i]):
                continue  # rejected: no particle explains it
            gate = None if escape[i] else params.gate_chi2
            for p in particles:
                update_particle(p, zi, int(j), R, update_map=params.mode != "localize", gate_chi2=gate,
                                beta=float(beta))
        escapes.record(stream.t[e], lm, explained)
        w = weights_from_log(np.array([p.logw for p in particles]))
        if effective_sample_size(w) < params.resample_threshold * M:
            idx = get_resampler(params.resampler)(w, rng)
            particles = [particles[i].copy() for i in idx]
            for p in particles:
                p.logw = 0.0
            w = np.full(M, 1.0 / M)
        path[e] = _combined_pose(particles, w)
    return particles, path


def _combined_pose(particles: list[Particle], w) -> np.ndarray:
    x = sum(wm * p.pose[0] for p, wm in zip(particles, w))
    y = sum(wm * p.pose[1] for p, wm in zip(particles, w))
    s = sum(wm * np.sin(p.pose[2]) for p, wm in zip(particles, w))
    c = sum(wm * np.cos(p.pose[2]) for p, wm in zip(particles, w))
    return np.array([x, y, np.arctan2(s, c)])
