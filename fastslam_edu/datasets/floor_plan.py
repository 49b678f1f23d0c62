"""A building to walk through: walls standing on 2D segments, the floor, and 3D rays cast in it.

:class:`FloorPlan` holds vertical walls of height ``H`` over 2D segments and the floor ``z = 0``;
:func:`default_floor_plan` is four rooms joined by 1 m doors, with a pillar and a cabinet, 20 m × 12 m, and
:data:`DEFAULT_WAYPOINTS` a tour through them. :func:`cast_rays` returns where a LiDAR's beams first meet a
wall or the floor: what the simulated THOR sequence (:mod:`fastslam_edu.datasets.thor_sim`) measures, and the
truth its maps are scored against (:mod:`fastslam_edu.grid.thor_slam`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["NO_HIT", "WALL", "FLOOR", "FloorPlan", "default_floor_plan", "DEFAULT_WAYPOINTS", "cast_rays"]

#: What a simulated beam hit (:attr:`fastslam_edu.datasets.thor_sim.ThorSequence.kind`).
NO_HIT, WALL, FLOOR = 0, 1, 2


@dataclass(frozen=True)
class FloorPlan:
    """Vertical walls on 2D segments, and the floor ``z = 0``.

    Attributes
    ----------
    walls : ndarray, shape (W, 2, 2)
        Segment ``w`` runs from ``walls[w, 0]`` to ``walls[w, 1]`` (``(x, y)`` [m]);
        the wall is the vertical rectangle above it, ``0 ≤ z ≤ height``.
    height : float
        Wall height [m].
    """

    walls: np.ndarray
    height: float = 2.5

    def __post_init__(self) -> None:
        w = np.asarray(self.walls, dtype=float)
        if w.ndim != 3 or w.shape[1:] != (2, 2) or w.shape[0] == 0:
            raise ValueError(f"FloorPlan: walls must have shape (W, 2, 2) with W ≥ 1, got {w.shape}")
        if not np.isfinite(w).all():
            raise ValueError("FloorPlan: walls contain a non-finite coordinate")
        if (np.linalg.norm(w[:, 1] - w[:, 0], axis=1) == 0).any():
            k = int(np.argmax(np.linalg.norm(w[:, 1] - w[:, 0], axis=1) == 0))
            raise ValueError(f"FloorPlan: wall {k} has zero length")
        if not (math.isfinite(self.height) and self.height > 0):
            raise ValueError(f"FloorPlan: height must be a positive number of metres, got {self.height}")
        object.__setattr__(self, "walls", w)

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(xmin, xmax, ymin, ymax)`` of the walls [m]."""
        p = self.walls.reshape(-1, 2)
        return float(p[:, 0].min()), float(p[:, 0].max()), float(p[:, 1].min()), float(p[:, 1].max())

    def distance_to_walls(self, xy) -> np.ndarray:
        """Distance [m] from each point to the nearest wall segment, shape ``(...)``.

        For segment ``p → q`` and point ``y``: ``‖y − (p + u (q − p))‖`` with
        ``u = clip((y − p)·(q − p) / ‖q − p‖², 0, 1)``.

        Parameters
        ----------
        xy : array_like, shape (..., 2)
        """
        y = np.asarray(xy, dtype=float)
        if y.ndim == 0 or y.shape[-1] != 2 or not np.isfinite(y).all():
            raise ValueError(f"FloorPlan.distance_to_walls: xy must be finite (..., 2), got shape {y.shape}")
        best = np.full(y.shape[:-1], np.inf)
        for p, q in self.walls:  # a loop over the (few) walls keeps the memory at O(points)
            e = q - p
            d = y - p
            u = np.clip((d @ e) / (e @ e), 0.0, 1.0)
            best = np.minimum(best, np.linalg.norm(d - u[..., None] * e, axis=-1))
        return best


def _rectangle_walls(x0: float, y0: float, x1: float, y1: float) -> list:
    return [[(x0, y0), (x1, y0)], [(x1, y0), (x1, y1)], [(x1, y1), (x0, y1)], [(x0, y1), (x0, y0)]]


#: Building coordinates of the default start (the world origin) [m].
_START = np.array([2.0, 2.5])

#: Default tour through the four rooms, in the world frame (start at the origin, heading +x) [m]:
#: room D → C → B → A, ending in A facing its far wall (+y) over 5 m of open floor.
DEFAULT_WAYPOINTS = np.array(
    [(2.0, 2.5), (5.5, 2.5), (3.5, 5.0), (3.5, 7.5), (6.5, 8.5), (10.0, 8.5), (11.0, 4.5), (14.5, 4.5),
     (15.5, 5.5), (15.5, 6.5)]
) - _START


def default_floor_plan(height: float = 2.5) -> FloorPlan:
    """Four rooms, 20 m × 12 m, joined by 1 m doors, with a pillar and a cabinet.

    In building coordinates (x 0 – 20 m, y 0 – 12 m): room D (x < 8, y < 6)
    opens into room C (x < 8, y > 6) through a door at ``x ∈ [3, 4]``; C opens
    into room B (8 < x < 13) at ``y ∈ [8, 9]``; B opens into room A (x > 13) at
    ``y ∈ [4, 5]``. A 1 m pillar stands in A, a 1.5 m × 1 m cabinet in B. The
    plan is shifted so that the default start, ``(2, 2.5)`` in the building,
    is the world origin (:data:`DEFAULT_WAYPOINTS` starts there, heading +x).
    """
    walls = (
        _rectangle_walls(0, 0, 20, 12)
        + [[(0, 6), (3, 6)], [(4, 6), (8, 6)]]  # D | C, door x 3–4
        + [[(8, 0), (8, 8)], [(8, 9), (8, 12)]]  # C, D | B, door y 8–9
        + [[(13, 0), (13, 4)], [(13, 5), (13, 12)]]  # B | A, door y 4–5
        + _rectangle_walls(17.5, 9.0, 18.5, 10.0)  # pillar in A
        + _rectangle_walls(10.0, 1.0, 11.5, 2.0)  # cabinet in B
    )
    return FloorPlan(np.array(walls, dtype=float) - _START, height)


# --------------------------------------------------------------------------- ray casting


def cast_rays(origin, directions, plan: FloorPlan) -> tuple[np.ndarray, np.ndarray]:
    """Range to the first wall or floor hit of 3D rays, vectorised over scans and beams.

    A ray ``o + s d`` (``d`` a unit vector, ``s > 0`` the range) meets

    * the wall over segment ``p → p + e`` where its horizontal projection
      crosses the segment, ``(o_xy − p) + s d_xy = u e`` with ``0 ≤ u ≤ 1``
      (2D cross products: ``s = (w × e) / (d_xy × e)``, ``u = (w × d_xy) / (d_xy × e)``,
      ``w = p − o_xy``), if the hit height ``o_z + s d_z`` is in ``[0, H]``;
    * the floor at ``s = −o_z / d_z`` if ``d_z < 0``.

    The range is the smallest of these (the nearer of floor and wall).

    Parameters
    ----------
    origin : array_like, shape (..., 3)
        Ray origins [m] (the LiDAR, one per scan).
    directions : array_like, shape (..., B, 3)
        Unit directions.
    plan : FloorPlan

    Returns
    -------
    ranges : ndarray, shape (..., B)
        ``s`` [m]; ``inf`` where nothing is hit (a ray over the walls).
    kind : ndarray of int8, shape (..., B)
        :data:`WALL`, :data:`FLOOR` or :data:`NO_HIT`.
    """
    o = np.asarray(origin, dtype=float)
    d = np.asarray(directions, dtype=float)
    if o.ndim == 0 or o.shape[-1] != 3 or d.ndim < 2 or d.shape[-1] != 3 or d.shape[:-2] != o.shape[:-1]:
        raise ValueError(f"cast_rays: origin must be (..., 3) and directions (..., B, 3), got {o.shape} and {d.shape}")
    if not (np.isfinite(o).all() and np.isfinite(d).all()):
        raise ValueError("cast_rays: origin or directions contain a non-finite value")
    p, e = plan.walls[:, 0], plan.walls[:, 1] - plan.walls[:, 0]  # (W, 2)
    dx, dy, dz = d[..., 0, None], d[..., 1, None], d[..., 2]  # (..., B, 1), (..., B, 1), (..., B)
    wx = p[:, 0] - o[..., None, None, 0]  # w = p − o_xy, (..., 1, W)
    wy = p[:, 1] - o[..., None, None, 1]
    w_cross_e = wx * e[:, 1] - wy * e[:, 0]  # (..., 1, W): the same for every beam
    den = dx * e[:, 1] - dy * e[:, 0]  # d_xy × e, (..., B, W)
    ok = np.abs(den) > 1e-12  # not parallel to the wall
    inv = 1.0 / np.where(ok, den, 1.0)
    s = w_cross_e * inv
    u = (wx * dy - wy * dx) * inv
    z = o[..., None, None, 2] + s * dz[..., None]
    hit = ok & (s > 0) & (u >= 0) & (u <= 1) & (z >= 0) & (z <= plan.height)
    s_wall = np.where(hit, s, np.inf).min(axis=-1)  # (..., B)
    down = dz < 0
    s_floor = np.where(down, -o[..., None, 2] / np.where(down, dz, -1.0), np.inf)
    ranges = np.minimum(s_wall, s_floor)
    kind = np.full(ranges.shape, NO_HIT, dtype=np.int8)
    kind[np.isfinite(s_wall) & (s_wall <= s_floor)] = WALL
    kind[np.isfinite(s_floor) & (s_floor < s_wall)] = FLOOR
    return ranges, kind
