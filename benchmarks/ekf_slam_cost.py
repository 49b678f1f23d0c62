"""The cost of one measurement update as the map grows: EKF-SLAM against FastSLAM (arrays and trees), K = 25 … 2000.

One update = one sighting ``z = (r, φ)`` of one landmark, in a map of K landmarks all seen:

* **EKF-SLAM** (:func:`fastslam_edu.landmark.ekf_slam_steps.update`): the joint covariance
  :math:`\\Sigma` is (3 + 2K)², and the Joseph-form update rewrites every entry — :math:`O(K^2)`
  time and memory traffic, :math:`8 (3+2K)^2` bytes held;
* **FastSLAM, arrays** (:func:`fastslam_edu.landmark.particle_set.update_with_measurements`, M = 100):
  one 2×2 EKF per particle, :math:`O(M)` whatever K. FastSLAM's K enters at resampling, which
  copies every particle's map (:meth:`ParticleSet.select`, :math:`O(MK)`), so the table also gives
  **update + resampling** (the step of ``benchmarks/landmark_tree.py``);
* **FastSLAM, trees** (:class:`fastslam_edu.landmark.fastslam_tree.TreeParticleSet`, M = 100):
  update + resampling, :math:`O(M \\log K)`.

Reported per K: seconds per update (median and minimum of repeats; each repeat is a block of calls
lasting at least ``--block`` seconds, the filters alternating so that a busy machine slows them
alike), bytes of state, the ratios EKF / FastSLAM at K = 2000 measured in this run, and the
growth exponent of each cost from K = 200 on (least-squares slope in log–log: 2 for K², 1 for K,
≈ 0 for log K). Prints a table; writes ``results/ekf_slam_cost.json``.

BLAS runs on one thread (set before numpy is imported), as FastSLAM's compiled kernels do.

Usage: python benchmarks/ekf_slam_cost.py [--quick] [--repeats 7] [--block 0.05] [--out FILE]
(about half a minute on a busy 2-core machine)
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import sys
import time
from pathlib import Path

# One thread for BLAS, as for FastSLAM's compiled kernels: on a busy machine BLAS's threads wait for each other
# (a 200 × 200 product then takes tens of milliseconds), which would time the machine, not the algorithm.
for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info, machine_line  # noqa: E402

from fastslam_edu.core.measurement import range_bearing  # noqa: E402
from fastslam_edu.core.resampling import systematic  # noqa: E402
from fastslam_edu.landmark.ekf_slam_steps import EKFSLAMState, landmark_slice, update  # noqa: E402
from fastslam_edu.landmark.particle_set import ParticleSet, update_with_measurements  # noqa: E402
from fastslam_edu.landmark.fastslam_tree import TreeParticleSet  # noqa: E402
from fastslam_edu.landmark.tree import LandmarkTree  # noqa: E402

KS = [25, 50, 100, 200, 500, 1000, 2000]
KS_QUICK = [25, 100, 500, 2000]
M = 100
#: Measurement noise of the timed updates (range [m], bearing [rad]).
R = np.diag([0.1**2, 0.02**2])


def world(n_landmarks: int, seed: int = 0):
    """K landmarks uniform in a 100 m square, the robot near the origin; what each filter holds after mapping them.

    EKF-SLAM: :math:`\\mu` with every landmark seen and a dense :math:`\\Sigma = D + U U^\\top` (landmark
    variances of a few cm², plus three shared directions — the pose's error every landmark inherits —
    so that every entry is non-zero, as in a real map). FastSLAM: M particles whose poses scatter by
    5 cm and 0.01 rad, each holding the K landmarks with Σ = 0.01 I (dense arrays, and trees).
    Returns ``(ekf_state, dense, trees, indices)``, ``indices`` from systematic resampling of random weights.
    """
    rng = np.random.default_rng(seed)
    K = int(n_landmarks)
    lm = rng.uniform(-50.0, 50.0, (K, 2))
    n = 3 + 2 * K
    state = EKFSLAMState.initial(K, [0.0, 0.0, 0.0])
    state.mu[3:] = lm.ravel()
    state.seen[:] = True
    U = rng.normal(0.0, 0.05, (n, 3))
    state.sigma[:] = U @ U.T
    state.sigma[np.diag_indices(n)] += rng.uniform(0.01, 0.05, n) ** 2
    poses = np.column_stack([rng.normal(0.0, 0.05, (M, 2)), rng.normal(0.0, 0.01, M)])
    sigma = np.tile(np.eye(2) * 0.01, (K, 1, 1))
    dense = ParticleSet(poses=poses, mu=np.broadcast_to(lm, (M, K, 2)).copy(),
                        sigma=np.broadcast_to(sigma, (M, K, 2, 2)).copy(), seen=np.ones((M, K), dtype=bool),
                        logw=np.zeros(M))
    trees = TreeParticleSet(poses=poses.copy(), trees=[LandmarkTree.from_arrays(lm, sigma)] * M, logw=np.zeros(M))
    w = rng.random(M)
    return state, dense, trees, systematic(w / w.sum(), rng)


def sightings(state: EKFSLAMState, n: int, seed: int = 1):
    """``n`` sightings ``(z (2,), k)`` of random landmarks, from the EKF's mean pose, 2 cm and 0.01 rad off."""
    rng = np.random.default_rng(seed)
    out = []
    for k in rng.integers(0, state.n_landmarks, n):
        z = range_bearing(state.mu[:3], state.mu[landmark_slice(int(k))]) + rng.normal(0, [0.02, 0.01])
        out.append((z, int(k)))
    return out


def timers(n_landmarks: int):
    """One callable per filter, each doing one update (a fresh sighting each call), and the bytes each holds."""
    state, dense, trees, indices = world(n_landmarks)
    seen_by = sightings(state, 64)
    counter = {"i": 0}

    def next_sighting():
        counter["i"] = (counter["i"] + 1) % len(seen_by)
        return seen_by[counter["i"]]

    def ekf():
        z, k = next_sighting()
        update(state, z, k, R)

    def arrays():
        z, k = next_sighting()
        update_with_measurements(dense, z[None], [k], R)

    def arrays_resample():
        z, k = next_sighting()
        update_with_measurements(dense.select(indices), z[None], [k], R)

    def trees_resample():
        z, k = next_sighting()
        trees.select(indices).update(z[None], [k], R)

    run = {"ekf": ekf, "fastslam_arrays": arrays, "fastslam_arrays_resample": arrays_resample,
           "fastslam_tree_resample": trees_resample}
    held = {"ekf": state.sigma.nbytes + state.mu.nbytes,
            "fastslam_arrays": sum(a.nbytes for a in (dense.mu, dense.sigma, dense.seen, dense.count, dense.poses))}
    return run, held


def seconds_per_call(fn, n_calls: int) -> float:
    gc.collect()
    t0 = time.perf_counter()
    for _ in range(n_calls):
        fn()
    return (time.perf_counter() - t0) / n_calls


def update_cost(n_landmarks: int, repeats: int, min_block_seconds: float) -> dict:
    """Seconds per update of each filter at K = ``n_landmarks`` (median and minimum of ``repeats`` blocks)."""
    run, held = timers(n_landmarks)
    block = {name: max(1, int(np.ceil(min_block_seconds / max(seconds_per_call(fn, 1), 1e-7))))
             for name, fn in run.items()}  # the first call is also a warm-up (numba compiles once)
    times: dict[str, list[float]] = {name: [] for name in run}
    for _ in range(repeats):
        for name, fn in run.items():
            times[name].append(seconds_per_call(fn, block[name]))
    row: dict = {"K": int(n_landmarks), "state_dim_ekf": 3 + 2 * int(n_landmarks), "M": M, "repeats": repeats}
    for name in run:
        row[f"{name}_seconds"] = float(np.median(times[name]))
        row[f"{name}_seconds_min"] = float(min(times[name]))
        row[f"{name}_calls_per_block"] = block[name]
    row.update({f"{name}_bytes": b for name, b in held.items()})
    return row


def exponent(rows: list[dict], name: str, stat: str = "seconds", k_from: int = 200) -> float:
    """Least-squares slope of log(time) against log(K) over K ≥ ``k_from``: 2 for K², 1 for K, ≈ 0 for log K."""
    use = [r for r in rows if r["K"] >= k_from] or rows[-2:]
    K = np.log([r["K"] for r in use])
    t = np.log([r[f"{name}_{stat}"] for r in use])
    return float(np.polyfit(K, t, 1)[0])


NAMES = ("ekf", "fastslam_arrays", "fastslam_arrays_resample", "fastslam_tree_resample")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help=f"only K = {KS_QUICK}, 3 repeats")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--block", type=float, default=0.05, help="seconds per timed block (at least one call)")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "ekf_slam_cost.json")
    args = ap.parse_args(argv)
    if args.repeats < 1 or not args.block > 0:
        ap.error("--repeats must be >= 1 and --block > 0")
    t_start = time.perf_counter()
    Ks = KS_QUICK if args.quick else KS
    repeats = 3 if args.quick else args.repeats
    rows = []
    for K in Ks:
        rows.append(update_cost(K, repeats, args.block))
        print(f"K = {K}: done ({time.perf_counter() - t_start:.0f} s)", file=sys.stderr)
    last = rows[-1]
    results = {
        "machine": machine_info(),
        "M": M,
        "rows": rows,
        "K_max": last["K"],
        "ratio_ekf_over_fastslam_arrays_update": last["ekf_seconds"] / last["fastslam_arrays_seconds"],
        "ratio_ekf_over_fastslam_arrays_update_minima": last["ekf_seconds_min"] / last["fastslam_arrays_seconds_min"],
        "ratio_ekf_over_fastslam_arrays_update_resample":
            last["ekf_seconds"] / last["fastslam_arrays_resample_seconds"],
        "ratio_ekf_over_fastslam_tree_update_resample": last["ekf_seconds"] / last["fastslam_tree_resample_seconds"],
        "exponents": {name: exponent(rows, name) for name in NAMES},
        "exponents_minima": {name: exponent(rows, name, "seconds_min") for name in NAMES},
        "seconds_total": None,
    }
    print(machine_line(results["machine"]))
    print(f"one measurement update in a map of K landmarks; FastSLAM with M = {M}; time = median (min) of repeats [ms]")
    print(f"{'K':>5} {'EKF-SLAM':>18} {'FastSLAM arrays':>18} {'arrays+resample':>18} {'tree+resample':>18} "
          f"{'EKF/arrays':>10} {'EKF Σ [MB]':>10}")
    for r in rows:
        cells = " ".join(f"{r[f'{n}_seconds'] * 1e3:>9.3f} ({r[f'{n}_seconds_min'] * 1e3:>6.3f})" for n in NAMES)
        print(f"{r['K']:>5} {cells} {r['ekf_seconds'] / r['fastslam_arrays_seconds']:>9.1f}x "
              f"{r['ekf_bytes'] / 1e6:>10.1f}")
    e = results["exponents"]
    e_min = results["exponents_minima"]
    print("growth exponent, slope of log time against log K from K = 200 on (2: K², 1: K, ~0: log K), "
          "medians (minima): " + ", ".join(f"{n} {e[n]:.2f} ({e_min[n]:.2f})" for n in NAMES))
    print(f"at K = {last['K']}: EKF-SLAM update / FastSLAM arrays update = "
          f"{results['ratio_ekf_over_fastslam_arrays_update']:.0f}x "
          f"(minima {results['ratio_ekf_over_fastslam_arrays_update_minima']:.0f}x); "
          f"/ arrays update + resampling = {results['ratio_ekf_over_fastslam_arrays_update_resample']:.1f}x; "
          f"/ tree update + resampling = {results['ratio_ekf_over_fastslam_tree_update_resample']:.1f}x")
    results["seconds_total"] = time.perf_counter() - t_start
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2))
    print(f"wrote {args.out} ({results['seconds_total']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
