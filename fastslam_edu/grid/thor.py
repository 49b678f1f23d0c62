"""THOR's LiDAR returns onto a 2D map: which returns to keep, and a planar laser log of them.

The geometry (from a beam on the moving head to a point in the world, ``p_W = T_WB T_BL p_L``, and the joint
sample of each scan) lives in :mod:`fastslam_edu.datasets.thor_geometry`, below the simulator and this module;
its names are importable from here too (``thor.lidar_points_world``, as the chapter writes them). A beam
straight ahead with the head pitched by ``φ > 0`` hits the floor ``(h_B + h_L) / tan φ`` = 1.41 m / tan φ
ahead of the robot — 7.4 m at the 10.8° THOR holds for a minute in its training log, 1.6 m at its 41° peak. Such
returns are not obstacles; before a scan is added to a 2D map:

* ranges outside ``[0.1, 30]`` m (the sensor's valid interval) are dropped;
* returns whose world height is below ``z_floor`` ≈ 0.1 m are dropped as floor.

:func:`filter_returns` applies both and counts what it drops; :func:`planar_laser_log` turns the 3D returns
into the planar scans grid SLAM reads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fastslam_edu.datasets import thor_geometry
from fastslam_edu.datasets.laser import LaserLog
from fastslam_edu.datasets.thor_lidar import ThorLidar
from fastslam_edu.datasets.thor_geometry import (  # noqa: F401 (the geometry, re-exported for the chapters)
    BODY_HEIGHT, FLOOR_Z, LIDAR_ABOVE_HEAD, LIDAR_HEIGHT, MAX_RANGE, MIN_RANGE, beam_directions_world,
    beam_points_lidar, body_to_world, homogeneous, joints_at, lidar_points_world, lidar_to_body, lidar_to_world,
    nearest_sample, rot_y, rot_z)

#: The geometry's names (re-exported), then this module's own.
__all__ = [
    *thor_geometry.__all__,
    "ReturnFilter",
    "filter_returns",
    "BAND_Z",
    "PLANAR_BEARING_STEP",
    "planar_laser_log",
]


# --------------------------------------------------------------------------- filtering


@dataclass(frozen=True)
class ReturnFilter:
    """Which returns of a scan (or scans) to map, and how many were dropped why.

    Attributes
    ----------
    keep : ndarray of bool, shape (..., B)
        True for returns to map: range in ``[min_range, max_range]`` and
        world height ``z ≥ z_floor`` (when the floor filter is on).
    out_of_range : ndarray of bool, shape (..., B)
        Range non-finite or outside ``[min_range, max_range]``.
    floor : ndarray of bool, shape (..., B)
        In range but world ``z < z_floor`` (always computed, dropped only if
        the floor filter is on).
    n_total, n_out_of_range, n_floor, n_kept : int
        Counts; ``n_total = n_out_of_range + n_floor + n_kept`` with the floor
        filter on, ``n_total = n_out_of_range + n_kept`` with it off.
    """

    keep: np.ndarray
    out_of_range: np.ndarray
    floor: np.ndarray
    n_total: int
    n_out_of_range: int
    n_floor: int
    n_kept: int


def filter_returns(
    ranges,
    z,
    *,
    min_range: float = MIN_RANGE,
    max_range: float = MAX_RANGE,
    z_floor: float | None = FLOOR_Z,
) -> ReturnFilter:
    """Drop out-of-range returns and floor returns, with counts.

    A return ``b`` is kept when ``min_range ≤ r_b ≤ max_range`` and, if
    ``z_floor`` is not None, its world height ``z_b ≥ z_floor``.

    Parameters
    ----------
    ranges : array_like, shape (..., B)
        Ranges as stored [m]; NaN and ±inf count as out of range.
    z : array_like, shape (..., B)
        World heights of the returns [m] (``lidar_points_world(...)[..., 2]``);
        only read where the range is valid (may be NaN elsewhere).
    min_range, max_range : float
        Valid range interval [m] (THOR: 0.1 – 30).
    z_floor : float or None
        Floor threshold [m]; None turns the floor filter off.

    Returns
    -------
    ReturnFilter
    """
    r = np.asarray(ranges, dtype=float)
    z = np.asarray(z, dtype=float)
    if r.shape != z.shape:
        raise ValueError(f"filter_returns: ranges and z must have the same shape, got {r.shape} and {z.shape}")
    if not (np.isfinite(min_range) and np.isfinite(max_range) and 0 <= min_range < max_range):
        raise ValueError(f"filter_returns: need 0 ≤ min_range < max_range, got {min_range}, {max_range}")
    if z_floor is not None and not np.isfinite(z_floor):
        raise ValueError(f"filter_returns: z_floor must be finite or None, got {z_floor}")
    in_range = np.isfinite(r)
    in_range[in_range] = (r[in_range] >= min_range) & (r[in_range] <= max_range)
    if not np.isfinite(z[in_range]).all():
        raise ValueError("filter_returns: z is not finite for a return whose range is valid")
    floor = np.zeros_like(in_range)
    if z_floor is not None:
        floor[in_range] = z[in_range] < z_floor
    keep = in_range & ~floor
    return ReturnFilter(
        keep=keep, out_of_range=~in_range, floor=floor, n_total=int(r.size),
        n_out_of_range=int((~in_range).sum()), n_floor=int(floor.sum()), n_kept=int(keep.sum()),
    )


# --------------------------------------------------------------------------- projection to a planar laser log

#: Height band [m above the floor] of the returns kept for a 2D map: above the floor, below a person's head.
BAND_Z = (0.1, 2.0)
#: Bearing step [rad] of the planar scans made by :func:`planar_laser_log` (0.5°).
PLANAR_BEARING_STEP = math.radians(0.5)


def _bearing_bins(bearing, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Fixed bearings ``β_i = −π + i Δ`` (``i = 0 … ⌈2π/Δ⌉ − 1``) and the bin ``i`` of each bearing ``β`` (nearest)."""
    n_bins = int(math.ceil(2 * math.pi / step - 1e-9))
    centres = -math.pi + step * np.arange(n_bins)
    idx = np.rint((np.asarray(bearing) + math.pi) / step).astype(np.int64) % n_bins
    return centres, idx


def planar_laser_log(
    lidar: ThorLidar,
    t_joints,
    neck,
    head,
    *,
    max_gap: float = 0.06,
    band=BAND_Z,
    z_floor: float | None = FLOOR_Z,
    bearing_step: float = PLANAR_BEARING_STEP,
) -> LaserLog:
    """Project a THOR LiDAR log onto the body's horizontal plane: a 2D :class:`LaserLog` for grid SLAM.

    For each scan ``k`` (time ``t_k``):

    1. head joints ``ψ_n(t_k), φ_h(t_k)`` from the nearest joint sample
       (:func:`joints_at`, at most ``max_gap`` seconds away);
    2. beam endpoints in the **body frame on the floor** (pose ``(0, 0, 0)``):
       ``p = T_WB(0) T_BL(ψ_n, φ_h) p_L`` (:func:`lidar_points_world`), so
       ``p_z`` is the height above the floor;
    3. drop out-of-range and floor returns (:func:`filter_returns`) and keep
       ``band[0] ≤ p_z ≤ band[1]``;
    4. each kept point becomes a planar beam: range ``ρ = √(p_x² + p_y²)`` and
       body-frame bearing ``β = atan2(p_y, p_x)``.

    The bearing of LiDAR beam ``α`` is ``β ≈ α + ψ_n`` (exactly so when
    ``φ_h = 0``), so it changes from scan to scan with the neck. A
    :class:`LaserLog` has one angle array for all scans, so the planar beams
    are **resampled to fixed bearings** ``β_i = −π + i Δ`` (a full circle,
    ``Δ`` = ``bearing_step``): each point goes to the nearest ``β_i`` and,
    when several land in one bin, the nearest point wins (the first obstacle
    along that bearing). The bearing error is at most ``Δ/2`` (0.25°: 4 cm at
    10 m, under a 0.1 m cell). Empty bins are NaN ("no return"). The ray's
    origin is the body's vertical axis: the LiDAR sits 0.15 m straight above
    the head joint, with no horizontal offset.

    The odometry is :meth:`ThorLidar.odometry_poses` (variant 1's ``pose``,
    variant 2's summed ``delta_pose``), stored as both :attr:`LaserLog.poses`
    and :attr:`LaserLog.odometry`, so that
    :func:`fastslam_edu.datasets.laser.odometry_increments` gives
    ``u_k = o_{k−1}⁻¹ ⊕ o_k``. Body roll and pitch (variant 1's ``rpy``) are
    not used: the body is taken as upright.

    Parameters
    ----------
    lidar : ThorLidar (:func:`fastslam_edu.datasets.thor_lidar.read_thor_lidar`)
    t_joints, neck, head : array_like, shape (n,)
        The joint log (:func:`fastslam_edu.datasets.thor_lidar.read_thor_joints`).
    max_gap : float
        Largest allowed time [s] between a scan and its joint sample.
    band : (float, float)
        Kept heights ``(z_min, z_max)`` above the floor [m].
    z_floor : float or None
        Floor threshold of :func:`filter_returns` [m].
    bearing_step : float
        ``Δ`` [rad] of the fixed bearings.

    Returns
    -------
    LaserLog
        ``ranges`` (N, ⌈2π/Δ⌉) [m] with NaN where nothing was kept; ``angles``
        the fixed bearings; ``max_range`` the LiDAR's; ``counts`` the returns
        per fate (``total``, ``out_of_range``, ``floor``, ``outside_band``,
        ``kept``, ``planar_beams``).
    """
    z_min, z_max = _check_planar(lidar, band, bearing_step)
    p, kept, in_band = _returns_in_band(lidar, joints_at(lidar.t, t_joints, neck, head, max_gap=max_gap),
                                        (z_min, z_max), z_floor)
    centres, ranges = _nearest_per_bearing(p, in_band, bearing_step)
    odo = lidar.odometry_poses()
    counts = {
        "total": kept.n_total, "out_of_range": kept.n_out_of_range, "floor": kept.n_floor,
        "outside_band": int(kept.n_kept - in_band.sum()), "kept": int(in_band.sum()),
        "planar_beams": int(np.isfinite(ranges).sum()),
    }
    params = {"max_gap": str(max_gap), "band": f"{z_min} {z_max}", "z_floor": str(z_floor),
              "bearing_step": str(bearing_step), "variant": str(lidar.variant)}
    return LaserLog(t=np.asarray(lidar.t, dtype=float), ranges=ranges, angles=centres, poses=odo, odometry=odo.copy(),
                    source=lidar.source or "THOR LiDAR log", max_range=float(lidar.max_range), params=params,
                    counts=counts)


def _check_planar(lidar, band, bearing_step) -> tuple[float, float]:
    """The arguments of :func:`planar_laser_log`, checked; returns ``(z_min, z_max)``."""
    if not isinstance(lidar, ThorLidar):
        raise ValueError(f"planar_laser_log: lidar must be a ThorLidar, got {type(lidar).__name__}")
    z_min, z_max = (float(v) for v in band)
    if not (math.isfinite(z_min) and math.isfinite(z_max) and z_min < z_max):
        raise ValueError(f"planar_laser_log: band must be two finite heights z_min < z_max, got {band}")
    if not (math.isfinite(bearing_step) and 0 < bearing_step <= math.pi):
        raise ValueError(f"planar_laser_log: bearing_step must lie in (0, π], got {bearing_step}")
    return z_min, z_max


def _returns_in_band(lidar: ThorLidar, head_joints, band, z_floor):
    """Steps 2–3 of :func:`planar_laser_log`: the endpoints (N, B, 3) in the body frame on the floor,
    :func:`filter_returns`' verdict, and which returns are kept within ``band``."""
    n = len(lidar)
    valid = lidar.valid()
    r_safe = np.where(valid, lidar.ranges, 0.0)  # invalid beams: a harmless finite stand-in, dropped below
    p = lidar_points_world(r_safe, lidar.angles, *head_joints, np.zeros((n, 3)))  # (N, B, 3)
    z = np.where(valid, p[..., 2], np.nan)
    kept = filter_returns(np.where(valid, lidar.ranges, np.nan), z, min_range=lidar.min_range,
                          max_range=lidar.max_range, z_floor=z_floor)
    in_band = kept.keep.copy()
    in_band[in_band] = (z[in_band] >= band[0]) & (z[in_band] <= band[1])
    return p, kept, in_band


def _nearest_per_bearing(p, in_band, bearing_step: float):
    """Step 4 of :func:`planar_laser_log`: the fixed bearings, and per scan and bearing the nearest kept
    point's horizontal range (NaN where none)."""
    n = p.shape[0]
    rho = np.hypot(p[..., 0], p[..., 1])
    centres, idx = _bearing_bins(np.arctan2(p[..., 1], p[..., 0]), bearing_step)
    b = centres.size
    flat = np.full(n * b, np.inf)
    rows = np.broadcast_to(np.arange(n)[:, None], idx.shape)
    np.minimum.at(flat, (rows * b + idx)[in_band], rho[in_band])  # nearest point per (scan, bearing)
    ranges = flat.reshape(n, b)
    ranges[~np.isfinite(ranges)] = np.nan
    return centres, ranges
