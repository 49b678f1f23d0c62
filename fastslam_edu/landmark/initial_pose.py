"""Where the robot starts, from its first sightings of surveyed landmarks.

FastSLAM estimates the map in the frame of the robot's initial pose
:math:`x_0`: on MR.CLAM the filter starts from the groundtruth at the first
step, and the absolute errors (path, landmarks) are measured in that frame.
Robots without groundtruth (Dataset 1, robots 3–5) have no :math:`x_0` to start
from. But the landmarks were surveyed (``Landmark_Groundtruth.dat``), and a
robot that sees two of them knows where it is:

1. **Dead-reckon** the first seconds of odometry from an arbitrary start frame
   :math:`S` (:math:`x = 0, y = 0, \\theta = 0` at the first step): pose :math:`x^S_j` at
   the time of sighting :math:`j` (noise-free, :func:`fastslam_edu.core.motion.dead_reckon_at`).
2. **Place each sighting** :math:`z_j = (r_j, \\phi_j)` of landmark :math:`k_j` in :math:`S` with the
   inverse measurement model, :math:`p_j = h^{-1}(x^S_j, z_j)`
   (:func:`fastslam_edu.core.measurement.landmark_from_measurement`), and take the
   median over the sightings of each landmark: one point :math:`\\bar p_k` per landmark.
3. **Align** the points onto the surveyed positions :math:`m_k` with the rigid
   motion :math:`(R, t)` that minimises :math:`\\sum_k \\| R \\bar p_k + t - m_k \\|^2`
   (:func:`fastslam_edu.core.se2.align_se2`): the start frame's origin and axis in
   the world, :math:`x_0 = (t_x, t_y, \\angle R)`.

With two landmarks the rotation rests on their separation: a few centimetres
of error over a metre is a few degrees. The window grows (``window_s``, up
to ``max_window_s``) until at least ``min_landmarks`` landmarks have been
seen, two of them at least ``min_separation_m`` apart (MR.CLAM's landmarks
stand in groups a few decimetres wide); the longer it has to be, the more the
dead reckoning adds. :func:`initial_pose_from_landmarks` reports what it used
and the residual of the fit, so that a poor start is seen, not hidden.

This uses the surveyed map to place the start, which the SLAM run itself
never sees afterwards; it is what groundtruth does for the other robots (an
absolute frame to score in), for logs that have none.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fastslam_edu.datasets.log import RobotLog
from fastslam_edu.core.measurement import landmark_from_measurement
from fastslam_edu.core.motion import dead_reckon_at
from fastslam_edu.core.se2 import align_se2, apply_se2

#: Seconds of the log looked at first, and at most.
WINDOW_S = 10.0
MAX_WINDOW_S = 60.0


@dataclass(frozen=True)
class InitialPose:
    """The initial pose found by :func:`initial_pose_from_landmarks`.

    Attributes
    ----------
    x0 : ndarray (3,)
        :math:`(x, y, \\theta)` at ``t0`` [m, m, rad], world frame.
    t0 : float
        Time of the pose [s]: the first odometry or measurement time of the log.
    window_s : float
        Seconds of sightings used.
    subjects : tuple of int
        Landmarks (subject numbers) used.
    sightings : int
        Number of sightings used.
    residual_m : float
        RMS distance between the aligned points :math:`R \\bar p_k + t` and the
        surveyed :math:`m_k` [m]: large when a sighting or the dead reckoning is off.
    """

    x0: np.ndarray
    t0: float
    window_s: float
    subjects: tuple[int, ...]
    sightings: int
    residual_m: float

    def describe(self) -> str:
        x, y, th = self.x0
        return (f"initial pose from {len(self.subjects)} surveyed landmarks ({self.sightings} sightings in the first "
                f"{self.window_s:g} s): x = {x:.3f} m, y = {y:.3f} m, theta = {np.degrees(th):.1f} deg, "
                f"fit residual {self.residual_m:.3f} m")


def initial_pose_from_landmarks(log: RobotLog, landmarks: np.ndarray, landmark_subjects, *,
                                window_s: float = WINDOW_S, max_window_s: float = MAX_WINDOW_S,
                                min_landmarks: int = 2, min_separation_m: float = 1.0) -> InitialPose:
    """The pose at the start of ``log`` from its first sightings of the surveyed ``landmarks``.

    Parameters
    ----------
    log : RobotLog
        Odometry and measurements (groundtruth not needed).
    landmarks : array_like, shape (N, 2)
        Surveyed landmark positions [m], in the order of ``landmark_subjects``.
    landmark_subjects : array_like of int, shape (N,)
        Subject number of each row of ``landmarks``.
    window_s, max_window_s : float
        Sightings of the first ``window_s`` seconds are used; the window is
        doubled (up to ``max_window_s``) until the landmarks suffice.
    min_landmarks : int
        Distinct landmarks needed (≥ 2: one landmark does not fix the heading).
    min_separation_m : float
        Two of the landmarks used must lie at least this far apart [m].

    Returns
    -------
    InitialPose

    Raises
    ------
    ValueError
        No odometry, or too few (or too close) landmarks seen within ``max_window_s``;
        the message says what was seen.
    """
    landmarks = np.asarray(landmarks, dtype=float)
    subjects = np.asarray(landmark_subjects, dtype=int)
    if landmarks.shape != (len(subjects), 2) or not np.isfinite(landmarks).all():
        raise ValueError(f"landmarks must be finite positions of shape ({len(subjects)}, 2), got {landmarks.shape}")
    if min_landmarks < 2:
        raise ValueError(f"min_landmarks must be at least 2 (one landmark leaves the heading free), got {min_landmarks}")
    odo, meas = log.odometry, log.measurements
    if len(odo) == 0:
        raise ValueError(f"robot {log.robot} ({log.source}): no odometry to dead-reckon the first seconds with")
    t0 = float(min(odo["time"].iloc[0], meas["time"].iloc[0] if len(meas) else np.inf))
    row = {int(s): i for i, s in enumerate(subjects)}
    known = meas[meas["subject"].isin(list(row))]
    window = float(window_s)
    while True:
        seen = known[known["time"] <= t0 + window]
        found = _fit(odo, seen, landmarks, row, t0, min_landmarks, min_separation_m)
        if found is not None or window >= max_window_s:
            break
        window = min(2.0 * window, float(max_window_s))
    if found is None:
        names = sorted(set(int(s) for s in seen["subject"]))
        raise ValueError(
            f"robot {log.robot} ({log.source}): in the first {window:g} s it sees {len(names)} surveyed "
            f"landmark(s) {names}; an initial pose needs {min_landmarks}, two of them at least {min_separation_m} m apart"
        )
    x0, used, n, residual = found
    return InitialPose(x0=x0, t0=t0, window_s=window, subjects=used, sightings=n, residual_m=residual)


def _fit(odo, seen, landmarks, row, t0, min_landmarks, min_separation_m):
    """Steps 1–3 of the module docstring for the sightings ``seen``; None if they do not suffice."""
    if len(seen) == 0:
        return None
    times = seen["time"].to_numpy(dtype=float)
    poses = dead_reckon_at(odo, np.concatenate([[t0], times]))[1:]  # start frame: x0 = (0, 0, 0) at t0
    z = seen[["range", "bearing"]].to_numpy(dtype=float)
    points = landmark_from_measurement(poses, z)
    keys = seen["subject"].to_numpy(dtype=int)
    used = sorted(set(keys.tolist()))
    if len(used) < min_landmarks:
        return None
    p = np.array([np.median(points[keys == s], axis=0) for s in used])
    m = landmarks[[row[s] for s in used]]
    if np.linalg.norm(m[:, None] - m[None], axis=2).max() < min_separation_m:
        return None
    R, t, angle = align_se2(p, m)
    residual = float(np.sqrt(np.mean(np.sum((apply_se2(p, R, t) - m) ** 2, axis=1))))
    return np.array([t[0], t[1], angle]), tuple(used), len(seen), residual


__all__ = ["InitialPose", "initial_pose_from_landmarks", "WINDOW_S", "MAX_WINDOW_S"]
