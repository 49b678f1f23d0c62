"""FastSLAM with unknown correspondences on MR.CLAM, against the association targets and two bounds.

Every robot with groundtruth — Dataset 1 robot 2 and the five robots of Dataset 6 (named by the targets), and
Dataset 1 robot 1 (not tuned on) — at full rate with the default ``AssociationParams``, over seeds 0 … N-1. For
each robot the table gives, as medians over the seeds:

* **oracle**: maximum-likelihood association at the groundtruth pose against the surveyed map, with the
  filter's :math:`R` (:func:`fastslam_edu.evaluation.association.association_accuracy_oracle`);
* **ceiling**: the same at the filter's own mean path against its own final map, both from FastSLAM run *with*
  known correspondences (:func:`fastslam_edu.evaluation.association.association_accuracy_ceiling`): what an
  association decided in the filter's frame reaches even when told the final map in advance;
* **online**: the filter's own association rule, decided by every particle of that same run at each instant
  against the map it has built so far, weighted by the particles' weights
  (:class:`fastslam_edu.evaluation.association.OnlineCeiling`): what a particle without barcodes gets right while
  it has made no wrong association (its ratio to the oracle bounds what the target can ask of this rule);
* **unknown**: the accuracy of FastSLAM without barcodes
  (:func:`fastslam_edu.app.experiment.run_mrclam_unknown`), its ratio to the oracle (target ≥ 0.60 on every
  robot, and ≥ 0.75 as the mean over the robots, the last line), the spurious landmarks (target ≤ 2) and the
  aligned landmark error (target ≤ 0.30 m), and the share of landmark sightings given to identities the final map
  no longer holds (``lost``,
  :func:`fastslam_edu.evaluation.association.association_breakdown`);
* **× barcodes**: its filter seconds over those of FastSLAM *with* barcodes on the same robot and seed, run in the
  same job without any hook (:func:`fastslam_edu.app.experiment.run_mrclam`), the median of the per-run ratios
  (target ≤ 3; both times without numba's compilation).

The last line is the figure a change to the defaults is judged by: the mean over the seven robots of the median
ratio to the oracle (target ≥ 0.75), with a 95 % bootstrap interval over the seeds
(:func:`fastslam_edu.evaluation.metrics.mean_of_medians`; the seeds of each robot
drawn again with replacement, 2,000 times). The filter's accuracy on one robot ranges from a few hundredths to 0.9
over seeds, so a difference inside that interval is no difference.

Prints a table and writes JSON (``results/association_mrclam.json``).

``--greedy``: the same with ``AssociationParams(association="greedy")``, the greedy pairing instead of the default
joint compatibility (the filter and the online ceiling; the joint rule takes 1.0–1.5 times its filter time). Over
seeds 0–39, the default's mean of medians was 0.51 against the greedy pairing's 0.48, a difference whose 95 %
bootstrap interval (each rule's seeds drawn again) stays above zero; at 20 seeds it did not.

The runs (robots × seeds) go through :func:`fastslam_edu.app.sweep.run_sweep`: ``--jobs N`` processes on this
machine (joblib, default all cores; ``--jobs 1`` serially), or ``--scheduler tcp://HOST:8786`` on a dask.distributed
cluster (README, "Sweeps on a cluster"); every run takes its seed from its job, so the numbers are the same whichever
runs them (only the times differ: ``filter_seconds`` and the JSON's ``sweep.wall_seconds``).

``--smoother``: also the associations re-decided by the smoother
(:func:`fastslam_edu.landmark.smoother_association.smooth_association`, from each run of the filter, scored by
:func:`fastslam_edu.app.experiment.summarize_smoother_association`), in a second table: its accuracy, the oracle and
the ratio (target >= 0.95), spurious landmarks (target <= 1), the aligned landmark error (target <= 0.15 m) and its
seconds (target <= 30 s per robot on the 2-core machine); the JSON gains ``smoother`` (its runs and table).
``--smoother-runs K``: the smoother starts from K filter runs (seeds s, s + 1000, ..., s + 1000 (K-1) for seed s),
whose starts compete by their final penalised cost; its seconds include the K-1 extra filter runs.
``--smoother-bounds``: also two references computed from the true correspondences
(:mod:`fastslam_edu.evaluation.smoother_bounds`): the smoother's cost over theirs, :math:`J / J^*` (above 1: the
cost prefers the truth and the search stopped short of it), the path solved with them, and the association a fresh
assignment reaches at that path (the path-given bound: near the oracle, the path is what the smoother misses).
``--transient-objects``: the smoother with ``SmootherAssociationParams(transient_objects=True)`` (the final map
without the landmarks more likely transient than static: other robots that stood still, then left).

``--deferred``, ``--split``: the filter with ``AssociationParams(deferred=True)`` (deferred commitment) and
``split_tentative=True`` (a provisional landmark seen twice in one frame splits). ``--gap-window K``:
``gap_window_sightings=K`` (re-association after a gap: the first K sightings after a stretch without any decided
together per particle, :mod:`fastslam_edu.landmark.gap_window`).

Usage: python benchmarks/association_mrclam.py [--seeds 3] [--jobs N | --scheduler ADDRESS] [--greedy] [--deferred]
[--split] [--gap-window K] [--smoother [--smoother-runs K] [--smoother-bounds] [--transient-objects]]
[--out FILE]
(data from $FASTSLAM_EDU_DATA, default ./data; about 30 s on 2 cores for 3 seeds)
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
from machine import machine_info, machine_line  # noqa: E402

from fastslam_edu.app.experiment import (anonymous_stream, association_ceiling, run_mrclam,  # noqa: E402
                                         run_mrclam_unknown, summarize_smoother_association)
from fastslam_edu.app.sweep import SweepError, add_sweep_options, run_sweep  # noqa: E402
from fastslam_edu.datasets import mrclam_path  # noqa: E402
from fastslam_edu.evaluation.association import OnlineCeiling  # noqa: E402
from fastslam_edu.evaluation.smoother_bounds import smoother_bounds  # noqa: E402
from fastslam_edu.evaluation.metrics import mean_of_medians  # noqa: E402
from fastslam_edu.landmark.association import AssociationParams, run_unknown  # noqa: E402
from fastslam_edu.landmark.fastslam import FastSLAMParams, run_fastslam  # noqa: E402
from fastslam_edu.landmark.smoother_association import SmootherAssociationParams, smooth_association  # noqa: E402

ROBOTS = [(1, 2), (6, 1), (6, 2), (6, 3), (6, 4), (6, 5)]  # named by the targets
EXTRA = [(1, 1)]  # has groundtruth, never tuned on
TARGETS = {"ratio_to_oracle": 0.60, "landmarks_spurious": 2, "landmark_error_aligned_mean_m": 0.30,
           "time_to_barcodes": 3.0}  # per robot, the medians over the seeds
MEAN_RATIO_TARGET = 0.75  # the mean over the robots of the median ratio to the oracle
BOUND_KEYS = ("cost_true", "cost_to_true", "truth_path_rmse_aligned_m", "path_given_ratio", "path_given_spurious")
SMOOTHER_TARGETS = {"ratio_to_oracle": 0.95, "landmarks_spurious": 1, "landmark_error_aligned_mean_m": 0.15,
                    "seconds": 30.0}


def bounds(dataset: int, robot: int, seed: int, params: AssociationParams) -> tuple[float, float, float, float]:
    """The association ceiling and the online ceiling (of ``params``' rule) of FastSLAM run with known
    correspondences (module docstring), from one run, and that run's filter seconds (with the probe's hook); then
    the filter seconds of the same run without the hook (the time target's yardstick), on the stream already read."""
    path = mrclam_path(dataset)
    probe = OnlineCeiling(params)
    known, _, context = run_mrclam(path, robot, seed=seed, hooks=(probe,))
    plain = run_fastslam(context["stream"], FastSLAMParams(), np.random.default_rng(seed),
                         landmarks=context["dataset"].landmark_positions)  # as run_mrclam runs it, no hook
    stream, true_index = anonymous_stream(path, robot, context["dataset"], context["log"], x0=context["stream"].x0)
    return (association_ceiling(known, stream, true_index, params.filter), probe.accuracy, known.filter_seconds,
            plain.filter_seconds)


def _run(dataset: int, robot: int, seed: int, params: AssociationParams) -> dict:
    """One job of the sweep: FastSLAM without barcodes on one robot with one seed, and its bounds."""
    _, summary, _ = run_mrclam_unknown(mrclam_path(dataset), robot, params, seed=seed)
    oracle = summary["association_accuracy_oracle"]
    ceiling, online, known_seconds, barcodes_seconds = bounds(dataset, robot, seed, params)
    return {"dataset": dataset, "robot": robot, "seed": seed, "oracle": oracle,
            "ceiling": ceiling, "online": online, "accuracy": summary["association_accuracy"],
            "ratio_to_oracle": summary["association_accuracy"] / oracle,
            "landmarks_spurious": summary["landmarks_spurious"], "landmarks_in_map": summary["landmarks_in_map"],
            "not_in_map": summary["association_breakdown"]["not_in_map"],
            "landmark_error_aligned_mean_m": summary["landmark_error_aligned_mean_m"],
            "path_rmse_aligned_m": summary["path_rmse_aligned_m"], "filter_seconds": summary["filter_seconds"],
            "known_seconds": known_seconds, "barcodes_seconds": barcodes_seconds,
            "time_to_barcodes": summary["filter_seconds"] / barcodes_seconds}


def _run_smoother(dataset: int, robot: int, seed: int, params: AssociationParams, runs: int = 1,
                  with_bounds: bool = False, settings: SmootherAssociationParams = SmootherAssociationParams()) -> dict:
    """One job of the ``--smoother`` sweep: FastSLAM without barcodes (``runs`` runs, seeds ``seed + 1000 k``), then
    the smoother's association from them (``settings``); ``with_bounds``: and the two references of
    :func:`fastslam_edu.evaluation.smoother_bounds.smoother_bounds` from the first run (not in ``seconds``)."""
    result, summary, context = run_mrclam_unknown(mrclam_path(dataset), robot, params, seed=seed)
    started = time.perf_counter()
    results = [result] + [run_unknown(context["stream"], params, np.random.default_rng(seed + 1000 * k))
                          for k in range(1, runs)]
    smoothed = smooth_association(context["stream"], results, settings=settings)
    part = summarize_smoother_association(smoothed, context["stream"], context["true_index"], context["dataset"],
                                          context["log"])
    oracle = summary["association_accuracy_oracle"]
    row = {"dataset": dataset, "robot": robot, "seed": seed, "oracle": oracle,
           "filter_accuracy": summary["association_accuracy"], "accuracy": part["association_accuracy"],
           "ratio_to_oracle": part["association_accuracy"] / oracle, "landmarks_spurious": part["landmarks_spurious"],
           "landmarks_in_map": part["landmarks_in_map"],
           "landmark_error_aligned_mean_m": part["landmark_error_aligned_mean_m"],
           "path_rmse_aligned_m": part["path_rmse_aligned_m"], "seconds": time.perf_counter() - started,
           "cost": smoothed.cost}
    if with_bounds:
        truth, given = smoother_bounds(context["stream"], context["true_index"], result, settings)
        scored = {name: summarize_smoother_association(r, context["stream"], context["true_index"],
                                                       context["dataset"], context["log"])
                  for name, r in (("truth", truth), ("given", given))}
        row.update(cost_true=truth.cost, cost_to_true=smoothed.cost / truth.cost,
                   truth_path_rmse_aligned_m=scored["truth"]["path_rmse_aligned_m"],
                   path_given_ratio=scored["given"]["association_accuracy"] / oracle,
                   path_given_spurious=scored["given"]["landmarks_spurious"])
    return row


def smoother_table(runs: list[dict], robots) -> list[dict]:
    """Per robot: the medians over the seeds of the ``--smoother`` runs, the range of the ratio, the targets met."""
    keys = ("oracle", "filter_accuracy", "accuracy", "ratio_to_oracle", "landmarks_spurious", "landmarks_in_map",
            "landmark_error_aligned_mean_m", "path_rmse_aligned_m", "seconds", "cost")
    keys += BOUND_KEYS if all("cost_true" in x for x in runs) else ()
    table = []
    for d, r in robots:
        mine = [x for x in runs if (x["dataset"], x["robot"]) == (d, r)]
        row = {"robot": f"D{d}R{r}", "named_by_targets": (d, r) in ROBOTS}
        row.update({k: statistics.median(x[k] for x in mine) for k in keys})
        row["ratio_range"] = [min(x["ratio_to_oracle"] for x in mine), max(x["ratio_to_oracle"] for x in mine)]
        row["meets"] = {k: (row[k] >= v if k == "ratio_to_oracle" else row[k] <= v)
                        for k, v in SMOOTHER_TARGETS.items()}
        table.append(row)
    return table


def print_smoother_table(table: list[dict], seeds: int) -> None:
    """The ``--smoother`` table: one line per robot, ``*`` where a target is missed."""
    print(f"Smoother association (smooth_association from the filter's runs), seeds 0-{seeds - 1}: medians")
    print(f"{'robot':<6} {'oracle':>7} {'filter':>7} {'smoother':>9} {'/oracle':>8} {'(range)':>13} {'spurious':>9} "
          f"{'aligned [m]':>12} {'path [m]':>9} {'seconds':>8}")
    for row in table:
        mark = {k: " " if row["meets"][k] else "*" for k in SMOOTHER_TARGETS}
        lo, hi = row["ratio_range"]
        print(f"{row['robot']:<6} {row['oracle']:>7.3f} {row['filter_accuracy']:>7.3f} {row['accuracy']:>9.3f} "
              f"{row['ratio_to_oracle']:>7.2f}{mark['ratio_to_oracle']} {f'({lo:.2f}-{hi:.2f})':>13} "
              f"{row['landmarks_spurious']:>8.1f}{mark['landmarks_spurious']} "
              f"{row['landmark_error_aligned_mean_m']:>11.3f}{mark['landmark_error_aligned_mean_m']} "
              f"{row['path_rmse_aligned_m']:>9.3f} {row['seconds']:>7.1f}{mark['seconds']}")
    t = SMOOTHER_TARGETS
    print(f"* misses the smoother's target (ratio to the oracle >= {t['ratio_to_oracle']}, spurious <= "
          f"{t['landmarks_spurious']}, aligned landmark error <= {t['landmark_error_aligned_mean_m']} m, <= "
          f"{t['seconds']:g} s per robot)")
    if table and "cost_true" in table[0]:
        print("References from the true correspondences (evaluation.smoother_bounds), medians: J/J* the smoother's "
              "penalised cost over the true correspondences'; path: the path solved with them, aligned RMSE; "
              "given path: a fresh assignment and alternation at that path, its ratio to the oracle and spurious")
        print(f"{'robot':<6} {'J/J*':>6} {'path [m]':>9} {'given path':>11} {'spurious':>9}")
        for row in table:
            print(f"{row['robot']:<6} {row['cost_to_true']:>6.2f} {row['truth_path_rmse_aligned_m']:>9.3f} "
                  f"{row['path_given_ratio']:>11.2f} {row['path_given_spurious']:>9.1f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    add_sweep_options(ap)
    ap.add_argument("--greedy", action="store_true",
                    help="decide each instant by the greedy pairing (AssociationParams(association='greedy')), "
                         "filter and online ceiling")
    ap.add_argument("--deferred", action="store_true",
                    help="deferred commitment (AssociationParams(deferred=True): far sightings never commit a "
                         "landmark's position)")
    ap.add_argument("--split", action="store_true",
                    help="a provisional landmark two sightings of one frame fit splits (split_tentative=True)")
    ap.add_argument("--gap-window", type=int, default=0, metavar="K",
                    help="re-association after a gap: the first K sightings decided together "
                         "(AssociationParams(gap_window_sightings=K); default 0: off)")
    ap.add_argument("--smoother", action="store_true",
                    help="also the smoother's association from each filter run (second table, JSON 'smoother')")
    ap.add_argument("--smoother-runs", type=int, default=1, metavar="K",
                    help="with --smoother: start the smoother from K filter runs (default 1)")
    ap.add_argument("--smoother-bounds", action="store_true",
                    help="with --smoother: also the references from the true correspondences (J*, the path-given "
                         "bound; evaluation.smoother_bounds), about 1.5 x the smoother's time more")
    ap.add_argument("--transient-objects", action="store_true",
                    help="with --smoother: SmootherAssociationParams(transient_objects=True), the final map without "
                         "the landmarks more likely transient than static")
    ap.add_argument("--out", type=Path, default=None,
                    help="JSON file (default results/association_mrclam.json; association_mrclam_greedy.json, "
                         "..._deferred, ..._split, ..._gapK, ..._transient, ..._runsK with those options)")
    args = ap.parse_args(argv)
    if args.smoother_runs < 1:
        ap.error(f"--smoother-runs must be >= 1, got {args.smoother_runs}")
    if args.gap_window < 0:
        ap.error(f"--gap-window must be >= 0, got {args.gap_window}")
    robots = ROBOTS + EXTRA
    params = AssociationParams(association="greedy" if args.greedy else "joint", deferred=args.deferred,
                               split_tentative=args.split, gap_window_sightings=args.gap_window)
    name = ("association_mrclam" + "_greedy" * args.greedy + "_deferred" * args.deferred + "_split" * args.split
            + f"_gap{args.gap_window}" * (args.gap_window > 0) + "_transient" * args.transient_objects
            + f"_runs{args.smoother_runs}" * (args.smoother and args.smoother_runs > 1) + ".json")
    args.out = args.out or Path(__file__).parent / "results" / name
    start = time.perf_counter()
    try:
        runs = run_sweep(_run, [(d, r, s, params) for d, r in robots for s in range(args.seeds)],
                         n_jobs=args.jobs, scheduler=args.scheduler)
    except SweepError as error:
        sys.exit(f"{ap.prog}: error: {error}")
    sweep = {"jobs": args.jobs, "scheduler": args.scheduler, "wall_seconds": time.perf_counter() - start}
    keys = ("oracle", "ceiling", "online", "accuracy", "ratio_to_oracle", "not_in_map", "landmarks_spurious",
            "landmarks_in_map", "landmark_error_aligned_mean_m", "path_rmse_aligned_m", "filter_seconds",
            "known_seconds", "barcodes_seconds", "time_to_barcodes")
    table = []
    for d, r in robots:
        mine = [x for x in runs if (x["dataset"], x["robot"]) == (d, r)]
        row = {"robot": f"D{d}R{r}", "named_by_targets": (d, r) in ROBOTS}
        row.update({k: statistics.median(x[k] for x in mine) for k in keys})
        row["ceiling_to_oracle"] = row["ceiling"] / row["oracle"]
        row["online_to_oracle"] = row["online"] / row["oracle"]
        row["ratio_range"] = [min(x["ratio_to_oracle"] for x in mine), max(x["ratio_to_oracle"] for x in mine)]
        row["meets"] = {k: (row[k] >= v if k == "ratio_to_oracle" else row[k] <= v) for k, v in TARGETS.items()}
        table.append(row)
    info = machine_info()
    print(machine_line(info))
    rule = "greedy pairing" if args.greedy else "defaults (joint compatibility)"
    print(f"FastSLAM 1.0, unknown correspondences, full rate, {rule}, seeds 0-{args.seeds - 1}: medians")
    print(f"{'robot':<6} {'oracle':>7} {'ceiling':>13} {'online':>13} {'unknown':>8} {'/oracle':>8} {'(range)':>13} "
          f"{'lost':>5} {'spurious':>9} {'aligned [m]':>12} {'seconds':>8} {'known':>6} {'x barcodes':>11}")
    for row in table:
        mark = {k: " " if row["meets"][k] else "*" for k in TARGETS}
        lo, hi = row["ratio_range"]
        print(f"{row['robot']:<6} {row['oracle']:>7.3f} {row['ceiling']:>6.3f} ({row['ceiling_to_oracle']:.2f}) "
              f"{row['online']:>6.3f} ({row['online_to_oracle']:.2f}) "
              f"{row['accuracy']:>8.3f} {row['ratio_to_oracle']:>7.2f}{mark['ratio_to_oracle']} "
              f"{f'({lo:.2f}-{hi:.2f})':>13} {row['not_in_map']:>5.2f} "
              f"{row['landmarks_spurious']:>8.1f}{mark['landmarks_spurious']} "
              f"{row['landmark_error_aligned_mean_m']:>11.2f}{mark['landmark_error_aligned_mean_m']} "
              f"{row['filter_seconds']:>8.1f} {row['known_seconds']:>6.1f} "
              f"{row['time_to_barcodes']:>10.1f}{mark['time_to_barcodes']}")
    print(f"* misses the target (ratio to the oracle >= {TARGETS['ratio_to_oracle']}, spurious <= "
          f"{TARGETS['landmarks_spurious']}, aligned landmark error <= {TARGETS['landmark_error_aligned_mean_m']} m, "
          f"x barcodes <= {TARGETS['time_to_barcodes']:g}); "
          "ceiling: own path and own map with known correspondences; online: the filter's rule decided by the "
          "particles of that run before each update (both with their ratio to the oracle in brackets); "
          "lost: landmark sightings given to identities the final map no longer holds; seconds, known: filter "
          "seconds without and with barcodes (the latter with the online probe's hook); x barcodes: the filter "
          "seconds over those of the run with barcodes and no hook, same seed (median of the ratios); "
          + ", ".join(f"D{d}R{r}" for d, r in EXTRA) + ": not tuned on")
    per_robot = [[x["ratio_to_oracle"] for x in runs if (x["dataset"], x["robot"]) == (d, r)] for d, r in robots]
    mean, low, high = mean_of_medians(per_robot)
    meets_mean = mean >= MEAN_RATIO_TARGET
    print(f"mean over the {len(robots)} robots of the median ratio to the oracle: {mean:.3f}"
          f"{' ' if meets_mean else '*'} (target >= {MEAN_RATIO_TARGET}; 95 % bootstrap interval over the seeds "
          f"{low:.3f}-{high:.3f})")
    where = f"dask scheduler {args.scheduler}" if args.scheduler else f"{args.jobs or 'all'} local process(es), joblib"
    print(f"sweep: {len(runs)} runs in {sweep['wall_seconds']:.1f} s wall time on {where}")
    out = {"machine": info, "sweep": sweep, "params": params.to_dict(), "seeds": args.seeds,
           "targets": {**TARGETS, "mean_ratio_to_oracle": MEAN_RATIO_TARGET}, "table": table, "runs": runs,
           "mean_ratio_to_oracle": {"mean": mean, "low": low, "high": high, "meets": meets_mean}}
    if args.smoother:
        try:
            settings = SmootherAssociationParams(transient_objects=args.transient_objects)
            smoothed = run_sweep(_run_smoother, [(d, r, s, params, args.smoother_runs, args.smoother_bounds, settings)
                                                 for d, r in robots for s in range(args.seeds)],
                                 n_jobs=args.jobs, scheduler=args.scheduler)
        except SweepError as error:
            sys.exit(f"{ap.prog}: error: {error}")
        out["smoother"] = {"targets": SMOOTHER_TARGETS, "table": smoother_table(smoothed, robots), "runs": smoothed}
        print_smoother_table(out["smoother"]["table"], args.seeds)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
