"""Occupancy-grid mapping: log-odds cells updated along the rays of a scan, and the map-correlation weight.

The map is a grid of square cells of side ``resolution`` [m]. Each cell
``m_i`` is occupied or free, and the grid stores, per cell, the **log-odds**
of occupancy given the scans ``z_{1:t}`` and poses ``x_{1:t}``
(Thrun, Burgard & Fox, *Probabilistic Robotics*, ch. 9)::

    l_{t,i} = log( p(m_i | z_{1:t}, x_{1:t}) / (1 − p(m_i | z_{1:t}, x_{1:t})) )

Bayes' rule with cells independent and the measurement independent of the
past given the cell turns into a sum in log-odds::

    l_{t,i} = l_{t−1,i} + logit p(m_i | z_t, x_t) − l_0

with ``logit p = log(p / (1 − p))`` (``scipy.special.logit``; its inverse,
``p = 1 / (1 + e^{−l})``, is ``scipy.special.expit``) and ``l_0 = logit p(m_i) = 0`` for the
prior ``p(m_i) = 0.5``. The *inverse sensor model* ``p(m_i | z_t, x_t)`` is
crude and effective: a cell in which a beam ends is occupied with probability
``p_hit`` (0.7 → ``l_occ = +0.85``), a cell the beam crosses before its end is
occupied with probability ``p_miss`` (0.4 → ``l_free = −0.41``), every other
cell is left alone. Clipping to ``[−l_max, l_max]`` keeps the map able to
change its mind (a door that closes, a person who walks away).

Cells and coordinates
---------------------
Cell ``(row, col)`` covers ``x ∈ [x_0 + col·res, x_0 + (col+1)·res)`` and
``y ∈ [y_0 + row·res, y_0 + (row+1)·res)``, with ``(x_0, y_0) = origin`` the
lower-left corner of cell ``(0, 0)``: the **row comes from y and the column
from x**, so ``log_odds[row, col]`` is displayed the right way up by
``plt.imshow(grid.probability(), origin="lower", extent=grid.extent)``.

Rays
----
The cells a beam crosses come from :mod:`fastslam_edu.grid.rays` (Bresenham's
digital line, and its closed form for a whole scan or many particles at once).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.special import expit, logit

from fastslam_edu.core.checks import finite_array
from fastslam_edu.core.se2 import transform_points
from fastslam_edu.grid.rays import int_cells, ray_cells

__all__ = [
    "OccupancyGrid",
    "update_maps",
    "scan_endpoints",
    "map_correlation",
    "cell_values",
]


# --------------------------------------------------------------------------- the grid


@dataclass
class OccupancyGrid:
    """A log-odds occupancy grid.

    Attributes
    ----------
    resolution : float
        Side of a cell [m].
    origin : tuple (x_0, y_0)
        World coordinates [m] of the lower-left corner of cell ``(0, 0)``.
    shape : tuple (H, W)
        Rows (along y) and columns (along x).
    l_occ : float
        Log-odds increment of a cell in which a beam ends, ``logit(p_hit)``
        (default ``logit(0.7) = 0.847``); must be > 0.
    l_free : float
        Log-odds increment of a cell a beam crosses, ``logit(p_miss)``
        (default ``logit(0.4) = −0.405``); must be < 0.
    l_max : float
        Log-odds are clipped to ``[−l_max, l_max]`` after every update
        (default 5: probabilities within 0.0067 of 0 and 1).
    log_odds : ndarray, shape (H, W)
        ``l_i`` per cell; zeros (``p = 0.5``, the prior) if not given.
    observed : ndarray of bool, shape (H, W)
        True for cells that some update touched (free or hit); used by
        :meth:`binary` to tell "unknown" from "free".
    """

    resolution: float
    origin: tuple[float, float]
    shape: tuple[int, int]
    l_occ: float = float(logit(0.7))
    l_free: float = float(logit(0.4))
    l_max: float = 5.0
    log_odds: np.ndarray | None = field(default=None, repr=False)
    observed: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        res = float(self.resolution)
        if not (math.isfinite(res) and res > 0):
            raise ValueError(f"OccupancyGrid: resolution must be a positive number of metres, got {self.resolution}")
        self.resolution = res
        origin = np.asarray(self.origin, dtype=float)
        if origin.shape != (2,) or not np.isfinite(origin).all():
            raise ValueError(f"OccupancyGrid: origin must be two finite numbers (x_0, y_0), got {self.origin}")
        self.origin = (float(origin[0]), float(origin[1]))
        shape = tuple(self.shape)
        if len(shape) != 2 or any(int(s) != s or s < 1 for s in shape):
            raise ValueError(f"OccupancyGrid: shape must be two positive integers (H, W), got {self.shape}")
        self.shape = (int(shape[0]), int(shape[1]))
        for name, val, ok in [
            ("l_occ", self.l_occ, lambda v: v > 0),
            ("l_free", self.l_free, lambda v: v < 0),
            ("l_max", self.l_max, lambda v: v > 0),
        ]:
            if not (math.isfinite(float(val)) and ok(float(val))):
                raise ValueError(
                    f"OccupancyGrid: {name} = {val} is not allowed (need l_occ > 0, l_free < 0, l_max > 0, finite)"
                )
        self.l_occ, self.l_free, self.l_max = float(self.l_occ), float(self.l_free), float(self.l_max)
        if self.log_odds is None:
            self.log_odds = np.zeros(self.shape)
        else:
            lo = np.asarray(self.log_odds, dtype=float)
            if lo.shape != self.shape or not np.isfinite(lo).all():
                raise ValueError(
                    f"OccupancyGrid: log_odds must be a finite array of shape {self.shape}, got shape {lo.shape}"
                )
            self.log_odds = lo.copy()
        if self.observed is None:
            self.observed = self.log_odds != 0
        else:
            ob = np.asarray(self.observed, dtype=bool)
            if ob.shape != self.shape:
                raise ValueError(f"OccupancyGrid: observed must have shape {self.shape}, got {ob.shape}")
            self.observed = ob.copy()

    # ---------------------------------------------------------------- construction

    @classmethod
    def around(
        cls,
        extent,
        resolution: float,
        *,
        margin: float = 0.0,
        p_hit: float | None = None,
        p_miss: float | None = None,
        **kwargs,
    ) -> OccupancyGrid:
        """An empty grid covering a region of the plane.

        Parameters
        ----------
        extent : float, or (xmin, xmax, ymin, ymax), or array (n, 2)
            A half-width ``e`` (the square ``[−e, e]²``), explicit bounds [m], or
            points to enclose (e.g. a path and its scan endpoints).
        resolution : float
            Cell side [m].
        margin : float
            Extra border [m] added on every side.
        p_hit, p_miss : float, optional
            Inverse sensor model as probabilities: ``l_occ = logit(p_hit)``,
            ``l_free = logit(p_miss)`` (else the defaults or ``l_occ``/``l_free``
            given in ``kwargs``).
        **kwargs
            Other fields of :class:`OccupancyGrid` (``l_occ``, ``l_free``, ``l_max``).

        Returns
        -------
        OccupancyGrid
            Origin at ``(xmin − margin, ymin − margin)``; for bounds,
            ``W = ceil(width / res)`` columns and ``H = ceil(height / res)`` rows
            (the half-open box); for points, ``⌊width / res⌋ + 1`` so that the
            points on the upper edges are inside too.
        """
        e = np.asarray(extent, dtype=float)
        points = False
        if not np.isfinite(e).all():
            raise ValueError("OccupancyGrid.around: extent contains NaN or inf")
        if e.ndim == 0:
            if e <= 0:
                raise ValueError(f"OccupancyGrid.around: half-width must be > 0, got {float(e)}")
            xmin, xmax, ymin, ymax = -float(e), float(e), -float(e), float(e)
        elif e.shape == (4,):
            xmin, xmax, ymin, ymax = (float(v) for v in e)
        elif e.ndim == 2 and e.shape[1] == 2 and len(e) > 0:
            xmin, ymin = e.min(axis=0)
            xmax, ymax = e.max(axis=0)
            points = True
        else:
            raise ValueError(
                "OccupancyGrid.around: extent must be a half-width, (xmin, xmax, ymin, ymax) or points (n, 2); "
                f"got shape {e.shape}"
            )
        if xmax < xmin or ymax < ymin:
            raise ValueError(f"OccupancyGrid.around: empty extent {(xmin, xmax, ymin, ymax)}")
        res = float(resolution)
        if not (math.isfinite(res) and res > 0):
            raise ValueError(f"OccupancyGrid.around: resolution must be > 0, got {resolution}")
        xmin, ymin, xmax, ymax = xmin - margin, ymin - margin, xmax + margin, ymax + margin
        if points:  # every point strictly inside: [xmin, xmax] closed
            width = math.floor((xmax - xmin) / res) + 1
            height = math.floor((ymax - ymin) / res) + 1
        else:  # the half-open box [xmin, xmax) × [ymin, ymax)
            width = max(1, math.ceil((xmax - xmin) / res - 1e-9))
            height = max(1, math.ceil((ymax - ymin) / res - 1e-9))
        for name, p, key in (("p_hit", p_hit, "l_occ"), ("p_miss", p_miss, "l_free")):
            if p is not None:
                if not 0 < p < 1:
                    raise ValueError(f"OccupancyGrid.around: {name} must lie strictly between 0 and 1, got {p}")
                kwargs[key] = float(logit(p))
        return cls(resolution=res, origin=(xmin, ymin), shape=(height, width), **kwargs)

    def copy(self) -> OccupancyGrid:
        """An independent copy (its arrays are copied)."""
        return OccupancyGrid(
            self.resolution, self.origin, self.shape, self.l_occ, self.l_free, self.l_max,
            self.log_odds.copy(), self.observed.copy(),
        )

    # ---------------------------------------------------------------- geometry

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(xmin, xmax, ymin, ymax)`` [m] of the grid, for ``plt.imshow(..., origin="lower")``."""
        x0, y0 = self.origin
        h, w = self.shape
        return (x0, x0 + w * self.resolution, y0, y0 + h * self.resolution)

    def world_to_cell(self, xy) -> np.ndarray:
        """Cell ``(row, col)`` holding world point(s) ``xy``.

        ``col = ⌊(x − x_0) / res⌋``, ``row = ⌊(y − y_0) / res⌋`` (row from y,
        column from x). Points outside the grid get indices outside
        ``[0, H) × [0, W)``; test them with :meth:`inside`.

        Parameters
        ----------
        xy : array_like, shape (..., 2)
            World points ``(x, y)`` [m].

        Returns
        -------
        ndarray of int64, shape (..., 2)
        """
        xy = finite_array("xy", xy, "OccupancyGrid.world_to_cell", (2,))
        col = np.floor((xy[..., 0] - self.origin[0]) / self.resolution)
        row = np.floor((xy[..., 1] - self.origin[1]) / self.resolution)
        return np.stack([row, col], axis=-1).astype(np.int64)

    def cell_to_world(self, cells) -> np.ndarray:
        """World coordinates ``(x, y)`` [m] of the **centre** of cell(s) ``(row, col)``.

        ``x = x_0 + (col + ½) res``, ``y = y_0 + (row + ½) res``; so
        ``world_to_cell(cell_to_world(c)) == c``.
        """
        c = int_cells("cells", cells, "OccupancyGrid.cell_to_world")
        x = self.origin[0] + (c[..., 1] + 0.5) * self.resolution
        y = self.origin[1] + (c[..., 0] + 0.5) * self.resolution
        return np.stack([x, y], axis=-1)

    def inside(self, cells) -> np.ndarray:
        """True where cell ``(row, col)`` lies in the grid: ``0 ≤ row < H`` and ``0 ≤ col < W``."""
        c = int_cells("cells", cells, "OccupancyGrid.inside")
        h, w = self.shape
        return (c[..., 0] >= 0) & (c[..., 0] < h) & (c[..., 1] >= 0) & (c[..., 1] < w)

    # ---------------------------------------------------------------- reading the map

    def probability(self) -> np.ndarray:
        """Occupancy probability per cell, ``p = 1 − 1 / (1 + exp(l))`` (the logistic of ``l``), (H, W)."""
        return expit(self.log_odds)

    def binary(self, threshold: float = 0.5) -> np.ndarray:
        """Thresholded map, int8 (H, W): 1 occupied, 0 free, −1 unknown.

        A cell is *occupied* if ``p > threshold`` (i.e. ``l > logit(threshold)``),
        *unknown* if no update ever touched it (``observed`` is False, whatever
        the threshold), and *free* otherwise (observed and ``p ≤ threshold``).
        """
        if not 0 < threshold < 1:
            raise ValueError(f"OccupancyGrid.binary: threshold must lie strictly between 0 and 1, got {threshold}")
        lt = logit(threshold)
        out = np.where(self.observed, 0, -1).astype(np.int8)
        out[self.observed & (self.log_odds > lt)] = 1
        return out

    # ---------------------------------------------------------------- the update

    def update(self, pose, endpoints, *, sensor_offset=(0.0, 0.0)) -> None:
        """Add one scan to the map (in place): the inverse sensor model in log-odds.

        The beam ``k`` goes from the sensor's cell to the cell of
        ``endpoints[k]`` (:func:`~fastslam_edu.grid.rays.ray_cells`). Then, for this scan,

        * each cell holding at least one endpoint gets ``l += l_occ`` **once**;
        * each other cell crossed by at least one beam gets ``l += l_free`` **once**
          (a cell that is the end of one beam and crossed by another counts as
          a hit only — the endpoint wins);
        * finally ``l ← clip(l, −l_max, l_max)``.

        Cells outside the grid are ignored (a beam leaving the grid updates the
        part inside it). "No return" beams must be left out beforehand (see
        :meth:`fastslam_edu.datasets.laser.LaserLog.beams`).

        Parameters
        ----------
        pose : array_like, shape (3,)
            Robot pose ``(x, y, θ)`` [m, m, rad] when the scan was taken.
        endpoints : array_like, shape (n, 2)
            Beam endpoints in the world [m] (:func:`scan_endpoints`).
        sensor_offset : (dx, dy)
            Sensor position in the robot frame [m]: beams start at
            ``pose ⊕ sensor_offset``.
        """
        pose = finite_array("pose", pose, "OccupancyGrid.update", (3,))
        if pose.shape != (3,):
            raise ValueError(f"OccupancyGrid.update: pose must have shape (3,), got {pose.shape}")
        ends = finite_array("endpoints", endpoints, "OccupancyGrid.update", (2,))
        if ends.ndim != 2:
            raise ValueError(f"OccupancyGrid.update: endpoints must have shape (n, 2), got {ends.shape}")
        sensor = transform_points(pose, finite_array("sensor_offset", sensor_offset, "OccupancyGrid.update", (2,)))
        free, hit = ray_cells(self.world_to_cell(sensor), self.world_to_cell(ends))
        self._add(free, hit)

    def _add(self, free_cells: np.ndarray, hit_cells: np.ndarray) -> None:
        """Log-odds update from cell lists (duplicates allowed): each cell once, hits win, clipped (:func:`_add_log_odds`)."""
        h, w = self.shape
        free_flat, hit_flat = _flat_index(free_cells, h, w), _flat_index(hit_cells, h, w)
        _add_log_odds(self.log_odds.reshape(-1), free_flat, hit_flat, self.l_occ, self.l_free, self.l_max)
        seen = self.observed.reshape(-1)
        seen[free_flat] = True
        seen[hit_flat] = True


def _flat_index(cells: np.ndarray, h: int, w: int) -> np.ndarray:
    """Flat indices of the cells inside an H × W grid: ``(row, col)`` into (H, W), ``(particle, row, col)`` into (M, H, W)."""
    c = cells[(cells[:, -2] >= 0) & (cells[:, -2] < h) & (cells[:, -1] >= 0) & (cells[:, -1] < w)]
    flat = c[:, -2] * w + c[:, -1]
    return flat + c[:, 0] * (h * w) if cells.shape[1] == 3 else flat


def _add_log_odds(lo: np.ndarray, free: np.ndarray, hit: np.ndarray, l_occ: float, l_free: float, l_max: float) -> None:
    """``l_free`` once to the flat cells ``free``, then ``l_occ`` once to ``hit`` (the endpoint wins), clipped; in place.

    Both read the log-odds before the update (NumPy's ``a[idx] = v`` with repeated
    indices writes the same value again, so a cell crossed by many beams changes once).
    """
    new_free = np.clip(lo[free] + l_free, -l_max, l_max)
    new_hit = np.clip(lo[hit] + l_occ, -l_max, l_max)
    lo[free] = new_free
    lo[hit] = new_hit


def update_maps(maps: np.ndarray, free: np.ndarray, hit: np.ndarray, l_occ: float, l_free: float, l_max: float) -> None:
    """Log-odds update of several maps in place (the rule of :meth:`OccupancyGrid.update`, per map).

    In each map, a cell crossed by at least one beam gets ``l_free`` once, a
    cell holding an endpoint gets ``l_occ`` once (the endpoint wins), and the
    result is clipped to ``[−l_max, l_max]``; cells outside the grid are ignored.

    Parameters
    ----------
    maps : ndarray, shape (M, H, W)
        Modified in place.
    free, hit : ndarray of int, shape (·, 3)
        ``(particle, row, col)`` from :func:`~fastslam_edu.grid.rays.ray_cells_batch`.
    """
    _, h, w = maps.shape
    _add_log_odds(maps.reshape(-1), _flat_index(free, h, w), _flat_index(hit, h, w), l_occ, l_free, l_max)


# --------------------------------------------------------------------------- scans


def scan_endpoints(pose, ranges, angles, sensor_offset=(0.0, 0.0)) -> np.ndarray:
    """World coordinates of the beam endpoints of one scan, for one or many poses.

    Beam ``b`` with range ``r_b`` at angle ``α_b`` (robot frame, 0 ahead,
    positive to the left) ends at::

        s + r_b (cos(θ + α_b), sin(θ + α_b)),   s = (x, y) + R(θ) o

    with ``o = sensor_offset`` the sensor's position in the robot frame (the
    sensor looks along the robot's heading).

    Parameters
    ----------
    pose : array_like, shape (3,) or (M, 3) (any (..., 3))
        Robot pose(s) ``(x, y, θ)`` [m, m, rad] — e.g. all particles at once.
    ranges : array_like, shape (B,)
        Ranges [m], finite and ≥ 0 (drop "no return" beams first).
    angles : array_like, shape (B,)
        Beam angles [rad].
    sensor_offset : (dx, dy)
        [m], robot frame.

    Returns
    -------
    ndarray, shape (..., B, 2)
        ``(B, 2)`` for one pose, ``(M, B, 2)`` for ``M``.
    """
    pose = finite_array("pose", pose, "scan_endpoints", (3,))
    r = np.asarray(ranges, dtype=float)
    a = np.asarray(angles, dtype=float)
    if r.ndim != 1 or a.shape != r.shape:
        raise ValueError(f"scan_endpoints: ranges and angles must both have shape (B,), got {r.shape} and {a.shape}")
    if not np.isfinite(r).all():
        k = int(np.argwhere(~np.isfinite(r))[0, 0])
        raise ValueError(
            f"scan_endpoints: ranges[{k}] = {r[k]} is not finite; drop 'no return' beams first "
            "(keep = np.isfinite(ranges), or LaserLog.beams(k))"
        )
    if (r < 0).any():
        k = int(np.argwhere(r < 0)[0, 0])
        raise ValueError(f"scan_endpoints: negative range ranges[{k}] = {r[k]}")
    if not np.isfinite(a).all():
        k = int(np.argwhere(~np.isfinite(a))[0, 0])
        raise ValueError(f"scan_endpoints: angles[{k}] = {a[k]} is not finite")
    off = finite_array("sensor_offset", sensor_offset, "scan_endpoints", (2,))
    sensor = transform_points(pose, off)  # (..., 2)
    phi = pose[..., 2, None] + a  # (..., B)
    return np.stack([sensor[..., 0, None] + r * np.cos(phi), sensor[..., 1, None] + r * np.sin(phi)], axis=-1)


def map_correlation(grid: OccupancyGrid, endpoints, values=None, *, threshold: float = 0.5) -> np.ndarray:
    """Map correlation of scans with the map: the grid-PF write-up's particle weight.

    For particle ``i`` with endpoints ``y_{i,b}`` (its scan projected from its
    pose), the correlation is ``c_i = Σ_b v(cell(y_{i,b}))``: by default
    ``v = 1`` on occupied cells (``binary(threshold) == 1``) and 0 elsewhere,
    i.e. the **number of endpoints that land on occupied cells**. Endpoints
    outside the grid count 0. The write-up weighs particles by
    ``w_i ∝ exp(c_i)`` (normalise in the log domain: subtract ``max c`` first).

    Parameters
    ----------
    grid : OccupancyGrid
        Gives the cell geometry, and the occupied cells when ``values`` is None.
    endpoints : array_like, shape (..., B, 2)
        World endpoints [m], e.g. ``(M, B, 2)`` from :func:`scan_endpoints`.
    values : array_like, shape (H, W), optional
        Per-cell value to sum instead (e.g. ``grid.log_odds``, or a ±1 map).
    threshold : float
        Occupancy threshold on the probability when ``values`` is None.

    Returns
    -------
    ndarray, shape (...,)
        ``(M,)`` for ``(M, B, 2)`` endpoints.
    """
    if not isinstance(grid, OccupancyGrid):
        raise ValueError(f"map_correlation: grid must be an OccupancyGrid, got {type(grid).__name__}")
    y = finite_array("endpoints", endpoints, "map_correlation", (2,))
    if y.ndim < 2:
        raise ValueError(f"map_correlation: endpoints must have shape (..., B, 2), got {y.shape}")
    if values is None:
        v = (grid.binary(threshold) == 1).astype(float)
    else:
        v = np.asarray(values, dtype=float)
        if v.shape != grid.shape or not np.isfinite(v).all():
            raise ValueError(f"map_correlation: values must be a finite array of shape {grid.shape}, got {v.shape}")
    cells = grid.world_to_cell(y)
    return cell_values(v, cells[..., 0], cells[..., 1]).sum(axis=-1)


def cell_values(values, rows, cols, outside=0.0) -> np.ndarray:
    """The map's value at each cell ``(rows, cols)``, ``outside`` for cells off the grid.

    ``values`` (H, W) is one map; (M, H, W) one map per particle, and then the
    leading axis of ``rows`` and ``cols`` (M, ...) is the particle's. The
    gather behind both map correlations (:func:`map_correlation`,
    :func:`fastslam_edu.grid.scan_matching.correlation`).
    """
    v = np.asarray(values)
    h, w = v.shape[-2:]
    rows, cols = np.asarray(rows), np.asarray(cols)
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    r, c = np.clip(rows, 0, h - 1), np.clip(cols, 0, w - 1)
    got = v[r, c] if v.ndim == 2 else v[np.arange(v.shape[0]).reshape((-1,) + (1,) * (r.ndim - 1)), r, c]
    return np.where(inside, got, outside)
