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
   (:func:`tempering_exponents`; 1 in the textbook).
3. **Resample** (:mod:`fastslam_edu.core.resampling`) when the effective sample size
   :math:`N_\\text{eff} = 1/\\sum_m (w^{[m]})^2` falls below a fraction of
   :math:`M` (default 0.5); weights are reset to uniform afterwards.
4. **Combine**: the weighted mean pose and map, and the highest-weight particle.

The state of the filter is a :class:`~fastslam_edu.landmark.particle_set.ParticleSet` (its arrays, shapes and units:
:mod:`fastslam_edu.landmark.particle_set`).

Steps 1 and 2 run particle by particle, as table 13.1 of *Probabilistic
Robotics* reads, in the compiled kernels of :mod:`fastslam_edu.landmark.fastslam_step`;
the particle set and the four steps on it are :mod:`fastslam_edu.landmark.particle_set`;
this module holds the filter's settings and the driver that runs the steps over a log,
with its proposal strategies (:mod:`fastslam_edu.landmark.proposal_strategies`), its gate
(:mod:`fastslam_edu.landmark.gate`), the exponents β (:mod:`fastslam_edu.landmark.evidence`),
the segments of steps (:mod:`fastslam_edu.landmark.segments`) and hooks
(:mod:`fastslam_edu.landmark.hooks`). A run on the dense particle set, with FastSLAM 1.0's or 2.0's
proposal and hooks that can wait for a chunk of steps, makes all its steps in compiled calls
(:meth:`FilterRun.run_compiled`); otherwise the driver's loop (:func:`run_python_loop`) goes
step by step in Python, for the hooks that act between the steps, with the same kernels
(:func:`~fastslam_edu.landmark.fastslam_step.weigh_instant` for step 2 and the weights) and the
same random numbers.

What real data needs beyond the textbook (see :mod:`fastslam_edu.evaluation.noise_estimation`):
noise densities per √s (independent of the odometry rate), and a gate against
outlier measurements: a measurement is rejected when, for *every* particle,
its squared Mahalanobis distance exceeds ``gate_chi2`` (default: the point of
χ² with 2 degrees of freedom exceeded once in a million), unless the same
landmark has been rejected for ``gate_escape_s`` seconds
(:func:`~fastslam_edu.landmark.particle_set.update_with_measurements`, :class:`~fastslam_edu.landmark.gate.Gate`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from fastslam_edu.core.motion import MotionNoise
from fastslam_edu.core.params import Params
from fastslam_edu.core.resampling import get_resampler
from fastslam_edu.core.timing import RunTimer
from fastslam_edu.datasets.log import EventStream
from fastslam_edu.landmark.evidence import tempering_exponents
from fastslam_edu.landmark.fastslam_step import combined_pose_kernel, normalise_weights, run_segments, weigh_instant
from fastslam_edu.landmark.gate import Gate
from fastslam_edu.landmark.hooks import ProgressBar
from fastslam_edu.landmark.particle_set import ParticleSet, combined_map
from fastslam_edu.landmark.proposal_strategies import ImprovedProposal, KnownPoses, MotionProposal
from fastslam_edu.landmark.segments import MAX_SEGMENT, measurement_segments, segment_chunks, stream_commands
from fastslam_edu.landmark.step_records import (N_TOTALS, RESAMPLER_CODES, RESAMPLES, SIGHTINGS_REJECTED, SIGHTINGS_USED,
                                                STEPS_DONE, Log, Record, Settings)

MODES = ("slam", "localize", "map")
PROPOSALS = ("motion", "fastslam2")

#: χ²₂ 99.9 % quantile (upper tail 1e-3) ≈ 13.8, the textbook gate for a well-modelled sensor.
#: For 2 degrees of freedom the tail is exp(−d²/2), so this is exactly −2 ln(1e-3).
CHI2_2DOF_999 = float(chi2.isf(1e-3, df=2))

#: χ²₂ quantile with an upper tail of one in a million ≈ 27.6 (= −2 ln(1e-6)). With the
#: inflated R of the defaults it catches only gross errors (a misread barcode, a range off
#: by metres).
CHI2_2DOF_1E6 = float(chi2.isf(1e-6, df=2))


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
      :math:`\\min(1, \\Delta t/\\tau)`, :math:`\\tau = 4` s (:func:`tempering_exponents`).
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
        the tempering exponent :math:`\\beta = \\min(1, \\Delta t / \\tau)` (:func:`tempering_exponents`): its error
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
class FastSLAMResult:
    """What a run produces.

    Attributes
    ----------
    t : (N,) step times [s]
    pose_mean : (N, 3) weighted-mean pose after each step
    pose_best : (N, 3) pose of the highest-weight particle after each step
    landmarks_mean, landmarks_cov, observed : the combined map at the end ((N, 2), (N, 2, 2), (N,))
    landmarks_best : (N, 2) map of the highest-weight particle at the end
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


@dataclass
class FilterRun:
    """The state of a run of :func:`run_fastslam` between its steps (what hooks see and may change).

    ``log``, ``settings`` and ``record``: the stream, the filter's settings and what the run writes, as the
    compiled kernels take them (:mod:`fastslam_edu.landmark.step_records`), shared by the compiled run and the
    Python loop. ``w`` (the current normalised weights), ``pose_mean``, ``pose_best``, ``last_seen`` and the
    counts are read from ``record``.
    """

    stream: EventStream
    params: FastSLAMParams
    rng: np.random.Generator
    particles: ParticleSet
    proposal: MotionProposal
    gate: Gate
    u: np.ndarray
    dt: np.ndarray
    R: np.ndarray
    log: Log
    settings: Settings
    record: Record
    measured: bool = False
    x_start: np.ndarray | None = None
    hooks: tuple = ()

    @property
    def update_map(self) -> bool:
        return self.params.mode != "localize"

    @property
    def w(self) -> np.ndarray:
        """The current normalised weights (M,), changed in place by the run."""
        return self.record.w

    @property
    def pose_mean(self) -> np.ndarray:
        return self.record.pose_mean

    @property
    def pose_best(self) -> np.ndarray:
        return self.record.pose_best

    @property
    def last_seen(self) -> np.ndarray:
        return self.record.last_seen

    @property
    def ess_t(self) -> np.ndarray:
        """The times of the measurement steps done so far [s]."""
        return self.record.ess_t[:self.record.totals[STEPS_DONE]]

    @property
    def ess(self) -> np.ndarray:
        """:math:`N_\\text{eff}` at each measurement step done so far, before resampling."""
        return self.record.ess[:self.record.totals[STEPS_DONE]]

    @property
    def n_resamples(self) -> int:
        return int(self.record.totals[RESAMPLES])

    @property
    def used(self) -> int:
        return int(self.record.totals[SIGHTINGS_USED])

    @property
    def rejected(self) -> int:
        return int(self.record.totals[SIGHTINGS_REJECTED])

    def measure(self, s: int, e: int) -> None:
        """Steps 2–4 at the measurement step ``e`` (the end of segment ``s..e``) with the compiled run's kernels:
        step 2 and the weights by :func:`~fastslam_edu.landmark.fastslam_step.weigh_instant` (the landmark trees:
        :meth:`weigh_trees`), step 3 here, so that hooks see the parents drawn and the set before
        (:meth:`Hook.after_resampling`), step 4 by :func:`~fastslam_edu.landmark.fastslam_step.combined_pose_kernel`."""
        if type(self.particles) is ParticleSet:
            n_eff = weigh_instant(self.particles.arrays(), self.log, self.settings, e, self.rng, self.record,
                                  self.proposal.prediction(self, s, e))
        else:
            n_eff = self.weigh_trees(e)
        w, m, threshold = self.record.w, len(self.particles), self.params.resample_threshold
        before, parents = self.particles, None
        if threshold >= 1.0 or n_eff < threshold * m:  # 1.0: at every measurement step (the write-up)
            parents = get_resampler(self.params.resampler)(w, self.rng)
            self.particles = before.select(parents)
        for hook in self.hooks:
            hook.after_resampling(self, parents, before)
        if parents is not None:
            w[:] = 1.0 / m
            self.record.totals[RESAMPLES] += 1
        combined_pose_kernel(self.particles.poses, w, self.pose_mean[e])
        self.pose_best[e] = self.particles.poses[int(np.argmax(w))]

    def weigh_trees(self, e: int) -> float:
        """:func:`~fastslam_edu.landmark.fastslam_step.weigh_instant` for a set stored otherwise than as the dense
        arrays (the landmark trees of :mod:`fastslam_edu.landmark.fastslam_tree`): the same steps and kernels
        around the set's own update. Returns :math:`N_\\text{eff}`."""
        t, record = self.stream.t[e], self.record
        z, lm = self.stream.measurements_at(e)
        escape = self.gate.escaped(t, lm)
        beta = tempering_exponents(t, lm, self.last_seen, self.params.measurement_correlation_s)
        R = self.R[self.stream.offsets[e] : self.stream.offsets[e + 1]]
        explained = self.particles.update(z, lm, R, update_map=self.update_map, gate_chi2=self.gate.chi2,
                                          escape=escape, beta=beta)
        self.gate.record(t, lm, explained)
        ok = explained | escape
        record.totals[SIGHTINGS_USED] += int(ok.sum())
        record.totals[SIGHTINGS_REJECTED] += int((~ok).sum())
        n_eff = normalise_weights(np.asarray(self.particles.logw, dtype=float), record.w)
        q = record.totals[STEPS_DONE]
        record.ess_t[q], record.ess[q] = t, n_eff
        record.totals[STEPS_DONE] += 1
        return n_eff

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
        stream = self.stream
        x_start = np.empty((len(self.particles), 3)) if type(self.proposal) is ImprovedProposal else None
        chunk = min((hook.chunk_steps for hook in hooks), default=len(self.stream))
        for a, b in segment_chunks(segments, chunk):
            run_segments(self.particles.arrays(), self.log, self.settings, segments[a:b], self.rng, self.record,
                         x_start)
            s, e = int(segments[a, 0]), int(segments[b - 1, 1])
            self.measured = bool(stream.offsets[e + 1] > stream.offsets[e])
            for hook in hooks:
                hook.after_step(self, s, e)

    def result(self, filter_seconds: float, compile_seconds: float = 0.0) -> FastSLAMResult:
        """Step 4 at the end: the combined map and the run's record (times in seconds, :class:`RunTimer`)."""
        final, particles = self.particles, self.particles.to_particle_set()
        mu, sigma, observed = combined_map(particles)
        best = int(np.argmax(particles.logw))
        return FastSLAMResult(
            t=np.asarray(self.stream.t, dtype=float), pose_mean=self.pose_mean, pose_best=self.pose_best,
            landmarks_mean=mu, landmarks_cov=sigma, observed=observed,
            landmarks_best=np.where(particles.seen[best][:, None], particles.mu[best], np.nan),
            ess_t=np.array(self.ess_t), ess=np.array(self.ess), n_resamples=self.n_resamples,
            measurements_used=self.used, measurements_rejected=self.rejected, filter_seconds=filter_seconds,
            particles=particles, params=self.params, landmark_subjects=np.asarray(self.stream.landmark_subjects),
            final=final, compile_seconds=compile_seconds,
        )


def kernel_inputs(stream: EventStream, params: FastSLAMParams, gate: Gate, improved: bool, w) -> tuple:
    """``(log, settings, record)`` of a run (:mod:`fastslam_edu.landmark.step_records`): the stream with its
    commands and noise, the settings (``improved``: FastSLAM 2.0's proposal), and an empty record that starts from
    the weights ``w`` (M,) and the ``gate``'s memory."""
    u, dt = stream_commands(stream, params)
    log = Log(t=np.asarray(stream.t, dtype=float), u=u, dt=dt, offsets=np.asarray(stream.offsets, dtype=np.int64),
              z=np.asarray(stream.z, dtype=float).reshape(-1, 2), j=np.asarray(stream.landmark, dtype=np.int64),
              R=np.ascontiguousarray(params.measurement_covariance(stream.z)))
    update_map = params.mode != "localize"
    tau = params.measurement_correlation_s
    settings = Settings(noise=params.motion_noise.densities, n_draws=params.motion_noise.n_draws,
                        gate_chi2=math.inf if gate.chi2 is None else float(gate.chi2), escape_s=gate.escape_s,
                        tau=0.0 if tau is None else float(tau), update_map=update_map,
                        resample_threshold=float(params.resample_threshold),
                        resampler=RESAMPLER_CODES.get(params.resampler, -1), proposal=int(improved),
                        min_count=2 if update_map else 1)
    T, n_instants = len(stream), int(np.count_nonzero(np.diff(stream.offsets)))
    record = Record(pose_mean=np.empty((T, 3)), pose_best=np.empty((T, 3)), ess_t=np.empty(n_instants),
                    ess=np.empty(n_instants), w=np.array(w, dtype=float), unexplained_since=gate.unexplained_since,
                    last_seen=np.full(stream.n_landmarks, -np.inf), totals=np.zeros(N_TOTALS, dtype=np.int64))
    return log, settings, record


def start_run(stream: EventStream, params: FastSLAMParams, rng, *, x0=None, landmarks=None, groundtruth_poses=None,
              particle_class=None) -> FilterRun:
    """The initial :class:`FilterRun` of :func:`run_fastslam` (arguments as there), checked."""
    rng = np.random.default_rng(rng) if not isinstance(rng, np.random.Generator) else rng
    x0 = stream.x0 if x0 is None else np.asarray(x0, dtype=float)
    if x0 is None:
        raise ValueError("no initial pose: the stream has no groundtruth; pass x0=(x, y, theta)")
    M, N, T = params.n_particles, stream.n_landmarks, len(stream)
    if T == 0:
        raise ValueError("the event stream is empty")
    particles = (ParticleSet if particle_class is None else particle_class).initial(M, N, x0)
    if params.mode == "localize":
        if landmarks is None:
            raise ValueError('mode="localize" needs the known landmark positions (landmarks=...)')
        landmarks = np.asarray(landmarks, dtype=float)
        if landmarks.shape != (N, 2):
            raise ValueError(f"landmarks must have shape ({N}, 2), got {landmarks.shape}")
        particles = particles.with_known_map(landmarks)
    if params.mode == "map":
        proposal = KnownPoses(groundtruth_poses)
    elif params.proposal == "fastslam2":
        if not isinstance(particles, ParticleSet):
            raise ValueError('proposal="fastslam2" needs the dense ParticleSet (particle_class=None)')
        proposal = ImprovedProposal()
    else:
        proposal = MotionProposal()
    gate = Gate(params.gate_chi2, params.gate_escape_s, N)
    log, settings, record = kernel_inputs(stream, params, gate, type(proposal) is ImprovedProposal, particles.weights)
    return FilterRun(stream=stream, params=params, rng=rng, particles=particles, proposal=proposal, gate=gate,
                     u=log.u, dt=log.dt, R=log.R, log=log, settings=settings, record=record)


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
    landmarks : (N, 2) known landmark positions, needed for ``mode="localize"``.
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
            segments = np.array(list(measurement_segments(stream, cut_times)), dtype=np.int64).reshape(-1, 2)
            run.run_compiled(segments, hooks)
        else:
            run_python_loop(run, cut_times)
        for hook in hooks:
            hook.close(run)
    return run.result(timer.filter_seconds, timer.compile_seconds)


def run_python_loop(run: FilterRun, cut_times) -> None:
    """Steps 1–4 segment by segment in Python, with every hook's calls (:class:`Hook`)."""
    stream, hooks = run.stream, run.hooks
    for s, e in measurement_segments(stream, cut_times):
        run.measured = stream.offsets[e + 1] > stream.offsets[e]
        last = e if run.measured else e + 1  # a measurement step's estimate is taken after the update
        run.pose_mean[s:last], run.pose_best[s:last] = run.proposal.move(run, s, e, last - s)
        for hook in hooks:
            hook.after_motion(run, s, e)
        if run.measured:
            run.measure(s, e)
        for hook in hooks:
            hook.after_step(run, s, e)


__all__ = ["FastSLAMParams", "FastSLAMResult", "FilterRun", "MODES", "PROPOSALS", "CHI2_2DOF_999", "CHI2_2DOF_1E6",
           "start_run", "run_fastslam", "run_python_loop"]

#: Names of other modules that files owned elsewhere read from here (smoother_factors.py, ekf_slam.py:
#: stream_commands, Gate; app/cli.py: ProgressBar; chapter 8: MAX_SEGMENT), kept importable from this module.
REEXPORTED = (stream_commands, Gate, ProgressBar, MAX_SEGMENT)
