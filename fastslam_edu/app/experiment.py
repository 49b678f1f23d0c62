"""One FastSLAM experiment on MR.CLAM, end to end: load, check, run, measure.

Used by the command line (``fastslam-edu run``), the benchmarks and the book,
so that all of them report the same figures computed the same way:

* ``path_rmse_m`` / ``path_max_m``: position error of the weighted-mean pose
  against groundtruth interpolated at the filter's step times (steps outside
  the groundtruth span are not scored);
* ``path_rmse_aligned_m``: the same after the least-squares SE(2) alignment of
  the estimated path onto groundtruth (what is left once the map's global
  rotation and offset — unobservable for SLAM — are removed);
* ``landmark_error_mean_m`` and ``landmark_error_aligned_mean_m``: mean
  distance between the combined map and the landmark table, raw and after
  aligning the map onto the table.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from fastslam_edu.evaluation import association as score
from fastslam_edu.evaluation import metrics
from fastslam_edu.evaluation.audit import apply_landmark_audit
from fastslam_edu.datasets.events import event_stream, groundtruth_at
from fastslam_edu.datasets.log import Dataset, EventStream, RobotLog
from fastslam_edu.datasets.mrclam import groundtruth_files, read_dataset, read_groundtruth_csv, read_groundtruth_dat, robots_in
from fastslam_edu.landmark.ekf_slam import EKFSLAMParams, EKFSLAMResult, run_ekf_slam
from fastslam_edu.landmark.fastslam import FastSLAMParams, FastSLAMResult, run_fastslam
from fastslam_edu.landmark.initial_pose import initial_pose_from_landmarks
from fastslam_edu.landmark.smoother import SmootherResult
from fastslam_edu.landmark.smoother_association import SmootherAssociationResult


def load_mrclam(path, robot: int, *, groundtruth_file=None, audit: bool = True):
    """Read one robot of a MR.CLAM dataset, with the landmark table audited.

    The audit (:mod:`fastslam_edu.evaluation.audit`) needs groundtruth poses: it
    uses the robot's own, or, for a robot without groundtruth (Dataset 1,
    robots 3–5), those of the dataset's other robots — the table is the
    dataset's, not the robot's, and a robot without groundtruth must not get
    the uncorrected table.

    Returns ``(dataset, log, notes)``; ``notes`` lists corrections made to the
    landmark table and other remarks.
    """
    path = Path(path)
    dataset = read_dataset(path, robots=[robot])
    if robot not in dataset.robots:
        raise ValueError(f"robot {robot} has no odometry file in {path} (robots: {sorted(dataset.robots)})")
    log = dataset.robots[robot]
    notes: list[str] = []
    if groundtruth_file is not None:
        gt_path = Path(groundtruth_file)
        gt = read_groundtruth_csv(gt_path) if gt_path.suffix.lower() == ".csv" else read_groundtruth_dat(gt_path)
        log = dataclasses.replace(log, groundtruth=gt)
        dataset = dataclasses.replace(dataset, robots={robot: log})
        notes.append(f"groundtruth from {gt_path}")
    if audit:
        checked = dataset
        if log.groundtruth is None:  # audit with the robots that have groundtruth
            others = [r for r in robots_in(path) if r != robot and any(f.is_file() for f in groundtruth_files(path, r))]
            if others:
                checked = read_dataset(path, robots=others)
        fixed, fixes = apply_landmark_audit(checked)
        if fixes and checked is not dataset:
            fixes = [f"{line} [checked with robots {', '.join(map(str, sorted(checked.robots)))}]" for line in fixes]
        if fixes:
            dataset = dataclasses.replace(dataset, landmarks=fixed.landmarks)
        notes += fixes
    return dataset, log, notes


def dropped_sightings_notes(log: RobotLog) -> list[str]:
    """Notes on the measurement rows the reader set aside as neither landmark nor robot (``log.dropped``).

    Sightings of the other robots are expected and only counted (in the run's summary); a barcode in no
    table, or a subject without a surveyed position, is a misread or a gap in the files and is noted.
    """
    notes = []
    where = f"robot {log.robot} measurements ({log.source or 'no source'})"
    unknown = log.dropped.get("unknown_barcodes", {})
    if unknown:
        listed = ", ".join(f"{b} ({n}x)" for b, n in unknown.items())
        notes.append(f"{where}: {sum(unknown.values())} sighting(s) of barcodes in no table skipped: {listed}")
    orphans = log.dropped.get("subjects_without_groundtruth", {})
    if orphans:
        listed = ", ".join(f"{s} ({n}x)" for s, n in orphans.items())
        notes.append(f"{where}: {sum(orphans.values())} sighting(s) of subjects with no surveyed position "
                     f"skipped: {listed}")
    return notes


def _scored(counts: dict, result, poses, landmarks, dataset: Dataset, log: RobotLog) -> dict:
    """``counts`` and the errors of ``poses`` (T, 3) and ``landmarks`` (N, 2) at ``result.t`` (:func:`score_estimate`)."""
    return counts | score_estimate(result.t, poses, landmarks, result.observed, result.landmark_subjects, dataset, log)


def summarize(result: FastSLAMResult, dataset: Dataset, log: RobotLog) -> dict:
    """The figures of a run against groundtruth (see the module docstring)."""
    counts = {"steps": int(len(result.t)), "measurements_used": result.measurements_used,
              "measurements_rejected": result.measurements_rejected, "resamples": result.n_resamples,
              "filter_seconds": round(result.filter_seconds, 4), "compile_seconds": round(result.compile_seconds, 4)}
    return _scored(counts, result, result.pose_mean, result.landmarks_mean, dataset, log)


def summarize_smoother(result: SmootherResult, dataset: Dataset, log: RobotLog) -> dict:
    """The figures of a :func:`fastslam_edu.landmark.smoother.smooth` solution, scored as a filter run is."""
    counts = {"keyframes": int(len(result.t)), "measurements_used": result.measurements_used,
              "measurements_rejected": result.measurements_rejected, "iterations": result.iterations,
              "smoother_seconds": round(result.seconds, 4), "backend": result.backend,
              "seconds": round(result.seconds, 4)}
    out = _scored(counts, result, result.poses, result.landmarks, dataset, log)
    out["landmark_std_mean_m"] = landmark_std_mean(result.landmarks_cov, result.observed)
    return out


def landmark_std_mean(cov, observed) -> float | None:
    """Mean over the observed landmarks of :math:`\\sqrt{\\mathrm{tr}\\,\\Sigma_k}` [m] (None if none observed)."""
    sd = np.sqrt(np.trace(cov[observed], axis1=1, axis2=2))
    return float(sd.mean()) if sd.size else None


def score_estimate(t, poses, landmarks, observed, landmark_subjects, dataset: Dataset, log: RobotLog) -> dict:
    """Path and map errors of an estimate against groundtruth (the figures of the module docstring).

    ``t`` (T,), ``poses`` (T, 3): the estimated path; ``landmarks`` (N, 2) with ``observed`` (N,)
    the map, in the order of ``landmark_subjects``. Poses outside the groundtruth's span are not scored.
    """
    out: dict = {"landmarks_observed": int(np.sum(observed))}
    truth = dataset.landmark_positions
    err = metrics.landmark_errors(landmarks, truth, observed)
    out["landmark_error_mean_m"] = float(np.nanmean(err)) if np.any(observed) else None
    out["landmark_error_aligned_mean_m"] = (
        float(np.nanmean(metrics.landmark_errors_aligned(landmarks, truth, observed)))
        if np.sum(observed) >= 2
        else None
    )
    out["landmark_errors_m"] = {
        int(s): (None if np.isnan(e) else round(float(e), 4)) for s, e in zip(landmark_subjects, err)
    }
    gt = log.groundtruth
    if gt is None:
        out.update(path_rmse_m=None, path_rmse_aligned_m=None, path_mean_m=None, path_max_m=None)
        return out
    t_gt = gt["time"].to_numpy()
    scored = (t >= t_gt[0]) & (t <= t_gt[-1])
    poses_gt = gt[["x", "y", "theta"]].to_numpy()
    e = metrics.trajectory_errors(t[scored], poses[scored], t_gt, poses_gt)
    ea = metrics.trajectory_errors(t[scored], poses[scored], t_gt, poses_gt, align=True)
    out.update(
        path_rmse_m=float(e["rmse"]),
        path_mean_m=float(e["mean"]),
        path_max_m=float(e["max"]),
        path_rmse_aligned_m=float(ea["rmse"]),
        heading_rmse_rad=float(e["heading_rmse"]) if e.get("heading_rmse") is not None else None,
        steps_scored=int(scored.sum()),
    )
    return out


def params_table(params: FastSLAMParams, name: str = "FastSLAMParams()"):
    """FastSLAMParams as one readable column (a pandas DataFrame), for the book.

    Every field, with the motion noise's non-zero entries spelled out and
    :math:`R` given as its standard deviations ``sigma_r [m]``, ``sigma_phi [rad]``.
    """
    import pandas as pd

    rows = {}
    for f in dataclasses.fields(params):
        value = getattr(params, f.name)
        if f.name == "motion_noise":
            rows.update({f"motion_noise.{k}": v for k, v in dataclasses.asdict(value).items() if v})
        elif f.name == "measurement_cov":
            rows["sigma_r [m]"], rows["sigma_phi [rad]"] = np.sqrt(np.diag(value)).round(4)
        else:
            rows[f.name] = value
    return pd.Series(rows, dtype=object).to_frame(name)


def _skipped(log: RobotLog) -> dict:
    """``log.dropped`` as JSON: counts of the measurement rows that are not landmark sightings."""
    d = log.dropped
    return {"robot_sightings": int(d.get("robot_sightings", 0)),
            "unknown_barcodes": {str(b): int(n) for b, n in d.get("unknown_barcodes", {}).items()},
            "subjects_without_groundtruth": {str(k): int(n) for k, n in d.get("subjects_without_groundtruth", {}).items()}}


def prepare_run(path, robot: int, *, rate: str = "full", x0=None, **load_options):
    """What every filter's run on a MR.CLAM robot starts from: ``(dataset, log, notes, stream)``.

    :func:`load_mrclam` (audited table, ``load_options``), the notes on skipped sightings, the initial
    pose (``x0``: a pose, ``"landmarks"``, or None for the groundtruth at the first step) and the event stream.
    """
    dataset, log, notes = load_mrclam(path, robot, **load_options)
    notes += dropped_sightings_notes(log)
    if isinstance(x0, str):
        if x0 != "landmarks":
            raise ValueError(f'x0 must be a pose (x, y, theta) or "landmarks", got {x0!r}')
        start = initial_pose_from_landmarks(log, dataset.landmark_positions, dataset.landmark_subjects)
        notes.append(start.describe())
        x0 = start.x0
    stream = event_stream(log, dataset.landmark_subjects, rate=rate, x0=x0)
    if stream.x0 is None:
        raise ValueError(
            f"robot {robot} in {path} has no groundtruth to take the initial pose from; "
            "pass --groundtruth FILE, or --x0 landmarks to find it from the surveyed landmarks"
        )
    return dataset, log, notes, stream


def run_mrclam(
    path,
    robot: int,
    params: FastSLAMParams = FastSLAMParams(),
    seed: int = 0,
    *,
    rate: str = "full",
    x0=None,
    hooks=(),
    **load_options,
):
    """Load, run and score FastSLAM on one robot of a MR.CLAM dataset.

    ``x0``: the initial pose ``(x, y, θ)``; ``"landmarks"`` to find it from the
    first sightings of the surveyed landmarks (:mod:`fastslam_edu.landmark.initial_pose`,
    for robots without groundtruth; the summary's notes say where it came from);
    default the groundtruth at the first step. ``hooks``: run alongside the filter
    (:class:`~fastslam_edu.landmark.fastslam.Kidnap`, :class:`~fastslam_edu.landmark.fastslam.ProgressBar`, ...).
    ``load_options`` go to :func:`load_mrclam` (``groundtruth_file``, ``audit``).

    Returns ``(result, summary, context)`` where ``context`` holds the dataset,
    the log, the event stream and the notes.
    """
    dataset, log, notes, stream = prepare_run(path, robot, rate=rate, x0=x0, **load_options)
    gt_fn = None
    if params.mode == "map":
        if log.groundtruth is None:
            raise ValueError('mode "map" needs groundtruth poses')
        gt_fn = lambda t: groundtruth_at(log, t)  # noqa: E731
    result = run_fastslam(
        stream,
        params,
        np.random.default_rng(seed),
        landmarks=dataset.landmark_positions,
        groundtruth_poses=gt_fn,
        hooks=hooks,
    )
    summary = summarize(result, dataset, log)
    summary.update(
        dataset=str(path), robot=robot, rate=rate, seed=seed, params=params.to_dict(), notes=notes,
        x0=[float(v) for v in stream.x0], sightings_skipped=_skipped(log),
    )
    return result, summary, {"dataset": dataset, "log": log, "stream": stream, "notes": notes}


def summarize_ekf(result: EKFSLAMResult, dataset: Dataset, log: RobotLog) -> dict:
    """The figures of an EKF-SLAM run (:mod:`fastslam_edu.landmark.ekf_slam`), with the keys of :func:`summarize`.

    No resampling in an EKF: no ``resamples``. ``landmark_std_mean_m``: the mean over the
    observed landmarks of :math:`\\sqrt{\\mathrm{tr}\\,\\Sigma_k}`, the standard deviation the filter reports.
    """
    counts = {"steps": int(len(result.t)), "measurements_used": result.measurements_used,
              "measurements_rejected": result.measurements_rejected, "filter_seconds": round(result.filter_seconds, 4),
              "compile_seconds": round(result.compile_seconds, 4)}
    out = _scored(counts, result, result.pose_mean, result.landmarks_mean, dataset, log)
    out["landmark_std_mean_m"] = landmark_std_mean(result.landmarks_cov, result.observed)
    return out


def run_mrclam_ekf(path, robot: int, params: EKFSLAMParams = EKFSLAMParams(), *, rate: str = "full", x0=None,
                   **load_options):
    """Load, run and score EKF-SLAM on one robot of a MR.CLAM dataset.

    As :func:`run_mrclam` (same loading, audit, initial pose and scores), with
    :func:`fastslam_edu.landmark.ekf_slam.run_ekf_slam` as the filter. Deterministic: no seed. With
    ``params.correspondences == "unknown"`` every sighting is given without its barcode, and the run is
    scored as FastSLAM's with unknown correspondences (:func:`anonymous_stream`, :func:`summarize_unknown`).
    Returns ``(result, summary, context)``.
    """
    dataset, log, notes, stream = prepare_run(path, robot, rate=rate, x0=x0, **load_options)
    if params.correspondences == "unknown":
        stream, true_index = anonymous_stream(path, robot, dataset, log, rate=rate, x0=stream.x0)
        notes = _unknown_notes(notes, log, true_index)
        result = run_ekf_slam(stream, params)
        summary = summarize_unknown(result, stream, true_index, dataset, log)
    else:
        result, true_index = run_ekf_slam(stream, params), None
        summary = summarize_ekf(result, dataset, log)
        summary["sightings_skipped"] = _skipped(log)
    summary.update(dataset=str(path), robot=robot, rate=rate, params=params.to_dict(), notes=notes,
                   x0=[float(v) for v in stream.x0])
    return result, summary, {"dataset": dataset, "log": log, "stream": stream, "notes": notes,
                             "true_index": true_index}


# ---------------------------------------------------------------- unknown correspondences


#: The subject given to every sighting that is not of a surveyed landmark (another robot, an unknown barcode).
CLUTTER = -1


def anonymous_stream(path, robot: int, dataset: Dataset, log: RobotLog, *, rate: str = "full", x0=None,
                     t_end: float | None = None):
    """Every sighting of the robot's measurement file, landmark or not, as an event stream, and its truth.

    Returns ``(stream, true_index)``: the stream holds all sightings (of landmarks, of the other
    robots, of barcodes in no table) in the order the known-correspondence stream would; ``true_index``
    (n,) is the surveyed landmark (index into ``dataset.landmark_subjects``) each is of, -1 for clutter.
    The filter with unknown correspondences reads only the stream's ``z``; ``true_index`` scores it.
    ``t_end``: the last time [s] of the stream (:func:`fastslam_edu.datasets.events.event_stream`; None: the whole log).
    """
    from fastslam_edu.datasets.mrclam import read_measurements

    raw = read_measurements(Path(path) / f"Robot{robot}_Measurement.dat")
    subject_of = {int(b): int(s) for b, s in dataset.barcodes.items()}
    surveyed = set(dataset.landmark_subjects.tolist())
    subject = np.array([subject_of.get(int(b), CLUTTER) for b in raw["barcode"]], dtype=np.int64)
    subject[~np.isin(subject, list(surveyed))] = CLUTTER
    measurements = raw.rename(columns={"barcode": "subject"}).assign(subject=subject)
    everything = dataclasses.replace(log, measurements=measurements)
    subjects = np.append(dataset.landmark_subjects, CLUTTER)
    stream = event_stream(everything, subjects, rate=rate, x0=x0, t_end=t_end)
    true_index = np.where(stream.landmark == len(subjects) - 1, -1, stream.landmark)
    return stream, true_index


def _unknown_notes(notes, log: RobotLog, true_index) -> list[str]:
    """The notes of a run without barcodes: none about skipped sightings (nothing is skipped), one about clutter."""
    return [n for n in notes if n not in dropped_sightings_notes(log)] + [
        f"{int(np.sum(np.asarray(true_index) < 0))} sighting(s) of other robots and unknown barcodes given to the "
        "filter as clutter (without identity, like every sighting)"]


def _unknown_counts(result) -> dict:
    """What a run with unknown correspondences reports of itself: FastSLAM's or EKF-SLAM's."""
    if isinstance(result, EKFSLAMResult):  # one hypothesis: nothing provisional, no resampling
        return {"landmarks_created": int(len(result.landmarks)), "filter_seconds": round(result.filter_seconds, 4)}
    return {"landmarks_provisional": result.n_provisional, "landmarks_created": result.landmarks_created,
            "resamples": result.n_resamples, "filter_seconds": round(result.filter_seconds, 4),
            "compile_seconds": round(result.compile_seconds, 4)}


def summarize_unknown(result, stream, true_index, dataset: Dataset, log: RobotLog) -> dict:
    """The figures of a run with unknown correspondences: association scores, map counts and the usual errors.

    The map's landmarks are matched to the surveyed ones (:func:`fastslam_edu.evaluation.association.match_landmarks`,
    starting from the SE(2) motion that fits the filter's mean path to the groundtruth when there is one, and from
    the motion that registers the map on the survey, :func:`fastslam_edu.evaluation.registration.register`);
    the landmark errors are those of the matched landmarks.
    """
    truth = dataset.landmark_positions
    start = None
    if log.groundtruth is not None:  # the map is matched in the frame that best fits the path to the groundtruth
        gt = log.groundtruth["time"].to_numpy()
        inside = (result.t >= gt[0]) & (result.t <= gt[-1])
        start = score.path_alignment(result.pose_mean[inside, :2], groundtruth_at(log, result.t[inside])[:, :2])
    match = score.match_landmarks(result.landmarks, truth, start=start)
    landmarks, observed = score.in_survey_order(result.landmarks, match, len(truth))
    out: dict = {
        "correspondences": "unknown",
        "steps": int(len(result.t)),
        "sightings": int(len(true_index)),
        "landmark_sightings": int(np.sum(true_index >= 0)),
        "clutter_sightings": int(np.sum(true_index < 0)),
        "association_accuracy": score.association_accuracy(result.history, true_index, result.landmark_ident, match),
        "association_breakdown": score.association_breakdown(result.history, true_index, result.landmark_ident, match),
        "association_accuracy_oracle": None,
        "landmarks_in_map": score.landmarks_in_map(result.landmarks),
        "landmarks_spurious": int(np.sum(match < 0)),
        **_unknown_counts(result),
    }
    if log.groundtruth is not None:
        t = stream.t[stream.sighting_steps]
        gt = log.groundtruth["time"].to_numpy()
        inside = (t >= gt[0] - 0.5) & (t <= gt[-1] + 0.5)
        poses = np.full((len(t), 3), np.nan)
        poses[inside] = groundtruth_at(log, t[inside])
        model = result.params if isinstance(result, EKFSLAMResult) else result.params.filter
        R = model.measurement_covariance(stream.z)
        out["association_accuracy_oracle"] = score.association_accuracy_oracle(
            poses[inside], stream.z[inside], R[inside], truth, np.asarray(true_index)[inside])
    out.update(score_estimate(result.t, result.pose_mean, landmarks, observed, dataset.landmark_subjects,
                              dataset, log))
    return out


def association_ceiling(known: FastSLAMResult, stream, true_index, params: FastSLAMParams = FastSLAMParams()) -> float:
    """The association ceiling of a FastSLAM run with known correspondences, ``known``, on the anonymous ``stream``
    of the same log (:func:`anonymous_stream`, with its ``true_index``): maximum-likelihood association with
    ``params``' :math:`R` at the run's own mean path against its own final map (unobserved landmarks left out)
    (:func:`fastslam_edu.evaluation.association.association_accuracy_ceiling`)."""
    from fastslam_edu.evaluation.association import association_accuracy_ceiling

    landmarks = np.where(known.observed[:, None], known.landmarks_mean, np.nan)
    return association_accuracy_ceiling(known.t, known.pose_mean, stream.t[stream.sighting_steps], stream.z,
                                        params.measurement_covariance(stream.z), landmarks, true_index)


def run_mrclam_unknown(path, robot: int, params=None, seed: int = 0, *, rate: str = "full", x0=None,
                       **load_options):
    """Load, run and score FastSLAM with unknown correspondences on one robot of a MR.CLAM dataset.

    As :func:`run_mrclam` (same loading, audit, initial pose), with every sighting of the robot's
    measurement file given to :func:`fastslam_edu.landmark.association.run_unknown` without its
    barcode (:func:`anonymous_stream`); the barcodes score the run (:func:`summarize_unknown`).
    ``params``: an :class:`~fastslam_edu.landmark.association.AssociationParams` (default: its defaults).
    Returns ``(result, summary, context)``; ``context`` adds ``true_index``.
    """
    from fastslam_edu.landmark.association import AssociationParams, run_unknown

    params = AssociationParams() if params is None else params
    dataset, log, notes, known = prepare_run(path, robot, rate=rate, x0=x0, **load_options)
    stream, true_index = anonymous_stream(path, robot, dataset, log, rate=rate, x0=known.x0)
    notes = _unknown_notes(notes, log, true_index)
    result = run_unknown(stream, params, np.random.default_rng(seed))
    summary = summarize_unknown(result, stream, true_index, dataset, log)
    summary.update(dataset=str(path), robot=robot, rate=rate, seed=seed, params=params.to_dict(), notes=notes,
                   x0=[float(v) for v in stream.x0])
    return result, summary, {"dataset": dataset, "log": log, "stream": stream, "notes": notes,
                             "true_index": true_index}


def summarize_smoother_association(result: SmootherAssociationResult, stream: EventStream, true_index,
                                   dataset: Dataset, log: RobotLog) -> dict:
    """The JSON ``smoother`` part of ``fastslam-edu run --correspondences unknown --smooth``: the association and map
    keys of the filter's summary (:func:`summarize_unknown`), computed by the same
    :mod:`fastslam_edu.evaluation.association` functions, and the smoother's own counts."""
    truth = dataset.landmark_positions
    start = None
    if log.groundtruth is not None:
        gt = log.groundtruth["time"].to_numpy()
        t = stream.t
        inside = (t >= gt[0]) & (t <= gt[-1])
        start = score.path_alignment(result.pose_mean[inside, :2], groundtruth_at(log, t[inside])[:, :2])
    match = score.match_landmarks(result.landmarks, truth, start=start)
    landmarks, observed = score.in_survey_order(result.landmarks, match, len(truth))
    out = {"association_accuracy": score.association_accuracy(result.history, true_index, result.landmark_ident, match),
           "association_breakdown": score.association_breakdown(result.history, true_index, result.landmark_ident,
                                                                match),
           "landmarks_in_map": score.landmarks_in_map(result.landmarks),
           "landmarks_spurious": int(np.sum(match < 0)), "outliers": result.outliers, "cost": result.cost,
           "restart_costs": [float(c) for c in result.costs], "rounds": result.rounds,
           "loop_closures": result.loop_closures, "smoother_seconds": round(result.seconds, 4),
           "seconds": round(result.seconds, 4)}
    out.update(score_estimate(stream.t, result.pose_mean, landmarks, observed, dataset.landmark_subjects, dataset, log))
    return out
