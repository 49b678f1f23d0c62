"""The grid-SLAM filter of :func:`fastslam_edu.grid.gridslam.run_grid_slam`, written with plain loops.

Read next to the grid-PF write-up: for each particle, draw three normals and compose; for each beam,
compute the endpoint with ``math.cos`` and look its cell up; map updates cast each beam with
:func:`fastslam_edu.grid.rays.bresenham`; resampling is the write-up's roulette loop with one uniform
``r ~ U(0, 1/M)``. It consumes the same random numbers in the same order as the vectorised filter, so the
same seed gives the same result: the tests check the package against it, and ``benchmarks/gridslam.py``
times the two side by side. Only the systematic resampler, and no scan matching.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.grid.gridslam import (GridSLAMParams, GridSLAMResult, ancestral_path, grid_for_path, odometry_of_run,
                                        scan_beams)
from fastslam_edu.grid.motion import increment_noise_std
from fastslam_edu.grid.scan_matching import correlation_weights
from fastslam_edu.grid.occupancy import OccupancyGrid
from fastslam_edu.grid.rays import bresenham

__all__ = ["run_grid_slam_loop"]


@dataclass
class LoopGrid:
    """The grid's geometry, the laser's offset and the map parameters, as plain numbers."""

    params: GridSLAMParams
    origin: tuple
    resolution: float
    shape: tuple
    offset: tuple

    def cell(self, x, y):
        """(row, col) of the cell holding the point (x, y)."""
        return math.floor((y - self.origin[1]) / self.resolution), math.floor((x - self.origin[0]) / self.resolution)

    def inside(self, i, j):
        return 0 <= i < self.shape[0] and 0 <= j < self.shape[1]

    def endpoints(self, pose, r, a):
        """The laser's position and each beam's endpoint, seen from ``pose``."""
        x, y, th = pose
        ox, oy = self.offset
        sx, sy = x + math.cos(th) * ox - math.sin(th) * oy, y + math.sin(th) * ox + math.cos(th) * oy
        return (sx, sy), [(sx + rb * math.cos(th + ab), sy + rb * math.sin(th + ab)) for rb, ab in zip(r, a)]

    def add_scan(self, lo, pose, r, a):
        """Log-odds update of map ``lo`` (list of rows): cells a beam crosses are freer, endpoints more occupied."""
        p = self.params
        (sx, sy), ends = self.endpoints(pose, r, a)
        r0, c0 = self.cell(sx, sy)
        free, hits = set(), set()
        for ex, ey in ends:
            r1, c1 = self.cell(ex, ey)
            hits.add((r1, c1))
            free.update((int(i), int(j)) for i, j in bresenham(r0, c0, r1, c1)[:-1])
        for (i, j), change in [(c, p.l_free) for c in free - hits] + [(c, p.l_occ) for c in hits]:
            if self.inside(i, j):
                lo[i][j] = min(max(lo[i][j] + change, -p.l_max), p.l_max)

    def score(self, lo, pose, r, a, kernel):
        """Map correlation: each endpoint counts the largest kernel weight of an occupied cell around it."""
        c = 0.0
        for ex, ey in self.endpoints(pose, r, a)[1]:
            ci, cj = self.cell(ex, ey)
            best = 0.0
            for (di, dj), g in kernel:
                ni, nj = ci + di, cj + dj
                if self.inside(ni, nj) and lo[ni][nj] > self.params.occupied_logodds and g > best:
                    best = g
            c += best
        return c


def propagate(pose, u, sigma, rng):
    """One particle moved by the odometry increment ``u`` plus noise (three normals, in the robot frame)."""
    e = rng.standard_normal(3)
    du = [u[j] + sigma[j] * e[j] for j in range(3)]
    x, y, th = pose
    return (x + math.cos(th) * du[0] - math.sin(th) * du[1], y + math.sin(th) * du[0] + math.cos(th) * du[1],
            wrap_angle(th + du[2]))


def normalise(logw):
    """Log weights normalised so that their exponentials sum to 1."""
    top = max(logw)
    total = sum(math.exp(v - top) for v in logw)
    return [v - top - math.log(total) for v in logw]


def roulette_one_uniform(w, rng):
    """The write-up's wheel: pointers (j + U)/M, one uniform; particle i owns [c_{i-1}, c_i)."""
    m, total = len(w), sum(w)
    uniform = rng.random()
    i, cum, chosen = 0, w[0] / total, []
    for j in range(m):
        pointer = (j + uniform) / m
        while pointer >= cum and i < m - 1:
            i += 1
            cum += w[i] / total
        chosen.append(i)
    return chosen


def run_grid_slam_loop(log, params: GridSLAMParams, rng: np.random.Generator, *, increments=None, x0=None,
                       sensor_offset=(0.0, 0.0), n_scans: int | None = None) -> GridSLAMResult:
    """The same algorithm and random numbers as :func:`fastslam_edu.grid.gridslam.run_grid_slam`, in loops."""
    if params.resampler != "systematic" or params.match_iterations:
        raise ValueError("run_grid_slam_loop: only resampler='systematic' and match_iterations=0 are implemented")
    u, x0, odo = odometry_of_run(log, increments, x0)
    n = len(log) if n_scans is None else min(int(n_scans), len(log))
    m = params.n_particles
    template = grid_for_path(odo[:n], params)
    g = LoopGrid(params, tuple(template.origin), template.resolution, template.shape,
                 tuple(float(v) for v in sensor_offset))
    offsets, weights = correlation_weights(params.hit_sigma, g.resolution)
    kernel = list(zip(offsets.tolist(), weights.tolist()))
    per_particle = params.maps == "particles"

    t_start = time.perf_counter()
    shared = [[0.0] * g.shape[1] for _ in range(g.shape[0])]
    g.add_scan(shared, tuple(x0), *scan_beams(log, 0, params))
    maps = [[row[:] for row in shared] for _ in range(m)] if per_particle else None
    particles = [tuple(float(v) for v in x0) for _ in range(m)]
    logw = [-math.log(m)] * m
    hist, parents, parent_of = [list(particles)], [list(range(m))], list(range(m))
    poses, n_eff, resampled, best_score = np.empty((n, 3)), np.full(n, float(m)), np.zeros(n, bool), np.zeros(n)
    poses[0] = x0
    for k in range(1, n):
        r, a = (list(v) for v in scan_beams(log, k, params))
        sigma = increment_noise_std(u[k], params)
        particles = [propagate(p, u[k], sigma, rng) for p in particles]  # 1. propagate
        scores = [g.score(maps[i] if per_particle else shared, particles[i], r, a, kernel) for i in range(m)]  # 2.
        logw = normalise([lw + c / params.temperature for lw, c in zip(logw, scores)])  # 3. normalise
        w = [math.exp(v) for v in logw]
        best = max(range(m), key=lambda i: logw[i])
        poses[k], best_score[k] = particles[best], scores[best]
        hist.append(list(particles))
        parents.append(parent_of)
        parent_of = list(range(m))
        n_eff[k] = 1.0 / sum(v * v for v in w)
        if r:  # 4. map(s)
            for i in range(m) if per_particle else [best]:
                g.add_scan(maps[i] if per_particle else shared, particles[i], r, a)
        if n_eff[k] < params.resample_threshold * m:  # 5. resample
            parent_of = roulette_one_uniform(w, rng)
            particles = [particles[i] for i in parent_of]
            if per_particle:
                maps = [[row[:] for row in maps[i]] for i in parent_of]
            logw = [-math.log(m)] * m
            resampled[k] = True
    seconds = time.perf_counter() - t_start
    best = max(range(m), key=lambda i: logw[i])
    lo = np.array(maps[best] if per_particle else shared, dtype=float)
    return GridSLAMResult(
        t=np.asarray(log.t[:n], dtype=float), poses=poses,
        path=ancestral_path(np.array(hist), np.array(parents), parent_of[best]), odometry=odo[:n],
        grid=OccupancyGrid(g.resolution, template.origin, g.shape, template.l_occ, template.l_free, template.l_max, lo),
        maps=np.array(maps, dtype=np.float32) if per_particle else None, particles=np.array(particles),
        log_weights=np.array(logw), n_eff=n_eff, resampled=resampled, best_score=best_score,
        beams_used=np.array([len(scan_beams(log, k, params)[0]) for k in range(n)]), params=params,
        filter_seconds=seconds,
    )
