"""FastSLAM 1.0 with known correspondences, vectorised over particles.

The filter of Montemerlo et al. (2002), in the order of the MR.CLAM write-up's
``propagate_all_states``, ``reweight_and_update``, ``resample`` and
``combine_particles``:

1. **Propagate** every particle's pose by sampling the motion model,
   :math:`x_t^{[m]} \\sim p(x_t \\mid x_{t-1}^{[m]}, u_t)` (:mod:`fastslam_edu.motion`).
2. **Update** for each measurement :math:`z = (r, \\phi)` of landmark :math:`k`:
   a landmark seen for the first time is initialised from the inverse model
   (:func:`fastslam_edu.ekf.initialise_landmark`); otherwise its 2×2 EKF is
   updated and the particle's log weight grows by the log-likelihood
   :math:`\\log \\mathcal N(\\nu; 0, Q)` (:func:`fastslam_edu.ekf.update_landmark`), times the
   fraction :math:`\\beta \\le 1` of independent evidence the sighting carries
   (:func:`evidence_fractions`; 1 in the textbook).
3. **Resample** (:mod:`fastslam_edu.resampling`) when the effective sample size
   :math:`N_\\text{eff} = 1/\\sum_m (w^{[m]})^2` falls below a fraction of
   :math:`M` (default 0.5); weights are reset to uniform afterwards.
4. **Combine**: the weighted mean pose and map, and the highest-weight particle.

State of the filter (:class:`ParticleSet`), for :math:`M` particles and :math:`K` landmarks:

=========  ==============  ==========================================
poses      (M, 3)          :math:`x^{[m]} = (x, y, \\theta)` [m, m, rad]
mu         (M, K, 2)       :math:`\\mu_k^{[m]}` [m]
sigma      (M, K, 2, 2)    :math:`\\Sigma_k^{[m]}` [m²]
seen       (M, K) bool     landmark k initialised in particle m
logw       (M,)            :math:`\\log w^{[m]}` (unnormalised)
=========  ==============  ==========================================

Between two measurement instants the filter propagates through every odometry
step of the segment at once, with running sums instead of a loop
(:func:`propagate_segment`, :func:`fastslam_edu.motion.segment_increments`), which
is what makes full-rate (~65 Hz) odometry cheap.

What real data needs beyond the textbook (see :mod:`fastslam_edu.noise_estimation`):
noise densities per √s (independent of the odometry rate), and a gate against
outlier measurements: a measurement is rejected when, for *every* particle,
its squared Mahalanobis distance exceeds ``gate_chi2`` (default: the point of
χ² with 2 degrees of freedom exceeded once in a million), unless the same
landmark has been rejected for ``gate_escape_s`` seconds (:func:`gate_measurements`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.stats import chi2

from .datasets.log import EventStream
from .ekf import initialise_landmark, innovation_unchecked, kalman_correction_unchecked
from .angles import wrap_angle
from .motion import MotionNoise, path_from_increments, segment_increments
from .proposal import motion_prediction, sample_improved_poses, segment_motion
from .resampling import get_resampler
from .weights import weights_from_log

MODES = ("slam", "localize", "map")
PROPOSALS = ("motion", "fastslam2")

#: χ²₂ 99.9 % quantile (upper tail 1e-3) ≈ 13.8, the textbook gate for a well-modelled sensor.
#: For 2 degrees of freedom the tail is exp(−d²/2), so this is exactly −2 ln(1e-3).
CHI2_2DOF_999 = float(chi2.isf(1e-3, df=2))

#: χ²₂ quantile with an upper tail of one in a million ≈ 27.6 (= −2 ln(1e-6)). With the
#: inflated R of the defaults it catches only gross errors (a misread barcode, a range off
#: by metres).
CHI2_2DOF_1E6 = float(chi2.isf(1e-6, df=2))

#: Longest run of odometry steps propagated at once (bounds memory: M × L × 3 floats).
MAX_SEGMENT = 512


@dataclass(frozen=True)
class FastSLAMParams:
    """Settings of the filter.

    Where the defaults come from (:mod:`fastslam_edu.noise_estimation`, chapter
    "The MR.CLAM data"; measured on every robot with groundtruth of Datasets 1 and 6):

    * **Measurement noise.** Robust (MAD) residuals of ~26 000 landmark sightings
      against groundtruth: :math:`\\sigma_r \\approx 0.033 + 0.030\\,r` m (range error grows
      with range) and :math:`\\sigma_\\phi \\approx 0.008` rad. But readings of one landmark
      within a second are near-copies (they differ by ~1 cm while sharing an
      error of ~13 cm; a landmark is read 2–3 times per second), and the error
      changes only as the viewpoint does, over seconds: it is not white, and a
      filter that fuses the copies as independent is several times too
      confident. The defaults double the standard deviations (quadruple the
      variances):
      :math:`\\sigma_r(r) = 0.07 + 0.06\\,r` m, :math:`\\sigma_\\phi = 0.02` rad.
    * **Motion noise** (per √s, so independent of the odometry rate). Odometry
      increments against groundtruth give 0.013–0.016 m/√s and 0.016–0.034 rad/√s
      at 1–4 s windows, but the error variance grows faster than linearly
      (errors are correlated over seconds: the robots lag the commands by
      ~0.2 s and turn 5–10 % less than commanded). Over the 10–60 s the filter
      dead-reckons between sightings, the heading error is ~0.3 rad per minute,
      so the defaults are :math:`\\sigma_v = 0.02` m/√s and :math:`\\sigma_\\omega = 0.05` rad/√s.
    * **Gate**: a sighting is rejected when :math:`d^2 > 27.6` (exceeded by one good
      sighting in a million) for *every* particle — with the inflated :math:`R`
      only gross errors are (a misread barcode, a range off by metres; Dataset 6
      robot 3 has sightings at :math:`d^2 \\sim 10^5`) — and applied without the gate once a
      landmark has been rejected for 5 s (``gate_escape_s``; the filter is lost).
      Measured, 20 seeds at full rate on the six robots with groundtruth: mean of
      the median path RMSEs 0.77 m (0.71 m without a gate: within the spread
      between seeds); at 1 Hz on Dataset 1 robot 2 it is what makes the
      difference: median path RMSE 0.78 m, worst 1.3 m, where the earlier
      per-particle floored gate (reject when particles holding half the weight
      are beyond the gate) gave 1.39 m, worst 4.3 m, rejecting 1,000 of 2,453
      sightings of a filter that was merely uncertain. After a kidnap the
      escape brings the filter back within one to two minutes (45–109 s in
      chapter "The write-up's experiments"), where the floored gate took ~500 s.
    * **Tempered likelihoods**: a sighting :math:`\\Delta t` after the previous sighting of
      the same landmark weighs the particles with its likelihood to the power
      :math:`\\min(1, \\Delta t/\\tau)`, :math:`\\tau = 4` s (:func:`evidence_fractions`: the
      bearing error's one-second correlation, 0.61, leaves about a quarter of an
      independent reading's information per second). Measured, 20 seeds at full
      rate on the six robots: mean of the median aligned landmark errors
      0.151 → 0.109 m (every robot ≤ 0.20 m), path RMSE 0.77 → 0.64 m, landmark
      error 0.91 → 0.80 m; τ = 10 s gives 0.105 / 0.74 / 0.89 m; a constant
      exponent 0.125 gives 0.119 / 0.67 / 0.77 m. At 1 Hz on Dataset 1 robot 2:
      path RMSE 0.78 → 0.74 m. Fewer resamplings keep more heading hypotheses
      alive (particle depletion is what limits FastSLAM 1.0 here: 1000
      particles without tempering give 0.112 / 0.59 / 0.67 m over 5 seeds).
    * **Resampling** when :math:`N_\\text{eff} < M/2`, the usual rule of thumb: it keeps
      the particle diversity that resampling at every step (the write-up's
      choice) throws away.

    What each choice is worth, measured (chapter "From textbook to real data"):
    on Dataset 1 robot 2 the change that clearly matters is the rate-correct
    motion noise (landmark error 0.67 → 0.37 m, aligned 0.36 → 0.07 m, 2 seeds);
    without it the defaults lose the robot. The inflation of :math:`R` is what lets
    the gate work: with the measured, uninflated :math:`R` the gate rejects
    1400–3200 good sightings per run and 2 of 8 seeds lose the robot. Beyond
    that, the inflation, the gate and the :math:`N_\\text{eff}` rule change the error
    by less than the spread between seeds.

    Attributes
    ----------
    n_particles : int
        :math:`M`.
    motion_noise : MotionNoise
        Per-√s noise densities (rate independent).
    measurement_cov : ndarray (2, 2)
        :math:`R = \\mathrm{diag}(\\sigma_r^2, \\sigma_\\phi^2)` [m², rad²].
    resampler : str
        ``"systematic"`` (default, lowest variance), ``"stratified"``,
        ``"residual"`` or ``"multinomial"`` (the roulette wheel).
    resample_threshold : float
        Resample when :math:`N_\\text{eff} < \\text{threshold}\\cdot M`; 1.0 resamples at
        every measurement step, whatever the weights (the write-up's behaviour), 0 never.
    gate_chi2 : float or None
        Outlier gate on :math:`d^2 = \\nu^\\top Q^{-1}\\nu` (:func:`gate_measurements`); None disables it.
    gate_escape_s : float or None
        Once every sighting of a landmark for this long [s] has been rejected,
        its sightings are applied without the gate until a particle explains
        one again: a landmark that disagrees with every particle, again and
        again, says that the filter is lost (a kidnap, a long drift), not that
        the sensor failed. A duration, not a count, because MR.CLAM's sightings
        of a landmark within a second are near-copies (one bad reading comes
        two or three times). None: never.
    measurement_correlation_s : float or None
        :math:`\\tau`: a sighting of a landmark :math:`\\Delta t` seconds after the previous
        sighting of the same landmark weighs the particles with its likelihood to
        the power :math:`\\beta = \\min(1, \\Delta t / \\tau)` (:func:`evidence_fractions`): its error
        repeats the previous one's, so it carries only part of an independent
        sighting's evidence. The EKF update of the landmark is unchanged. None:
        every sighting counts fully (the textbook).
    mode : str
        ``"slam"``, ``"localize"`` (landmarks known, fixed) or ``"map"`` (poses known).
    proposal : str
        ``"motion"`` (FastSLAM 1.0, the default: poses sampled from the motion
        model alone) or ``"fastslam2"`` (FastSLAM 2.0's proposal, poses sampled
        given the sighting too, :mod:`fastslam_edu.proposal`). Measured, 20 seeds at
        full rate, M = 100, on the six robots the issue's targets name
        (``benchmarks/fastslam_accuracy.py --proposal``), means of the per-robot medians:
        path RMSE 0.64 → 0.51 m, landmark error 0.80 → 0.62 m, aligned 0.109 → 0.088 m,
        mean of the worst path RMSEs 1.45 → 0.98 m; it resamples several times less often
        (Dataset 6 robot 2: 86 against 531 times) and takes ~2.2× the time (chapter
        "FastSLAM 2.0's proposal"). At 1 Hz on Dataset 1 robot 2 (10 seeds): path RMSE
        0.70 → 0.61 m, aligned landmark error 0.154 → 0.094 m.
    range_std_slope : float
        Growth of the range noise with range [m/m]: the filter uses
        :math:`\\sigma_r(r) = \\sqrt{R_{00}} + \\text{slope}\\cdot r` for a measurement of range
        :math:`r` (MR.CLAM's camera estimates range from the barcode's apparent
        size; its error grows ~3 cm per metre, see :mod:`fastslam_edu.noise_estimation`).
    odometry_scale : (float, float)
        Calibration :math:`(k_v, k_\\omega)` of the commands: the filter moves with
        :math:`(k_v v, k_\\omega \\omega)`. MR.CLAM's odometry is the *commanded*
        velocity, and the robots turn less than commanded (see
        :mod:`fastslam_edu.noise_estimation`).
    """

    n_particles: int = 100
    motion_noise: MotionNoise = field(
        default_factory=lambda: MotionNoise(mode="control", sigma_v=0.02, sigma_omega=0.05)
    )
    measurement_cov: np.ndarray = field(default_factory=lambda: np.diag([0.07**2, 0.02**2]))
    resampler: str = "systematic"
    resample_threshold: float = 0.5
    gate_chi2: float | None = CHI2_2DOF_1E6
    gate_escape_s: float | None = 5.0
    measurement_correlation_s: float | None = 4.0
    mode: str = "slam"
    odometry_scale: tuple[float, float] = (1.0, 1.0)
    range_std_slope: float = 0.06
    proposal: str = "motion"

    def __post_init__(self):
        if int(self.n_particles) < 1:
            raise ValueError(f"n_particles must be >= 1, got {self.n_particles!r}")
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        if self.proposal not in PROPOSALS:
            raise ValueError(f"proposal must be one of {PROPOSALS}, got {self.proposal!r}")
        R = np.asarray(self.measurement_cov, dtype=float)
        if R.shape != (2, 2) or not np.all(np.isfinite(R)) or np.any(np.linalg.eigvalsh(R) <= 0):
            raise ValueError(f"measurement_cov must be a 2x2 positive definite matrix, got {R!r}")
        object.__setattr__(self, "measurement_cov", R)
        if not 0.0 <= float(self.resample_threshold) <= 1.0:
            raise ValueError(f"resample_threshold must be in [0, 1], got {self.resample_threshold!r}")
        if self.gate_chi2 is not None and not float(self.gate_chi2) > 0:
            raise ValueError(f"gate_chi2 must be positive or None, got {self.gate_chi2!r}")
        if self.gate_escape_s is not None and not float(self.gate_escape_s) >= 0:
            raise ValueError(f"gate_escape_s must be >= 0 seconds or None, got {self.gate_escape_s!r}")
        tau = self.measurement_correlation_s
        if tau is not None and not (np.isfinite(tau) and float(tau) > 0):
            raise ValueError(f"measurement_correlation_s must be > 0 seconds or None, got {tau!r}")
        get_resampler(self.resampler)  # validates the name
        if not (np.isfinite(self.range_std_slope) and self.range_std_slope >= 0):
            raise ValueError(f"range_std_slope must be >= 0, got {self.range_std_slope!r}")

    def measurement_covariance(self, z) -> np.ndarray:
        """:math:`R` for each measurement ``z`` (n, 2): shape (n, 2, 2)."""
        z = np.asarray(z, dtype=float).reshape(-1, 2)
        R = np.repeat(self.measurement_cov[None], len(z), axis=0)
        if self.range_std_slope:
            R[:, 0, 0] = (np.sqrt(self.measurement_cov[0, 0]) + self.range_std_slope * z[:, 0]) ** 2
        return R


@dataclass
class ParticleSet:
    """The M particles of FastSLAM 1.0 (arrays, see the module docstring)."""

    poses: np.ndarray
    mu: np.ndarray
    sigma: np.ndarray
    seen: np.ndarray
    logw: np.ndarray
    count: np.ndarray | None = None  # (M, K) sightings used per landmark (default: 1 where seen)

    def __post_init__(self):
        if self.count is None:
            self.count = np.asarray(self.seen, dtype=np.int64).copy()

    @classmethod
    def initial(cls, n_particles: int, n_landmarks: int, x0) -> "ParticleSet":
        """All particles at pose ``x0`` (3,), no landmark seen, uniform weights."""
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (3,) or not np.all(np.isfinite(x0)):
            raise ValueError(f"initial pose must be 3 finite numbers (x, y, theta), got {x0!r}")
        M, K = int(n_particles), int(n_landmarks)
        return cls(
            poses=np.tile(x0, (M, 1)),
            mu=np.zeros((M, K, 2)),
            sigma=np.tile(np.eye(2), (M, K, 1, 1)),
            seen=np.zeros((M, K), dtype=bool),
            logw=np.zeros(M),
        )

    def __len__(self) -> int:
        return self.poses.shape[0]

    @property
    def weights(self) -> np.ndarray:
        """Normalised weights :math:`w^{[m]}`, shape (M,)."""
        return weights_from_log(self.logw)

    def with_known_map(self, landmarks) -> "ParticleSet":
        """Every particle holding the known landmarks ``(K, 2)`` (localisation), Σ = 10⁻⁶ I."""
        self.mu[:] = landmarks
        self.sigma[:] = np.eye(2) * 1e-6
        self.seen[:] = True
        self.count[:] = 1
        return self

    def update(self, z, k, R, *, update_map: bool = True, gate_chi2: float | None = None, escape=None,
               power=None, proposal_loglik=None) -> np.ndarray:
        """Step 2 for the measurements of one instant: :func:`update_with_measurements`."""
        return update_with_measurements(self, z, k, R, update_map=update_map, gate_chi2=gate_chi2, escape=escape,
                                        power=power, proposal_loglik=proposal_loglik)

    def to_particle_set(self) -> "ParticleSet":
        """The set as dense arrays: itself (see the tree storage of :mod:`fastslam_edu.fastslam_tree`)."""
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
        Every particle's pose after each step (headings not wrapped: they run on
        continuously from the wrapped starting headings); ``particles.poses`` is
        set to the poses after the last step (heading wrapped).
    """
    x0, (dx, dy, theta) = _sample_segment(particles, u, dt, noise, rng)
    return path_from_increments(x0, dx, dy, theta, wrap=False)


def propagate_segment(particles: ParticleSet, u, dt, noise: MotionNoise, rng: np.random.Generator, w,
                      n_record: int | None = None):
    """Step 1 as the filter runs it: :func:`propagate`, returning only the estimates along the way.

    The same random numbers and the same final poses as :func:`propagate`, but
    instead of every particle's path (M, L, 3) it returns what the filter
    records at each step: the weighted-mean pose and the pose of the
    highest-weight particle. The mean position is a running sum of mean
    displacements, :math:`\\bar x_t = \\sum_m w^{[m]} x_0^{[m]} + \\sum_{j \\le t} \\sum_m w^{[m]} \\Delta x_j^{[m]}`
    (weights sum to 1): one running sum of L numbers instead of M of them.

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
    x0, (dx, dy, theta) = _sample_segment(particles, u, dt, noise, rng)
    L = dx.shape[1]
    n = L if n_record is None else n_record
    if n == 0:
        return np.empty((0, 3)), np.empty((0, 3))
    b = int(np.argmax(w))
    if L == 1:  # one step (the 1 Hz stream): the poses are the new ones
        return combined_pose(particles.poses, w)[None], particles.poses[b][None]
    if n < L:
        dx, dy, theta = dx[:, :n], dy[:, :n], theta[:, :n]
    mean = np.empty((n, 3))
    mean[:, 0] = w @ x0[:, 0] + np.cumsum(w @ dx)
    mean[:, 1] = w @ x0[:, 1] + np.cumsum(w @ dy)
    mean[:, 2] = combined_heading(theta, w)
    best = np.empty_like(mean)
    best[:, 0] = x0[b, 0] + np.cumsum(dx[b])
    best[:, 1] = x0[b, 1] + np.cumsum(dy[b])
    best[:, 2] = wrap_angle(theta[b])
    return mean, best


def _sample_segment(particles: ParticleSet, u, dt, noise: MotionNoise, rng: np.random.Generator):
    """Draw the segment's noise, compute the increments, move ``particles.poses`` to the end.

    Returns ``(x0, (dx, dy, theta))``: the starting poses and
    :func:`fastslam_edu.motion.segment_increments`.
    """
    u = np.atleast_2d(np.asarray(u, dtype=float))
    dt = np.atleast_1d(np.asarray(dt, dtype=float))
    eps = rng.standard_normal((len(particles), len(dt), noise.n_draws))
    x0 = particles.poses
    dx, dy, theta = segment_increments(x0, u, dt, noise, eps)
    end = np.empty_like(x0)
    if dx.shape[1] == 1:  # one step (the 1 Hz stream): the same numbers without the sums
        end[:, 0] = x0[:, 0] + dx[:, 0]
        end[:, 1] = x0[:, 1] + dy[:, 0]
    else:
        end[:, 0] = x0[:, 0] + dx.sum(axis=1)
        end[:, 1] = x0[:, 1] + dy.sum(axis=1)
    end[:, 2] = wrap_angle(theta[:, -1])
    particles.poses = end
    return x0, (dx, dy, theta)


def update_with_measurement(
    particles: ParticleSet,
    z,
    k: int,
    R,
    *,
    update_map: bool = True,
    gate_chi2: float | None = None,
    escape: bool = False,
    power: float = 1.0,
    proposal_loglik=None,
) -> bool:
    """Step 2 for one measurement ``z = (r, φ)`` of landmark ``k``, all particles at once.

    Particles that have not seen landmark ``k`` initialise it
    (:math:`\\mu = h^{-1}(x, z)`, :math:`\\Sigma = G R G^\\top`) and keep their weight;
    the others update its EKF and add :math:`\\log \\mathcal N(\\nu; 0, Q)` to their
    log weight. With ``update_map=False`` (localisation with a known map) only
    the weight changes.

    The gate (see :func:`gate_measurements`) sets aside a measurement that *no*
    particle explains (:math:`d^2 = \\nu^\\top Q^{-1} \\nu >` ``gate_chi2`` for every
    particle that has seen the landmark): it changes neither weights nor
    maps. ``escape=True`` applies it without the gate (the run does so once
    every sighting of the landmark for ``gate_escape_s`` seconds has been
    unexplained: then it is the filter that is wrong, not the measurement). ``power``
    :math:`\\beta` scales the log-likelihood added to the weights (:func:`evidence_fractions`).
    ``proposal_loglik`` (M,): where not NaN, the log-likelihood to weigh with instead of
    :math:`\\log \\mathcal N(\\nu; 0, Q)` (FastSLAM 2.0's weight,
    :func:`fastslam_edu.proposal.sample_improved_poses`).

    Returns
    -------
    bool
        False when no particle explains the measurement (it was rejected, unless ``escape``).
    """
    z = np.asarray(z, dtype=float)
    new = ~particles.seen[:, k]  # a new array: initialising below must not change it
    explained = True
    if not new.all():
        idx = slice(None) if not new.any() else ~new
        explained = _update_seen(particles, idx, k, z, R, update_map=update_map, gate_chi2=gate_chi2,
                                 escape=escape, power=power,
                                 proposal_loglik=None if proposal_loglik is None else proposal_loglik[idx])
    if new.any():
        particles.mu[new, k], particles.sigma[new, k] = initialise_landmark(particles.poses[new], z, R)
        particles.seen[new, k] = True
        particles.count[new, k] = 1
    return bool(explained)


def _update_seen(particles: ParticleSet, idx, k, z, R, *, update_map, gate_chi2, escape, power, proposal_loglik):
    """The EKF update of landmark(s) ``k`` in the particles ``idx`` that have seen them, behind the gate.

    One landmark: ``k`` an int, ``idx`` a slice or a mask over particles, arrays (M',).
    Several: ``k`` (n,), ``idx`` all particles, arrays (M, n) (:func:`update_with_measurements`).
    Adds the (gated, tempered) log-likelihoods to the log weights, writes the
    corrected landmarks, counts the sightings used; returns ``explained``
    (:func:`gate_measurements`).
    """
    mu, sigma, poses = particles.mu[idx, k], particles.sigma[idx, k], particles.poses[idx]
    several = np.ndim(k) == 1
    if several:
        poses = poses[:, None, :]
    terms, d2, loglik = innovation_unchecked(mu, sigma, poses, z, R)
    if proposal_loglik is not None:
        loglik = _with_proposal_loglik(loglik, proposal_loglik)
    if np.ndim(power) or power != 1.0:
        loglik = loglik * power
    apply, young, explained = None, None, True
    if gate_chi2 is not None:
        loglik, apply, young, explained = gate_measurements(
            d2, gate_chi2, loglik, count=particles.count[idx, k], update_map=update_map, escape=escape
        )
    particles.logw[idx] += loglik.sum(axis=1) if several else loglik
    if update_map:
        mu, sigma = kalman_correction_unchecked(mu, terms, apply)
        if young is not None:  # re-initialised from the new sighting (rare)
            shape = young.shape
            mu[young], sigma[young] = initialise_landmark(
                np.broadcast_to(poses, shape + (3,))[young],
                np.broadcast_to(z, shape + (2,))[young],
                np.broadcast_to(R, shape + (2, 2))[young],
            )
        particles.mu[idx, k], particles.sigma[idx, k] = mu, sigma
    particles.count[idx, k] += True if apply is None else apply
    return explained


def gate_measurements(d2, gate_chi2, loglik, *, count, update_map=True, escape=False):
    """The outlier gate, given the squared Mahalanobis distances of an EKF update.

    ``d2`` is :math:`d^2 = \\nu^\\top Q^{-1} \\nu` per particle (M',) or per particle and
    measurement (M, n); ``loglik`` their log-likelihoods, ``count`` the sightings each
    particle has used of the landmark. Where :math:`d^2 >` ``gate_chi2`` the
    measurement is an outlier *for that particle*:

    * if it is an outlier for **every** particle, no hypothesis explains it — a
      misread barcode, a range off by metres: it is **rejected**, weights and
      maps unchanged;
    * otherwise each particle keeps its log-likelihood (a particle that
      disagrees with a measurement others explain *should* lose weight), and an
      outlier particle leaves its landmark alone: an update from a pose that
      does not fit would bend its map;
    * a landmark seen only once whose second sighting is an outlier is
      re-initialised from the new sighting instead, at no cost in weight: one
      of the two sightings is wrong, and a landmark initialised from an outlier
      would otherwise reject every good sighting after it (with ``update_map``).

    ``escape`` (bool, or (n,)) switches the gate off for a measurement: it is
    applied to every particle as if there were no gate.

    Returns ``(loglik, apply, young, explained)``: the log-likelihoods to add to the
    weights; ``apply`` (bool, like ``d2``, or None for all) the particle–measurement
    pairs whose landmark is corrected (and whose sighting is counted); ``young`` (or
    None) those re-initialised; ``explained`` (scalar or (n,)) False where no particle
    explains the measurement (rejected unless escaped).
    """
    outlier = d2 > gate_chi2
    if not outlier.any():
        return loglik, None, None, True
    explained = ~outlier.all(axis=0)
    escape = np.asarray(escape)
    if escape.any():
        outlier = outlier & ~escape
    rejected = ~explained & ~escape
    young = outlier & (count == 1) if update_map else None
    if young is not None and not young.any():
        young = None
    drop = rejected if young is None else young | rejected
    if drop.any():
        loglik = np.where(drop, 0.0, loglik)
    return loglik, ~outlier, young, explained


def update_with_measurements(
    particles: ParticleSet,
    z,
    k,
    R,
    *,
    update_map: bool = True,
    gate_chi2: float | None = None,
    escape=None,
    power=None,
    proposal_loglik=None,
) -> np.ndarray:
    """Step 2 for all the measurements of one instant: ``z`` (n, 2) of landmarks ``k`` (n,).

    Measurements of *different* landmarks are independent given the pose, so
    they are applied at once on (M, n) arrays — the same numbers as applying
    them one by one with :func:`update_with_measurement` (log weights add).
    A landmark seen twice at one instant is applied in a second round, after
    the first. ``escape`` (n,) bool: measurements applied without the gate;
    ``power`` (n,): the exponents :math:`\\beta` of their likelihoods (default 1);
    ``proposal_loglik`` (M, n): where not NaN, log-likelihoods to weigh with instead of
    FastSLAM 1.0's (:func:`update_with_measurement`). Returns a bool (n,): False where no particle explains the measurement
    (rejected by the gate, unless escaped).
    """
    z = np.asarray(z, dtype=float).reshape(-1, 2)
    k = np.asarray(k, dtype=int).reshape(-1)
    n = len(k)
    R = np.asarray(R, dtype=float)
    if R.ndim == 2:
        R = np.broadcast_to(R, (n, 2, 2))  # one R per measurement
    escape = np.zeros(n, dtype=bool) if escape is None else np.asarray(escape, dtype=bool).reshape(-1)
    power = np.ones(n) if power is None else np.asarray(power, dtype=float).reshape(-1)
    if n == 1:  # the common case: one landmark, read and written through views (no copies)
        return np.array([update_with_measurement(
            particles, z[0], int(k[0]), R[0], update_map=update_map, gate_chi2=gate_chi2, escape=bool(escape[0]),
            power=float(power[0]), proposal_loglik=None if proposal_loglik is None else proposal_loglik[:, 0],
        )])
    if len(escape) != n or len(power) != n:
        escape, power = np.broadcast_to(escape, k.shape), np.broadcast_to(power, k.shape)
    column = (lambda j: None) if proposal_loglik is None else (lambda j: proposal_loglik[:, j])  # noqa: E731
    explained = np.ones(n, dtype=bool)
    if len(set(k.tolist())) < n:  # the same landmark twice: distinct ones first, then the rest
        first = np.unique(k, return_index=True)[1]
        rest = np.setdiff1d(np.arange(n), first)
        for part in (first, rest):
            explained[part] = update_with_measurements(
                particles, z[part], k[part], R[part], update_map=update_map, gate_chi2=gate_chi2, escape=escape[part],
                power=power[part], proposal_loglik=column(part),
            )
        return explained
    seen = particles.seen[:, k]  # (M, n), a copy
    batch = np.ones(n, dtype=bool) if seen.all() else seen.all(axis=0)  # seen by every particle: the common case
    if batch.any():
        everything = batch.all()
        kb, zb, Rb, eb, pb = ((k, z, R, escape, power) if everything
                              else (k[batch], z[batch], R[batch], escape[batch], power[batch]))
        explained[batch] = _update_seen(particles, slice(None), kb, zb, Rb, update_map=update_map,
                                        gate_chi2=gate_chi2, escape=eb, power=pb, proposal_loglik=column(batch))
    if not batch.all():
        for j in np.flatnonzero(~batch):  # first sightings (or particles that differ)
            explained[j] = update_with_measurement(
                particles, z[j], int(k[j]), R[j], update_map=update_map, gate_chi2=gate_chi2, escape=bool(escape[j]),
                power=float(power[j]), proposal_loglik=column(j),
            )
    return explained


def _with_proposal_loglik(loglik, proposal_loglik):
    """FastSLAM 1.0's log-likelihoods, replaced by the proposal's where it gives one (not NaN)."""
    return np.where(np.isnan(proposal_loglik), loglik, proposal_loglik)


class GateEscape:
    """When a landmark's sightings escape the gate (``FastSLAMParams.gate_escape_s``).

    Per landmark, the time of the first of its sightings that no particle has
    explained since (``unexplained_since``, ``inf`` while they are explained).
    Once that is ``escape_s`` seconds ago, its sightings are applied without the
    gate until one is explained again. Shared by the engine and the loop reference.
    """

    def __init__(self, n_landmarks: int, escape_s: float | None):
        self.escape_s = np.inf if escape_s is None else float(escape_s)
        self.unexplained_since = np.full(n_landmarks, np.inf)

    def escaped(self, t: float, landmarks) -> np.ndarray:
        """Bool (n,): the sightings of ``landmarks`` (n,) at time ``t`` that skip the gate."""
        return t - self.unexplained_since[landmarks] >= self.escape_s

    def record(self, t: float, landmarks, explained) -> None:
        """Note which sightings at ``t`` some particle explained (``explained`` (n,) bool)."""
        since = self.unexplained_since[landmarks]
        self.unexplained_since[landmarks] = np.where(explained, np.inf, np.minimum(since, t))


def evidence_fractions(t, landmarks, last_seen, tau: float | None) -> np.ndarray:
    """Exponents :math:`\\beta = \\min(1, \\Delta t / \\tau)` of the likelihoods of sightings at time ``t``.

    :math:`\\Delta t` is the time since the previous sighting of the same landmark
    (``last_seen`` (K,) [s], ``-inf`` if none; updated in place to ``t``).

    Why: FastSLAM multiplies the likelihoods of all sightings as if their errors
    were independent. MR.CLAM's are not: a landmark's range and bearing errors
    persist for seconds (correlation of the residuals against groundtruth,
    Dataset 6: range 0.87 after 1 s, 0.59 after 4 s; bearing 0.61 and 0.50),
    and a landmark in view is read 2–3 times per second. Counted as
    independent, a few seconds of near-copies make the weights far too peaked,
    resampling throws away particles that were right, and the heading
    hypotheses die out (particle depletion). Raising each likelihood to the
    power β — a "tempered" likelihood — counts a sighting :math:`\\Delta t` after the
    previous one as the fraction :math:`\\Delta t / \\tau` of an independent one. For an
    AR(1) error with one-second correlation ρ, the new information per reading is
    about :math:`(1-\\rho)/(1+\\rho)`: 0.24 for the bearing (:math:`\\tau \\approx 4` s), 0.07 for the
    range (~14 s). ``tau=None`` gives β = 1 (the textbook).

    Returns ``beta`` (n,) for ``landmarks`` (n,).
    """
    landmarks = np.asarray(landmarks, dtype=int)
    if tau is None:
        return np.ones(len(landmarks))
    beta = np.minimum(1.0, (t - last_seen[landmarks]) / tau)
    last_seen[landmarks] = t
    return beta


def resample_if_needed(
    particles: ParticleSet, resampler: str, threshold: float, rng: np.random.Generator
) -> tuple[ParticleSet, float, bool]:
    """Step 3: resample when :math:`N_\\text{eff} < \\text{threshold}\\cdot M`.

    Returns ``(particles, N_eff before, resampled?)``; after resampling the
    weights are uniform (the evidence is now in the particle counts — keeping
    the old weights as well would count it twice).
    """
    w = particles.weights
    n_eff = 1.0 / np.dot(w, w)  # effective_sample_size(w), without re-checking w
    if threshold >= 1.0 or n_eff < threshold * len(particles):  # 1.0: at every call (the write-up)
        return particles.select(get_resampler(resampler)(w, rng)), n_eff, True
    return particles, n_eff, False


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
    For many headings it is computed relative to particle 0's heading
    :math:`\\theta^{[0]}` (the same number: rotating every angle rotates the mean):
    the deviations :math:`\\delta^{[m]} = \\theta^{[m]} - \\theta^{[0]}`, wrapped, are small, so
    their sines and cosines can be taken in single precision (~10× faster; error
    ~1e-8 rad for a spread of 0.1 rad) — the filter averages every particle's
    heading at every odometry step.
    """
    theta = np.asarray(theta, dtype=float)
    if theta.ndim == 1:  # one heading per particle: one number
        mean = float(np.arctan2(w @ np.sin(theta), w @ np.cos(theta)))
        return np.pi if mean == -np.pi else mean  # wrap_angle of an atan2: only -π moves (to π)
    if theta.size <= 256:  # a few headings: the direct formula is fewer operations
        return wrap_angle(np.arctan2(w @ np.sin(theta), w @ np.cos(theta)))
    ref = theta[0]
    delta = wrap_angle(theta - ref).astype(np.float32)
    return wrap_angle(ref + np.arctan2(w @ np.sin(delta).astype(float), w @ np.cos(delta).astype(float)))


def combined_map(particles: ParticleSet):
    """Step 4 for the map: weighted mean landmarks and their mixture covariance.

    :math:`\\bar\\mu_k = \\sum_m w^{[m]} \\mu_k^{[m]}` over the particles that have seen
    ``k`` (weights renormalised among them), and
    :math:`\\bar\\Sigma_k = \\sum_m w^{[m]} (\\Sigma_k^{[m]} + (\\mu_k^{[m]}-\\bar\\mu_k)(\\mu_k^{[m]}-\\bar\\mu_k)^\\top)`,
    the covariance of the Gaussian mixture (the write-up's "weighted sum of squared
    covariances" is not a covariance: see the chapter on putting it together).

    Returns ``mu (K, 2)``, ``sigma (K, 2, 2)``, ``observed (K,)``; NaN for unseen landmarks.
    """
    w = particles.weights[:, None] * particles.seen  # (M, K)
    tot = w.sum(axis=0)
    observed = tot > 0
    wn = np.divide(w, tot, out=np.zeros_like(w), where=observed)
    mu = np.einsum("mk,mkd->kd", wn, particles.mu)
    d = particles.mu - mu[None]
    sigma = np.einsum("mk,mkij->kij", wn, particles.sigma + d[..., :, None] * d[..., None, :])
    mu[~observed] = np.nan
    sigma[~observed] = np.nan
    return mu, sigma, observed


# ---------------------------------------------------------------- the whole run


@dataclass
class FastSLAMResult:
    """What a run produces.

    Attributes
    ----------
    t : (N,) step times [s]
    pose_mean : (N, 3) weighted-mean pose after each step
    pose_best : (N, 3) pose of the highest-weight particle after each step
    landmarks_mean, landmarks_cov, observed : the combined map at the end ((K,2), (K,2,2), (K,))
    landmarks_best : (K, 2) map of the highest-weight particle at the end
    ess_t, ess : times and :math:`N_\\text{eff}` at every step that had measurements
    n_resamples, measurements_used, measurements_rejected : counts
    filter_seconds : wall time of the filter loop
    particles : the final ParticleSet (dense arrays)
    final : the final particle set as the filter stored it (a ParticleSet, or tree-backed)
    """

    t: np.ndarray
    pose_mean: np.ndarray
    pose_best: np.ndarray
    landmarks_mean: np.ndarray
    landmarks_cov: np.ndarray
    observed: np.ndarray
    landmarks_best: np.ndarray
    ess_t: np.ndarray
    ess: np.ndarray
    n_resamples: int
    measurements_used: int
    measurements_rejected: int
    filter_seconds: float
    particles: ParticleSet
    params: FastSLAMParams
    landmark_subjects: np.ndarray
    final: object = None


def _segments(stream: EventStream, cut_times=()):
    """Split steps into runs ending at a measurement step (or MAX_SEGMENT, or a cut time)."""
    n_meas = np.diff(stream.offsets)
    ends = set(np.flatnonzero(n_meas > 0).tolist())
    for tc in cut_times:
        k = int(np.searchsorted(stream.t, tc, side="left"))
        if k < len(stream):
            ends.add(k)  # the step at or just after tc ends a segment
    ends.add(len(stream) - 1)
    start = 0
    for end in sorted(ends):
        while end - start + 1 > MAX_SEGMENT:
            yield start, start + MAX_SEGMENT - 1
            start += MAX_SEGMENT
        if end >= start:
            yield start, end
        start = end + 1


def stream_commands(stream: EventStream, params: FastSLAMParams):
    """The stream's commands times ``params.odometry_scale``, and its time steps, checked: ``(u (N, 2), dt (N,))``."""
    u = np.asarray(stream.u, dtype=float) * np.asarray(params.odometry_scale, dtype=float)
    dt = np.asarray(stream.dt, dtype=float)
    if not (np.isfinite(u).all() and np.isfinite(dt).all()) or (dt < 0).any():
        bad = np.flatnonzero(~np.isfinite(u).all(axis=1) | ~np.isfinite(dt) | (dt < 0))
        raise ValueError(f"the event stream has non-finite commands or negative time steps ({len(bad)} step(s), "
                         f"the first at step {bad[0]}, t = {stream.t[bad[0]]!r})")
    return u, dt


def run_fastslam(
    stream: EventStream,
    params: FastSLAMParams = FastSLAMParams(),
    rng: np.random.Generator | int | None = 0,
    *,
    x0=None,
    landmarks=None,
    groundtruth_poses=None,
    kidnap: tuple[float, tuple[float, float, float]] | None = None,
    progress: bool = False,
    particle_class=None,
    monitor=None,
) -> FastSLAMResult:
    """Run FastSLAM 1.0 over an event stream.

    Parameters
    ----------
    stream : EventStream
        From :func:`fastslam_edu.datasets.events.event_stream` (full rate or 1 Hz).
    params : FastSLAMParams
    rng : numpy.random.Generator or int seed
    x0 : (3,) initial pose; default ``stream.x0`` (groundtruth at the first step).
    landmarks : (K, 2) known landmark positions, needed for ``mode="localize"``.
    groundtruth_poses : callable ``t -> (n, 3)`` poses, needed for ``mode="map"``.
    kidnap : ``(t_k, (x, y, θ))`` — at the first step at or after ``t_k`` every
        particle is moved to that pose (the write-up's kidnapped-robot test).
    progress : show a tqdm progress bar.
    particle_class : how particles store their maps: :class:`ParticleSet` (dense
        arrays, the default) or :class:`fastslam_edu.fastslam_tree.TreeParticleSet`
        (Montemerlo's trees); anything with the same ``initial``, ``with_known_map``,
        ``update``, ``select``, ``weights`` and ``to_particle_set``. The result's
        ``particles`` is always dense; ``final`` is the set as stored.
    monitor : callable ``monitor(t, particles, w)``, optional
        Called after every measurement step (after resampling) with the step's
        time, the particle set as stored (``particle_class``) and the normalised
        weights the step's estimate used: a way to look inside the filter (chapter "Is the filter's
        uncertainty honest?") without changing it. It must not modify them;
        its time counts in ``filter_seconds``.
    """
    rng = np.random.default_rng(rng) if not isinstance(rng, np.random.Generator) else rng
    x0 = stream.x0 if x0 is None else np.asarray(x0, dtype=float)
    if x0 is None:
        raise ValueError("no initial pose: the stream has no groundtruth; pass x0=(x, y, theta)")
    M, K, N = params.n_particles, stream.n_landmarks, len(stream)
    if N == 0:
        raise ValueError("the event stream is empty")
    particles = (ParticleSet if particle_class is None else particle_class).initial(M, K, x0)
    update_map = params.mode != "localize"
    if params.mode == "localize":
        if landmarks is None:
            raise ValueError('mode="localize" needs the known landmark positions (landmarks=...)')
        landmarks = np.asarray(landmarks, dtype=float)
        if landmarks.shape != (K, 2):
            raise ValueError(f"landmarks must have shape ({K}, 2), got {landmarks.shape}")
        particles = particles.with_known_map(landmarks)
    if params.mode == "map" and groundtruth_poses is None:
        raise ValueError('mode="map" needs the groundtruth poses (groundtruth_poses=callable t -> (n, 3))')
    improved = params.proposal == "fastslam2" and params.mode != "map"  # map mode: the poses are known
    if improved and not isinstance(particles, ParticleSet):
        raise ValueError('proposal="fastslam2" needs the dense ParticleSet (particle_class=None)')

    pose_mean = np.empty((N, 3))
    pose_best = np.empty((N, 3))
    ess_t, ess = [], []
    n_resamples = used = rejected = 0
    escapes = GateEscape(K, params.gate_escape_s)
    last_seen = np.full(K, -np.inf)  # per landmark: time of its latest sighting (for evidence_fractions)
    kidnap_step = None
    if kidnap is not None:
        kidnap_step = int(np.searchsorted(stream.t, kidnap[0], side="left"))

    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=N, unit="step", desc=f"FastSLAM M={M}", mininterval=0.5)
    t_start = time.perf_counter()
    u_all, dt_all = stream_commands(stream, params)
    R_all = params.measurement_covariance(stream.z)  # R of every measurement, once
    w = particles.weights
    for s, e in _segments(stream, () if kidnap is None else (kidnap[0],)):
        z, lm = stream.measurements_at(e)
        last = e if len(z) else e + 1  # a measurement step's estimate is taken after the update
        if params.mode == "map":  # every particle at the groundtruth poses
            truth = np.asarray(groundtruth_poses(stream.t[s : e + 1]), dtype=float)
            mean = best = truth[: last - s]
            particles.poses = np.tile(truth[-1], (M, 1))
        else:
            x_start = particles.poses.copy() if improved else None
            mean, best = propagate_segment(particles, u_all[s : e + 1], dt_all[s : e + 1], params.motion_noise, rng, w,
                                           n_record=last - s)
        kidnapped = kidnap_step is not None and s <= kidnap_step <= e  # segments end at the kidnap step
        if kidnapped:
            particles.poses[:] = np.asarray(kidnap[1], dtype=float)
            mean, best = np.array(mean), np.array(best)
            mean[kidnap_step - s :] = best[kidnap_step - s :] = particles.poses[0]
        if last > s:
            pose_mean[s:last] = mean
            pose_best[s:last] = best
        if len(z):
            t_e = stream.t[e]
            escape = escapes.escaped(t_e, lm)
            power = evidence_fractions(t_e, lm, last_seen, params.measurement_correlation_s)
            R = R_all[stream.offsets[e] : stream.offsets[e + 1]]
            proposal_loglik = None
            if improved and not kidnapped:  # FastSLAM 2.0: move the poses given the sightings first
                x_bar, P = motion_prediction(x_start, *segment_motion(u_all[s : e + 1], dt_all[s : e + 1],
                                                                      params.motion_noise))
                proposal_loglik = sample_improved_poses(particles, z, lm, R, x_bar, P, gate_chi2=params.gate_chi2,
                                                        escape=escape, rng=rng, min_count=2 if update_map else 1)
            explained = particles.update(
                z, lm, R, update_map=update_map, gate_chi2=params.gate_chi2, escape=escape, power=power,
                proposal_loglik=proposal_loglik,
            )
            escapes.record(t_e, lm, explained)
            ok = explained | escape
            used += int(ok.sum())
            rejected += int((~ok).sum())
            particles, n_eff, did = resample_if_needed(
                particles, params.resampler, params.resample_threshold, rng
            )
            n_resamples += did
            ess_t.append(t_e)
            ess.append(n_eff)
            w = np.full(M, 1.0 / M) if did else particles.weights
            pose_mean[e] = combined_pose(particles.poses, w)
            pose_best[e] = particles.poses[int(np.argmax(w))]
            if monitor is not None:
                monitor(t_e, particles, w)
        if bar is not None:
            bar.update(e - s + 1)
    filter_seconds = time.perf_counter() - t_start
    if bar is not None:
        bar.close()

    final, particles = particles, particles.to_particle_set()
    mu, sigma, observed = combined_map(particles)
    best = int(np.argmax(particles.logw))
    lm_best = np.where(particles.seen[best][:, None], particles.mu[best], np.nan)
    return FastSLAMResult(
        t=np.asarray(stream.t, dtype=float),
        pose_mean=pose_mean,
        pose_best=pose_best,
        landmarks_mean=mu,
        landmarks_cov=sigma,
        observed=observed,
        landmarks_best=lm_best,
        ess_t=np.asarray(ess_t),
        ess=np.asarray(ess),
        n_resamples=n_resamples,
        measurements_used=int(used),
        measurements_rejected=int(rejected),
        filter_seconds=filter_seconds,
        particles=particles,
        params=params,
        landmark_subjects=np.asarray(stream.landmark_subjects),
        final=final,
    )


def with_params(params: FastSLAMParams, **changes) -> FastSLAMParams:
    """A copy of ``params`` with some fields changed (validated again)."""
    return replace(params, **changes)


__all__ = [
    "FastSLAMParams",
    "ParticleSet",
    "FastSLAMResult",
    "propagate",
    "propagate_segment",
    "combined_heading",
    "update_with_measurement",
    "update_with_measurements",
    "evidence_fractions",
    "GateEscape",
    "resample_if_needed",
    "combined_pose",
    "combined_map",
    "run_fastslam",
    "with_params",
]
