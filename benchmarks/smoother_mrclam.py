"""How far FastSLAM 1.0 is from the best its own model allows: the batch least-squares smoother on MR.CLAM.

For every robot of ``fastslam_accuracy.py`` (Dataset 1 robot 2 and Dataset 6's five robots, which
the engine's targets name; Dataset 1 robot 1; Dataset 1's robots 3–5 without groundtruth, scored by
their maps), at full rate with the default ``FastSLAMParams``:

* the filter, M = 100, seeds 0 … N-1: the median path RMSE, landmark error and aligned landmark error;
* :func:`fastslam_edu.landmark.smoother.smooth` with the same model, started from the filter's run with seed 0:
  the same three figures, the landmarks' standard deviation from the Laplace approximation (how well
  the data fix them in the absolute frame), iterations, seconds; and started from dead reckoning, to
  show where that start is enough (least squares finds the optimum nearest its start);
* the smoother with the odometry calibration :math:`(k_v, k_\\omega, \\tau)` estimated with the path and map
  (``SolverSettings(calibrate_odometry=True)``, from the same start): the three figures and the estimate.

The smoother uses every sighting at once; the filter must decide online and keeps M = 100 samples of
the path. The gap between the two is what FastSLAM 1.0 loses, not what the data lack.

Usage: python benchmarks/smoother_mrclam.py [--seeds 5] [--jobs 2] [--out FILE]
(data from $FASTSLAM_EDU_DATA, default ./data; about 10 min on 2 cores, most of it the starts from dead reckoning)
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fastslam_accuracy import EXTRA, NO_GROUNDTRUTH, ROBOTS, TARGETS, _load, _run  # noqa: E402
from machine import machine_info  # noqa: E402

from fastslam_edu.app.experiment import summarize_smoother  # noqa: E402
from fastslam_edu.landmark.fastslam import FastSLAMParams, run_fastslam  # noqa: E402
from fastslam_edu.landmark.smoother import SolverSettings, smooth  # noqa: E402

KEYS = list(TARGETS)


def _smoother(job) -> dict:
    dataset, robot = job
    data, log, stream = _load(dataset, robot)
    params = FastSLAMParams()
    out = {"dataset": dataset, "robot": robot}
    filt = run_fastslam(stream, params, np.random.default_rng(0))
    for start in ("filter_seed0", "dead_reckoning", "calibrated"):
        solver = SolverSettings(calibrate_odometry=start == "calibrated")
        result = smooth(stream, params, initial=None if start == "dead_reckoning" else filt, solver=solver)
        s = summarize_smoother(result, data, log)
        out[start] = {k: s[k] for k in KEYS + ["landmark_std_mean_m", "iterations", "smoother_seconds",
                                               "measurements_rejected", "keyframes"]}
        if result.odometry_calibration is not None:
            out[start]["odometry_calibration"] = [round(float(x), 4) for x in result.odometry_calibration]
            out[start]["odometry_calibration_std"] = [round(float(x), 4) for x in result.odometry_calibration_std]
    return out


def _fmt(value, digits=2):
    return "n/a" if value is None else f"{value:.{digits}f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "smoother_mrclam.json")
    args = ap.parse_args(argv)
    robots = ROBOTS + EXTRA + NO_GROUNDTRUTH
    with ProcessPoolExecutor(args.jobs) as pool:
        filters = list(pool.map(_run, [(d, r, s, FastSLAMParams()) for d, r in robots for s in range(args.seeds)]))
        smoothers = list(pool.map(_smoother, robots))
    table = []
    for (d, r), sm in zip(robots, smoothers):
        runs = [x for x in filters if (x["dataset"], x["robot"]) == (d, r)]
        row = {"robot": f"D{d}R{r}", "named_by_targets": (d, r) in ROBOTS}
        for k in KEYS:
            values = [x[k] for x in runs]
            row[f"filter_{k}_median"] = None if None in values else statistics.median(values)
        row["smoother"] = sm["filter_seed0"]
        row["smoother_from_dead_reckoning"] = sm["dead_reckoning"]
        row["smoother_calibrated"] = sm["calibrated"]
        table.append(row)

    print(f"Full rate, default FastSLAMParams. Filter: M = 100, median of seeds 0-{args.seeds - 1}. "
          "Smoother: least squares over the whole log, from the filter's seed-0 run [m]")
    head = f"{'robot':<6} {'path RMSE':>13} {'landmarks':>13} {'aligned':>13} {'lm std':>7} {'iter':>5} {'s':>6}"
    print(head)
    print(f"{'':<6} {'filter  smth':>13} {'filter  smth':>13} {'filter  smth':>13}")
    for row in table:
        sm = row["smoother"]
        cells = [f"{_fmt(row[f'filter_{k}_median']):>6} {_fmt(sm[k]):>6}" for k in KEYS]
        print(f"{row['robot']:<6} {cells[0]:>13} {cells[1]:>13} {cells[2]:>13} {_fmt(sm['landmark_std_mean_m']):>7} "
              f"{sm['iterations']:>5} {sm['smoother_seconds']:>6.1f}")
    print("started from dead reckoning instead (difference in the three figures, rejected sightings):")
    for row in table:
        dr, sm = row["smoother_from_dead_reckoning"], row["smoother"]
        diff = max(abs(dr[k] - sm[k]) for k in KEYS if sm[k] is not None)
        print(f"  {row['robot']}: {diff:.3f} m, {dr['measurements_rejected']} against {sm['measurements_rejected']} "
              f"rejected, {dr['smoother_seconds']:.1f} s")
    print("with the odometry calibration (k_v, k_w, tau) estimated (SolverSettings(calibrate_odometry=True)):")
    print(f"{'robot':<6} {'path':>6} {'lm':>6} {'aligned':>7} {'lm std':>7} {'rej':>5} {'k_v':>6} {'k_w':>6} {'tau s':>6}")
    for row in table:
        c = row["smoother_calibrated"]
        kv, kw, tau = c["odometry_calibration"]
        print(f"{row['robot']:<6} {_fmt(c['path_rmse_m']):>6} {_fmt(c['landmark_error_mean_m']):>6} "
              f"{_fmt(c['landmark_error_aligned_mean_m']):>7} {_fmt(c['landmark_std_mean_m']):>7} "
              f"{c['measurements_rejected']:>5} {kv:>6.3f} {kw:>6.3f} {tau:>6.3f}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"machine": machine_info(), "params": FastSLAMParams().to_dict(),
                                    "seeds": args.seeds, "table": table, "filter_runs": filters}, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
