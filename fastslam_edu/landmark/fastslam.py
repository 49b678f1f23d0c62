"""FastSLAM 1.0 with known correspondences: the particle set and the run over a log.

The filter of Montemerlo et al. (2002), in the order of the MR.CLAM write-up's
``propagate_all_states``, ``reweight_and_update``, ``resample`` and
``combine_particles``:

1. **Propagate** every particle's pose by sampling the motion model,
   :math:`x_t^{[m]} \\sim p(x_t \\mid x_{t-1}^{[m]}, u_t)` (:mod:`fastslam_edu.core.motion`).
2. **Update** for each measurement :math:`z = (r, \\phi)` of landmark :math:`k`:
   a landmark seen for the first time is initialised from the inverse model
   (:func:`fastslam_edu.core.ekf.initialise_landmark`); otherwise its 2×2 EKF is
   updated and the particle's log weight grows by the log-likelihood
   :math:`\\log \\mathcal N(\\nu; 0, Q)` (:func:`fastslam_edu.core.ekf.update_landmark`), times the
   fraction :math:`\\beta \\le 1` of independent evidence the sighting carries
   (:func:`evidence_fractions`; 1 in the textbook).
3. **Resample** (:mod:`fastslam_edu.core.resampling`) when the effective sample size
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

Steps 1 and 2 run particle by particle, as table 13.1 of *Probabilistic
Robotics* reads, in the compiled kernels of :mod:`fastslam_edu.landmark.fastslam_step`;
this module holds the particle set, the resampling and combining steps and the
driver that runs them over a log. The driver's loop (:func:`run_fastslam`) is
Python, step by step, with hooks; a run without hooks, with FastSLAM 1.0's
proposal on the dense particle set, makes the same steps with the same random
numbers in one compiled call (:meth:`FilterRun.run_compiled`).

What real data needs beyond the textbook (see :mod:`fastslam_edu.evaluation.noise_estimation`):
noise densities per √s (independent of the odometry rate), and a gate against
outlier measurements: a measurement is rejected when, for *every* particle,
its squared Mahalanobis distance exceeds ``gate_chi2`` (default: the point of
χ² with 2 degrees of freedom exceeded once in a million), unless the same
landmark has been rejected for ``gate_escape_s`` seconds (:func:`update_with_measurements`, :class:`Gate`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from fastslam_edu.datasets.log import EventStream
from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.landmark.fastslam_step import (RESAMPLER_CODES, Log, Particles, Record, Settings, Sightings,
                                                 gate_escapes, gate_record, normalise_weights, run_segments,
                                                 sample_segment, standard_normals, tempering_exponents,
                                                 update_particles, weighted_mean_pose)
from fastslam_edu.core.motion import MotionNoise, move_segment
from fastslam_edu.core.params import Params
from fastslam_edu.landmark.proposal import motion_prediction, sample_improved_poses, segment_motion
from fastslam_edu.core.resampling import get_resampler
from fastslam_edu.core.timing import RunTimer

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


@dataclass(frozen=True, eq=False)
class FastSLAMParams(Params):
    """Settings of the filter.

    Where the defaults come from (measured against groundtruth on every robot of
    MR.CLAM Datasets 1 and 6; :mod:`fastslam_edu.evaluation.noise_estimation`, chapters "The
    MR.CLAM data" and "From textbook to real data"; ``benchmarks/fastslam_accuracy.py``
    prints the errors they give):

    * **Measurement noise** :math:`\\sigma_r(r) = 0.07 + 0.06\\,r` m, :math:`\\sigma_\\phi = 0.02` rad:
      twice the robust standard deviations of the sightings' residuals (the
      range error grows with range). Readings of one landmark within a second
      are near-copies whose error changes only as the viewpoint does: counted
      as independent, they make the filter several times too confident.
    * **Motion noise** per √s (independent of the odometry rate),
      :math:`\\sigma_v = 0.02` m/√s and :math:`\\sigma_\\omega = 0.05` rad/√s: the drift of
      the heading over the tens of seconds the filter dead-reckons between
      sightings, which grows faster than the increments' own noise suggests
      (the robots lag the commands and turn less than commanded).
    * **Gate**: a sighting is rejected when :math:`d^2 > 27.6` (exceeded by one good
      sighting in a million) for *every* particle: with the inflated :math:`R` only
      gross errors are (a misread barcode, a range off by metres). Once a
      landmark has been rejected for 5 s (``gate_escape_s``) its sightings are
      applied without the gate: the filter is lost, not the sensor.
    * **Tempered likelihoods**: a sighting :math:`\\Delta t` after the previous sighting
      of the same landmark weighs the particles with its likelihood to the power
      :math:`\\min(1, \\Delta t/\\tau)`, :math:`\\tau = 4` s (:func:`evidence_fractions`).
    * **Resampling** when :math:`N_\\text{eff} < M/2`, the usual rule of thumb: it keeps
      the particle diversity that resampling at every step (the write-up's
      choice) throws away.

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
        ``"residual"`` or ``"roulette"`` (the roulette wheel, also called ``"multinomial"``).
    resample_threshold : float
        Resample when :math:`N_\\text{eff} < \\text{threshold}\\cdot M`; 1.0 resamples at
        every measurement step, whatever the weights (the write-up's behaviour), 0 never.
    gate_chi2 : float or None
        Outlier gate on :math:`d^2 = \\nu^\\top Q^{-1}\\nu` (:func:`update_with_measurements`); None disables it.
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
        given the sighting too, :mod:`fastslam_edu.landmark.proposal`; chapter "FastSLAM 2.0's
        proposal" and ``benchmarks/fastslam_accuracy.py --proposal`` measure what it gives).
    range_std_slope : float
        Growth of the range noise with range [m/m]: the filter uses
        :math:`\\sigma_r(r) = \\sqrt{R_{00}} + \\text{slope}\\cdot r` for a measurement of range
        :math:`r` (MR.CLAM's camera estimates range from the barcode's apparent
        size; its error grows ~3 cm per metre, see :mod:`fastslam_edu.evaluation.noise_estimation`).
    odometry_scale : (float, float)
        Calibration :math:`(k_v, k_\\omega)` of the commands: the filter moves with
        :math:`(k_v v, k_\\omega \\omega)`. MR.CLAM's odometry is the *commanded*
        velocity, and the robots turn less than commanded (see
        :mod:`fastslam_edu.evaluation.noise_estimation`).
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
        object.__setattr__(self, "measurement_cov", self.read_only(R))
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
        """Normalised weights :math:`w^{[m]}`, shape (M,) (all log weights :math:`-\\infty`: uniform)."""
        w = np.empty(len(self.logw))
        normalise_weights(np.asarray(self.logw, dtype=float), w)
        return w

    def with_known_map(self, landmarks) -> "ParticleSet":
        """Every particle holding the known landmarks ``(K, 2)`` (localisation), Σ = 10⁻⁶ I."""
        self.mu[:] = landmarks
        self.sigma[:] = np.eye(2) * 1e-6
        self.seen[:] = True
        self.count[:] = 1
        return self

    def arrays(self) -> Particles:
        """The arrays as the step's kernels take them (:class:`fastslam_edu.landmark.fastslam_step.Particles`), shared."""
        return Particles(self.poses, self.mu, self.sigma, self.seen, self.count, self.logw)

    def update(self, z, k, R, *, update_map: bool = True, gate_chi2: float | None = None, escape=None,
               power=None, proposal_loglik=None) -> np.ndarray:
        """Step 2 for the measurements of one instant: :func:`update_with_sightings`."""
        sightings = make_sightings(z, k, R, len(self), escape=escape, power=power, proposal_loglik=proposal_loglik)
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
    :func:`fastslam_edu.landmark.fastslam_step.sample_segment` reads them (drawn by the compiled loop when
    there are many)."""
    if m * n_steps * k < 4096:
        return np.ascontiguousarray(rng.standard_normal((m, n_steps, k)).transpose(1, 2, 0))
    out = np.empty((n_steps, k, m))
    standard_normals(rng, out)
    return out


def propagate_segment(particles: ParticleSet, u, dt, noise: MotionNoise, rng: np.random.Generator, w,
                      n_record: int | None = None):
    """Step 1 as the filter runs it: line 4 of table 13.1 for each particle, recording the estimates.

    The same random numbers as :func:`propagate`, but instead of every
    particle's path (M, L, 3) it returns what the filter records at each step:
    the weighted-mean pose and the pose of the highest-weight particle
    (:func:`fastslam_edu.landmark.fastslam_step.sample_segment`).

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
    sample_segment(particles.poses, u, dt, noise.densities, draw_normals(rng, len(particles), len(dt), noise.n_draws),
                   w, mean, best)
    return mean, best


def update_with_measurement(particles: ParticleSet, z, k: int, R, **options) -> bool:
    """Step 2 for one measurement ``z = (r, φ)`` of landmark ``k``: :func:`update_with_measurements` with n = 1."""
    return bool(update_with_measurements(particles, np.reshape(z, (1, 2)), [k], np.reshape(R, (1, 2, 2)),
                                         **options)[0])


def make_sightings(z, k, R, n_particles: int, *, escape=None, power=None, proposal_loglik=None) -> Sightings:
    """The sightings of one instant as the step's kernels take them (:class:`fastslam_edu.landmark.fastslam_step.Sightings`).

    ``z`` (n, 2), ``k`` (n,), ``R`` (n, 2, 2) or (2, 2); ``escape`` (n,) bool
    (default none escapes the gate), ``power`` (n,) the likelihoods' exponents β
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
    power = np.ones(n) if power is None else _per_sighting(power, float, n)
    loglik = (np.full((n_particles, n), np.nan) if proposal_loglik is None
              else np.asarray(proposal_loglik, float).reshape(n_particles, n))
    return Sightings(z, k, R, escape, power, loglik)


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
                             gate_chi2: float | None = None, escape=None, power=None) -> np.ndarray:
    """Step 2 for all the measurements of one instant: ``z`` (n, 2) of landmarks ``k`` (n,), in order.

    Lines 5–17 of table 13.1 for every particle
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
    power : (n,), optional
        Exponents :math:`\\beta` of their likelihoods (:func:`evidence_fractions`; default 1).

    FastSLAM 2.0 weighs with its own log weights: :func:`make_sightings` (``proposal_loglik``)
    and :func:`update_with_sightings`.

    Returns
    -------
    explained : (n,) bool
        False where no particle explains the measurement (rejected by the gate, unless escaped).
    """
    sightings = make_sightings(z, k, R, len(particles), escape=escape, power=power)
    return update_with_sightings(particles, sightings, gate_chi2=gate_chi2, update_map=update_map)


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
    landmarks = _landmark_indices(landmarks)
    beta = np.empty(len(landmarks))
    tempering_exponents(float(t), landmarks, last_seen, 0.0 if tau is None else float(tau), beta)
    return beta


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
    filter_seconds : wall time of the filter loop, without compilation
    compile_seconds : wall time numba spent compiling its kernels in the loop, or loading them from its cache
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
    compile_seconds: float = 0.0


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


def segment_chunks(segments: np.ndarray, max_steps: int):
    """``(a, b)``: runs ``segments[a:b]`` of whole segments (S, 2) covering at most ``max_steps`` steps each
    (a longer segment alone), in order: what the compiled run does between two calls to the hooks."""
    a = 0
    while a < len(segments):
        b = a + 1
        while b < len(segments) and segments[b, 1] - segments[a, 0] + 1 <= max_steps:
            b += 1
        yield a, b
        a = b


def stream_commands(stream: EventStream, params: FastSLAMParams):
    """The stream's commands times ``params.odometry_scale``, and its time steps, checked: ``(u (N, 2), dt (N,))``."""
    u = np.asarray(stream.u, dtype=float) * np.asarray(params.odometry_scale, dtype=float)
    dt = np.asarray(stream.dt, dtype=float)
    if not (np.isfinite(u).all() and np.isfinite(dt).all()) or (dt < 0).any():
        bad = np.flatnonzero(~np.isfinite(u).all(axis=1) | ~np.isfinite(dt) | (dt < 0))
        raise ValueError(f"the event stream has non-finite commands or negative time steps ({len(bad)} step(s), "
                         f"the first at step {bad[0]}, t = {stream.t[bad[0]]!r})")
    return u, dt


# ---------------------------------------------------------------- strategies and hooks of the run


class MotionProposal:
    """FastSLAM 1.0's proposal: step 1 samples the motion model; the weight is the sighting's likelihood."""

    def move(self, run: "FilterRun", s: int, e: int, n_record: int):
        """Step 1 through steps ``s..e``; returns the estimates ``(mean, best)`` of the first ``n_record`` steps."""
        return propagate_segment(run.particles, run.u[s : e + 1], run.dt[s : e + 1], run.params.motion_noise,
                                 run.rng, run.w, n_record=n_record)

    def weigh(self, run: "FilterRun", s: int, e: int, sightings) -> np.ndarray | None:
        """Log weights (M, n) that replace FastSLAM 1.0's (NaN: keep them); None: all of FastSLAM 1.0's."""
        return None


class ImprovedProposal(MotionProposal):
    """FastSLAM 2.0's proposal: poses drawn given the sightings too (:mod:`fastslam_edu.landmark.proposal`)."""

    def move(self, run, s, e, n_record):
        run.x_start = run.particles.poses.copy()
        return super().move(run, s, e, n_record)

    def weigh(self, run, s, e, sightings):
        if run.x_start is None:  # the poses were moved by a hook (a kidnap): no motion to condition on
            return None
        u, dt = run.u[s : e + 1], run.dt[s : e + 1]
        x_bar, P = motion_prediction(run.x_start, *segment_motion(u, dt, run.params.motion_noise))
        return sample_improved_poses(run.particles, sightings, x_bar, P, gate_chi2=run.gate.chi2,
                                     rng=run.rng, min_count=2 if run.update_map else 1)


class KnownPoses(MotionProposal):
    """Mode ``"map"``: every particle at the groundtruth pose (``groundtruth_poses(t) -> (n, 3)``)."""

    def __init__(self, groundtruth_poses):
        if groundtruth_poses is None:
            raise ValueError('mode="map" needs the groundtruth poses (groundtruth_poses=callable t -> (n, 3))')
        self.groundtruth_poses = groundtruth_poses

    def move(self, run, s, e, n_record):
        truth = np.asarray(self.groundtruth_poses(run.stream.t[s : e + 1]), dtype=float)
        run.particles.poses = np.tile(truth[-1], (len(run.particles), 1))
        return truth[:n_record], truth[:n_record]


class Gate:
    """The outlier gate (``FastSLAMParams.gate_chi2``) and its escape (``gate_escape_s``), as one object.

    ``chi2``: reject a sighting that every particle puts beyond :math:`d^2 >` ``chi2``
    (None: no gate). Per landmark, the time of the first of its sightings that no
    particle has explained since (``unexplained_since``, ``inf`` while they are
    explained): once that is ``escape_s`` seconds ago, its sightings are applied
    without the gate until one is explained again.
    """

    def __init__(self, chi2: float | None, escape_s: float | None, n_landmarks: int):
        self.chi2 = chi2
        self.escape_s = np.inf if escape_s is None else float(escape_s)
        self.unexplained_since = np.full(n_landmarks, np.inf)

    def escaped(self, t: float, landmarks) -> np.ndarray:
        """Bool (n,): the sightings of ``landmarks`` (n,) at time ``t`` that skip the gate (:func:`gate_escapes`)."""
        j = _landmark_indices(landmarks)
        escape = np.empty(len(j), dtype=bool)
        gate_escapes(float(t), j, self.unexplained_since, self.escape_s, escape)
        return escape

    def record(self, t: float, landmarks, explained) -> None:
        """Note which sightings at ``t`` some particle explained (``explained`` (n,) bool; :func:`gate_record`)."""
        gate_record(float(t), _landmark_indices(landmarks), np.asarray(explained, dtype=bool).reshape(-1),
                    self.unexplained_since)


def _landmark_indices(landmarks) -> np.ndarray:
    """Landmark indices as the compiled kernels take them: int64, shape (n,)."""
    return np.asarray(landmarks, dtype=np.int64).reshape(-1)


class Hook:
    """Something run alongside the filter, without changing it unless that is its purpose.

    ``after_motion(run, s, e)`` is called after step 1 of each segment of steps
    ``s..e``; ``after_resampling(run, parents, before)`` after step 3 at each
    measurement step, with the indices drawn (``parents`` (M,): particle ``m``
    is a copy of ``before``'s ``parents[m]``; None when :math:`N_\text{eff}` was
    high enough) and the set as it was before; ``after_step(run, s, e)`` after the
    whole step (with ``run.measured`` True when it had sightings); ``close(run)``
    at the end. ``cut_times``: times at which a segment must end (a hook that acts
    at a time).

    ``chunk_steps``: a hook that uses only ``after_step`` and ``close`` sets it to the
    number of steps it lets the compiled run make between two calls; the run then
    stays compiled (:meth:`FilterRun.run_compiled`) and calls ``after_step(run, s, e)``
    once per chunk of steps ``s..e`` (whole segments; ``run.measured``: whether step
    ``e`` had sightings). None (the default): the hook needs the step-by-step Python loop.
    """

    cut_times: tuple = ()
    chunk_steps: int | None = None

    def after_motion(self, run: "FilterRun", s: int, e: int) -> None:
        pass

    def after_resampling(self, run: "FilterRun", parents: np.ndarray | None, before: ParticleSet) -> None:
        pass

    def after_step(self, run: "FilterRun", s: int, e: int) -> None:
        pass

    def close(self, run: "FilterRun") -> None:
        pass


class Kidnap(Hook):
    """The write-up's kidnapped-robot test: at the first step at or after ``t`` every particle jumps to ``pose``."""

    def __init__(self, t: float, pose):
        self.t, self.pose = float(t), np.asarray(pose, dtype=float)
        self.cut_times = (self.t,)

    def after_motion(self, run, s, e):
        k = int(np.searchsorted(run.stream.t, self.t, side="left"))
        if s <= k <= e:  # segments end at the kidnap step
            run.particles.poses[:] = self.pose
            run.pose_mean[k : e + 1] = run.pose_best[k : e + 1] = self.pose
            run.x_start = None


class Monitor(Hook):
    """Calls ``callback(t, particles, w)`` after every measurement step (after resampling).

    With the step's time, the particle set as stored and the normalised weights
    the step's estimate used: a way to look inside the filter (chapter "Is the
    filter's uncertainty honest?") without changing it. The callback must not
    modify them; its time counts in ``filter_seconds``. Served by the compiled run after each
    measurement step (chunks of one segment).
    """

    chunk_steps = 1

    def __init__(self, callback):
        self.callback = callback

    def after_step(self, run, s, e):
        if run.measured:
            self.callback(run.stream.t[e], run.particles, run.w)


#: Steps the compiled run makes between two updates of the progress bar (a few hundredths of a second).
PROGRESS_CHUNK_STEPS = 4096


class ProgressBar(Hook):
    """A tqdm progress bar over the steps, updated between compiled chunks of :data:`PROGRESS_CHUNK_STEPS` steps
    (as fast as no bar)."""

    chunk_steps = PROGRESS_CHUNK_STEPS

    def __init__(self):
        self.bar = None

    def after_step(self, run, s, e):
        if self.bar is None:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=len(run.stream), unit="step", desc=f"FastSLAM M={len(run.particles)}",
                            mininterval=0.5)
        self.bar.update(e - s + 1)

    def close(self, run):
        if self.bar is not None:
            self.bar.close()


# ---------------------------------------------------------------- the whole run


@dataclass
class FilterRun:
    """The state of a run of :func:`run_fastslam` between its steps (what hooks see and may change)."""

    stream: EventStream
    params: FastSLAMParams
    rng: np.random.Generator
    particles: ParticleSet
    proposal: MotionProposal
    gate: Gate
    u: np.ndarray
    dt: np.ndarray
    R: np.ndarray
    w: np.ndarray
    pose_mean: np.ndarray
    pose_best: np.ndarray
    last_seen: np.ndarray
    ess_t: list = field(default_factory=list)
    ess: list = field(default_factory=list)
    n_resamples: int = 0
    used: int = 0
    rejected: int = 0
    measured: bool = False
    x_start: np.ndarray | None = None
    hooks: tuple = ()

    @property
    def update_map(self) -> bool:
        return self.params.mode != "localize"

    def measure(self, s: int, e: int) -> None:
        """Steps 2–4 at the measurement step ``e`` (the end of segment ``s..e``)."""
        t = self.stream.t[e]
        z, lm = self.stream.measurements_at(e)
        escape = self.gate.escaped(t, lm)
        power = evidence_fractions(t, lm, self.last_seen, self.params.measurement_correlation_s)
        R = self.R[self.stream.offsets[e] : self.stream.offsets[e + 1]]
        proposal_loglik = self.proposal.weigh(self, s, e, (z, lm, R, escape))
        explained = self.particles.update(z, lm, R, update_map=self.update_map, gate_chi2=self.gate.chi2,
                                          escape=escape, power=power, proposal_loglik=proposal_loglik)
        self.gate.record(t, lm, explained)
        ok = explained | escape
        self.used += int(ok.sum())
        self.rejected += int((~ok).sum())
        before = self.particles
        parents, n_eff, w = draw_parents(before, self.params.resampler, self.params.resample_threshold, self.rng)
        did = parents is not None
        if did:
            self.particles = before.select(parents)
        for hook in self.hooks:
            hook.after_resampling(self, parents, before)
        self.n_resamples += did
        self.ess_t.append(t)
        self.ess.append(n_eff)
        self.w = np.full(len(self.particles), 1.0 / len(self.particles)) if did else w
        weighted_mean_pose(self.particles.poses, self.w, self.pose_mean[e])
        self.pose_best[e] = self.particles.poses[int(np.argmax(self.w))]

    def compiled(self, hooks) -> bool:
        """Whether :meth:`run_compiled` can run this filter: FastSLAM 1.0's or 2.0's proposal, dense particles,
        hooks that can wait for a chunk of steps (:attr:`Hook.chunk_steps`)."""
        return (all(hook.chunk_steps is not None for hook in hooks)
                and type(self.proposal) in (MotionProposal, ImprovedProposal)
                and type(self.particles) is ParticleSet and self.params.resampler in RESAMPLER_CODES)

    def run_compiled(self, segments: np.ndarray, hooks=()) -> None:
        """Steps 1–4 over all ``segments`` in compiled calls (:func:`fastslam_edu.landmark.fastslam_step.run_segments`):
        the same lines as the Python loop of :func:`run_fastslam` and the same random numbers, returning to
        Python only between chunks of segments, to serve the ``hooks`` (one call without hooks); the result
        does not depend on the chunks."""
        p, stream = self.params, self.stream
        log = Log(np.asarray(stream.t, dtype=float), self.u, self.dt, np.asarray(stream.offsets, dtype=np.int64),
                  np.asarray(stream.z, dtype=float).reshape(-1, 2), np.asarray(stream.landmark, dtype=np.int64),
                  np.ascontiguousarray(self.R))
        settings = Settings(p.motion_noise.densities, p.motion_noise.n_draws,
                            math.inf if self.gate.chi2 is None else float(self.gate.chi2), self.gate.escape_s,
                            0.0 if p.measurement_correlation_s is None else float(p.measurement_correlation_s),
                            self.update_map, float(p.resample_threshold), RESAMPLER_CODES[p.resampler],
                            int(type(self.proposal) is ImprovedProposal), 2 if self.update_map else 1)
        n_instants = int(np.count_nonzero(np.diff(stream.offsets)))
        record = Record(self.pose_mean, self.pose_best, np.empty(n_instants), np.empty(n_instants),
                        np.array(self.w, dtype=float), self.gate.unexplained_since, self.last_seen,
                        np.zeros(4, dtype=np.int64))
        x_start = np.empty((len(self.particles), 3)) if type(self.proposal) is ImprovedProposal else None
        self.w = record.w  # changed in place by the run: what hooks see between chunks
        chunk = min((hook.chunk_steps for hook in hooks), default=len(self.stream))
        for a, b in segment_chunks(segments, chunk):
            run_segments(self.particles.arrays(), log, settings, segments[a:b], self.rng, record, x_start)
            s, e = int(segments[a, 0]), int(segments[b - 1, 1])
            self.measured = bool(stream.offsets[e + 1] > stream.offsets[e])
            for hook in hooks:
                hook.after_step(self, s, e)
        self.ess_t, self.ess = list(record.ess_t), list(record.ess)
        self.used, self.rejected, self.n_resamples = (int(v) for v in record.totals[1:])

    def result(self, filter_seconds: float, compile_seconds: float = 0.0) -> FastSLAMResult:
        """Step 4 at the end: the combined map and the run's record (times in seconds, :class:`RunTimer`)."""
        final, particles = self.particles, self.particles.to_particle_set()
        mu, sigma, observed = combined_map(particles)
        best = int(np.argmax(particles.logw))
        return FastSLAMResult(
            t=np.asarray(self.stream.t, dtype=float), pose_mean=self.pose_mean, pose_best=self.pose_best,
            landmarks_mean=mu, landmarks_cov=sigma, observed=observed,
            landmarks_best=np.where(particles.seen[best][:, None], particles.mu[best], np.nan),
            ess_t=np.asarray(self.ess_t), ess=np.asarray(self.ess), n_resamples=self.n_resamples,
            measurements_used=self.used, measurements_rejected=self.rejected, filter_seconds=filter_seconds,
            particles=particles, params=self.params, landmark_subjects=np.asarray(self.stream.landmark_subjects),
            final=final, compile_seconds=compile_seconds,
        )


def start_run(stream: EventStream, params: FastSLAMParams, rng, *, x0=None, landmarks=None, groundtruth_poses=None,
              particle_class=None) -> FilterRun:
    """The initial :class:`FilterRun` of :func:`run_fastslam` (arguments as there), checked."""
    rng = np.random.default_rng(rng) if not isinstance(rng, np.random.Generator) else rng
    x0 = stream.x0 if x0 is None else np.asarray(x0, dtype=float)
    if x0 is None:
        raise ValueError("no initial pose: the stream has no groundtruth; pass x0=(x, y, theta)")
    M, K, N = params.n_particles, stream.n_landmarks, len(stream)
    if N == 0:
        raise ValueError("the event stream is empty")
    particles = (ParticleSet if particle_class is None else particle_class).initial(M, K, x0)
    if params.mode == "localize":
        if landmarks is None:
            raise ValueError('mode="localize" needs the known landmark positions (landmarks=...)')
        landmarks = np.asarray(landmarks, dtype=float)
        if landmarks.shape != (K, 2):
            raise ValueError(f"landmarks must have shape ({K}, 2), got {landmarks.shape}")
        particles = particles.with_known_map(landmarks)
    if params.mode == "map":
        proposal = KnownPoses(groundtruth_poses)
    elif params.proposal == "fastslam2":
        if not isinstance(particles, ParticleSet):
            raise ValueError('proposal="fastslam2" needs the dense ParticleSet (particle_class=None)')
        proposal = ImprovedProposal()
    else:
        proposal = MotionProposal()
    u, dt = stream_commands(stream, params)
    return FilterRun(stream=stream, params=params, rng=rng, particles=particles, proposal=proposal,
                     gate=Gate(params.gate_chi2, params.gate_escape_s, K), u=u, dt=dt,
                     R=params.measurement_covariance(stream.z), w=particles.weights, pose_mean=np.empty((N, 3)),
                     pose_best=np.empty((N, 3)), last_seen=np.full(K, -np.inf))


def run_fastslam(
    stream: EventStream,
    params: FastSLAMParams = FastSLAMParams(),
    rng: np.random.Generator | int | None = 0,
    *,
    x0=None,
    landmarks=None,
    groundtruth_poses=None,
    particle_class=None,
    hooks=(),
) -> FastSLAMResult:
    """Run FastSLAM 1.0 over an event stream: steps 1–4 for each segment of odometry steps.

    Parameters
    ----------
    stream : EventStream
        From :func:`fastslam_edu.datasets.events.event_stream` (full rate or 1 Hz).
    params : FastSLAMParams
    rng : numpy.random.Generator or int seed
    x0 : (3,) initial pose; default ``stream.x0`` (groundtruth at the first step).
    landmarks : (K, 2) known landmark positions, needed for ``mode="localize"``.
    groundtruth_poses : callable ``t -> (n, 3)`` poses, needed for ``mode="map"``.
    particle_class : how particles store their maps: :class:`ParticleSet` (dense
        arrays, the default) or :class:`fastslam_edu.landmark.fastslam_tree.TreeParticleSet`
        (Montemerlo's trees); anything with the same ``initial``, ``with_known_map``,
        ``update``, ``select``, ``weights`` and ``to_particle_set``. The result's
        ``particles`` is always dense; ``final`` is the set as stored.
    hooks : :class:`Hook` objects run alongside: :class:`Kidnap`, :class:`Monitor`,
        :class:`ProgressBar`, or your own.
    """
    run = start_run(stream, params, rng, x0=x0, landmarks=landmarks, groundtruth_poses=groundtruth_poses,
                    particle_class=particle_class)
    run.hooks = tuple(hooks)
    cut_times = [t for hook in hooks for t in hook.cut_times]
    with RunTimer() as timer:  # filter_seconds without the compilation of the kernels (compile_seconds)
        if run.compiled(hooks):  # the same steps in compiled chunks
            run.run_compiled(np.array(list(_segments(stream, cut_times)), dtype=np.int64).reshape(-1, 2), hooks)
        else:
            run_python_loop(run, cut_times)
        for hook in hooks:
            hook.close(run)
    return run.result(timer.filter_seconds, timer.compile_seconds)


def run_python_loop(run: FilterRun, cut_times) -> None:
    """Steps 1–4 segment by segment in Python, with every hook's calls (:class:`Hook`)."""
    stream, hooks = run.stream, run.hooks
    for s, e in _segments(stream, cut_times):
        run.measured = stream.offsets[e + 1] > stream.offsets[e]
        last = e if run.measured else e + 1  # a measurement step's estimate is taken after the update
        run.pose_mean[s:last], run.pose_best[s:last] = run.proposal.move(run, s, e, last - s)
        for hook in hooks:
            hook.after_motion(run, s, e)
        if run.measured:
            run.measure(s, e)
        for hook in hooks:
            hook.after_step(run, s, e)


__all__ = [
    "FastSLAMParams",
    "ParticleSet",
    "FastSLAMResult",
    "propagate",
    "propagate_segment",
    "combined_heading",
    "update_with_measurement",
    "update_with_measurements",
    "make_sightings",
    "update_with_sightings",
    "evidence_fractions",
    "Gate",
    "Hook",
    "Kidnap",
    "Monitor",
    "ProgressBar",
    "MotionProposal",
    "ImprovedProposal",
    "KnownPoses",
    "FilterRun",
    "start_run",
    "resample_if_needed",
    "draw_parents",
    "combined_pose",
    "combined_map",
    "run_fastslam",
    "run_python_loop",
    "segment_chunks",
    "PROGRESS_CHUNK_STEPS",
]
