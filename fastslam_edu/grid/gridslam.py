"""Particle-filter SLAM with an occupancy grid: the grid-PF write-up's algorithm, and a Rao–Blackwellised variant.

The write-up (a course project on THOR humanoid LiDAR) runs, for every scan
``z_k`` with odometry increment ``u_k``:

1. **Propagate** every particle with the odometry and noise,
   ``x_k^{[i]} = x_{k−1}^{[i]} ⊕ (u_k + ε_k^{[i]})`` (:func:`sample_motion`).
2. **Weigh** it by the *map correlation* of its scan with the current map,
   ``w^{[i]} ∝ w^{[i]} · exp(c^{[i]} / T)``, ``c^{[i]} = Σ_{b} m(cell(y_b^{[i]}))``:
   the number of beam endpoints ``y_b^{[i]}`` (scan ``z_k`` projected from
   ``x_k^{[i]}``) that land on cells the map holds occupied
   (:func:`correlation`). The write-up's rule is ``T = 1``; a *temperature*
   ``T > 1`` tempers it (see below).
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

Motion noise, scaled to the increment
-------------------------------------
With ``u_k = (Δx, Δy, Δθ)`` in the robot frame and ``d = ‖(Δx, Δy)‖``, the
noise is ``ε ~ N(0, diag(σ_t², σ_t², σ_θ²))`` with (:func:`increment_noise_std`)::

    σ_t = α_tt d + α_tr |Δθ| + σ_t0        [m]
    σ_θ = α_rt d + α_rr |Δθ| + σ_θ0        [rad]

so a robot standing still gets only the floors ``σ_t0, σ_θ0``, and the spread
grows with what odometry measured (the same four-parameter shape as
GMapping's ``srr, srt, str, stt`` and Thrun et al.'s ``α₁…α₄``). Noise is added
to the increment *before* composition, i.e. in the robot frame of ``x_{k−1}``.

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

Optional scan matching
----------------------
``match_iterations > 0`` moves each particle, after propagation, uphill on
its correlation score (:func:`scan_match`, a vectorised version of GMapping's
hill-climbing matcher: try ±``match_xy`` m and ±``match_theta`` rad, halve
the steps when nothing improves). This is the first half of what GMapping's
improved proposal does (it then samples around the matched pose) and shows
what scan matching adds.

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
from fastslam_edu.grid.occupancy import (OccupancyGrid, cell_values, ray_cells_batch, scan_endpoints,
                                         update_maps)
from fastslam_edu.core.checks import finite_array
from fastslam_edu.core.params import Params
from fastslam_edu.core.resampling import get_resampler
from fastslam_edu.core.se2 import compose, compose_increments, transform_points
from fastslam_edu.core.weights import effective_sample_size, normalise_log_weights

__all__ = [
    "map_from_poses",
    "GridSLAMParams",
    "GridSLAMResult",
    "MAP_MODES",
    "increment_noise_std",
    "sample_motion",
    "grid_for_path",
    "endpoint_cells",
    "correlation_kernel",
    "correlation",
    "add_scans",
    "scan_match",
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
        Motion noise scaled to the increment (:func:`increment_noise_std`):
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
        Width σ [m] of the graded correlation (:func:`correlation_kernel`); 0 is
        the write-up's count of endpoints on occupied cells.
    min_range, max_range : float, float or None
        Beams outside ``[min_range, max_range]`` [m] are not used (neither for
        weights nor for the map); ``None``: no upper limit.
    match_iterations, match_xy, match_theta : int, float, float
        Scan matching (:func:`scan_match`): rounds of hill climbing and initial
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


# --------------------------------------------------------------------------- motion


def increment_noise_std(u, params: GridSLAMParams) -> np.ndarray:
    """Standard deviations ``(σ_t, σ_t, σ_θ)`` of the noise added to an increment.

    ``σ_t = α_tt d + α_tr |Δθ| + σ_t0``, ``σ_θ = α_rt d + α_rr |Δθ| + σ_θ0`` with
    ``d = ‖(Δx, Δy)‖``.

    Parameters
    ----------
    u : array_like, shape (..., 3)
        Increments ``(Δx, Δy, Δθ)`` [m, m, rad] in the robot frame.
    params : GridSLAMParams

    Returns
    -------
    ndarray, shape (..., 3)
        ``(σ_t, σ_t, σ_θ)`` [m, m, rad].
    """
    u = np.asarray(u, dtype=float)
    if u.shape[-1:] != (3,) or not np.isfinite(u).all():
        raise ValueError(f"increment_noise_std: u must be finite with shape (..., 3), got shape {u.shape}")
    d = np.hypot(u[..., 0], u[..., 1])
    rot = np.abs(u[..., 2])
    st = params.alpha_tt * d + params.alpha_tr * rot + params.sigma_t0
    sr = params.alpha_rt * d + params.alpha_rr * rot + params.sigma_theta0
    return np.stack([st, st, sr], axis=-1)


def sample_motion(particles, u, params: GridSLAMParams, rng: np.random.Generator) -> np.ndarray:
    """Propagate all particles with one noisy increment: ``x_k^{[i]} = x_{k−1}^{[i]} ⊕ (u_k + ε^{[i]})``.

    ``ε^{[i]} = σ ⊙ n^{[i]}``, ``n^{[i]} ~ N(0, I₃)`` with ``σ`` from
    :func:`increment_noise_std`. Draws exactly ``rng.standard_normal((M, 3))``.

    Parameters
    ----------
    particles : ndarray, shape (M, 3)
    u : array_like, shape (3,)
    params : GridSLAMParams
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (M, 3)
    """
    particles = np.asarray(particles, dtype=float)
    if particles.ndim != 2 or particles.shape[1] != 3:
        raise ValueError(f"sample_motion: particles must have shape (M, 3), got {particles.shape}")
    sigma = increment_noise_std(u, params)
    noise = rng.standard_normal(particles.shape) * sigma
    return compose(particles, np.asarray(u, dtype=float) + noise)


# --------------------------------------------------------------------------- map geometry and weights


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


def endpoint_cells(grid: OccupancyGrid, points) -> tuple[np.ndarray, np.ndarray]:
    """Cells ``(row, col)`` of world points: ``row = ⌊(y − y_0)/res⌋``, ``col = ⌊(x − x_0)/res⌋``.

    Not clipped: points outside the grid get indices outside ``[0, H) × [0, W)``.

    Parameters
    ----------
    grid : OccupancyGrid
        Cell geometry.
    points : array_like, shape (..., 2)
        World points [m].

    Returns
    -------
    rows, cols : ndarray of int64, shape (...)
    """
    p = np.asarray(points, dtype=float)
    col = np.floor((p[..., 0] - grid.origin[0]) / grid.resolution).astype(np.int64)
    row = np.floor((p[..., 1] - grid.origin[1]) / grid.resolution).astype(np.int64)
    return row, col


def correlation_kernel(hit_sigma: float, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """Neighbour offsets and weights ``g(δ) = exp(−‖δ‖² res² / (2 σ²))`` of the graded correlation.

    Offsets ``δ = (Δrow, Δcol)`` cover the disc ``‖δ‖ ≤ r = ⌈2σ / res⌉`` cells;
    ``σ = 0`` gives the single offset ``(0, 0)`` with weight 1 (the write-up's rule).

    Returns
    -------
    offsets : ndarray of int64, shape (K, 2)
        ``(0, 0)`` first.
    weights : ndarray, shape (K,)
        Rounded to multiples of 1/256, so that a scan's score is the same
        whatever order its beams are summed in (vectorised or loop).
    """
    if not (math.isfinite(hit_sigma) and hit_sigma >= 0):
        raise ValueError(f"correlation_kernel: hit_sigma must be ≥ 0, got {hit_sigma}")
    r = int(math.ceil(2.0 * hit_sigma / resolution - 1e-9)) if hit_sigma > 0 else 0
    d = np.arange(-r, r + 1)
    offsets = np.array([(a, b) for a in d for b in d if a * a + b * b <= r * r], dtype=np.int64).reshape(-1, 2)
    offsets = offsets[np.argsort((offsets**2).sum(axis=1), kind="stable")]  # (0, 0) first
    if r == 0:
        return offsets, np.ones(1)
    weights = np.exp(-(offsets**2).sum(axis=1) * resolution**2 / (2.0 * hit_sigma**2))
    # multiples of 1/256: sums of them are exact in floating point, in any order
    return offsets, np.round(weights * 256.0) / 256.0


def correlation(log_odds, rows, cols, threshold: float = 0.0, kernel=None) -> np.ndarray:
    """Map correlation of each particle's scan: endpoints on occupied cells.

    The write-up's score (``kernel=None``) counts the endpoints whose cell the
    map holds occupied::

        c^{[i]} = Σ_b o(cell(y_b^{[i]})),   o(cell) = 1[l(cell) > threshold]

    With a kernel (:func:`correlation_kernel`) an endpoint near an occupied
    cell earns part of the point: ``c^{[i]} = Σ_b max_δ g(δ) o(cell(y_b^{[i]}) + δ)``
    — a cheap stand-in for the likelihood field of Thrun et al. (ch. 6.4),
    which makes the score a smooth function of the pose instead of a
    step function at every cell border. Cells outside the grid count 0.

    Parameters
    ----------
    log_odds : ndarray, shape (H, W) or (M, H, W)
        One shared map, or one map per particle (particle ``i`` is scored
        against ``log_odds[i]``).
    rows, cols : ndarray of int, shape (M, ...)
        Endpoint cells (:func:`endpoint_cells`); the last axis (beams) is summed.
    threshold : float
        Log-odds above which a cell is occupied (0: ``p > 0.5``).
    kernel : (offsets (K, 2), weights (K,)), optional

    Returns
    -------
    ndarray, shape (M, ...) without the last axis
        Integer-valued without a kernel.
    """
    lo = np.asarray(log_odds)
    if lo.ndim not in (2, 3):
        raise ValueError(f"correlation: log_odds must be (H, W) or (M, H, W), got shape {lo.shape}")
    rows, cols = np.asarray(rows), np.asarray(cols)
    if kernel is None:
        return (cell_values(lo, rows, cols, outside=-np.inf) > threshold).sum(axis=-1)
    offsets, weights = (np.asarray(k) for k in kernel)
    occupied = cell_values(lo, rows[..., None] + offsets[:, 0], cols[..., None] + offsets[:, 1], outside=-np.inf) > threshold
    return (occupied * weights).max(axis=-1).sum(axis=-1)


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


# --------------------------------------------------------------------------- scan matching


def hit_field(log_odds, threshold: float, kernel, window) -> np.ndarray:
    """The graded occupancy ``f(cell) = max_δ g(δ) o(cell + δ)`` on a window of cells.

    Precomputing ``f`` once per scan makes a candidate pose cost one lookup
    per beam (``Σ_b f(cell(y_b))``) instead of ``K`` — what scan matching
    needs, since it scores many candidate poses per particle. ``Σ_b f`` equals
    :func:`correlation` with the same kernel for endpoints inside the window.

    Parameters
    ----------
    log_odds : ndarray, shape (H, W) or (M, H, W)
        One map, or one per particle.
    threshold : float
        ``o(cell) = 1[l > threshold]``; cells outside the grid have ``o = 0``.
    kernel : (offsets (K, 2), weights (K,)) or None
        :func:`correlation_kernel` (None: ``f = o``).
    window : (r0, r1, c0, c1)
        Rows ``r0 … r1 − 1`` and columns ``c0 … c1 − 1`` (may extend beyond the grid).

    Returns
    -------
    ndarray, shape (r1 − r0, c1 − c0) or (M, r1 − r0, c1 − c0)
    """
    r0, r1, c0, c1 = (int(v) for v in window)
    offsets, weights = (np.zeros((1, 2), dtype=np.int64), np.ones(1)) if kernel is None else kernel
    rad = int(np.abs(offsets).max())
    lo = np.asarray(log_odds)
    h, w = lo.shape[-2:]
    lead = lo.shape[:-2]
    occ = np.zeros(lead + (r1 - r0 + 2 * rad, c1 - c0 + 2 * rad))  # the window plus a border of rad cells
    gr0, gr1 = max(r0 - rad, 0), min(r1 + rad, h)
    gc0, gc1 = max(c0 - rad, 0), min(c1 + rad, w)
    if gr1 > gr0 and gc1 > gc0:
        occ[..., gr0 - (r0 - rad): gr1 - (r0 - rad), gc0 - (c0 - rad): gc1 - (c0 - rad)] = (
            lo[..., gr0:gr1, gc0:gc1] > threshold
        )
    field = np.zeros(lead + (r1 - r0, c1 - c0))
    for (dr, dc), g in zip(offsets.tolist(), weights.tolist()):  # K shifts of the window, not a loop over cells
        np.maximum(field, g * occ[..., rad + dr: rad + dr + r1 - r0, rad + dc: rad + dc + c1 - c0], out=field)
    return field


def _field_score(field, r0: int, c0: int, grid: OccupancyGrid, points) -> np.ndarray:
    """``Σ_b f(cell(y_b))`` over the last axis of ``points`` (M, ..., B, 2); 0 outside the window.

    ``field`` is (h, w) or (M, h, w) (particle ``i`` reads ``field[i]``).
    """
    rows, cols = endpoint_cells(grid, points)
    rows, cols = rows - r0, cols - c0
    hf, wf = field.shape[-2:]
    ok = (rows >= 0) & (rows < hf) & (cols >= 0) & (cols < wf)
    rows, cols = np.clip(rows, 0, hf - 1), np.clip(cols, 0, wf - 1)
    if field.ndim == 2:
        v = field[rows, cols]
    else:
        v = field[np.arange(field.shape[0]).reshape((-1,) + (1,) * (rows.ndim - 1)), rows, cols]
    return np.where(ok, v, 0.0).sum(axis=-1)


#: The six moves tried by the scan matcher: ±x, ±y (robot frame), ±θ.
_MOVES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)


def scan_match(particles, log_odds, grid: OccupancyGrid, ranges, angles, params: GridSLAMParams,
               sensor_offset=(0.0, 0.0)) -> np.ndarray:
    """Move each particle uphill on the map-correlation score (GMapping-style hill climbing).

    Starting from the propagated pose ``x^{[i]}``, each round tries the six
    moves ``x ⊕ (±s_xy, 0, 0)``, ``x ⊕ (0, ±s_xy, 0)``, ``x ⊕ (0, 0, ±s_θ)``;
    a particle takes its best move if it raises its score ``Σ_b f(cell(y_b))``
    (:func:`hit_field`), else halves its steps. ``match_iterations`` rounds,
    initial steps ``match_xy`` [m] and ``match_theta`` [rad]. All particles
    move at once (one array of candidates ``(M, 6, B)`` per round).

    This is what GMapping's *improved proposal* starts from: the scan-matched
    pose is where the laser says the robot is, usually much closer to the
    truth than anything the odometry noise samples.

    Parameters
    ----------
    particles : ndarray, shape (M, 3)
    log_odds : ndarray, shape (H, W) or (M, H, W)
        The shared map, or each particle's own map.
    grid : OccupancyGrid
        Cell geometry.
    ranges, angles : ndarray, shape (B,)
    params : GridSLAMParams
    sensor_offset : (dx, dy)

    Returns
    -------
    ndarray, shape (M, 3)
        Matched poses.
    """
    pose = np.array(particles, dtype=float)
    m = len(pose)
    if params.match_iterations == 0 or len(ranges) == 0:
        return pose
    kernel = correlation_kernel(params.hit_sigma, grid.resolution) if params.hit_sigma > 0 else None
    # the scan in the robot frame, once: o + r_b (cos α_b, sin α_b); a candidate pose then costs no trigonometry per beam
    local = np.asarray(sensor_offset, dtype=float) + np.column_stack([ranges * np.cos(angles), ranges * np.sin(angles)])
    ends = transform_points(pose[:, None, :], local)  # (M, B, 2)
    rows, cols = endpoint_cells(grid, ends)
    reach = params.match_xy * 2 + float(np.max(ranges)) * params.match_theta * 2  # how far an endpoint can move [m]
    pad = int(math.ceil(reach / grid.resolution)) + 1
    r0, c0 = int(rows.min()) - pad, int(cols.min()) - pad
    field = hit_field(log_odds, params.occupied_logodds, kernel, (r0, int(rows.max()) + pad + 1, c0, int(cols.max()) + pad + 1))
    best = _field_score(field, r0, c0, grid, ends)
    step = np.tile([params.match_xy, params.match_xy, params.match_theta], (m, 1))
    for _ in range(params.match_iterations):
        cand = compose(pose[:, None, :], _MOVES * step[:, None, :])  # (M, 6, 3)
        score = _field_score(field, r0, c0, grid, transform_points(cand[:, :, None, :], local))
        j = np.argmax(score, axis=1)
        top = score[np.arange(m), j]
        up = top > best
        pose[up] = cand[up, j[up]]
        best[up] = top[up]
        step[~up] *= 0.5
    return pose


# --------------------------------------------------------------------------- the filter


def _prepare(log: LaserLog, increments, x0):
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


def _beams(log: LaserLog, k: int, params: GridSLAMParams):
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
                  kernel=correlation_kernel(params.hit_sigma, grid.resolution) if params.hit_sigma > 0 else None,
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
        self.particles = sample_motion(self.particles, u, self.params, rng)
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
    u, x0, odo = _prepare(log, increments, x0)
    n = len(log) if n_scans is None else min(int(n_scans), len(log))
    t_start = time.perf_counter()
    run = GridRun.start(params, grid_for_path(odo[:n], params), x0, _beams(log, 0, params), n, sensor_offset)
    steps = range(1, n)
    if progress:
        from tqdm.auto import tqdm

        steps = tqdm(steps, desc="grid SLAM", unit="scan", leave=False)
    for k in steps:
        scan = _beams(log, k, params)
        w = run.weigh(k, u[k], scan, rng)
        run.update_maps(scan)
        run.resample_if_needed(k, w, rng)
    return run.result(log.t[:n], odo[:n], time.perf_counter() - t_start)
