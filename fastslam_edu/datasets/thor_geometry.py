"""THOR humanoid geometry: from a LiDAR beam on a moving head to a point in the world.

The sensor's own geometry, below both of its users: the simulator (:mod:`fastslam_edu.datasets.thor_sim`)
casts its beams, and the mapping layer (:mod:`fastslam_edu.grid.thor`) places its returns.

THOR's Hokuyo UTM-30LX sits on a head with two joints, the **neck** (yaw,
``ψ_n``) and the **head** (pitch, ``φ_h``), on top of a body that walks. A beam
at angle ``α`` with range ``r`` is a point in the LiDAR frame (x ahead, y left,
z up; the scan plane is the LiDAR's x–y plane)::

    p_L = (r cos α, r sin α, 0)

and reaches the world through two rigid motions, written as 4 × 4 homogeneous
matrices ``T = [[R, t], [0, 1]]`` (the convention of the course hand-outs and of
the THOR README):

* **LiDAR → body**: ``T_BL = [[R_z(ψ_n) R_y(φ_h), (0, 0, h_L)]]`` — the head
  turns by the neck yaw, then tilts by the head pitch, and the LiDAR's origin is
  ``h_L`` = 0.15 m above the head joint (the offset is not rotated);
* **body → world**: ``T_WB = [[R_z(θ), (x, y, h_B)]]`` — the body frame, at the
  top of the body, stands ``h_B`` = 0.93 + 0.33 = 1.26 m above the floor at the
  walking pose ``(x, y, θ)``.

So ``p_W = T_WB T_BL p_L``: first the head joints, then the body pose. With
``R_y(φ)`` the right-handed rotation about y, a **positive** head pitch tilts
the beam straight ahead **down**: ``R_y(φ) (1, 0, 0) = (cos φ, 0, −sin φ)``. A
beam straight ahead with the head pitched by ``φ > 0`` therefore hits the floor
``(h_B + h_L) / tan φ`` = 1.41 m / tan φ ahead of the robot — 7.4 m at the 10.8°
THOR holds for a minute in its training log, 1.6 m at its 41° peak.

Scans (~40 Hz) and joint samples (~120 Hz) come from different logs:
:func:`joints_at` picks, for each scan, the joint sample nearest in time.
Which returns to map (range limits, floor) is decided by the mapping layer,
:func:`fastslam_edu.grid.thor.filter_returns`.

Every function is vectorised: scans, joint angles and poses broadcast over
leading dimensions ``...``, beams run along the last axis ``B``.
"""

from __future__ import annotations

import numpy as np

from fastslam_edu.core.checks import finite_array

__all__ = [
    "BODY_HEIGHT",
    "LIDAR_ABOVE_HEAD",
    "LIDAR_HEIGHT",
    "MIN_RANGE",
    "MAX_RANGE",
    "FLOOR_Z",
    "rot_z",
    "rot_y",
    "homogeneous",
    "lidar_to_body",
    "body_to_world",
    "lidar_to_world",
    "beam_points_lidar",
    "beam_directions_world",
    "lidar_points_world",
    "joints_at",
    "nearest_sample",
]

#: Height of the body frame (top of the head joint) above the floor [m]: 0.93 + 0.33.
BODY_HEIGHT = 0.93 + 0.33
#: Height of the LiDAR's origin above the head joint [m].
LIDAR_ABOVE_HEAD = 0.15
#: Height of the LiDAR's origin above the floor [m]: 1.41.
LIDAR_HEIGHT = BODY_HEIGHT + LIDAR_ABOVE_HEAD
#: Valid range interval of the Hokuyo UTM-30LX [m].
MIN_RANGE, MAX_RANGE = 0.1, 30.0
#: Returns whose world height is below this [m] are taken as floor.
FLOOR_Z = 0.1


# --------------------------------------------------------------------------- checks


def _pose(pose, caller: str) -> np.ndarray:
    p = finite_array("pose", pose, caller)
    if p.ndim == 0 or p.shape[-1] != 3:
        raise ValueError(f"{caller}: pose must have shape (..., 3) = (x, y, yaw), got shape {p.shape}")
    return p


# --------------------------------------------------------------------------- rotations and rigid motions


def rot_z(a) -> np.ndarray:
    """Rotation about z by ``a`` [rad] (yaw), shape ``(..., 3, 3)``.

    ``R_z(a) = [[cos a, −sin a, 0], [sin a, cos a, 0], [0, 0, 1]]``: turns x
    towards y (to the left).
    """
    a = finite_array("a", a, "rot_z")
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def rot_y(a) -> np.ndarray:
    """Rotation about y by ``a`` [rad] (pitch), shape ``(..., 3, 3)``.

    ``R_y(a) = [[cos a, 0, sin a], [0, 1, 0], [−sin a, 0, cos a]]``: turns x
    towards −z, so a positive pitch looks **down**.
    """
    a = finite_array("a", a, "rot_y")
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def homogeneous(R, t) -> np.ndarray:
    """The 4 × 4 rigid motion ``[[R, t], [0, 0, 0, 1]]``, shape ``(..., 4, 4)``.

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
        Rotation.
    t : array_like, shape (..., 3)
        Translation [m]; leading dimensions broadcast with those of ``R``.
    """
    R = finite_array("R", R, "homogeneous")
    t = finite_array("t", t, "homogeneous")
    if R.shape[-2:] != (3, 3) or t.ndim == 0 or t.shape[-1] != 3:
        raise ValueError(f"homogeneous: R must be (..., 3, 3) and t (..., 3), got {R.shape} and {t.shape}")
    lead = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros(lead + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def lidar_to_body(neck, head) -> np.ndarray:
    """``T_BL``: LiDAR frame → body frame, ``[[R_z(ψ_n) R_y(φ_h), (0, 0, h_L)]]``, shape ``(..., 4, 4)``.

    Parameters
    ----------
    neck : array_like, shape (...)
        Neck yaw ``ψ_n`` [rad] (positive: looks left).
    head : array_like, shape (...)
        Head pitch ``φ_h`` [rad] (positive: looks down).
    """
    neck = finite_array("neck", neck, "lidar_to_body")
    head = finite_array("head", head, "lidar_to_body")
    R = rot_z(neck) @ rot_y(head)
    return homogeneous(R, np.array([0.0, 0.0, LIDAR_ABOVE_HEAD]))


def body_to_world(pose) -> np.ndarray:
    """``T_WB``: body frame → world, ``[[R_z(θ), (x, y, h_B)]]``, shape ``(..., 4, 4)``.

    Parameters
    ----------
    pose : array_like, shape (..., 3)
        Walking pose ``(x, y, θ)`` [m, m, rad] of the body on the floor.
    """
    p = _pose(pose, "body_to_world")
    t = np.stack([p[..., 0], p[..., 1], np.full(p.shape[:-1], BODY_HEIGHT)], axis=-1)
    return homogeneous(rot_z(p[..., 2]), t)


def lidar_to_world(neck, head, pose) -> np.ndarray:
    """``T_WL = T_WB T_BL``: LiDAR frame → world, shape ``(..., 4, 4)`` (leading dims broadcast).

    Its last column holds the LiDAR's origin in the world, ``(x, y, h_B + h_L)``.
    """
    return body_to_world(pose) @ lidar_to_body(neck, head)


# --------------------------------------------------------------------------- beams


def beam_points_lidar(ranges, angles) -> np.ndarray:
    """Beam endpoints in the LiDAR frame, ``p_L = (r cos α, r sin α, 0)``, shape ``(..., B, 3)``.

    Parameters
    ----------
    ranges : array_like, shape (..., B)
        Ranges ``r`` [m], finite (drop "no return" beams first, or use :func:`filter_returns`).
    angles : array_like, shape (B,)
        Beam angles ``α`` [rad], 0 ahead, positive to the left.
    """
    r = finite_array("ranges", ranges, "beam_points_lidar")
    a = finite_array("angles", angles, "beam_points_lidar")
    if a.ndim != 1 or r.ndim == 0 or r.shape[-1] != a.shape[0]:
        raise ValueError(
            f"beam_points_lidar: angles must be (B,) and ranges (..., B), got {a.shape} and {r.shape}"
        )
    return np.stack([r * np.cos(a), r * np.sin(a), np.zeros_like(r)], axis=-1)


def beam_directions_world(angles, neck, head, pose) -> tuple[np.ndarray, np.ndarray]:
    """Origin and unit directions of the beams in the world (for ray casting).

    ``o = T_WL (0, 0, 0, 1)``, ``d_b = R_z(θ) R_z(ψ_n) R_y(φ_h) (cos α_b, sin α_b, 0)``.

    Parameters
    ----------
    angles : array_like, shape (B,)
    neck, head : array_like, shape (...)
    pose : array_like, shape (..., 3)

    Returns
    -------
    origin : ndarray, shape (..., 3)
        The LiDAR's origin [m], ``(x, y, 1.41)``.
    directions : ndarray, shape (..., B, 3)
        Unit vectors.
    """
    T = lidar_to_world(neck, head, pose)
    a = finite_array("angles", angles, "beam_directions_world")
    if a.ndim != 1:
        raise ValueError(f"beam_directions_world: angles must be (B,), got {a.shape}")
    u = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=-1)  # (B, 3)
    d = u @ np.swapaxes(T[..., :3, :3], -1, -2)  # row b: R u_b
    return T[..., :3, 3], d


def lidar_points_world(ranges, angles, neck, head, pose) -> np.ndarray:
    """World coordinates of beam endpoints, ``p_W = T_WB(x, y, θ) T_BL(ψ_n, φ_h) p_L``.

    Parameters
    ----------
    ranges : array_like, shape (..., B)
        Ranges [m] of one scan ``(B,)`` or of many ``(N, B)``.
    angles : array_like, shape (B,)
        Beam angles [rad].
    neck, head : float or array_like, shape (...)
        Neck yaw and head pitch [rad] at each scan (:func:`joints_at`).
    pose : array_like, shape (..., 3)
        Body pose ``(x, y, θ)`` at each scan.

    Returns
    -------
    ndarray, shape (..., B, 3)
        ``(B, 3)`` for one scan; ``(N, B, 3)`` for ``N`` scans with ``ranges``
        ``(N, B)``, ``neck``/``head`` ``(N,)`` and ``pose`` ``(N, 3)``.
    """
    p_l = beam_points_lidar(ranges, angles)
    T = lidar_to_world(neck, head, pose)  # (..., 4, 4)
    lead = np.broadcast_shapes(p_l.shape[:-2], T.shape[:-2])
    T = np.broadcast_to(T, lead + (4, 4))
    p_l = np.broadcast_to(p_l, lead + p_l.shape[-2:])
    return p_l @ np.swapaxes(T[..., :3, :3], -1, -2) + T[..., None, :3, 3]  # row b: R p_b + t


# --------------------------------------------------------------------------- time matching


def nearest_sample(t_query, t_samples) -> np.ndarray:
    """Index of the sample nearest in time to each query: ``argmin_j |t_j − t_k|``.

    Ties (a query exactly half-way) go to the earlier sample. Queries before
    the first sample get index 0, after the last get the last index.

    Parameters
    ----------
    t_query : array_like, shape (N,)
        E.g. scan times [s].
    t_samples : array_like, shape (n,)
        E.g. joint-sample times [s], non-decreasing.

    Returns
    -------
    ndarray of int64, shape (N,)
    """
    tq = finite_array("t_query", t_query, "nearest_sample")
    ts = finite_array("t_samples", t_samples, "nearest_sample")
    if ts.ndim != 1 or ts.size == 0:
        raise ValueError(f"nearest_sample: t_samples must be a non-empty 1-D array, got shape {ts.shape}")
    if ts.size > 1 and (np.diff(ts) < 0).any():
        k = int(np.argmax(np.diff(ts) < 0))
        raise ValueError(f"nearest_sample: t_samples must be non-decreasing; t[{k + 1}] = {ts[k + 1]} < t[{k}] = {ts[k]}")
    if ts.size == 1:
        return np.zeros(tq.shape, dtype=np.int64)
    j = np.clip(np.searchsorted(ts, tq, side="left"), 1, ts.size - 1)  # ts[j−1] < t ≤ ts[j] inside the log
    earlier = (tq - ts[j - 1]) <= (ts[j] - tq)
    return np.where(earlier, j - 1, j).astype(np.int64)


def joints_at(t_scans, t_joints, neck, head, *, max_gap: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Neck and head angles at each scan: the joint sample nearest in time.

    ``ψ_n(t_k) = neck[j_k]``, ``φ_h(t_k) = head[j_k]`` with
    ``j_k = argmin_j |t_j − t_k|`` (:func:`nearest_sample`).

    Parameters
    ----------
    t_scans : array_like, shape (N,)
        Scan times [s].
    t_joints : array_like, shape (n,)
        Joint-sample times [s] (same clock), non-decreasing.
    neck, head : array_like, shape (n,)
        Neck yaw and head pitch [rad] per joint sample.
    max_gap : float, optional
        If given, a scan whose nearest joint sample is more than ``max_gap``
        seconds away raises ValueError (e.g. a scan outside the joint log).

    Returns
    -------
    neck_k, head_k : ndarray, shape (N,) each
    """
    tj = finite_array("t_joints", t_joints, "joints_at")
    neck = finite_array("neck", neck, "joints_at")
    head = finite_array("head", head, "joints_at")
    if tj.ndim != 1 or neck.shape != tj.shape or head.shape != tj.shape:
        raise ValueError(
            f"joints_at: t_joints, neck and head must be 1-D of equal length, got {tj.shape}, {neck.shape}, {head.shape}"
        )
    ts = finite_array("t_scans", t_scans, "joints_at")
    j = nearest_sample(ts, tj)
    if max_gap is not None:
        gap = np.abs(tj[j] - ts)
        if (gap > max_gap).any():
            k = int(np.argmax(gap))
            raise ValueError(
                f"joints_at: scan {k} at t = {ts.flat[k]:.3f} s is {gap.flat[k]:.3f} s from the nearest joint sample "
                f"(max_gap = {max_gap} s): is it outside the joint log [{tj[0]:.3f}, {tj[-1]:.3f}]?"
            )
    return neck[j], head[j]
