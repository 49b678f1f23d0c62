"""Scoring a scan against a map (map correlation) and moving a pose uphill on that score (scan matching).

A particle's scan, projected from its pose, lands its beam endpoints ``y_b`` in cells of the map; the
*map correlation* counts those on occupied cells (:func:`correlation`, the grid filter's weight), optionally
graded by a kernel so that an endpoint next to a wall earns part of the point (:func:`correlation_weights`).

Scan matching
-------------
``match_iterations > 0`` moves each particle, after propagation, uphill on
its correlation score (:func:`scan_match`, a vectorised version of GMapping's
hill-climbing matcher: try ±``match_xy`` m and ±``match_theta`` rad, halve
the steps when nothing improves). This is the first half of what GMapping's
improved proposal does (it then samples around the matched pose) and shows
what scan matching adds.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from fastslam_edu.core.se2 import compose, transform_points
from fastslam_edu.grid.occupancy import OccupancyGrid, cell_values

if TYPE_CHECKING:  # only for the annotations: gridslam imports this module
    from fastslam_edu.grid.gridslam import GridSLAMParams

__all__ = ["endpoint_cells", "correlation_weights", "correlation", "hit_field", "scan_match"]


# --------------------------------------------------------------------------- map correlation


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


def correlation_weights(hit_sigma: float, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """Neighbour offsets and weights ``g(δ) = exp(−‖δ‖² res² / (2 σ²))`` of the graded correlation.

    The correlation's kernel in the mathematical sense (the suffix ``_kernel`` is kept for compiled twins,
    see :mod:`fastslam_edu`).

    Offsets ``δ = (Δrow, Δcol)`` cover the disc ``‖δ‖ ≤ r = ⌈2σ / res⌉`` cells;
    ``σ = 0`` gives the single offset ``(0, 0)`` with weight 1 (the write-up's rule).

    Returns
    -------
    offsets : ndarray of int64, shape (D, 2)
        ``(0, 0)`` first.
    weights : ndarray, shape (D,)
        Rounded to multiples of 1/256, so that a scan's score is the same
        whatever order its beams are summed in (vectorised or loop).
    """
    if not (math.isfinite(hit_sigma) and hit_sigma >= 0):
        raise ValueError(f"correlation_weights: hit_sigma must be ≥ 0, got {hit_sigma}")
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

    With a kernel (:func:`correlation_weights`) an endpoint near an occupied
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
    kernel : (offsets (D, 2), weights (D,)), optional

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


# --------------------------------------------------------------------------- scan matching


def hit_field(log_odds, threshold: float, kernel, window) -> np.ndarray:
    """The graded occupancy ``f(cell) = max_δ g(δ) o(cell + δ)`` on a window of cells.

    Precomputing ``f`` once per scan makes a candidate pose cost one lookup
    per beam (``Σ_b f(cell(y_b))``) instead of ``D`` (the kernel's offsets) — what scan matching
    needs, since it scores many candidate poses per particle. ``Σ_b f`` equals
    :func:`correlation` with the same kernel for endpoints inside the window.

    Parameters
    ----------
    log_odds : ndarray, shape (H, W) or (M, H, W)
        One map, or one per particle.
    threshold : float
        ``o(cell) = 1[l > threshold]``; cells outside the grid have ``o = 0``.
    kernel : (offsets (D, 2), weights (D,)) or None
        :func:`correlation_weights` (None: ``f = o``).
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
    for (dr, dc), g in zip(offsets.tolist(), weights.tolist()):  # D shifts of the window, not a loop over cells
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
    kernel = correlation_weights(params.hit_sigma, grid.resolution) if params.hit_sigma > 0 else None
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
