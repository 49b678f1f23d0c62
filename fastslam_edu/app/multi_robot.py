"""Several robots of one MR.CLAM dataset, end to end: load each, run the filter on each, solve all of them together
(:func:`fastslam_edu.landmark.multi_robot.smooth_robots`), score every robot's path and the shared map.

Used by ``fastslam-edu run --robots 1,2,3,4,5 --smooth`` and ``benchmarks/multi_robot_mrclam.py``. Each robot is
loaded and started as a single-robot run is (:func:`fastslam_edu.app.experiment.prepare_run`: the audited landmark
table, the initial pose from groundtruth at its first step, or from the surveyed landmarks); the filter's run with
``seed`` is the smoother's starting point (the seed changes nothing else).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fastslam_edu.app.experiment import landmark_std_mean, prepare_run, score_estimate, summarize, summarize_smoother
from fastslam_edu.datasets.mrclam import groundtruth_files
from fastslam_edu.landmark.fastslam import FastSLAMParams, run_fastslam
from fastslam_edu.landmark.multi_robot import MultiRobotResult, check_robot_numbers, check_streams, smooth_robots
from fastslam_edu.landmark.smoother import BEST_ESTIMATE, PRIOR_STD, SolverSettings
from fastslam_edu.landmark.smoother_gtsam import require_gtsam

#: Prior standard deviations on a first pose found from the surveyed landmarks [m, m, rad]
#: (:mod:`fastslam_edu.landmark.initial_pose`: decimetres and degrees off); a groundtruth start is pinned (``PRIOR_STD``).
LANDMARK_START_STD = (0.3, 0.3, 0.1)


def load_robots(path, robots, *, rate: str = "full", x0=None, audit: bool = True):
    """Each robot's ``(dataset, log, notes, stream)`` (:func:`~fastslam_edu.app.experiment.prepare_run`).

    ``x0``: None (groundtruth at the first step), ``"landmarks"``, a pose, or a dict robot → one of those.
    Raises one line for a robot number out of 1–5 or repeated, a missing file (naming it), a robot without a start
    (naming what works: ``x0="landmarks"``), logs that share no time (robots from different datasets) — all before
    any filter runs.
    """
    robots = check_robot_numbers(robots)
    path = Path(path)
    if not path.is_dir():
        raise FileNotFoundError(f"{path}: no such dataset folder")
    for r in robots:
        for kind in ("Odometry", "Measurement"):
            if not (path / f"Robot{r}_{kind}.dat").is_file():
                raise FileNotFoundError(f"robot {r}: no {kind.lower()} file {path / f'Robot{r}_{kind}.dat'}")
    starts = x0 if isinstance(x0, dict) else {r: x0 for r in robots}
    unstarted = [r for r in robots if starts.get(r) is None and not any(f.is_file() for f in groundtruth_files(path, r))]
    if unstarted:
        raise ValueError(f"robot(s) {', '.join(map(str, unstarted))} in {path} have no groundtruth to take the initial "
                         "pose from: start every robot from the surveyed landmarks (--x0 landmarks; "
                         "x0='landmarks' in Python)")
    loaded = {r: prepare_run(path, r, rate=rate, x0=starts.get(r), audit=audit) for r in robots}
    check_streams({r: loaded[r][3] for r in robots})
    return loaded


def run_mrclam_robots(path, robots, params: FastSLAMParams = FastSLAMParams(), seed: int = 0, *, rate: str = "full",
                      x0=None, solver: SolverSettings = BEST_ESTIMATE, audit: bool = True, hooks=(),
                      backend: str = "scipy"):
    """Load, filter, smooth together and score several robots of one MR.CLAM dataset.

    ``backend``: who solves the joint least squares, ``"scipy"`` (the package's Levenberg–Marquardt) or ``"gtsam"``
    (:func:`~fastslam_edu.landmark.multi_robot.smooth_robots`; needs the extra ``graph``).

    Returns ``(result, summary, context)``: the :class:`~fastslam_edu.landmark.multi_robot.MultiRobotResult`, the
    JSON summary (the filters' figures per robot under ``filters``; the joint solution's under ``smoother``:
    ``robots`` keyed by robot number with ``path_rmse_m``, ``path_rmse_aligned_m`` (None without groundtruth), and for
    the shared map ``landmark_error_mean_m``, ``landmark_error_aligned_mean_m``, ``robot_sightings_used``,
    ``robot_sightings_gated``), and a context dict robot → ``{"dataset", "log", "stream", "filter"}``.
    """
    robots = check_robot_numbers(robots)
    if backend not in ("scipy", "gtsam"):
        raise ValueError(f"backend must be 'scipy' or 'gtsam', got {backend!r}")
    if backend == "gtsam":
        require_gtsam()  # before the filters run: an ImportError naming the extra to install
    loaded = load_robots(path, robots, rate=rate, x0=x0, audit=audit)
    streams = {r: loaded[r][3] for r in robots}
    starts = x0 if isinstance(x0, dict) else {r: x0 for r in robots}
    stds = {r: LANDMARK_START_STD if isinstance(starts.get(r), str) else PRIOR_STD for r in robots}
    filters = {r: run_fastslam(streams[r], params, np.random.default_rng(seed), hooks=hooks) for r in robots}
    sightings = {r: loaded[r][1].robot_sightings for r in robots}
    result = smooth_robots(streams, sightings, params, initial=filters, x0_std=stds, solver=solver, backend=backend)
    notes = [n for r in robots for n in loaded[r][2]] + result.notes
    dataset = loaded[robots[0]][0]
    summary = {
        "dataset": str(path), "robots": list(robots), "rate": rate, "seed": seed, "params": params.to_dict(),
        "solver": solver.to_dict(), "notes": notes,
        "x0": {str(r): [float(v) for v in streams[r].x0] for r in robots},
        "filters": {str(r): summarize(filters[r], loaded[r][0], loaded[r][1]) for r in robots},
        "smoother": summarize_robots(result, {r: (loaded[r][0], loaded[r][1]) for r in robots}, dataset),
    }
    context = {r: {"dataset": loaded[r][0], "log": loaded[r][1], "stream": streams[r], "filter": filters[r]}
               for r in robots}
    return result, summary, context


def summarize_robots(result: MultiRobotResult, logs: dict, dataset) -> dict:
    """The joint solution's figures: per robot (``robots``, keyed by robot number as a string) its path's errors
    against its groundtruth (None without), the shared map's errors against ``dataset``'s landmark table, which
    solver ran (``backend``) and its wall time (``seconds``, also ``smoother_seconds``) [s]."""
    per_robot = {}
    for r in result.robots:
        s = summarize_smoother(result.robot(r), *logs[r])
        per_robot[str(r)] = {k: s.get(k) for k in ("path_rmse_m", "path_rmse_aligned_m", "path_mean_m", "path_max_m",
                                                   "heading_rmse_rad", "steps_scored", "keyframes")}
    first = result.robots[0]
    shared = score_estimate(result.t[first], result.poses[first], result.landmarks, result.observed,
                            result.landmark_subjects, dataset, logs[first][1])
    return {
        "robots": per_robot,
        **{k: shared[k] for k in ("landmark_error_mean_m", "landmark_error_aligned_mean_m", "landmarks_observed",
                                  "landmark_errors_m")},
        "landmark_std_mean_m": landmark_std_mean(result.landmarks_cov, result.observed),
        "robot_sightings_used": result.robot_sightings_used, "robot_sightings_gated": result.robot_sightings_gated,
        "robot_sightings_skipped": result.robot_sightings_skipped,
        "measurements_used": result.measurements_used, "measurements_rejected": result.measurements_rejected,
        "iterations": result.iterations, "cost": result.cost, "backend": result.backend,
        "seconds": round(result.seconds, 4), "smoother_seconds": round(result.seconds, 4),
    }
