"""The structures every data source produces: a robot's log and the filter's event stream.

Both the MR.CLAM reader (:mod:`fastslam_edu.datasets.mrclam`) and the simulator
(:mod:`fastslam_edu.datasets.sim`) produce a :class:`Dataset` of :class:`RobotLog` objects;
:func:`event_stream` turns one robot's log into the time-ordered
:class:`EventStream` the filters consume.

Conventions used throughout the package
---------------------------------------
* Times are seconds (float, as in the ``.dat`` files).
* A pose is ``(x, y, θ)`` in metres and radians, world frame.
* A measurement is ``z = (r, φ)``: range [m] and bearing [rad] in the robot frame.
* Landmarks are indexed ``0 … N-1`` inside the filter; ``landmark_subjects[k]``
  gives the MR.CLAM subject number (6–20) of index ``k``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd


@dataclass(frozen=True)
class RobotLog:
    """Everything recorded by one robot.

    Attributes
    ----------
    robot : int
        Subject number of the robot (1–5 in MR.CLAM).
    odometry : pandas.DataFrame
        Columns ``time, v, omega``: the commanded forward velocity [m/s] and
        angular velocity [rad/s], sorted by time (non-decreasing).
    measurements : pandas.DataFrame
        Columns ``time, subject, range, bearing``: landmark sightings only
        (other robots and unknown barcodes removed), barcodes already mapped to
        subject numbers, sorted by time.
    groundtruth : pandas.DataFrame or None
        Columns ``time, x, y, theta`` (Vicon), or None when the dataset has none.
    dropped : dict
        What was removed from the measurement file and why, e.g.
        ``{"robot_sightings": 212, "unknown_barcodes": {43: 3}}``.
    source : str
        Where the log came from (a folder, or ``"simulation"``): used in messages.
    robot_sightings : pandas.DataFrame or None
        Columns ``time, subject, range, bearing``: this robot's sightings of the other robots
        (subjects 1–5), the rows ``measurements`` leaves out
        (:func:`fastslam_edu.datasets.mrclam.robot_sightings`); None when not read.
    """

    robot: int
    odometry: pd.DataFrame
    measurements: pd.DataFrame
    groundtruth: pd.DataFrame | None
    dropped: dict = field(default_factory=dict)
    source: str = ""
    robot_sightings: pd.DataFrame | None = None


@dataclass(frozen=True)
class Dataset:
    """A whole MR.CLAM-style dataset.

    Attributes
    ----------
    path : pathlib.Path or None
        Folder it was read from (None for a simulation).
    barcodes : dict[int, int]
        Barcode number -> subject number.
    landmarks : pandas.DataFrame
        Landmark groundtruth, index ``subject`` (int), columns ``x, y, x_std, y_std`` [m],
        sorted by subject.
    robots : dict[int, RobotLog]
        Robot subject number -> its log.
    """

    path: Path | None
    barcodes: dict[int, int]
    landmarks: pd.DataFrame
    robots: dict[int, RobotLog]

    @property
    def landmark_subjects(self) -> np.ndarray:
        """Subject numbers of the landmarks, in filter index order, shape (N,)."""
        return self.landmarks.index.to_numpy(dtype=int)

    @property
    def landmark_positions(self) -> np.ndarray:
        """Groundtruth landmark positions in filter index order, shape (N, 2) [m]."""
        return self.landmarks[["x", "y"]].to_numpy(dtype=float)


@dataclass(frozen=True)
class EventStream:
    """The time-ordered input of a filter: N steps, each "propagate, then measure".

    Step ``k`` means: move the robot from ``t[k-1]`` to ``t[k]`` (``dt[k]``
    seconds) with the command ``u[k] = (v, ω)``, then apply the measurements
    ``z[offsets[k]:offsets[k+1]]`` (zero, one or several) of landmarks
    ``landmark[offsets[k]:offsets[k+1]]``.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Step times [s].
    dt : ndarray, shape (N,)
        ``t[k] - t[k-1]`` [s]; ``dt[0] = 0``.
    u : ndarray, shape (N, 2)
        Command ``(v [m/s], ω [rad/s])`` in force during ``(t[k-1], t[k]]``.
    offsets : ndarray of int, shape (N + 1,)
        Measurement slice boundaries, ``offsets[0] = 0``, ``offsets[-1] = n``.
    z : ndarray, shape (n, 2)
        Measurements ``(r [m], φ [rad])``.
    landmark : ndarray of int, shape (n,)
        Filter index (0 … N-1) of the landmark each measurement sees.
    landmark_subjects : ndarray of int, shape (N,)
        Subject number of each filter index.
    x0 : ndarray, shape (3,) or None
        Initial pose (from groundtruth at ``t[0]``) if known.
    rate : str
        ``"full"`` or ``"1hz"``.
    """

    t: np.ndarray
    dt: np.ndarray
    u: np.ndarray
    offsets: np.ndarray
    z: np.ndarray
    landmark: np.ndarray
    landmark_subjects: np.ndarray
    x0: np.ndarray | None = None
    rate: str = "full"

    def __len__(self) -> int:
        return len(self.t)

    def measurements_at(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """``(z, landmark)`` of step ``k``: shapes (n_k, 2) and (n_k,)."""
        s, e = self.offsets[k], self.offsets[k + 1]
        return self.z[s:e], self.landmark[s:e]

    @property
    def n_measurements(self) -> int:
        return int(self.offsets[-1])

    @property
    def sighting_steps(self) -> np.ndarray:
        """The step of each measurement (n,): measurement ``i`` is taken at time ``t[sighting_steps[i]]``."""
        return np.repeat(np.arange(len(self.t)), np.diff(self.offsets))

    @property
    def n_landmarks(self) -> int:
        return len(self.landmark_subjects)
