"""EKF-SLAM with known or unknown correspondences: one Gaussian over the pose and the whole map.

The baseline FastSLAM was designed to beat (*Probabilistic Robotics*, table 10.1; with
unknown correspondences, table 10.2: see "Unknown correspondences" below).
The state is the pose and all :math:`N` landmarks stacked,

.. math::

    \\mathbf y = (x, y, \\theta, l_{1,x}, l_{1,y}, \\dots, l_{N,x}, l_{N,y})^\\top, \\qquad
    \\mathbf y \\sim \\mathcal N(\\mu, \\Sigma),

with :math:`\\mu` of shape (3 + 2N,) [m, m, rad, m, ...] and :math:`\\Sigma` (3 + 2N, 3 + 2N).
Landmark :math:`k` occupies rows ``3 + 2k`` and ``4 + 2k`` (:func:`~.ekf_slam_steps.landmark_slice`).
The off-diagonal blocks are what FastSLAM does without: how the error of one
landmark is tied to the pose's and to every other landmark's.

The filter, for each step of an event stream
(:func:`fastslam_edu.datasets.events.event_stream`):

1. **Prediction** (table 10.1, lines 2–5; :func:`~.ekf_slam_steps.predict`): the pose moves by the
   unicycle of :mod:`fastslam_edu.core.motion` (Euler step, heading at the start),
   the map stays. With the Jacobian :math:`G_t = \\partial g / \\partial x` and the
   motion noise :math:`V_t M_t V_t^\\top` in pose space (noise densities per √s, as
   FastSLAM's :class:`~fastslam_edu.core.motion.MotionNoise`),

   .. math::

       \\Sigma_{xx} \\leftarrow G_t \\Sigma_{xx} G_t^\\top + V_t M_t V_t^\\top, \\qquad
       \\Sigma_{xm} \\leftarrow G_t \\Sigma_{xm} .

   Only the pose's rows and columns change: :math:`O(N)`. Between two sightings the
   steps are composed in one (:func:`~.ekf_slam_steps.predict_segment`, equal to the step-by-step
   prediction to rounding).
2. **A landmark seen for the first time** is initialised from the inverse model
   :math:`\\mathbf l_k = h^{-1}(x, z)` (:func:`~.ekf_slam_steps.augment_state`) with its cross-covariances:
   :math:`\\Sigma_{kk} = J_x \\Sigma_{xx} J_x^\\top + G R G^\\top`, :math:`\\Sigma_{k\\cdot} = J_x \\Sigma_{x\\cdot}`
   (:math:`J_x = \\partial h^{-1}/\\partial x`, :math:`G = \\partial h^{-1}/\\partial z`), not table 10.1's
   "infinite prior".
3. **Update** (table 10.1, the loop over the sightings; :func:`~.ekf_slam_steps.update`) for each sighting
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
   :math:`O(N^2)` per sighting, the cost FastSLAM avoids (:func:`~.ekf_slam_steps.joseph_update`).
4. **The gate**: a sighting whose squared Mahalanobis distance
   :math:`d^2 = \\nu^\\top Q^{-1} \\nu` exceeds ``gate_chi2`` is set aside, with the
   escape of FastSLAM's :class:`~fastslam_edu.landmark.fastslam.Gate` (after
   ``gate_escape_s`` seconds of rejections of one landmark, its sightings are applied).

**Unknown correspondences** (``correspondences="unknown"``, table 10.2): the filter never
reads ``stream.landmark``. The map grows one landmark at a time (the state's size is
:math:`3 + 2N_t`, :math:`N_t` the landmarks made so far). For each sighting the squared
Mahalanobis distance :math:`d_k^2 = \\nu_k^\\top Q_k^{-1}\\nu_k` to every map landmark is computed
(:func:`~.ekf_slam_association.association_distances`); the nearest one (smallest :math:`d^2`) is updated as above if
:math:`d^2 \\le \\min(` ``gate_chi2``, ``new_landmark_chi2`` :math:`)`; if :math:`d^2 >`
``new_landmark_chi2`` for *every* map landmark the sighting starts a new landmark; in between it is
set aside (too far to update, too near to be new). With ``mutual_exclusion`` the sightings of one
instant are associated jointly (:func:`~.ekf_slam_association.associate`, an assignment problem): two sightings of one
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

from fastslam_edu.core.checks import finite_array
from fastslam_edu.core.motion import MotionNoise
from fastslam_edu.core.params import Params
from fastslam_edu.core.timing import RunTimer
from fastslam_edu.datasets.log import EventStream
from fastslam_edu.landmark.ekf_slam_association import (NEW, SET_ASIDE, add_new_landmark, associate,
                                                        association_distances)
from fastslam_edu.landmark.ekf_slam_steps import (INITIALISED, REJECTED, UPDATED, EKFSLAMState, predict_segment,
                                                  update_unchecked)
from fastslam_edu.landmark.fastslam import FastSLAMParams, Gate, stream_commands

__all__ = ["EKFSLAMParams", "EKFSLAMResult", "run_ekf_slam", "NEW_LANDMARK_CHI2"]


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


# ---------------------------------------------------------------- the run


@dataclass
class EKFSLAMResult:
    """What :func:`run_ekf_slam` produces (the fields the scorers of FastSLAM's result read, and the joint Gaussian).

    Attributes
    ----------
    t : (T,) step times [s]
    pose_mean : (T, 3) :math:`\\mu_x` after each step (after the update at a measurement step)
    landmarks_mean, landmarks_cov, observed : (N, 2), (N, 2, 2), (N,) the map at the end (NaN where not seen)
    mean, cov : (3 + 2N,), (3 + 2N, 3 + 2N) the final joint :math:`\\mu`, :math:`\\Sigma`
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

    For each segment of steps ending at a measurement step: :func:`~.ekf_slam_steps.predict_segment`,
    then for each sighting of the step in order, with :math:`R` = ``params.measurement_covariance(z)``:

    * known correspondences: :func:`~.ekf_slam_steps.update` of landmark ``stream.landmark[j]``, with the gate;
    * unknown: :func:`~.ekf_slam_association.associate` (the sightings of the step jointly if
      ``params.mutual_exclusion``, on the distances before the step's updates; otherwise one by one, each after the
      previous update), then :func:`~.ekf_slam_steps.update` of the chosen landmark or
      :func:`~.ekf_slam_association.add_new_landmark`.
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
    commands = stream_commands(stream, params)
    z_all = np.asarray(stream.z, dtype=float)
    sightings = (z_all, params.measurement_covariance(z_all))
    record = _RunRecord(pose_mean=np.empty((len(stream), 3)), sighting_map=np.full(len(z_all), SET_ASIDE))
    with RunTimer() as timer:  # filter_seconds without numba's compiling (compile_seconds)
        _filter_loop(state, stream, commands, sightings, params, record)
    map_mean, map_cov = state.landmarks()
    counts = record.counts
    return EKFSLAMResult(
        t=np.asarray(stream.t, dtype=float), pose_mean=record.pose_mean, landmarks_mean=map_mean,
        landmarks_cov=map_cov, observed=state.seen.copy(), mean=state.mu, cov=state.sigma,
        update_t=np.asarray(record.update_t), pose_cov=np.asarray(record.pose_cov).reshape(-1, 3, 3),
        measurements_used=counts[INITIALISED] + counts[UPDATED], measurements_rejected=counts[REJECTED],
        filter_seconds=timer.filter_seconds, params=params, compile_seconds=timer.compile_seconds,
        landmark_subjects=np.asarray(stream.landmark_subjects), correspondences=params.correspondences,
        sighting_map=record.sighting_map, map_mean=map_mean, map_cov=map_cov,
    )


@dataclass
class _RunRecord:
    """What the run writes down as it goes (:class:`EKFSLAMResult` is built from it)."""

    pose_mean: np.ndarray  # (T, 3) μ_x after every step
    sighting_map: np.ndarray  # (n,) the map landmark each sighting updated or started (SET_ASIDE: none)
    update_t: list = field(default_factory=list)  # the time of every measurement step [s]
    pose_cov: list = field(default_factory=list)  # Σ_xx (3, 3) after every measurement step
    counts: dict = field(default_factory=lambda: {INITIALISED: 0, UPDATED: 0, REJECTED: 0})


def _filter_loop(state: EKFSLAMState, stream: EventStream, commands, sightings, params: EKFSLAMParams,
                 record: _RunRecord) -> None:
    """Prediction and update over the whole stream, in place on ``state`` and ``record``.

    ``commands`` = ``(u (T, 2), dt (T,))`` (:func:`~fastslam_edu.landmark.fastslam.stream_commands`),
    ``sightings`` = ``(z (n, 2), R (n, 2, 2))`` of every sighting of the stream.
    """
    u, dt = commands
    unknown = params.correspondences == "unknown"
    gate = Gate(params.gate_chi2, params.gate_escape_s, stream.n_landmarks)
    for s, e, measured in _measurement_steps(stream):
        record.pose_mean[s : e + 1] = predict_segment(state, u[s : e + 1], dt[s : e + 1], params.motion_noise)
        if not measured:
            continue
        if unknown:
            _associate_and_update(state, sightings, range(stream.offsets[e], stream.offsets[e + 1]), params, record)
        else:
            _update_known(state, stream, e, sightings, gate, record)
        record.pose_mean[e] = state.mu[:3]
        record.update_t.append(float(stream.t[e]))
        record.pose_cov.append(state.sigma[:3, :3].copy())


def _update_known(state: EKFSLAMState, stream: EventStream, e: int, sightings, gate: Gate, record: _RunRecord) -> None:
    """Table 10.1's updates for the sightings of step ``e``, their landmarks read from the stream, with the gate and
    its escape (in place; fills ``record``)."""
    z_all, R_all = sightings
    t = float(stream.t[e])
    for j in range(stream.offsets[e], stream.offsets[e + 1]):
        k = int(stream.landmark[j])
        outcome = update_unchecked(state, z_all[j], k, R_all[j], gate.chi2, bool(gate.escaped(t, [k])[0]))
        gate.record(t, [k], [outcome != REJECTED])
        record.counts[outcome] += 1
        if outcome != REJECTED:
            record.sighting_map[j] = k


def _associate_and_update(state: EKFSLAMState, sightings, rows, params: EKFSLAMParams, record: _RunRecord) -> None:
    """Table 10.2 for the sightings ``rows`` of one instant (in place; fills ``record``)."""
    z_all, R_all = sightings
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
            record.sighting_map[j] = add_new_landmark(state, z_all[j], R_all[j])
            record.counts[INITIALISED] += 1
        elif c == SET_ASIDE:
            record.counts[REJECTED] += 1
        else:
            update_unchecked(state, z_all[j], c, R_all[j], None, True)
            record.sighting_map[j] = c
            record.counts[UPDATED] += 1
