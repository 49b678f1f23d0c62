"""FastSLAM 1.0 on MR.CLAM: speed and accuracy, printed as a table and written as JSON.

(a) the write-up's setting: Dataset 1 robot 2, 1 Hz, 100 particles;
(b) full rate, Dataset 1 robot 2, 100 and 1000 particles (the latter's time also scaled as below);
(c) the loop over particle objects (benchmarks/textbook_loop.py) against the filter on the same work
    (same stream, particles and seed), as a ratio measured in this run;
(d) full rate, 100 particles, with FastSLAM 2.0's proposal (``proposal="fastslam2"``):
    its cost against (b) in the same run.

The write-up's own code, measured on a machine like this one
(../shared/reference/README.md): 11.9 s for its 1489-step loop (13.0 s whole run).
Its code is not part of this project, so it cannot run in the same run as ours; the
machine, a shared VM, is not always as fast (the same code has run 3x slower on one day
than on another). So the table gives two ratios: against the recorded 11.9 s as it is,
and against 11.9 s scaled by how much slower this machine runs our own textbook loop
reference (c) than when the 11.9 s was recorded (61 s, the mean of 59-64 s measured then;
both are Python loops over particles and measurements calling small numpy functions).

Usage: python benchmarks/fastslam_mrclam.py [--seeds N] [--out FILE]
(data from $FASTSLAM_EDU_DATA, default ./data)
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

from fastslam_edu.datasets import mrclam_path  # noqa: E402
from fastslam_edu.datasets.events import event_stream  # noqa: E402
from fastslam_edu.app.experiment import load_mrclam, summarize  # noqa: E402
from fastslam_edu.landmark.fastslam import FastSLAMParams, run_fastslam  # noqa: E402
from textbook_loop import run_fastslam_loop  # noqa: E402

REFERENCE_LOOP_SECONDS = 11.9  # the write-up's code, 1489-step loop, 100 particles
LOOP_REFERENCE_SECONDS_THEN = 61.0  # our loop reference on case (c) when the 11.9 s was recorded (59-64 s)


def case(stream, dataset, log, params, seeds):
    rows = []
    for seed in seeds:
        result = run_fastslam(stream, params, np.random.default_rng(seed))
        rows.append(summarize(result, dataset, log))
    times = [r["filter_seconds"] for r in rows]
    pick = lambda k: [r[k] for r in rows]  # noqa: E731
    return {
        "seconds_median": statistics.median(times),
        "seconds_min": min(times),
        "path_rmse_m_median": statistics.median(pick("path_rmse_m")),
        "landmark_error_mean_m_median": statistics.median(pick("landmark_error_mean_m")),
        "landmark_error_aligned_mean_m_median": statistics.median(pick("landmark_error_aligned_mean_m")),
        "steps": rows[0]["steps"],
        "measurements": rows[0]["measurements_used"] + rows[0]["measurements_rejected"],
        "seeds": list(seeds),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "fastslam_mrclam.json")
    args = ap.parse_args(argv)
    seeds = range(args.seeds)
    dataset, log, notes = load_mrclam(mrclam_path(1), 2)
    full = event_stream(log, dataset.landmark_subjects, rate="full")
    onehz = event_stream(log, dataset.landmark_subjects, rate="1hz")
    base = FastSLAMParams(n_particles=100)
    results = {"machine": machine_info(), "notes": notes, "reference_loop_seconds": REFERENCE_LOOP_SECONDS}
    results["a_writeup_1hz_M100"] = case(onehz, dataset, log, base, seeds)
    results["b_full_M100"] = case(full, dataset, log, base, seeds)
    results["b_full_M1000"] = case(full, dataset, log, base.replace(n_particles=1000), seeds)
    results["d_full_M100_fastslam2"] = case(full, dataset, log, base.replace(proposal="fastslam2"), seeds)
    # (c) the loop over particle objects vs the compiled filter, same work, same seed
    t = time.perf_counter()
    run_fastslam_loop(onehz, base, np.random.default_rng(0))
    loop_s = time.perf_counter() - t
    t = time.perf_counter()
    run_fastslam(onehz, base, np.random.default_rng(0))
    vec_s = time.perf_counter() - t
    results["c_loop_vs_filter_1hz_M100"] = {"loop_seconds": loop_s, "filter_seconds": vec_s, "ratio": loop_s / vec_s}
    slowdown = loop_s / LOOP_REFERENCE_SECONDS_THEN  # this machine against the one the 11.9 s was recorded on
    reference_here = REFERENCE_LOOP_SECONDS * slowdown
    results["machine_slowdown_vs_reference_machine"] = slowdown
    results["reference_loop_seconds_scaled"] = reference_here

    print(machine_line(results["machine"]))
    print(f"{'case':<28} {'steps':>7} {'meas':>6} {'time [s]':>9} {'vs ref':>7} {'scaled':>7} "
          f"{'path RMSE':>10} {'lm err':>7} {'lm aligned':>10}")
    for name in ("a_writeup_1hz_M100", "b_full_M100", "b_full_M1000", "d_full_M100_fastslam2"):
        r = results[name]
        r["vs_reference"] = REFERENCE_LOOP_SECONDS / r["seconds_median"]
        r["vs_reference_scaled"] = reference_here / r["seconds_median"]
        print(f"{name:<28} {r['steps']:>7} {r['measurements']:>6} {r['seconds_median']:>9.3f} "
              f"{r['vs_reference']:>6.0f}x {r['vs_reference_scaled']:>6.0f}x {r['path_rmse_m_median']:>10.3f} "
              f"{r['landmark_error_mean_m_median']:>7.3f} {r['landmark_error_aligned_mean_m_median']:>10.3f}")
    c = results["c_loop_vs_filter_1hz_M100"]
    print(f"loop reference {c['loop_seconds']:.2f} s vs the filter {c['filter_seconds']:.3f} s: {c['ratio']:.0f}x (same stream, M=100, seed 0)")
    print(f"vs ref: against the recorded {REFERENCE_LOOP_SECONDS} s; scaled: against {reference_here:.1f} s, the same "
          f"scaled by this machine's slowdown on the loop reference ({loop_s:.0f} s here, "
          f"{LOOP_REFERENCE_SECONDS_THEN:.0f} s when the 11.9 s was recorded: x{slowdown:.2f})")
    big = results["b_full_M1000"]
    big["seconds_median_scaled"] = big["seconds_median"] / slowdown
    print(f"full rate, M=1000: {big['seconds_median']:.2f} s here (median of {len(seeds)} seeds; fastest "
          f"{big['seconds_min']:.2f} s), {big['seconds_median_scaled']:.2f} s scaled to the reference machine")
    d = results["d_full_M100_fastslam2"]["seconds_median"] / results["b_full_M100"]["seconds_median"]
    results["d_fastslam2_over_fastslam1_time"] = d
    print(f"FastSLAM 2.0 proposal / FastSLAM 1.0, full rate, M=100: {d:.2f}x the time")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
