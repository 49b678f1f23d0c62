"""Grid SLAM: speed (vectorised vs the loop reference, time per scan) and accuracy on the Intel lab (and FR079).

Speed (default):

* **ratio** — :func:`run_grid_slam` and :func:`run_grid_slam_loop` on the same
  work (the first ``--ratio-scans`` scans, M = 30, the filter without scan
  matching, same seed), in one run; the two results are checked to be equal.
* **time per scan** for M = 30 and 100 particles, for the default filter
  (scan matching), without scan matching, and with one map per particle,
  over the first ``--speed-scans`` scans.

Accuracy (``--accuracy``): on all 910 Intel scans, median over seeds 0–4 of
Kümmerle et al.'s relation error (the 97 relations whose both ends are among
the 910 scans, time tolerance 1 ms) and the RMSE to GMapping's poses after
SE(2) alignment, for raw odometry, the write-up's exact rule, the filter
without scan matching, the default filter, the Rao–Blackwellised filter
and GMapping itself; ``--fr079`` adds FR079 (recovered odometry, RMSE to
GMapping only: its relations use a time base we cannot match).

Real data come from ``$FASTSLAM_EDU_DATA`` (intel/, fr079/); without them the
speed part runs on the simulated office (``simulate_laser_world``) and says so.

Usage: python benchmarks/gridslam.py [--accuracy] [--fr079] [--quick] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402

from fastslam_edu.datasets import data_root  # noqa: E402
from fastslam_edu.datasets.laser import read_carmen, read_intel_json, read_relations  # noqa: E402
from fastslam_edu.grid.gridslam import GridSLAMParams, run_grid_slam  # noqa: E402
from grid_loop import run_grid_slam_loop  # noqa: E402
from fastslam_edu.evaluation.relations import reference_errors, score_trajectory  # noqa: E402
from fastslam_edu.datasets.sim_laser import simulate_laser_world  # noqa: E402

VARIANTS = {  # name -> GridSLAMParams changes (M set separately)
    "write-up rule (0/1 map, exp(c), resample always)": ("writeup", {}),
    "graded correlation, no scan matching": ("default", {"match_iterations": 0}),
    "default (graded + scan matching)": ("default", {}),
    "RBPF: map per particle, no scan matching": ("default", {"maps": "particles", "match_iterations": 0}),
}


def params_for(kind: str, changes: dict, m: int) -> GridSLAMParams:
    base = GridSLAMParams.writeup() if kind == "writeup" else GridSLAMParams()
    return base.replace(n_particles=m, **changes)


def intel():
    root = data_root() / "intel"
    if not (root / "intel_gfs.json.gz").is_file():
        return None
    return (read_intel_json(root / "intel_gfs.json.gz"), read_intel_json(root / "intel_corrected_log.json.gz"),
            read_relations(root / "intel.relations"))


def speed(log, source: str, ratio_scans: int, speed_scans: int) -> dict:
    out = {"source": source}
    p = GridSLAMParams(n_particles=30, match_iterations=0)
    t0 = time.perf_counter()
    vec = run_grid_slam(log, p, np.random.default_rng(0), n_scans=ratio_scans)
    t_vec = time.perf_counter() - t0
    t0 = time.perf_counter()
    loop = run_grid_slam_loop(log, p, np.random.default_rng(0), n_scans=ratio_scans)
    t_loop = time.perf_counter() - t0
    same = bool(np.allclose(vec.poses, loop.poses, atol=1e-9) and np.array_equal(vec.resampled, loop.resampled))
    out["ratio"] = {"scans": ratio_scans, "particles": 30, "params": "hit_sigma=0.1, no scan matching",
                    "vectorised_s": t_vec, "loop_s": t_loop, "speedup": t_loop / t_vec, "same_result": same}
    print(f"vectorised {t_vec:.2f} s, loop {t_loop:.2f} s on {ratio_scans} scans × 30 particles: "
          f"{t_loop / t_vec:.0f}× (same result: {same})", flush=True)
    rows = []
    for name, (kind, changes) in VARIANTS.items():
        for m in (30, 100):
            p = params_for(kind, changes, m)
            t0 = time.perf_counter()
            res = run_grid_slam(log, p, np.random.default_rng(0), n_scans=speed_scans)
            wall = time.perf_counter() - t0
            ms = 1e3 * res.filter_seconds / (len(res.t) - 1)
            rows.append({"variant": name, "particles": m, "scans": len(res.t), "ms_per_scan": ms, "wall_s": wall,
                         "grid_cells": int(np.prod(res.grid.shape))})
            print(f"  {name:50s} M = {m:3d}: {ms:6.1f} ms per scan", flush=True)
    out["time_per_scan"] = rows
    return out


def accuracy(seeds: list[int]) -> dict:
    data = intel()
    if data is None:
        raise SystemExit("--accuracy needs intel/ under $FASTSLAM_EDU_DATA")
    odo, ref, rel = data
    table = []

    def score(name, poses_list, seconds=None):
        scores = [score_trajectory(odo.t, p, relations=rel, reference=(ref.t, ref.poses)) for p in poses_list]
        rels = [s["relations"] for s in scores]
        rms = [s["reference"]["rmse_m"] for s in scores]
        row = {
            "variant": name, "seeds": len(poses_list), "relations_used": rels[0]["n_used"],
            "relation_trans_mean_m": [r["trans_mean_m"] for r in rels], "relation_trans_std_m": [r["trans_std_m"] for r in rels],
            "relation_rot_mean_deg": [r["rot_mean_deg"] for r in rels], "rmse_vs_gmapping_m": rms,
        }
        med = int(np.argsort(row["relation_trans_mean_m"])[len(rels) // 2])  # the median run (by relation error)
        row["median"] = {"relation_trans_mean_m": float(np.median(row["relation_trans_mean_m"])),
                         "relation_trans_std_m_of_median_run": row["relation_trans_std_m"][med],
                         "relation_rot_mean_deg": float(np.median(row["relation_rot_mean_deg"])),
                         "rmse_vs_gmapping_m": float(np.median(rms))}
        if seconds is not None:
            row["filter_seconds"] = seconds
        table.append(row)
        print(f"{name:50s} relation {row['median']['relation_trans_mean_m']:.3f} m "
              f"(± {row['median']['relation_trans_std_m_of_median_run']:.3f}), rot {row['median']['relation_rot_mean_deg']:.2f}°, "
              f"RMSE {row['median']['rmse_vs_gmapping_m']:.3f} m   per seed: "
              f"{np.round(row['relation_trans_mean_m'], 3).tolist()} / {np.round(rms, 2).tolist()}", flush=True)

    score("raw odometry", [odo.poses])
    for name, (kind, changes) in VARIANTS.items():
        runs = [run_grid_slam(odo, params_for(kind, changes, 30), np.random.default_rng(s)) for s in seeds]
        score(name, [r.estimate for r in runs], [r.filter_seconds for r in runs])
    score("GMapping (reference)", [ref.poses])
    return {"dataset": "Intel lab, 910 scans (intel_gfs.json.gz), relations intel.relations, tolerance 1 ms",
            "particles": 30, "seeds": seeds, "rows": table}


def fr079(seeds: list[int]) -> dict:
    path = data_root() / "fr079" / "freiburg-079-corrected.log.gz"
    log = read_carmen(path)
    rows = []
    odo = None
    for name, changes in (("default (graded + scan matching)", {}), ("graded correlation, no scan matching",
                                                                        {"match_iterations": 0})):
        rms, secs = [], []
        for s in seeds:
            res = run_grid_slam(log, GridSLAMParams(n_particles=30, **changes), np.random.default_rng(s))
            rms.append(reference_errors(res.t, res.estimate, log.t, log.poses)["rmse"])
            secs.append(res.filter_seconds)
            odo = reference_errors(res.t, res.odometry, log.t, log.poses)["rmse"]
        rows.append({"variant": name, "rmse_vs_gmapping_m": rms, "median_rmse_m": float(np.median(rms)),
                     "filter_seconds": secs})
        print(f"FR079 {name:45s} RMSE {np.median(rms):.3f} m per seed {np.round(rms, 2).tolist()}", flush=True)
    print(f"FR079 raw odometry (recovered) RMSE {odo:.3f} m", flush=True)
    return {"dataset": f"FR079, {len(log)} scans, odometry recovered from ODOM lines", "seeds": seeds,
            "odometry_rmse_m": odo, "rows": rows}


def markdown(result: dict) -> str:
    lines = [f"# Grid SLAM benchmark\n\nMachine: {result['machine'].get('cpu_model', '?')}, "
             f"{result['machine']['cpu_count']} cores, numpy {result['machine']['numpy']}\n"]
    sp = result.get("speed")
    if sp:
        r = sp["ratio"]
        lines += [f"## Speed ({sp['source']})\n",
                  f"Vectorised vs loop reference, {r['scans']} scans × {r['particles']} particles: "
                  f"{r['vectorised_s']:.2f} s vs {r['loop_s']:.1f} s → **{r['speedup']:.0f}×** "
                  f"(same result: {r['same_result']})\n",
                  "| variant | M | ms per scan |", "| --- | ---: | ---: |"]
        lines += [f"| {row['variant']} | {row['particles']} | {row['ms_per_scan']:.1f} |" for row in sp["time_per_scan"]]
        lines.append("")
    acc = result.get("accuracy")
    if acc:
        lines += [f"## Accuracy: {acc['dataset']}, M = {acc['particles']}, median of seeds {acc['seeds']}\n",
                  "| variant | relation error [m] | rotation [deg] | RMSE vs GMapping [m] |",
                  "| --- | ---: | ---: | ---: |"]
        for row in acc["rows"]:
            md = row["median"]
            lines.append(f"| {row['variant']} | {md['relation_trans_mean_m']:.3f} ± "
                         f"{md['relation_trans_std_m_of_median_run']:.3f} | {md['relation_rot_mean_deg']:.2f} | "
                         f"{md['rmse_vs_gmapping_m']:.3f} |")
        lines.append(f"\nRelations used: {acc['rows'][0]['relations_used']} of 2984.\n")
    fr = result.get("fr079")
    if fr:
        lines += [f"## {fr['dataset']}\n", f"Raw odometry RMSE {fr['odometry_rmse_m']:.3f} m.\n",
                  "| variant | median RMSE vs GMapping [m] | per seed |", "| --- | ---: | --- |"]
        lines += [f"| {r['variant']} | {r['median_rmse_m']:.3f} | {np.round(r['rmse_vs_gmapping_m'], 2).tolist()} |"
                  for r in fr["rows"]]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--accuracy", action="store_true", help="Intel accuracy table (5 seeds)")
    ap.add_argument("--fr079", action="store_true", help="also FR079 (slow: 4791 scans)")
    ap.add_argument("--no-speed", action="store_true", help="skip the speed part")
    ap.add_argument("--quick", action="store_true", help="fewer scans and seeds (smoke test)")
    ap.add_argument("--ratio-scans", type=int, default=30)
    ap.add_argument("--speed-scans", type=int, default=300)
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results")
    args = ap.parse_args()
    if args.quick:
        args.ratio_scans, args.speed_scans = 8, 40
    seeds = [0, 1] if args.quick else [0, 1, 2, 3, 4]
    result = {"machine": machine_info()}
    if not args.no_speed:
        data = intel()
        if data is not None:
            log, source = data[0], "Intel lab (intel_gfs.json.gz)"
        else:
            log, source = simulate_laser_world(0).log, "simulated office (no real data found)"
        result["speed"] = speed(log, source, args.ratio_scans, args.speed_scans)
    if args.accuracy:
        result["accuracy"] = accuracy(seeds)
    if args.fr079:
        result["fr079"] = fr079(seeds[:3])
    args.out.mkdir(parents=True, exist_ok=True)
    stem = "gridslam" if not args.quick else "gridslam_quick"
    (args.out / f"{stem}.json").write_text(json.dumps(result, indent=2))
    (args.out / f"{stem}.md").write_text(markdown(result))
    print(markdown(result))


if __name__ == "__main__":
    main()
