"""Particle-filter SLAM with an occupancy grid: the grid-PF write-up's algorithm, and a Rao–Blackwellised variant.

The write-up (a course project on THOR humanoid LiDAR) runs, for every scan
``z_k`` with odometry increment ``u_k``:

1. **Propagate** every particle with the odometry and noise,
   ``x_k^{[i]} = x_{k−1}^{[i]} ⊕ (u_k + ε_k^{[i]})``
   (:func:`fastslam_edu.grid.motion.sample_odometry_motion`).
2. **Weigh** it by the *map correlation* of its scan with the current map,
   ``w^{[i]} ∝ w^{[i]} · exp(c^{[i]} / T)``, ``c^{[i]} = Σ_{b} m(cell(y_b^{[i]}))``:
   the number of beam endpoints ``y_b^{[i]}`` (scan ``z_k`` projected from
   ``x_k^{[i]}``) that land on cells the map holds occupied
   (:func:`fastslam_edu.grid.scan_matching.correlation`). The write-up's rule is ``T = 1``;
   a *temperature* ``T > 1`` tempers it (see below).
3. **Normalise** the weights, in log space
   (:func:`fastslam_edu.core.weights.normalise_log_weights`).
4. **Map**: add the scan, seen from the **best** particle (largest weight),
   to one shared log-odds grid (:class:`fastslam_edu.grid.occupancy.OccupancyGrid`).
5. **Resample** (systematic) — the write-up does it every step; here only when
   ``N_eff = 1 / Σ w² < resample_threshold · M`` (Doucet's rule), and the
   weights are reset to ``1/M`` afterwards.

With ``maps="particles"`` every particle carries **its own map** ``m^{[i]}``,
weighs its scan against it and adds its scan to it; resampling copies the
maps. This is the Rao–Blackwellised particle filter of grid SLAM (GMapping,
Grisetti et al. 2007) *without* GMapping's scan-matched proposal: the
posterior ``p(x_{1:k}, m | z_{1:k}, u_{1:k}) = p(m | x_{1:k}, z_{1:k})
p(x_{1:k} | z_{1:k}, u_{1:k})`` is sampled by paths, and the map of each path
is computed exactly (given the path) by log-odds mapping. The write-up's
shared map is the shortcut that conditions every particle on the best
particle's history instead.

The motion noise grows with the increment (:mod:`fastslam_edu.grid.motion`); ``match_iterations > 0`` moves
each particle uphill on its correlation score before it is weighed (:mod:`fastslam_edu.grid.scan_matching`).

The weight rule and its temperature
-----------------------------------
``exp(c)`` treats every endpoint on an occupied cell as multiplying the
likelihood by ``e ≈ 2.7`` — as if 180 beams were independent. They are not
(neighbouring beams hit the same wall), so the rule is overconfident: two
particles whose scores differ by 10 endpoints get a weight ratio ``e^{10} ≈ 2·10⁴``,
and the filter keeps essentially only the best particle at every step. The
temperature ``T`` divides the score, ``log w += c / T``: ``T = 1`` is the
write-up's rule, larger ``T`` keeps more hypotheses alive. Everything is done
in log space (:func:`fastslam_edu.core.weights.weights_from_log`), so ``exp(180)``
never overflows.

Implementations
---------------
:func:`run_grid_slam` is vectorised over particles (one Python loop over
scans, each step a method of :class:`GridRun`). ``benchmarks/grid_loop.py``
holds the same algorithm written with plain loops over particles and beams
(Bresenham per beam, the write-up's roulette loop for resampling): the
reference the tests check this module against. Both consume the same random
numbers — per step ``M × 3`` standard normals for the motion, then one
uniform if resampling — and give the same result.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.special import logit

from fastslam_edu.datasets.laser import LaserLog, odometry_increments
from fastslam_edu.grid.occupancy import OccupancyGrid, scan_endpoints, update_maps
from fastslam_edu.grid.rays import ray_cells_batch
from fastslam_edu.core.checks import finite_array
from fastslam_edu.core.params import Params
from fastslam_edu.core.resampling import get_resampler
from fastslam_edu.core.se2 import compose_increments, transform_points
from fastslam_edu.core.weights import effective_sample_size, normalise_log_weights
from fastslam_edu.grid.motion import sample_odometry_motion
from fastslam_edu.grid.scan_matching import correlation, correlation_weights, endpoint_cells, scan_match

__all__ = [
    "map_from_poses",
    "GridSLAMParams",
    "GridSLAMResult",
    "MAP_MODES",
    "grid_for_path",
    "add_scans",
    "odometry_of_run",
    "scan_beams",
    "ancestral_path",
    "GridRun",
    "run_grid_slam",
]

#: ``"best"``: the write-up's one map, updated from the best particle; ``"particles"``: one map per particle (RBPF).
MAP_MODES = ("best", "particles")


@dataclass(frozen=True, eq=False)
class GridSLAMParams(Params):
    """Settings of grid SLAM (units: m, rad).

    The defaults are what works on the Intel lab log (measured in
    ``benchmarks/gridslam.py``): the graded correlation (``hit_sigma = 0.1`` m),
    resampling when ``N_eff < M/2``, and scan matching (10 rounds). The
    write-up's exact algorithm is :meth:`writeup`; without scan matching use
    ``replace(match_iterations=0)``.

    Attributes
    ----------
    n_particles : int
        ``M``.
    maps : {"best", "particles"}
        One shared map updated from the best particle (the write-up), or one
        map per particle (Rao–Blackwellised, GMapping without scan matching).
    alpha_tt, alpha_tr, alpha_rt, alpha_rr, sigma_t0, sigma_theta0 : float
        Motion noise scaled to the increment (:func:`fastslam_edu.grid.motion.increment_noise_std`):
        [m/m], [m/rad], [rad/m], [rad/rad], [m], [rad].
    temperature : float
        ``T`` in ``log w += c / T`` (``T = 1``: the write-up's ``exp(c)``).
    resample_threshold : float
        Resample when ``N_eff < resample_threshold · M`` (1.0 ≈ every step, as
        the write-up; 0 never).
    resampler : str
        A name of :data:`fastslam_edu.core.resampling.RESAMPLERS` (default systematic).
    resolution : float
        Cell side [m].
    margin : float
        The grid covers the odometry path's bounding box plus this border [m]
        (:func:`grid_for_path`), unless ``extent`` is given.
    extent : tuple (xmin, xmax, ymin, ymax) or None
        Explicit grid bounds [m].
    p_hit, p_miss, l_max : float
        Inverse sensor model (``l_occ = logit(p_hit)``, ``l_free = logit(p_miss)``)
        and log-odds clipping, as in :class:`~fastslam_edu.grid.occupancy.OccupancyGrid`.
    occupied_logodds : float
        A cell counts as occupied in the correlation when ``l > occupied_logodds``
        (0: ``p > 0.5``).
    hit_sigma : float
        Width σ [m] of the graded correlation (:func:`fastslam_edu.grid.scan_matching.correlation_weights`); 0 is
        the write-up's count of endpoints on occupied cells.
    min_range, max_range : float, float or None
        Beams outside ``[min_range, max_range]`` [m] are not used (neither for
        weights nor for the map); ``None``: no upper limit.
    match_iterations, match_xy, match_theta : int, float, float
        Scan matching (:func:`fastslam_edu.grid.scan_matching.scan_match`): rounds of hill climbing and initial
        steps [m, rad]; ``match_iterations = 0`` turns it off.
    """

    n_particles: int = 30
    maps: str = "best"
    alpha_tt: float = 0.1
    alpha_tr: float = 0.05
    alpha_rt: float = 0.1
    alpha_rr: float = 0.1
    sigma_t0: float = 0.01
    sigma_theta0: float = 0.005
    temperature: float = 1.0
    resample_threshold: float = 0.5
    resampler: str = "systematic"
    resolution: float = 0.1
    margin: float = 10.0
    extent: tuple | None = None
    p_hit: float = 0.7
    p_miss: float = 0.4
    l_max: float = 5.0
    occupied_logodds: float = 0.0
    hit_sigma: float = 0.1
    min_range: float = 0.0
    max_range: float | None = None
    match_iterations: int = 10
    match_xy: float = 0.1
    match_theta: float = 0.05

    def __post_init__(self) -> None:
        if int(self.n_particles) != self.n_particles or self.n_particles < 1:
            raise ValueError(f"GridSLAMParams: n_particles must be a positive integer, got {self.n_particles}")
        if self.maps not in MAP_MODES:
            raise ValueError(f"GridSLAMParams: maps must be one of {MAP_MODES}, got {self.maps!r}")
        nonneg = ("alpha_tt", "alpha_tr", "alpha_rt", "alpha_rr", "sigma_t0", "sigma_theta0", "margin", "hit_sigma",
                  "min_range", "match_xy", "match_theta")
        for name in nonneg:
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"GridSLAMParams: {name} must be a finite number ≥ 0, got {v!r}")
        for name in ("temperature", "resolution", "l_max"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"GridSLAMParams: {name} must be a finite number > 0, got {v!r}")
        if not (0 <= self.resample_threshold <= 1):
            raise ValueError(f"GridSLAMParams: resample_threshold must lie in [0, 1], got {self.resample_threshold}")
        get_resampler(self.resampler)  # raises on an unknown name
        for name in ("p_hit", "p_miss"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0 < v < 1):
                raise ValueError(f"GridSLAMParams: {name} must lie strictly between 0 and 1, got {v!r}")
        if not (self.p_hit > 0.5 > self.p_miss):
            raise ValueError(f"GridSLAMParams: need p_hit > 0.5 > p_miss, got {self.p_hit}, {self.p_miss}")
        if self.max_range is not None and not (math.isfinite(self.max_range) and self.max_range > self.min_range):
            raise ValueError(f"GridSLAMParams: max_range must be None or > min_range, got {self.max_range}")
        if int(self.match_iterations) != self.match_iterations or self.match_iterations < 0:
            raise ValueError(f"GridSLAMParams: match_iterations must be an integer ≥ 0, got {self.match_iterations}")
        if self.extent is not None:
            e = np.asarray(self.extent, dtype=float)
            if e.shape != (4,) or not np.isfinite(e).all() or e[1] <= e[0] or e[3] <= e[2]:
                raise ValueError(f"GridSLAMParams: extent must be (xmin, xmax, ymin, ymax) with max > min, got {self.extent}")

    @property
    def l_occ(self) -> float:
        return float(logit(self.p_hit))

    @property
    def l_free(self) -> float:
        return float(logit(self.p_miss))

    @classmethod
    def writeup(cls, **changes) -> GridSLAMParams:
        """The write-up's algorithm exactly: ``w ∝ exp(c)`` with the 0/1 map, resampling every step, no matching.

        ``hit_sigma = 0`` (an endpoint counts only in its own cell),
        ``temperature = 1``, ``resample_threshold = 1`` (``N_eff < M``, as the
        write-up computes it: every step whose weights are not all equal, and
        with all-equal weights whenever rounding puts :math:`1/\\sum w^2` just
        below M, as it does for some M, e.g. 5, 6 and 10, but not 4 or 30),
        ``match_iterations = 0``.
        """
        base = dict(hit_sigma=0.0, temperature=1.0, resample_threshold=1.0, match_iterations=0)
        base.update(changes)
        return cls(**base)


@dataclass
class GridSLAMResult:
    """What :func:`run_grid_slam` returns.

    Attributes
    ----------
    t : ndarray (N,)
        Scan times [s], as in the log.
    poses : ndarray (N, 3)
        The best particle's pose at each scan — the pose the shared map was
        built from (``maps="best"``).
    path : ndarray (N, 3)
        The history of the final best particle (follow its ancestors back
        through the resampling steps, :func:`ancestral_path`): a consistent
        path, the estimate of the Rao–Blackwellised filter.
    estimate : ndarray (N, 3)
        The filter's trajectory estimate: ``poses`` for ``maps="best"``,
        ``path`` for ``maps="particles"``.
    odometry : ndarray (N, 3)
        Dead reckoning from the same start and increments.
    grid : OccupancyGrid
        The shared map, or the final best particle's map.
    maps : ndarray (M, H, W) float32 or None
        Every particle's log-odds map at the end (``maps="particles"`` only).
    particles : ndarray (M, 3)
        Final particle poses.
    log_weights : ndarray (M,)
        Final normalised log-weights.
    n_eff : ndarray (N,)
        ``N_eff`` after weighing each scan (before resampling); ``M`` at scan 0.
    resampled : ndarray of bool (N,)
    best_score : ndarray (N,)
        Correlation ``c`` of the best particle (0 at scan 0).
    beams_used : ndarray of int (N,)
    params : GridSLAMParams
    filter_seconds : float
    """

    t: np.ndarray
    poses: np.ndarray
    path: np.ndarray
    odometry: np.ndarray
    grid: OccupancyGrid
    maps: np.ndarray | None
    particles: np.ndarray
    log_weights: np.ndarray
    n_eff: np.ndarray
    resampled: np.ndarray
    best_score: np.ndarray
    beams_used: np.ndarray
    params: GridSLAMParams
    filter_seconds: float = 0.0
    history: dict = field(default_factory=dict, repr=False)

    @property
    def estimate(self) -> np.ndarray:
        return self.poses if self.params.maps == "best" else self.path


# --------------------------------------------------------------------------- the map of a run


def grid_for_path(path, params: GridSLAMParams) -> OccupancyGrid:
    """An empty grid for a run: ``params.extent``, else the bounding box of ``path`` plus ``params.margin``.

    Parameters
    ----------
    path : array_like, shape (N, 3) or (N, 2)
        Usually the dead-reckoning path (the filter's path stays near it
        unless odometry is very poor — then give ``extent``).
    """
    if params.extent is not None:
        extent = tuple(float(v) for v in params.extent)
        margin = 0.0
    else:
        p = np.asarray(path, dtype=float)
        if p.ndim != 2 or p.shape[1] < 2 or not np.isfinite(p[:, :2]).all():
            raise ValueError(f"grid_for_path: path must be a finite (N, 2|3) array, got shape {p.shape}")
        extent, margin = p[:, :2], params.margin
    return OccupancyGrid.around(
        extent, params.resolution, margin=margin, p_hit=params.p_hit, p_miss=params.p_miss, l_max=params.l_max
    )


def map_from_poses(log: LaserLog, poses, params: GridSLAMParams, *, grid: OccupancyGrid | None = None,
                   every: int = 1, n_scans: int | None = None) -> OccupancyGrid:
    """The log-odds map of a log's scans seen from given poses (no filter): odometry's map, or the truth's.

    Same cells and inverse sensor model as the filter's map
    (:func:`grid_for_path` on the log's odometry,
    unless ``grid`` is given), same beams (``params.min_range``, ``params.max_range``).

    Parameters
    ----------
    log : LaserLog
    poses : array_like, shape (N, 3)
        One pose per scan (e.g. ``log.odometry``, or a simulated truth).
    params : GridSLAMParams
    grid : OccupancyGrid, optional
        An empty grid to fill (copied); default the filter's grid for this log.
    every : int
        Use scans ``0, every, 2·every, …``.
    n_scans : int, optional
        Use only the first ``n_scans`` scans.

    Returns
    -------
    OccupancyGrid
    """
    p = finite_array("poses", poses, "map_from_poses")
    if p.shape != (len(log), 3):
        raise ValueError(f"map_from_poses: poses must have shape ({len(log)}, 3), got {p.shape}")
    if int(every) != every or every < 1:
        raise ValueError(f"map_from_poses: every must be a positive integer, got {every}")
    base = log.odometry if log.odometry is not None else log.poses
    if n_scans is not None and (int(n_scans) != n_scans or n_scans < 1):
        raise ValueError(f"map_from_poses: n_scans must be a positive integer, got {n_scans}")
    n = len(log) if n_scans is None else min(int(n_scans), len(log))
    g = grid_for_path(base, params) if grid is None else grid.copy()
    for k in range(0, n, int(every)):  # one ray-traced update per scan
        r, a = log.beams(k, min_range=params.min_range, max_range=params.max_range)
        if len(r):
            g.update(p[k], scan_endpoints(p[k], r, a))
    return g


# --------------------------------------------------------------------------- map updates


def add_scans(maps: np.ndarray, grid: OccupancyGrid, poses, ranges, angles, params: GridSLAMParams,
              sensor_offset=(0.0, 0.0)) -> None:
    """Add one scan to every particle's own map, each seen from its own pose (in place).

    Beams of particle ``m`` run from its sensor cell (``x^{[m]} ⊕ o``) to the
    cells of its endpoints (:func:`ray_cells_batch`), and map ``m`` gets the
    log-odds update of :meth:`OccupancyGrid.update` (:func:`update_maps`).

    Parameters
    ----------
    maps : ndarray, shape (M, H, W)
        Log-odds maps on the geometry of ``grid``.
    grid : OccupancyGrid
        Cell geometry (its own log-odds are not touched).
    poses : ndarray, shape (M, 3)
    ranges, angles : ndarray, shape (B,)
    params : GridSLAMParams
        ``l_occ``, ``l_free``, ``l_max``.
    sensor_offset : (dx, dy)
    """
    ends = scan_endpoints(poses, ranges, angles, sensor_offset)  # (M, B, 2)
    sensor = transform_points(poses, np.asarray(sensor_offset, dtype=float))  # (M, 2)
    free, hit = ray_cells_batch(np.stack(endpoint_cells(grid, sensor), -1), np.stack(endpoint_cells(grid, ends), -1))
    update_maps(maps, free, hit, params.l_occ, params.l_free, params.l_max)


# --------------------------------------------------------------------------- the filter


def odometry_of_run(log: LaserLog, increments, x0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The checked odometry a run starts from: ``(u (N, 3), x0 (3,), path (N, 3))``.

    ``u_k`` the increment of scan ``k`` (row 0 unused; default
    :func:`fastslam_edu.datasets.laser.odometry_increments`), ``x0`` the start pose (default
    ``log.poses[0]``) and the odometry path ``x_k = x_{k−1} ⊕ u_k`` from it.
    """
    if not isinstance(log, LaserLog):
        raise ValueError(f"grid SLAM needs a LaserLog, got {type(log).__name__}")
    n = len(log)
    if n < 2:
        raise ValueError(f"{log.source}: grid SLAM needs at least 2 scans, got {n}")
    u = odometry_increments(log) if increments is None else np.asarray(increments, dtype=float)
    if u.shape != (n, 3):
        raise ValueError(f"increments must have shape ({n}, 3) (one per scan, row 0 unused), got {u.shape}")
    if not np.isfinite(u).all():
        k = int(np.argwhere(~np.isfinite(u))[0, 0])
        raise ValueError(f"{log.source}: odometry increment of scan {k} is not finite: {u[k].tolist()}")
    x0 = np.asarray(log.poses[0] if x0 is None else x0, dtype=float)
    if x0.shape != (3,) or not np.isfinite(x0).all():
        raise ValueError(f"x0 must be a finite pose (x, y, θ), got {x0}")
    return u, x0, compose_increments(x0, u[1:])


def scan_beams(log: LaserLog, k: int, params: GridSLAMParams) -> tuple[np.ndarray, np.ndarray]:
    """``(ranges, angles)`` of scan ``k`` that the filter uses: ranges in ``[min_range, max_range]``."""
    return log.beams(k, min_range=params.min_range, max_range=params.max_range)


def ancestral_path(history: np.ndarray, parents: np.ndarray, last: int) -> np.ndarray:
    """Follow particle ``last`` back through the resampling steps.

    Parameters
    ----------
    history : ndarray, shape (N, M, 3)
        Particle poses after weighing scan ``k`` (before resampling).
    parents : ndarray of int, shape (N, M)
        ``parents[k, i]``: the particle of ``history[k − 1]`` that particle
        ``i`` of scan ``k`` was propagated from (row 0 unused).
    last : int
        Particle index at the last scan.

    Returns
    -------
    ndarray, shape (N, 3)
    """
    n = history.shape[0]
    path = np.empty((n, 3))
    i = int(last)
    for k in range(n - 1, -1, -1):  # a loop over time, not over particles
        path[k] = history[k, i]
        i = int(parents[k, i])
    return path


@dataclass
class GridRun:
    """The state of :func:`run_grid_slam` between scans, and what it records (arrays over the N scans)."""

    params: GridSLAMParams
    grid: OccupancyGrid
    offset: np.ndarray  # the laser in the robot frame (dx, dy) [m]
    kernel: tuple | None
    particles: np.ndarray  # (M, 3)
    logw: np.ndarray  # (M,) normalised log weights
    maps: np.ndarray | None  # (M, H, W) float32, maps="particles" only
    parent_idx: np.ndarray  # (M,) the particle of the previous scan each one comes from
    hist: np.ndarray  # (N, M, 3) poses after weighing scan k
    parents: np.ndarray  # (N, M)
    poses: np.ndarray  # (N, 3) the best particle's pose
    n_eff: np.ndarray  # (N,)
    resampled: np.ndarray  # (N,) bool
    best_score: np.ndarray  # (N,)
    beams_used: np.ndarray  # (N,)

    @classmethod
    def start(cls, params: GridSLAMParams, grid: OccupancyGrid, x0, first_scan, n: int, sensor_offset):
        """All particles at ``x0``, weights 1/M, the first scan in the map(s) (``first_scan`` = ranges, angles)."""
        m, off = params.n_particles, np.asarray(sensor_offset, dtype=float)
        r, a = first_scan
        grid.update(x0, scan_endpoints(x0, r, a, off), sensor_offset=off)
        run = cls(params=params, grid=grid, offset=off,
                  kernel=correlation_weights(params.hit_sigma, grid.resolution) if params.hit_sigma > 0 else None,
                  particles=np.tile(x0, (m, 1)), logw=np.full(m, -math.log(m)),
                  maps=np.repeat(grid.log_odds.astype(np.float32)[None], m, axis=0) if params.maps == "particles"
                  else None, parent_idx=np.arange(m), hist=np.empty((n, m, 3)),
                  parents=np.zeros((n, m), dtype=np.int64), poses=np.empty((n, 3)), n_eff=np.empty(n),
                  resampled=np.zeros(n, dtype=bool), best_score=np.zeros(n), beams_used=np.zeros(n, dtype=np.int64))
        run.hist[0], run.poses[0], run.n_eff[0], run.beams_used[0] = run.particles, x0, m, len(r)
        return run

    def current_maps(self) -> np.ndarray:
        """What particles are weighed against: each one's map, or the shared one."""
        return self.maps if self.maps is not None else self.grid.log_odds

    def weigh(self, k: int, u, scan, rng: np.random.Generator) -> np.ndarray:
        """Steps 1–3 at scan ``k``: propagate (and scan-match), weigh by map correlation, normalise; returns w (M,)."""
        r, a = scan
        self.particles = sample_odometry_motion(self.particles, u, self.params, rng)
        if self.params.match_iterations:  # optional: climb to the scan's best fit
            self.particles = scan_match(self.particles, self.current_maps(), self.grid, r, a, self.params, self.offset)
        rows, cols = endpoint_cells(self.grid, scan_endpoints(self.particles, r, a, self.offset))
        scores = correlation(self.current_maps(), rows, cols, self.params.occupied_logodds, self.kernel)
        self.logw = normalise_log_weights(self.logw + scores / self.params.temperature)
        w = np.exp(self.logw)
        best = int(np.argmax(self.logw))
        self.hist[k], self.parents[k] = self.particles, self.parent_idx
        self.poses[k], self.best_score[k], self.beams_used[k] = self.particles[best], scores[best], len(r)
        self.n_eff[k] = effective_sample_size(w)
        return w

    def update_maps(self, scan) -> None:
        """Step 4: the scan into every particle's map, or into the shared map from the best particle."""
        r, a = scan
        if not len(r):
            return
        if self.maps is not None:
            add_scans(self.maps, self.grid, self.particles, r, a, self.params, self.offset)
        else:
            best = self.particles[int(np.argmax(self.logw))]
            self.grid.update(best, scan_endpoints(best, r, a, self.offset), sensor_offset=self.offset)

    def resample_if_needed(self, k: int, w, rng: np.random.Generator) -> None:
        """Step 5: resample when ``N_eff < resample_threshold · M``; weights back to 1/M."""
        m = len(w)
        self.parent_idx = np.arange(m)
        if self.n_eff[k] < self.params.resample_threshold * m:
            idx = get_resampler(self.params.resampler)(w, rng)
            self.particles, self.parent_idx = self.particles[idx], idx
            if self.maps is not None:
                self.maps = self.maps[idx]
            self.logw = np.full(m, -math.log(m))
            self.resampled[k] = True

    def result(self, t, odometry, seconds: float) -> GridSLAMResult:
        """The run's record, with the final best particle's ancestral path (and map)."""
        best = int(np.argmax(self.logw))
        path = ancestral_path(self.hist, self.parents, self.parent_idx[best])
        grid = self.grid
        if self.maps is not None:
            grid = OccupancyGrid(grid.resolution, grid.origin, grid.shape, grid.l_occ, grid.l_free, grid.l_max,
                                 self.maps[best].astype(float))
        return GridSLAMResult(
            t=np.asarray(t, dtype=float), poses=self.poses, path=path, odometry=odometry, grid=grid, maps=self.maps,
            particles=self.particles, log_weights=self.logw, n_eff=self.n_eff, resampled=self.resampled,
            best_score=self.best_score, beams_used=self.beams_used, params=self.params, filter_seconds=seconds,
            history={"particles": self.hist, "parents": self.parents},
        )


def run_grid_slam(
    log: LaserLog,
    params: GridSLAMParams,
    rng: np.random.Generator,
    *,
    increments=None,
    x0=None,
    sensor_offset=(0.0, 0.0),
    progress: bool = False,
    n_scans: int | None = None,
) -> GridSLAMResult:
    """Grid SLAM over a laser log, vectorised over particles: steps 1–5 of the module docstring for each scan.

    Parameters
    ----------
    log : LaserLog
        Scans (``ranges``, ``angles``, ``t``).
    params : GridSLAMParams
    rng : numpy.random.Generator
    increments : array_like, shape (N, 3), optional
        Odometry increment ``u_k`` of each scan (row 0 unused); default
        :func:`fastslam_edu.datasets.laser.odometry_increments`.
    x0 : array_like, shape (3,), optional
        Start pose (default ``log.poses[0]``).
    sensor_offset : (dx, dy)
        Laser position in the robot frame [m].
    progress : bool
        Show a tqdm progress bar.
    n_scans : int, optional
        Use only the first ``n_scans`` scans.

    Returns
    -------
    GridSLAMResult
    """
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"run_grid_slam: rng must be a numpy.random.Generator, got {type(rng).__name__}")
    u, x0, odo = odometry_of_run(log, increments, x0)
    n = len(log) if n_scans is None else min(int(n_scans), len(log))
    t_start = time.perf_counter()
    run = GridRun.start(params, grid_for_path(odo[:n], params), x0, scan_beams(log, 0, params), n, sensor_offset)
    steps = range(1, n)
    if progress:
        from tqdm.auto import tqdm

        steps = tqdm(steps, desc="grid SLAM", unit="scan", leave=False)
    for k in steps:
        scan = scan_beams(log, k, params)
        w = run.weigh(k, u[k], scan, rng)
        run.update_maps(scan)
        run.resample_if_needed(k, w, rng)
    return run.result(log.t[:n], odo[:n], time.perf_counter() - t_start)
