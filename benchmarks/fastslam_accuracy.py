"""FastSLAM accuracy on MR.CLAM against the targets of the engine's issue.

Every robot with groundtruth that the targets name — Dataset 1 robot 2 and the
five robots of Dataset 6 — and Dataset 1 robot 1 (1 Hz groundtruth too) at full rate, with the default ``FastSLAMParams``
(or ``--particles M``), over seeds 0 … N-1: the median and the worst of path
RMSE, mean landmark error and aligned mean landmark error, next to the targets
(≤ 0.5 m, ≤ 0.5 m, ≤ 0.25 m). Dataset 1's robots 3–5, which have no
groundtruth, are run too (no tuning was ever done on them): from an initial pose found from their first
sightings of the surveyed landmarks (:mod:`fastslam_edu.landmark.initial_pose`, decimetres and degrees off),
scored by their maps — the aligned landmark error does not depend on the start. Prints a table and writes JSON. ``--proposal
fastslam2`` runs FastSLAM 2.0's proposal instead of 1.0's (``FastSLAMParams.proposal``).

This is an accuracy benchmark, not a speed one: the runs (robots × seeds) go through
:func:`fastslam_edu.app.sweep.run_sweep` — ``--jobs N`` processes (joblib, default all cores; 1: serially) or
``--scheduler ADDRESS``, a dask.distributed cluster — so the filter times it records are not comparable with
``fastslam_mrclam.py``'s; every other number is the same whichever runs them (each run takes its seed from its job).

Usage: python benchmarks/fastslam_accuracy.py [--seeds 10] [--particles 100] [--proposal motion|fastslam2]
       [--odometry-scale KV KW] [--jobs N | --scheduler ADDRESS] [--out FILE]
(data from $FASTSLAM_EDU_DATA, default ./data; about 30 s on 2 cores for 10 seeds)
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from functools import lru_cache
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402

from fastslam_edu.datasets import mrclam_path  # noqa: E402
from fastslam_edu.datasets.events import event_stream  # noqa: E402
from fastslam_edu.app.experiment import load_mrclam, summarize  # noqa: E402
from fastslam_edu.app.sweep import SweepError, add_sweep_options, run_sweep  # noqa: E402
from fastslam_edu.landmark.fastslam import PROPOSALS, FastSLAMParams, run_fastslam  # noqa: E402
from fastslam_edu.landmark.initial_pose import initial_pose_from_landmarks  # noqa: E402

ROBOTS = [(1, 2), (6, 1), (6, 2), (6, 3), (6, 4), (6, 5)]  # the targets
EXTRA = [(1, 1)]  # also has groundtruth (1 Hz), not named by the targets: a check of generalisation
NO_GROUNDTRUTH = [(1, 3), (1, 4), (1, 5)]  # maps only, from an initial pose found from the landmarks
TARGETS = {"path_rmse_m": 0.5, "landmark_error_mean_m": 0.5, "landmark_error_aligned_mean_m": 0.25}


@lru_cache(maxsize=None)
def _load(dataset: int, robot: int):
    data, log, _ = load_mrclam(mrclam_path(dataset), robot)
    x0 = None
    if log.groundtruth is None:
        x0 = initial_pose_from_landmarks(log, data.landmark_positions, data.landmark_subjects).x0
    return data, log, event_stream(log, data.landmark_subjects, rate="full", x0=x0)


def _run(dataset: int, robot: int, seed: int, params: FastSLAMParams) -> dict:
    """One job of the sweep: FastSLAM on one robot with one seed, scored against the targets."""
    data, log, stream = _load(dataset, robot)
    result = run_fastslam(stream, params, np.random.default_rng(seed))
    summary = summarize(result, data, log)
    return {"dataset": dataset, "robot": robot, "seed": seed, **{k: summary[k] for k in TARGETS},
            "measurements_rejected": summary["measurements_rejected"]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--particles", type=int, default=100)
    ap.add_argument("--proposal", choices=PROPOSALS, default="motion")
    ap.add_argument("--odometry-scale", type=float, nargs=2, metavar=("KV", "KW"), default=(1.0, 1.0),
                    help="FastSLAMParams.odometry_scale: the commands are multiplied by (k_v, k_omega)")
    add_sweep_options(ap)
    ap.add_argument("--out", type=Path, help="default: results/fastslam_accuracy[_fastslam2].json")
    args = ap.parse_args(argv)
    if args.out is None:
        suffix = "" if args.proposal == "motion" else f"_{args.proposal}"
        args.out = Path(__file__).parent / "results" / f"fastslam_accuracy{suffix}.json"
    params = FastSLAMParams(n_particles=args.particles, proposal=args.proposal, odometry_scale=tuple(args.odometry_scale))
    robots = ROBOTS + EXTRA + NO_GROUNDTRUTH
    jobs = [(d, r, s, params) for d, r in robots for s in range(args.seeds)]
    try:
        runs = run_sweep(_run, jobs, n_jobs=args.jobs, scheduler=args.scheduler)
    except SweepError as error:
        sys.exit(f"{ap.prog}: error: {error}")
    table = []
    for d, r in robots:
        mine = [x for x in runs if (x["dataset"], x["robot"]) == (d, r)]
        row = {"robot": f"D{d}R{r}", "named_by_targets": (d, r) in ROBOTS}
        row["initial_pose"] = "landmarks" if (d, r) in NO_GROUNDTRUTH else "groundtruth"
        for key, target in TARGETS.items():
            values = [x[key] for x in mine]
            if None in values:  # no groundtruth path to score
                row[f"{key}_median"] = row[f"{key}_worst"] = row[f"{key}_meets"] = None
                continue
            row[f"{key}_median"] = statistics.median(values)
            row[f"{key}_worst"] = max(values)
            row[f"{key}_meets"] = statistics.median(values) <= target
        row["rejected_median"] = statistics.median(x["measurements_rejected"] for x in mine)
        table.append(row)

    name = "FastSLAM 1.0" if args.proposal == "motion" else "FastSLAM 2.0 proposal"
    scale = "" if tuple(args.odometry_scale) == (1.0, 1.0) else f", odometry scale {tuple(args.odometry_scale)}"
    print(f"{name}, full rate, M = {args.particles}{scale}, seeds 0-{args.seeds - 1}: median (worst) [m]")
    print(f"{'robot':<6} {'path RMSE ≤ 0.5':>18} {'landmarks ≤ 0.5':>18} {'aligned ≤ 0.25':>18} {'rejected':>9}")
    for row in table:
        cells = []
        for key in TARGETS:
            if row[f"{key}_median"] is None:
                cells.append("n/a")
                continue
            mark = " " if row[f"{key}_meets"] else "*"
            cells.append(f"{row[f'{key}_median']:.2f}{mark}({row[f'{key}_worst']:.2f})")
        print(f"{row['robot']:<6} {cells[0]:>18} {cells[1]:>18} {cells[2]:>18} {row['rejected_median']:>9.0f}")
    print("* median above the target; " + ", ".join(f"D{d}R{r}" for d, r in EXTRA + NO_GROUNDTRUTH)
          + ": not named by the targets; " + ", ".join(f"D{d}R{r}" for d, r in NO_GROUNDTRUTH)
          + ": no groundtruth, started from the landmarks (their absolute errors include the start's error)")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"machine": machine_info(), "params": params.to_dict(), "seeds": args.seeds, "targets": TARGETS, "table": table, "runs": runs},
        indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    # run as the module fastslam_accuracy, not as __main__: a sweep's worker process then finds _run and its cached
    # _load by name (cloudpickle would send _run by value but cannot send the lru_cache of __main__'s _load)
    import fastslam_accuracy

    sys.exit(fastslam_accuracy.main())
