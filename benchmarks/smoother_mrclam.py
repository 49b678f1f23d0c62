"""How far FastSLAM 1.0 is from the best its own model allows: the batch least-squares smoother on MR.CLAM.

For every robot of ``fastslam_accuracy.py`` (Dataset 1 robot 2 and Dataset 6's five robots, which
the engine's targets name; Dataset 1 robot 1; Dataset 1's robots 3–5 without groundtruth, scored by
their maps), at full rate with the default ``FastSLAMParams``:

* the filter, M = 100, seeds 0 … N-1: the median path RMSE, landmark error and aligned landmark error;
* :func:`fastslam_edu.landmark.smoother.smooth` with the same model, started from the filter's run with seed 0:
  the same three figures, the landmarks' standard deviation from the Laplace approximation (how well
  the data fix them in the absolute frame), iterations, seconds; and started from dead reckoning, to
  show where that start is enough (least squares finds the optimum nearest its start);
* the book's best estimate (``BEST_ESTIMATE``: every sighting counted in full), started from each of the
  filter's N runs: the median of the figures and their spread over the starts;
* variants, from the filter's seed-0 run, each estimating parameters of the model with the path and map
  (``SolverSettings.calibrate``): the odometry's scale and lag :math:`(k_v, k_\\omega, \\tau)` under the default
  (tempered) settings and under ``BEST_ESTIMATE``, and a bearing bias or a travel offset under ``BEST_ESTIMATE``.

For every solution also the rotation [°] of the rigid motion that best maps its landmarks onto the surveyed ones
(:func:`fastslam_edu.evaluation.metrics.align_se2`): what is left of the absolute error once the map's shape is right.

The smoother uses every sighting at once; the filter must decide online and keeps M = 100 samples of
the path. The gap between the two is what FastSLAM 1.0 loses, not what the data lack.

The filter runs (robots × seeds) and the smoothers (one job per robot) go through
:func:`fastslam_edu.app.sweep.run_sweep`: ``--jobs N`` processes (joblib, default all cores; 1: serially) or
``--scheduler ADDRESS``, a dask.distributed cluster whose workers have ``benchmarks/`` on their ``PYTHONPATH``
(README, "Sweeps on a cluster"); the numbers are the same whichever runs them, the times are not.

Usage: python benchmarks/smoother_mrclam.py [--seeds 5] [--jobs N | --scheduler ADDRESS] [--out FILE]
(data from $FASTSLAM_EDU_DATA, default ./data; about 10 min on one core, most of it the starts from dead reckoning)
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fastslam_accuracy import EXTRA, NO_GROUNDTRUTH, ROBOTS, TARGETS, _load, _run  # noqa: E402
from machine import machine_info  # noqa: E402

from fastslam_edu.app.experiment import summarize_smoother  # noqa: E402
from fastslam_edu.app.sweep import SweepError, add_sweep_options, run_sweep  # noqa: E402
from fastslam_edu.evaluation.metrics import align_se2  # noqa: E402
from fastslam_edu.landmark.fastslam import FastSLAMParams, run_fastslam  # noqa: E402
from fastslam_edu.landmark.smoother import BEST_ESTIMATE, ODOMETRY_CALIBRATION, SolverSettings, smooth  # noqa: E402

KEYS = list(TARGETS)
FIGURES = KEYS + ["path_rmse_aligned_m", "rotation_deg", "landmark_std_mean_m", "iterations", "smoother_seconds",
                  "measurements_rejected", "keyframes"]
#: The variants, from the filter's seed-0 run: name → settings.
VARIANTS = {
    "smoother_calibrated": SolverSettings(calibrate=ODOMETRY_CALIBRATION),
    "best_calibrated": BEST_ESTIMATE.replace(calibrate=ODOMETRY_CALIBRATION),
    "best_bearing_bias": BEST_ESTIMATE.replace(calibrate=("bearing_bias",)),
    "best_travel_offset": BEST_ESTIMATE.replace(calibrate=("travel_offset",)),
}


def _figures(result, data, log) -> dict:
    """The figures of one smoother solution (``FIGURES``), and its calibration when estimated."""
    s = summarize_smoother(result, data, log)
    o = result.observed
    s["rotation_deg"] = float(np.degrees(align_se2(result.landmarks[o], data.landmark_positions[o])[2]))
    out = {k: s.get(k) for k in FIGURES}
    if result.calibration is not None:
        out["calibration"] = {k: round(v, 5) for k, v in result.calibration.items()}
        out["calibration_std"] = {k: round(v, 5) for k, v in result.calibration_std.items()}
    return out


def _smoother(dataset: int, robot: int, seeds: int) -> dict:
    """One job of the sweep: the smoother and its variants on one robot, from the filter's runs with seeds 0 … N-1."""
    data, log, stream = _load(dataset, robot)
    params = FastSLAMParams()
    filters = [run_fastslam(stream, params, np.random.default_rng(seed)) for seed in range(seeds)]
    out = {"dataset": dataset, "robot": robot}
    out["smoother"] = _figures(smooth(stream, params, initial=filters[0]), data, log)
    out["smoother_from_dead_reckoning"] = _figures(smooth(stream, params), data, log)
    out["best_estimate_runs"] = [_figures(smooth(stream, params, initial=f, solver=BEST_ESTIMATE), data, log)
                                 for f in filters]
    for name, solver in VARIANTS.items():
        out[name] = _figures(smooth(stream, params, initial=filters[0], solver=solver), data, log)
    return out


def _median_runs(runs: list[dict]) -> dict:
    """Median over the starts of every figure, and the spread (max − min) of the three target figures."""
    row = {k: None if runs[0][k] is None else statistics.median(r[k] for r in runs) for k in FIGURES}
    row["spread_m"] = {k: None if runs[0][k] is None else max(r[k] for r in runs) - min(r[k] for r in runs) for k in KEYS}
    return row


def _fmt(value, digits=2):
    return "n/a" if value is None else f"{value:.{digits}f}"


def _print(table, args) -> None:
    print(f"Full rate, default FastSLAMParams. Filter: M = 100, median of seeds 0-{args.seeds - 1}. "
          "Smoother: least squares over the whole log, from the filter's seed-0 run [m]")
    print(f"{'robot':<6} {'path RMSE':>13} {'landmarks':>13} {'aligned':>13} {'lm std':>7} {'iter':>5} {'s':>6}")
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
    spread = max(v for r in table for v in r["best_estimate"]["spread_m"].values() if v is not None)
    print(f"path RMSE / landmark error / aligned landmark error [m], rotation of the map [deg]; best estimate: median of "
          f"{args.seeds} starts (largest spread {spread:.3f} m)")
    names = ["smoother", "best_estimate", *VARIANTS]
    print(f"{'robot':<6} " + " ".join(f"{n:>24}" for n in names))
    for row in table:
        cells = [f"{_fmt(row[n]['path_rmse_m'])}/{_fmt(row[n]['landmark_error_mean_m'])}/"
                 f"{_fmt(row[n]['landmark_error_aligned_mean_m'])} {row[n]['rotation_deg']:+5.1f}" for n in names]
        print(f"{row['robot']:<6} " + " ".join(f"{c:>24}" for c in cells))
    print("estimated calibrations (BEST_ESTIMATE variants): k_v k_w tau [s] | bearing bias [deg] | travel offset [deg]")
    for row in table:
        c, b, d = (row[n]["calibration"] for n in ("best_calibrated", "best_bearing_bias", "best_travel_offset"))
        print(f"{row['robot']:<6} {c['k_v']:.3f} {c['k_omega']:.3f} {c['tau']:.3f} | "
              f"{np.degrees(b['bearing_bias']):+.2f} | {np.degrees(d['travel_offset']):+.2f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    add_sweep_options(ap)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "smoother_mrclam.json")
    args = ap.parse_args(argv)
    if args.seeds < 1:
        ap.error(f"--seeds must be >= 1 (got {args.seeds})")
    robots = ROBOTS + EXTRA + NO_GROUNDTRUTH
    sweep = {"n_jobs": args.jobs, "scheduler": args.scheduler}
    try:
        filters = run_sweep(_run, [(d, r, s, FastSLAMParams()) for d, r in robots for s in range(args.seeds)], **sweep)
        smoothers = run_sweep(_smoother, [(d, r, args.seeds) for d, r in robots], **sweep)
    except SweepError as error:
        sys.exit(f"{ap.prog}: error: {error}")
    table = []
    for (d, r), sm in zip(robots, smoothers):
        runs = [x for x in filters if (x["dataset"], x["robot"]) == (d, r)]
        row = {"robot": f"D{d}R{r}", "named_by_targets": (d, r) in ROBOTS}
        for k in KEYS:
            values = [x[k] for x in runs]
            row[f"filter_{k}_median"] = None if None in values else statistics.median(values)
        row["best_estimate"] = _median_runs(sm.pop("best_estimate_runs"))
        row.update({k: v for k, v in sm.items() if k not in ("dataset", "robot")})
        table.append(row)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"machine": machine_info(), "params": FastSLAMParams().to_dict(),
                                    "best_estimate": BEST_ESTIMATE.to_dict(), "seeds": args.seeds, "table": table,
                                    "filter_runs": filters}, indent=2))
    _print(table, args)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
