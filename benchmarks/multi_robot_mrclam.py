"""The five robots of MR.CLAM in one least-squares problem against each robot alone.

Datasets 1 and 6, every robot, full rate, default ``FastSLAMParams``, ``BEST_ESTIMATE`` (every sighting counted in
full). For filter seeds 0 … N-1 (the seed only changes the smoother's starting point, the filter's run):

* **single**: :func:`fastslam_edu.landmark.smoother.smooth` on each robot alone, from that robot's filter run;
* **joint**: :func:`fastslam_edu.landmark.multi_robot.smooth_robots` on all five robots, from their filter runs,
  with their sightings of each other (:func:`fastslam_edu.app.multi_robot.run_mrclam_robots`).

Per robot: absolute and aligned path RMSE (robots with groundtruth), landmark error and aligned landmark error
(single: the robot's own map; joint: the shared map), the median over the seeds; and the times. Robots without
groundtruth (Dataset 1, robots 3–5) start from the surveyed landmarks (:mod:`fastslam_edu.landmark.initial_pose`),
with a loose prior in the joint problem (``LANDMARK_START_STD``); the single-robot smoother pins them, as
``smoother_mrclam.py`` does. Target (issue 31): joint, every robot with groundtruth, path RMSE ≤ 0.30 m and landmark
error ≤ 0.30 m. Nothing here is tuned: the model is ``FastSLAMParams()``'s.

The (dataset, seed) jobs go through :func:`fastslam_edu.app.sweep.run_sweep`: ``--jobs N`` processes (joblib,
default all cores; 1: serially) or ``--scheduler ADDRESS``, a dask.distributed cluster (README, "Sweeps on a
cluster"); the numbers are the same whichever runs them, the times are not.

Usage: python benchmarks/multi_robot_mrclam.py [--seeds 3] [--jobs N | --scheduler ADDRESS] [--out FILE]
(data from $FASTSLAM_EDU_DATA; about 10 min on 2 cores, most of it the joint solves)
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402

from fastslam_edu.app.experiment import summarize_smoother  # noqa: E402
from fastslam_edu.app.multi_robot import LANDMARK_START_STD, run_mrclam_robots  # noqa: E402
from fastslam_edu.app.sweep import SweepError, add_sweep_options, run_sweep  # noqa: E402
from fastslam_edu.datasets import mrclam_path  # noqa: E402
from fastslam_edu.landmark.fastslam import FastSLAMParams  # noqa: E402
from fastslam_edu.landmark.smoother import BEST_ESTIMATE, smooth  # noqa: E402

DATASETS = (1, 6)
ROBOTS = (1, 2, 3, 4, 5)
FIGURES = ("path_rmse_m", "path_rmse_aligned_m", "landmark_error_mean_m", "landmark_error_aligned_mean_m")
TARGET_M = 0.30


def _job(dataset: int, seed: int) -> dict:
    """One dataset, one seed: the five single-robot solutions and the joint one."""
    path = mrclam_path(dataset)
    has_gt = {r: any((path / name).exists() for name in (f"Robot{r}_Groundtruth.dat",
                                                         f"groundtruth_1hz/Robot{r}_Groundtruth_1hz.csv",
                                                         f"groundtruth_1hz/Cleaned_Robot{r}_Groundtruth.csv"))
              for r in ROBOTS}
    x0 = {r: None if has_gt[r] else "landmarks" for r in ROBOTS}
    params = FastSLAMParams()
    started = time.perf_counter()
    result, summary, ctx = run_mrclam_robots(path, ROBOTS, params, seed, x0=x0, solver=BEST_ESTIMATE)
    total = time.perf_counter() - started
    out = {"dataset": dataset, "seed": seed, "joint": {}, "single": {},
           "joint_seconds": result.seconds, "joint_total_seconds": total,
           "robot_sightings_used": result.robot_sightings_used, "robot_sightings_gated": result.robot_sightings_gated,
           "joint_map": {k: summary["smoother"][k] for k in ("landmark_error_mean_m", "landmark_error_aligned_mean_m")}}
    for r in ROBOTS:
        c = ctx[r]
        single = smooth(c["stream"], params, initial=c["filter"], solver=BEST_ESTIMATE)
        s = summarize_smoother(single, c["dataset"], c["log"])
        out["single"][r] = {k: s.get(k) for k in FIGURES} | {"seconds": single.seconds}
        j = summary["smoother"]["robots"][str(r)]
        out["joint"][r] = {k: j.get(k) for k in FIGURES[:2]} | out["joint_map"]
    return out


def _median(values):
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def _fmt(v):
    return "  n/a" if v is None else f"{v:5.2f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    add_sweep_options(ap)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "multi_robot_mrclam.json")
    args = ap.parse_args(argv)
    if args.seeds < 1:
        ap.error(f"--seeds must be >= 1 (got {args.seeds})")
    jobs = [(d, s) for d in DATASETS for s in range(args.seeds)]
    try:
        runs = run_sweep(_job, jobs, n_jobs=args.jobs, scheduler=args.scheduler)
    except SweepError as error:
        sys.exit(f"{ap.prog}: error: {error}")
    table = []
    for d in DATASETS:
        mine = [x for x in runs if x["dataset"] == d]
        for r in ROBOTS:
            row = {"robot": f"D{d}R{r}"}
            for kind in ("single", "joint"):
                row[kind] = {k: _median([x[kind][r][k] for x in mine]) for k in FIGURES}
            row["single_seconds"] = _median([x["single"][r]["seconds"] for x in mine])
            gt = row["joint"]["path_rmse_m"] is not None
            row["meets_target"] = (row["joint"]["path_rmse_m"] <= TARGET_M
                                   and row["joint"]["landmark_error_mean_m"] <= TARGET_M) if gt else None
            table.append(row)
    times = {f"D{d}": {"joint_seconds_median": _median([x["joint_seconds"] for x in runs if x["dataset"] == d]),
                       "robot_sightings_used": _median([x["robot_sightings_used"] for x in runs if x["dataset"] == d]),
                       "robot_sightings_gated": _median([x["robot_sightings_gated"] for x in runs if x["dataset"] == d])}
             for d in DATASETS}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"machine": machine_info(), "params": FastSLAMParams().to_dict(),
                                    "solver": BEST_ESTIMATE.to_dict(), "landmark_start_std": LANDMARK_START_STD,
                                    "seeds": args.seeds, "target_m": TARGET_M, "table": table, "times": times,
                                    "runs": runs}, indent=2))
    print(f"Full rate, FastSLAMParams(), BEST_ESTIMATE; median of filter seeds 0-{args.seeds - 1} [m]. "
          "single: each robot alone; joint: five robots, shared map, robot-robot sightings")
    print(f"{'robot':<6} {'path RMSE':>13} {'path aligned':>13} {'landmarks':>13} {'lm aligned':>13} {'single s':>9}")
    print(f"{'':<6}" + " single joint" * 4)
    for row in table:
        cells = " ".join(f"{_fmt(row['single'][k])} {_fmt(row['joint'][k])}  " for k in FIGURES)
        print(f"{row['robot']:<6} {cells} {row['single_seconds']:8.1f}")
    for d, t in times.items():
        print(f"{d}: joint solve {t['joint_seconds_median']:.1f} s, robot sightings used {t['robot_sightings_used']:.0f}, "
              f"gated {t['robot_sightings_gated']:.0f}")
    met = [r["meets_target"] for r in table if r["meets_target"] is not None]
    print(f"target (joint, path and landmarks <= {TARGET_M} m on every robot with groundtruth): "
          f"{'met' if all(met) else 'NOT met'} on {sum(met)} of {len(met)}")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
