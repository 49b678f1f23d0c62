"""Grid SLAM on a THOR LiDAR log, and how to score its map against a known world.

The THOR write-up's particle filter (:func:`fastslam_edu.grid.gridslam.run_grid_slam`
with :meth:`~fastslam_edu.grid.gridslam.GridSLAMParams.writeup`) works on a
planar laser log. A THOR log becomes one in :func:`planar_scans`: every return
is carried through the head joints to the body frame
(:func:`fastslam_edu.grid.thor.planar_laser_log`), returns on the floor are
dropped — or, with ``floor_filter=False``, kept, to see what they do to the
map and the path — and what remains is a 2D scan around the body.
:func:`thor_grid_slam` runs the filter on it.

A simulated sequence (:mod:`fastslam_edu.datasets.thor_sim`) knows its world, a
:class:`~fastslam_edu.datasets.thor_sim.FloorPlan` of vertical walls, so a map
can be scored cell by cell (:func:`map_scores`):

* **precision** — the share of the map's occupied cells (``p > 0.5``) whose
  centre lies within ``tol`` of a wall; the others are *phantom* obstacles;
* **coverage** — the share of the walls' cells (:func:`wall_cells`, the cells a
  wall segment passes through) that have an occupied cell within one cell
  (their 3 × 3 neighbourhood). Walls the LiDAR never saw count as missed, so
  coverage compares maps of the *same* scans; it is not an absolute figure.

The map's frame is the filter's: both the filter and the simulator start at
the first odometry pose, which the simulator sets to the true start pose, so
no alignment is needed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fastslam_edu.datasets.laser import LaserLog
from fastslam_edu.datasets.thor_lidar import ThorLidar
from fastslam_edu.datasets.floor_plan import FloorPlan
from fastslam_edu.grid.gridslam import GridSLAMParams, GridSLAMResult, run_grid_slam
from fastslam_edu.grid.occupancy import OccupancyGrid
from fastslam_edu.datasets.thor_geometry import FLOOR_Z, MAX_RANGE
from fastslam_edu.grid.thor import BAND_Z, PLANAR_BEARING_STEP, planar_laser_log

__all__ = [
    "NO_FLOOR_FILTER_BAND",
    "planar_scans",
    "ThorSLAM",
    "thor_grid_slam",
    "wall_cells",
    "MapScores",
    "map_scores",
]

#: Height band [m] kept when the floor filter is off: everything below the band's top (nothing is lower than −30 m).
NO_FLOOR_FILTER_BAND = (-MAX_RANGE, BAND_Z[1])


def planar_scans(
    lidar: ThorLidar,
    t_joints,
    neck,
    head,
    *,
    floor_filter: bool = True,
    bearing_step: float = PLANAR_BEARING_STEP,
    max_gap: float = 0.06,
) -> LaserLog:
    """A THOR log as planar scans around the body, with the floor filter on or off.

    ``floor_filter=True``: :func:`fastslam_edu.grid.thor.planar_laser_log` with
    its defaults — returns below ``z = 0.1`` m are floor and dropped, and the
    kept heights are ``0.1 … 2.0`` m (:data:`~fastslam_edu.grid.thor.BAND_Z`).
    ``floor_filter=False``: no floor threshold and a band that reaches below
    any floor, :data:`NO_FLOOR_FILTER_BAND`, so that floor returns become
    planar beams like wall returns (the band's top, 2 m, is the same in both).

    Parameters
    ----------
    lidar : ThorLidar
        From :func:`fastslam_edu.datasets.thor_lidar.read_thor_lidar` (either variant).
    t_joints, neck, head : array_like, shape (n,)
        The joint log.
    floor_filter : bool
    bearing_step : float
        Bearing step [rad] of the planar scans.
    max_gap : float
        Largest time [s] between a scan and its joint sample.

    Returns
    -------
    LaserLog
        ``counts["floor"]`` is 0 with the filter off.
    """
    if floor_filter:
        return planar_laser_log(lidar, t_joints, neck, head, max_gap=max_gap, band=BAND_Z, z_floor=FLOOR_Z,
                                bearing_step=bearing_step)
    return planar_laser_log(lidar, t_joints, neck, head, max_gap=max_gap, band=NO_FLOOR_FILTER_BAND, z_floor=None,
                            bearing_step=bearing_step)


@dataclass
class ThorSLAM:
    """A grid-SLAM run on a THOR log: the planar scans it ran on and the filter's result."""

    log: LaserLog
    result: GridSLAMResult
    floor_filter: bool


def thor_grid_slam(
    lidar: ThorLidar,
    joints,
    params: GridSLAMParams,
    rng: np.random.Generator,
    *,
    floor_filter: bool = True,
    bearing_step: float = PLANAR_BEARING_STEP,
    n_scans: int | None = None,
) -> ThorSLAM:
    """Project a THOR log to planar scans (:func:`planar_scans`) and run grid SLAM on them.

    ``joints``: the joint log ``(t_joints, neck, head)`` (times [s], neck and head angles [rad]).

    The filter is :func:`fastslam_edu.grid.gridslam.run_grid_slam`, driven by
    the log's odometry (variant 1's ``pose`` or variant 2's summed
    ``delta_pose``) and started at the first odometry pose.

    Returns
    -------
    ThorSLAM
    """
    log = planar_scans(lidar, *joints, floor_filter=floor_filter, bearing_step=bearing_step)
    result = run_grid_slam(log, params, rng, n_scans=n_scans)
    return ThorSLAM(log=log, result=result, floor_filter=floor_filter)


def wall_cells(plan: FloorPlan, grid: OccupancyGrid) -> np.ndarray:
    """The grid cells the plan's wall segments pass through, ``(n, 2)`` int ``(row, col)``, unique, inside the grid.

    Each segment is sampled every ``resolution / 4`` (and at both ends), and the
    cell of every sample is taken; a segment along a cell border may pick the
    cells on either side.
    """
    if not isinstance(plan, FloorPlan):
        raise ValueError(f"wall_cells: plan must be a FloorPlan, got {type(plan).__name__}")
    step = grid.resolution / 4
    pts = []
    for p, q in plan.walls:  # a loop over the (few) walls
        n = max(2, int(math.ceil(np.linalg.norm(q - p) / step)) + 1)
        s = np.linspace(0.0, 1.0, n)[:, None]
        pts.append(p + s * (q - p))
    cells = grid.world_to_cell(np.concatenate(pts))
    cells = cells[grid.inside(cells)]
    return np.unique(cells, axis=0)


@dataclass(frozen=True)
class MapScores:
    """A map against the walls of its world (:func:`map_scores`).

    Attributes
    ----------
    n_occupied : int
        Cells with ``p > threshold``.
    n_on_walls : int
        Occupied cells whose centre is within ``tol`` of a wall.
    precision : float
        ``n_on_walls / n_occupied`` (NaN for a map with no occupied cell).
    n_phantom : int
        ``n_occupied − n_on_walls``: obstacles that are not there.
    phantom : ndarray, shape (n_phantom, 2)
        Their cell centres [m].
    n_wall_cells : int
        Cells the walls pass through (:func:`wall_cells`).
    coverage : float
        Share of those with an occupied cell in their 3 × 3 neighbourhood.
    tol : float
        [m].
    """

    n_occupied: int
    n_on_walls: int
    precision: float
    n_phantom: int
    phantom: np.ndarray
    n_wall_cells: int
    coverage: float
    tol: float

    def row(self) -> dict:
        """The scalar fields, for a table."""
        return {"occupied cells": self.n_occupied, "on walls": self.n_on_walls, "precision": self.precision,
                "phantom cells": self.n_phantom, "wall coverage": self.coverage}


def map_scores(grid: OccupancyGrid, plan: FloorPlan, *, tol: float = 0.15, threshold: float = 0.5) -> MapScores:
    """Score a map against the walls of a known world: precision, phantom obstacles, coverage.

    Parameters
    ----------
    grid : OccupancyGrid
        The map, in the plan's frame.
    plan : FloorPlan
    tol : float
        An occupied cell is *on a wall* when its centre is within ``tol`` [m] of
        one (0.15 m: a cell's half-diagonal, 0.07 m, plus a cell's worth of slack
        at 0.1 m cells).
    threshold : float
        Occupied means ``p > threshold``.

    Returns
    -------
    MapScores
    """
    if not isinstance(grid, OccupancyGrid):
        raise ValueError(f"map_scores: grid must be an OccupancyGrid, got {type(grid).__name__}")
    if not (math.isfinite(tol) and tol >= 0):
        raise ValueError(f"map_scores: tol must be a finite distance ≥ 0, got {tol}")
    occ = grid.binary(threshold) == 1
    centres = grid.cell_to_world(np.argwhere(occ))
    on_wall = plan.distance_to_walls(centres) <= tol if len(centres) else np.zeros(0, dtype=bool)
    n_occ, n_on = int(occ.sum()), int(on_wall.sum())
    near = occ.copy()  # 3 × 3 dilation of the occupied cells, by shifting
    h, w = occ.shape
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            near[max(dr, 0):h + min(dr, 0), max(dc, 0):w + min(dc, 0)] |= \
                occ[max(-dr, 0):h + min(-dr, 0), max(-dc, 0):w + min(-dc, 0)]
    walls = wall_cells(plan, grid)
    coverage = float(near[walls[:, 0], walls[:, 1]].mean()) if len(walls) else math.nan
    return MapScores(
        n_occupied=n_occ, n_on_walls=n_on, precision=n_on / n_occ if n_occ else math.nan, n_phantom=n_occ - n_on,
        phantom=centres[~on_wall], n_wall_cells=len(walls), coverage=coverage, tol=float(tol),
    )
