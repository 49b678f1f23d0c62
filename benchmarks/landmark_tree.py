"""The cost of one FastSLAM step with tree maps vs dense arrays, for K = 15 … 10⁵ landmarks.

One step = resample all M = 100 particles (indices from systematic resampling
of random weights, fixed seed) and update 2 landmarks in every particle
(:func:`step_cost`):

* dense arrays (the array engine): ``ParticleSet.select`` copies every
  particle's K means, covariances and flags by fancy indexing — O(MK);
* trees: the offspring share their parent's tree; each update path-copies
  ⌈log2 K⌉ + 1 nodes — O(M log K).

Measured per K: wall time (median of repeats), bytes allocated (tracemalloc:
peak during the step, and retained by the new particle set), tree nodes
created. Reports the crossover K (where the tree starts to win in wall time,
interpolated in log K), the tree's time growth from K = 10³ to 10⁵ (expected
≤ 2×: the path grows from 11 to 18 nodes) and the speed-up at K = 10⁵
(expected ≥ 20×). Writes results/landmark_tree.json and results/landmark_tree.png.

Timing on a shared machine: each repeat is a block of steps long enough to
time (≥ 5 ms), tree and dense blocks alternate; the median is reported as
asked, and the minimum too — when other processes compete for the cores, the
minimum is the better estimate of the intrinsic cost, so the crossover and the
targets are given from both.

A second, narrower measurement isolates the tree's update (:func:`set_step_cost`):
resample the M trees (references), then 2 :meth:`LandmarkTree.set` per particle,
against copying the dense ``mu (M, K, 2)`` and ``sigma (M, K, 2, 2)`` arrays and
writing the 2 landmarks; its table at K = 10³, 10⁴, 10⁵ gives the tree time, the
dense time, their ratio (target ≥ 20× at K = 10⁵) and the growth 10³ → 10⁵.

Usage: python benchmarks/landmark_tree.py [--quick] [--out FILE]
"""

from __future__ import annotations

import argparse
import gc
import json
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from ekf_slam_cost import seconds_per_call  # noqa: E402
from machine import machine_info, machine_line  # noqa: E402

from fastslam_edu.landmark.particle_set import ParticleSet  # noqa: E402
from fastslam_edu.landmark.fastslam_tree import TreeParticleSet  # noqa: E402
from fastslam_edu.landmark.tree import LandmarkTree, count_new_nodes, tree_depth  # noqa: E402
from fastslam_edu.core.resampling import systematic  # noqa: E402

K_MAIN = [100, 1_000, 10_000, 100_000]
K_BETWEEN = [15, 200, 300, 500, 2_000, 3_000, 5_000, 20_000, 50_000]
M = 100
#: Measurement noise of the timed updates (range [m], bearing [rad]).
R_STEP = np.diag([0.1**2, 0.02**2])


def step_world(n_landmarks: int, n_particles: int, n_updates: int, seed: int):
    """A full map of K landmarks held by M particles (dense and tree), poses, measurements, resampling indices.

    Landmarks uniform in a 100 m square, every particle near the origin,
    ``n_updates`` distinct landmarks measured (exact range and bearing from
    the origin); indices from systematic resampling of uniform random weights.
    Returns ``(dense, tree, indices, keys, z)``.
    """
    rng = np.random.default_rng(seed)
    K, M = int(n_landmarks), int(n_particles)
    if K < n_updates:
        raise ValueError(f"need K >= {n_updates} landmarks, got K = {K}")
    lm = rng.uniform(-50.0, 50.0, (K, 2))
    sigma = np.tile(np.eye(2) * 0.01, (K, 1, 1))
    poses = np.column_stack([rng.normal(0.0, 0.05, (M, 2)), rng.normal(0.0, 0.01, M)])
    keys = rng.choice(K, size=n_updates, replace=False)
    d = lm[keys]
    z = np.column_stack([np.hypot(d[:, 0], d[:, 1]), np.arctan2(d[:, 1], d[:, 0])])
    w = rng.random(M)
    indices = systematic(w / w.sum(), rng)
    dense = ParticleSet(
        poses=poses, mu=np.broadcast_to(lm, (M, K, 2)).copy(), sigma=np.broadcast_to(sigma, (M, K, 2, 2)).copy(),
        seen=np.ones((M, K), dtype=bool), logw=np.zeros(M),
    )
    tree = TreeParticleSet(poses=poses.copy(), trees=[LandmarkTree.from_arrays(lm, sigma)] * M, logw=np.zeros(M))
    return dense, tree, indices, keys, z


def step(particles: ParticleSet | TreeParticleSet, indices, keys, z) -> ParticleSet | TreeParticleSet:
    """One filter step on either representation: resample ``indices``, then update landmarks ``keys`` with ``z``.

    The same two calls on both (``select``, then ``update`` without a gate,
    :data:`R_STEP`); returns the new set, the input is unchanged.
    """
    new = particles.select(indices)
    new.update(z, keys, R_STEP)
    return new


def seconds_per_step(particles, indices, keys, z, n_steps: int) -> float:
    """Mean wall time of ``n_steps`` calls of :func:`step` (each result dropped at once)."""
    return seconds_per_call(lambda: step(particles, indices, keys, z), n_steps)


def step_cost(n_landmarks: int, n_particles: int = 100, *, n_updates: int = 2, repeats: int = 5,
              seed: int = 0, min_block_seconds: float = 0.02) -> dict:
    """Measure one filter step (resample all M particles, update ``n_updates`` landmarks) on trees and dense arrays.

    Timing, like :mod:`timeit`: a *block* runs the step ``n`` times in a row
    (``n`` chosen so that a block lasts at least ``min_block_seconds``) and
    gives the mean time per step; ``repeats`` blocks alternate between the two
    representations (so a busy machine slows both alike), and the median and
    the minimum over the blocks are reported. Memory is measured with
    :mod:`tracemalloc` in a separate run (tracing slows Python code down).

    Returns
    -------
    dict
        ``K, M, n_updates, depth, repeats``;
        ``tree_seconds, dense_seconds`` (median), ``tree_seconds_min, dense_seconds_min``,
        ``tree_steps_per_block, dense_steps_per_block``, ``speedup`` (dense / tree, medians);
        ``tree_bytes_peak, dense_bytes_peak``: the most allocated at once during the step;
        ``tree_bytes_retained, dense_bytes_retained``: what the new particle set holds beyond the old one;
        ``tree_nodes_created``: distinct nodes of the new trees that are in none of the old ones — per
        particle the union of the ``n`` root-to-leaf paths, at most ``tree_nodes_bound``
        :math:`= M n (\\lceil\\log_2 K\\rceil + 1)` (the first update's copy of a node on both paths,
        the root at least, is replaced by the second's);
        ``dense_bytes_copied``: the landmark arrays ``select`` copies (:math:`\\propto MK`).
    """
    if int(repeats) < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats!r}")
    dense, tree, indices, keys, z = step_world(n_landmarks, n_particles, n_updates, seed)
    out: dict = {"K": int(n_landmarks), "M": int(n_particles), "n_updates": int(n_updates),
                 "depth": tree_depth(n_landmarks), "repeats": int(repeats)}
    sets = {"tree": tree, "dense": dense}
    block = {name: max(1, int(np.ceil(min_block_seconds / seconds_per_step(p, indices, keys, z, 1))))
             for name, p in sets.items()}  # the first call is also a warm-up
    times: dict[str, list[float]] = {name: [] for name in sets}
    for _ in range(int(repeats)):
        for name, p in sets.items():
            times[name].append(seconds_per_step(p, indices, keys, z, block[name]))
    for name, p in sets.items():
        out[f"{name}_seconds"] = float(np.median(times[name]))
        out[f"{name}_seconds_min"] = float(min(times[name]))
        out[f"{name}_steps_per_block"] = block[name]
        gc.collect()
        started = not tracemalloc.is_tracing()
        if started:
            tracemalloc.start()
        try:
            before = tracemalloc.get_traced_memory()[0]
            tracemalloc.reset_peak()
            new = step(p, indices, keys, z)
            current, peak = tracemalloc.get_traced_memory()
        finally:
            if started:
                tracemalloc.stop()
        out[f"{name}_bytes_peak"] = int(peak - before)
        out[f"{name}_bytes_retained"] = int(current - before)
        if name == "tree":
            out["tree_nodes_created"] = count_new_nodes(new.trees, tree.trees)
        del new
    out["tree_nodes_bound"] = int(n_particles) * int(n_updates) * (out["depth"] + 1)
    out["dense_bytes_copied"] = int(sum(a.nbytes for a in (dense.mu, dense.sigma, dense.seen, dense.count)))
    out["speedup"] = out["dense_seconds"] / out["tree_seconds"]
    return out


def set_step(trees: list, indices, keys, mu, sigma) -> list:
    """Resample the trees ``indices`` (references), then ``tree.set(keys[j], mu[m, j], sigma[m, j])`` per particle."""
    new = [trees[i] for i in indices.tolist()]
    for m, tree in enumerate(new):
        for j, k in enumerate(keys):
            tree = tree.set(k, mu[m, j], sigma[m, j])
        new[m] = tree
    return new


def dense_set_step(mu_all: np.ndarray, sigma_all: np.ndarray, indices, keys, mu, sigma):
    """The same on dense arrays: copy ``mu_all[indices]`` (M, K, 2), ``sigma_all[indices]`` (M, K, 2, 2); write."""
    mu_all, sigma_all = mu_all[indices], sigma_all[indices]
    mu_all[:, keys], sigma_all[:, keys] = mu, sigma
    return mu_all, sigma_all


def set_step_cost(n_landmarks: int, n_particles: int = 100, *, n_updates: int = 2, repeats: int = 5,
                  seed: int = 0, min_block_seconds: float = 0.02) -> dict:
    """Time :func:`set_step` against :func:`dense_set_step` (blocks alternate, as in :func:`step_cost`).

    The new values are fresh (writable) arrays, as a filter's EKF update makes
    them, so every ``set`` stores a read-only copy of its 2 + 4 floats.
    Returns ``K, tree_seconds, dense_seconds`` (medians), ``…_min`` and ``speedup`` (dense / tree, medians).
    """
    dense, tree, indices, keys, _ = step_world(n_landmarks, n_particles, n_updates, seed)
    rng = np.random.default_rng(seed + 1)
    mu = dense.mu[0, keys] + rng.normal(0.0, 0.01, (n_particles, n_updates, 2))
    sigma = np.broadcast_to(np.eye(2) * 0.005, (n_particles, n_updates, 2, 2)).copy()
    keys = keys.tolist()
    calls = {"tree": lambda: set_step(tree.trees, indices, keys, mu, sigma),
             "dense": lambda: dense_set_step(dense.mu, dense.sigma, indices, keys, mu, sigma)}
    times = {name: [] for name in calls}
    block = {name: max(1, int(np.ceil(min_block_seconds / seconds_per_call(call, 1)))) for name, call in calls.items()}
    for _ in range(int(repeats)):
        for name, call in calls.items():
            times[name].append(seconds_per_call(call, block[name]))
    out = {"K": int(n_landmarks)}
    for name in calls:
        out[f"{name}_seconds"], out[f"{name}_seconds_min"] = float(np.median(times[name])), float(min(times[name]))
    out["speedup"] = out["dense_seconds"] / out["tree_seconds"]
    return out


def crossover_k(rows: list[dict], stat: str = "seconds") -> float | None:
    """The K from which the tree is faster, from :func:`step_cost` results sorted by K.

    Where :math:`g(K) = \\log(t_\\text{dense} / t_\\text{tree})` crosses 0 for the last time,
    interpolated linearly in :math:`\\log K` between the two measured K around it;
    ``rows[0]["K"]`` if the tree wins everywhere measured, None if it never
    wins at the largest K. ``stat``: ``"seconds"`` (medians) or ``"seconds_min"`` (minima).
    """
    K = np.array([r["K"] for r in rows], dtype=float)
    if len(K) == 0 or np.any(np.diff(K) <= 0):
        raise ValueError(f"crossover_k needs step_cost rows sorted by increasing K, got K = {K.tolist()}")
    gain = np.log(np.array([r[f"dense_{stat}"] / r[f"tree_{stat}"] for r in rows]))
    if gain[-1] <= 0:
        return None
    losing = np.flatnonzero(gain <= 0)
    if len(losing) == 0:
        return float(K[0])
    i = losing[-1]  # the last K where dense arrays still win; the tree wins from i + 1 on
    a, b = np.log(K[i]), np.log(K[i + 1])
    return float(np.exp(a + (b - a) * gain[i] / (gain[i] - gain[i + 1])))


def repeats_for(K: int) -> int:
    return 15 if K <= 10_000 else 7


def plot(rows: list[dict], k_cross: float | None, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    K = np.array([r["K"] for r in rows])
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    ax = axes[0]
    for name, marker, label in (("dense", "o", "dense arrays (copy M×K)"), ("tree", "s", "trees (path copying)")):
        med = np.array([r[f"{name}_seconds"] for r in rows]) * 1e3
        low = np.array([r[f"{name}_seconds_min"] for r in rows]) * 1e3
        ax.errorbar(K, med, yerr=[med - low, 0 * med], fmt=marker + "-", ms=4, capsize=2,
                    label=label + " (median, bar to min)")
    ax.set(xscale="log", yscale="log")
    ax.loglog(K, rows[-1]["dense_seconds"] * 1e3 * K / K[-1], ":", c="grey", lw=1, label="∝ K")
    if k_cross is not None:
        ax.axvline(k_cross, c="k", ls="--", lw=0.8, label=f"crossover K ≈ {k_cross:.0f}")
    ax.set(xlabel="landmarks K", ylabel="one step [ms]", title=f"resample + 2 updates, M = {rows[0]['M']}")
    ax.legend(fontsize=7)
    ax = axes[1]
    ax.loglog(K, [r["dense_bytes_peak"] for r in rows], "o-", label="dense arrays")
    ax.loglog(K, [r["tree_bytes_peak"] for r in rows], "s-", label="trees")
    ax.set(xlabel="landmarks K", ylabel="bytes allocated (peak)", title="memory of one step")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def print_set_steps(rows: list[dict]) -> dict:
    """Print the :func:`set_step_cost` table (K = 10³, 10⁴, 10⁵); return the rows, the growth and the targets."""
    print(f"\nresample M={M} trees + 2 LandmarkTree.set each, vs copying dense mu, sigma; median (min)")
    print(f"{'K':>7} {'tree [ms]':>17} {'dense [ms]':>19} {'ratio':>7}")
    for r in rows:
        print(f"{r['K']:>7} {r['tree_seconds'] * 1e3:>7.3f} ({r['tree_seconds_min'] * 1e3:>7.3f}) "
              f"{r['dense_seconds'] * 1e3:>8.3f} ({r['dense_seconds_min'] * 1e3:>8.3f}) {r['speedup']:>6.1f}x")
    growth = rows[-1]["tree_seconds"] / rows[0]["tree_seconds"]
    print(f"tree growth K=10³→10⁵: {growth:.2f}x (target ≤ 2x); ratio at K=10⁵: {rows[-1]['speedup']:.1f}x "
          "(target ≥ 20x)")
    return {"rows": rows, "tree_growth_1e3_to_1e5": growth,
            "targets": {"tree_growth_at_most_2x": growth <= 2.0,
                        "speedup_at_1e5_at_least_20x": rows[-1]["speedup"] >= 20.0}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="only K = 10², 10³, 10⁴, 3 repeats")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "landmark_tree.json")
    args = ap.parse_args(argv)
    Ks = sorted(K_MAIN if args.quick else K_MAIN + K_BETWEEN)
    if args.quick:
        Ks = Ks[:-1]
    t_start = time.perf_counter()
    rows = [step_cost(K, M, repeats=3 if args.quick else repeats_for(K), seed=0, min_block_seconds=0.005) for K in Ks]
    k_cross = crossover_k(rows)
    by_K = {r["K"]: r for r in rows}
    results = {
        "machine": machine_info(),
        "M": M,
        "n_updates": 2,
        "rows": rows,
        "crossover_K": k_cross,
        "crossover_K_from_minima": crossover_k(rows, "seconds_min"),
        "seconds_total": None,
    }
    if 1_000 in by_K and 100_000 in by_K:
        results["tree_growth_1e3_to_1e5"] = by_K[100_000]["tree_seconds"] / by_K[1_000]["tree_seconds"]
        results["dense_growth_1e3_to_1e5"] = by_K[100_000]["dense_seconds"] / by_K[1_000]["dense_seconds"]
        results["speedup_at_1e5"] = by_K[100_000]["speedup"]
        results["tree_growth_1e3_to_1e5_minima"] = by_K[100_000]["tree_seconds_min"] / by_K[1_000]["tree_seconds_min"]
        results["speedup_at_1e5_minima"] = by_K[100_000]["dense_seconds_min"] / by_K[100_000]["tree_seconds_min"]
        results["targets"] = {"tree_growth_at_most_2x": results["tree_growth_1e3_to_1e5"] <= 2.0,
                              "speedup_at_1e5_at_least_20x": results["speedup_at_1e5"] >= 20.0}

    print(machine_line(results["machine"]))
    print(f"one step = resample M={M} particles + update 2 landmarks each; time = median (min) of repeats")
    print(f"{'K':>7} {'depth':>5} {'tree [ms]':>16} {'dense [ms]':>18} {'speed-up':>9} "
          f"{'tree peak B':>12} {'dense peak B':>13} {'tree kept B':>12} {'dense kept B':>13} {'nodes':>6}")
    for r in rows:
        print(f"{r['K']:>7} {r['depth']:>5} {r['tree_seconds'] * 1e3:>7.3f} ({r['tree_seconds_min'] * 1e3:>6.3f}) "
              f"{r['dense_seconds'] * 1e3:>8.3f} ({r['dense_seconds_min'] * 1e3:>7.3f}) "
              f"{r['speedup']:>8.2f}x {r['tree_bytes_peak']:>12,} {r['dense_bytes_peak']:>13,} "
              f"{r['tree_bytes_retained']:>12,} {r['dense_bytes_retained']:>13,} {r['tree_nodes_created']:>6}")
    k_min = results["crossover_K_from_minima"]
    print(f"crossover: the tree is faster from K ≈ {k_cross:.0f} (medians), ≈ {k_min:.0f} (minima)"
          if k_cross and k_min else f"crossover: medians {k_cross}, minima {k_min}")
    if "speedup_at_1e5" in results:
        print(f"tree time growth K=10³→10⁵: {results['tree_growth_1e3_to_1e5']:.2f}x (target ≤ 2x); "
              f"dense: {results['dense_growth_1e3_to_1e5']:.0f}x; "
              f"tree speed-up at K=10⁵: {results['speedup_at_1e5']:.0f}x (target ≥ 20x); from minima: "
              f"growth {results['tree_growth_1e3_to_1e5_minima']:.2f}x, speed-up {results['speedup_at_1e5_minima']:.0f}x")
    if not args.quick:
        set_rows = [set_step_cost(K, M, repeats=repeats_for(K), min_block_seconds=0.005) for K in K_MAIN[1:]]
        results["set_step"] = print_set_steps(set_rows)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    png = args.out.with_suffix(".png")
    plot(rows, k_cross, png)
    results["seconds_total"] = time.perf_counter() - t_start
    args.out.write_text(json.dumps(results, indent=2))
    print(f"wrote {args.out} and {png} ({results['seconds_total']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
