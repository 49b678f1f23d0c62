"""From a robot's log to the filter's event stream: when to move, with what, and what is seen.

A filter consumes an :class:`~fastslam_edu.datasets.log.EventStream`: N steps,
each "propagate from ``t[k-1]`` to ``t[k]`` with ``u[k]`` over ``dt[k]``,
then apply the measurements of step ``k``". Two ways to build one from a
:class:`~fastslam_edu.datasets.log.RobotLog`:

* ``rate="full"`` (:func:`full_rate_stream`) uses every time stamp of the
  log, with the odometry command held between its rows (zero-order hold);
* ``rate="1hz"`` (:func:`one_hz_stream`) repeats the cleaning of the
  FastSLAM-on-MR.CLAM write-up (Chen, Iwasa et al., E205): everything
  averaged per whole second, one step per second.

:func:`groundtruth_at` interpolates the groundtruth pose at any time (for
the initial pose ``x0`` and for error curves).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd

from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.core.se2 import interpolate_poses
from fastslam_edu.datasets.log import EventStream, RobotLog

RATES = ("full", "1hz")


# --------------------------------------------------------------------------
# groundtruth
# --------------------------------------------------------------------------


def groundtruth_at(log: RobotLog, t, tolerance: float = 0.5) -> np.ndarray:
    """Groundtruth pose of the robot at time(s) ``t``, interpolated.

    ``x`` and ``y`` are interpolated linearly between the two nearest
    groundtruth rows; the heading is unwrapped first (so that going from
    179° to -179° interpolates through 180°, not through 0°), interpolated,
    then wrapped back to (-π, π]. Times up to ``tolerance`` before the first
    or after the last row get that row's pose.

    Parameters
    ----------
    log : RobotLog
        Must have groundtruth.
    t : float or array_like, shape (n,)
        Times [s].
    tolerance : float
        How far [s] outside the groundtruth time span ``t`` may be.

    Returns
    -------
    ndarray, shape (n, 3)
        Poses ``(x, y, θ)`` [m, m, rad].

    Raises
    ------
    ValueError
        If the log has no groundtruth, ``t`` is not finite, or a ``t`` lies
        more than ``tolerance`` outside the groundtruth span.
    """
    gt = log.groundtruth
    if gt is None:
        raise ValueError(f"robot {log.robot} ({log.source or 'no source'}) has no groundtruth")
    t = np.atleast_1d(np.asarray(t, dtype=float))
    if not np.isfinite(t).all():
        raise ValueError(f"groundtruth_at: times must be finite, got {float(t[~np.isfinite(t)][0])}")
    tg = gt["time"].to_numpy(dtype=float)
    lo, hi = tg[0] - tolerance, tg[-1] + tolerance
    outside = (t < lo) | (t > hi)
    if outside.any():
        raise ValueError(
            f"robot {log.robot} ({log.source or 'no source'}): t = {float(t[outside][0])!r} s is outside the "
            f"groundtruth span [{float(tg[0])!r}, {float(tg[-1])!r}] s by more than {tolerance} s"
        )
    return interpolate_poses(t, tg, gt[["x", "y", "theta"]].to_numpy(dtype=float), tolerance=tolerance)


# --------------------------------------------------------------------------
# the 1 Hz cleaning of the write-up
# --------------------------------------------------------------------------


def round_to_second(t) -> np.ndarray:
    """Round times to the nearest whole second, halves up: ``⌊t + 0.5⌋``.

    So second ``s`` collects the times in ``[s - 0.5, s + 0.5)``.
    """
    return np.floor(np.asarray(t, dtype=float) + 0.5)


def clean_1hz_table(df: pd.DataFrame, keys: Iterable[str] = ("time",),
                    angle_columns: Iterable[str] = ()) -> pd.DataFrame:
    """Average a table per whole second (and per other ``keys``), as the write-up does.

    The ``time`` column is rounded with :func:`round_to_second`; the other
    columns are averaged over the rows that share the same ``keys``. Angle
    columns are averaged as angles: each value is first brought next to the
    group's first value, ``φ_ref + wrap(φ - φ_ref)``, then averaged and
    wrapped, so that ``{179°, -179°}`` averages to 180°, not 0°. (Away from
    ±π this is exactly the arithmetic mean.)

    Parameters
    ----------
    df : DataFrame
        Has a ``time`` column [s].
    keys : iterable of str
        Grouping columns, including ``"time"``; e.g. ``("time", "subject")``
        for measurements.
    angle_columns : iterable of str
        Columns holding angles [rad].

    Returns
    -------
    DataFrame
        Same columns, one row per group, sorted by ``keys``; ``time`` holds
        whole seconds.

    Examples
    --------
    Odometry ``clean_1hz_table(log.odometry)``; measurements
    ``clean_1hz_table(log.measurements, ("time", "subject"), ("bearing",))``;
    groundtruth ``clean_1hz_table(log.groundtruth, angle_columns=("theta",))``.
    """
    keys = list(keys)
    if "time" not in keys:
        raise ValueError(f"clean_1hz_table: keys must include 'time', got {keys}")
    out = df.copy()
    out["time"] = round_to_second(out["time"].to_numpy())
    values = [c for c in df.columns if c not in keys]
    for c in angle_columns:
        ref = out.groupby(keys, sort=False)[c].transform("first").to_numpy(dtype=float)
        out[c] = ref + wrap_angle(out[c].to_numpy(dtype=float) - ref)
    mean = out.groupby(keys, sort=True)[values].mean().reset_index()
    for c in angle_columns:
        mean[c] = wrap_angle(mean[c].to_numpy(dtype=float))
    mean.attrs = {}
    return mean[list(df.columns)]


# --------------------------------------------------------------------------
# helpers shared by both rates
# --------------------------------------------------------------------------


def _landmark_index(log: RobotLog, landmark_subjects: np.ndarray, subjects: np.ndarray) -> np.ndarray:
    """Filter index ``k`` with ``landmark_subjects[k] == subject`` for each subject."""
    order = np.argsort(landmark_subjects, kind="stable")
    sorted_subjects = landmark_subjects[order]
    pos = np.searchsorted(sorted_subjects, subjects)
    pos_c = np.minimum(pos, len(sorted_subjects) - 1)
    found = (pos < len(sorted_subjects)) & (sorted_subjects[pos_c] == subjects)
    if not found.all():
        missing = sorted(set(subjects[~found].tolist()))
        raise ValueError(
            f"robot {log.robot} ({log.source or 'no source'}) measures subjects {missing} "
            f"that are not in landmark_subjects {landmark_subjects.tolist()}"
        )
    return order[pos_c]


def _as_subjects(landmark_subjects) -> np.ndarray:
    subjects = np.asarray(landmark_subjects)
    if subjects.ndim != 1 or subjects.size == 0:
        raise ValueError(f"landmark_subjects must be a non-empty 1-D list of ints, got {landmark_subjects!r}")
    if not np.issubdtype(subjects.dtype, np.integer):
        if not (np.isfinite(subjects.astype(float)).all() and (subjects == np.round(subjects)).all()):
            raise ValueError(f"landmark_subjects must be whole numbers, got {subjects.tolist()}")
    subjects = subjects.astype(np.int64)
    if np.unique(subjects).size != subjects.size:
        raise ValueError(f"landmark_subjects has repeated subjects: {subjects.tolist()}")
    return subjects


def _check_table(log: RobotLog, df: pd.DataFrame, columns: list[str], what: str) -> np.ndarray:
    """The columns of ``df`` as floats, checked finite and time-ordered."""
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise ValueError(f"robot {log.robot} {what}: missing columns {missing}")
    values = df[columns].to_numpy(dtype=float)
    bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
    if bad.size:
        raise ValueError(f"robot {log.robot} {what} row {int(bad[0])}: NaN or inf in {values[bad[0]].tolist()}")
    back = np.flatnonzero(np.diff(values[:, 0]) < 0)
    if back.size:
        raise ValueError(f"robot {log.robot} {what} row {int(back[0]) + 1}: time goes backwards")
    return values


def _window(t: np.ndarray, t_start: float | None, t_end: float | None) -> np.ndarray:
    keep = np.ones(t.shape, dtype=bool)
    if t_start is not None:
        keep &= t >= t_start
    if t_end is not None:
        keep &= t <= t_end
    return keep


def _start_pose(log: RobotLog, t0: float, x0) -> np.ndarray | None:
    if x0 is not None:
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (3,) or not np.isfinite(x0).all():
            raise ValueError(f"x0 must be a finite pose (x, y, θ) of shape (3,), got {x0.tolist()}")
        return x0
    if log.groundtruth is None:
        return None
    return groundtruth_at(log, [t0])[0]


def _step_boundaries(step: np.ndarray, n_steps: int) -> np.ndarray:
    """Slice boundaries of the measurements of each step (``step`` sorted)."""
    return np.concatenate([[0], np.cumsum(np.bincount(step, minlength=n_steps))]).astype(np.int64)


# --------------------------------------------------------------------------
# the two event streams
# --------------------------------------------------------------------------


def full_rate_stream(log: RobotLog, landmark_subjects, x0=None, t_start: float | None = None,
                     t_end: float | None = None) -> EventStream:
    """Event stream at the log's own time stamps (see :func:`event_stream`, ``rate="full"``)."""
    subjects = _as_subjects(landmark_subjects)
    odo = _check_table(log, log.odometry, ["time", "v", "omega"], "odometry")
    meas = _check_table(log, log.measurements, ["time", "subject", "range", "bearing"], "measurements")
    t_odo, commands = odo[:, 0], odo[:, 1:3]
    keep = _window(meas[:, 0], t_start, t_end)
    meas = meas[keep]
    t = np.unique(np.concatenate([t_odo[_window(t_odo, t_start, t_end)], meas[:, 0]]))
    if t.size == 0:
        raise ValueError(f"robot {log.robot}: no odometry or measurement between t_start={t_start} and t_end={t_end}")
    # u[k]: the last odometry row at or before t[k-1] (zero before the first row)
    u = np.zeros((t.size, 2))
    last = np.searchsorted(t_odo, t[:-1], side="right") - 1
    u[1:][last >= 0] = commands[last[last >= 0]]
    dt = np.diff(t, prepend=t[0])
    step = np.searchsorted(t, meas[:, 0])
    order = np.argsort(step, kind="stable")
    return EventStream(
        t=t, dt=dt, u=u, offsets=_step_boundaries(step[order], t.size),
        z=meas[order][:, 2:4].copy(),
        landmark=_landmark_index(log, subjects, meas[order][:, 1].astype(np.int64)),
        landmark_subjects=subjects, x0=_start_pose(log, float(t[0]), x0), rate="full",
    )


def one_hz_stream(log: RobotLog, landmark_subjects, x0=None, t_start: float | None = None,
                  t_end: float | None = None) -> EventStream:
    """Event stream of the write-up's 1 Hz cleaning (see :func:`event_stream`, ``rate="1hz"``)."""
    subjects = _as_subjects(landmark_subjects)
    _check_table(log, log.odometry, ["time", "v", "omega"], "odometry")
    _check_table(log, log.measurements, ["time", "subject", "range", "bearing"], "measurements")
    odo = clean_1hz_table(log.odometry[["time", "v", "omega"]])
    meas = clean_1hz_table(log.measurements[["time", "subject", "range", "bearing"]],
                           keys=("time", "subject"), angle_columns=("bearing",))
    odo = odo[_window(odo["time"].to_numpy(), t_start, t_end)]
    meas = meas[_window(meas["time"].to_numpy(), t_start, t_end)]
    seconds = np.concatenate([odo["time"].to_numpy(), meas["time"].to_numpy()])
    if seconds.size == 0:
        raise ValueError(f"robot {log.robot}: no odometry or measurement between t_start={t_start} and t_end={t_end}")
    first, last = seconds.min(), seconds.max()
    t = np.arange(first, last + 1.0)
    u = np.zeros((t.size, 2))
    u[(odo["time"].to_numpy() - first).astype(np.int64)] = odo[["v", "omega"]].to_numpy(dtype=float)
    dt = np.ones(t.size)
    dt[0] = 0.0
    step = (meas["time"].to_numpy() - first).astype(np.int64)
    order = np.argsort(step, kind="stable")
    return EventStream(
        t=t, dt=dt, u=u, offsets=_step_boundaries(step[order], t.size),
        z=meas[["range", "bearing"]].to_numpy(dtype=float)[order],
        landmark=_landmark_index(log, subjects, meas["subject"].to_numpy(dtype=np.int64)[order]),
        landmark_subjects=subjects, x0=_start_pose(log, float(t[0]), x0), rate="1hz",
    )


def event_stream(log: RobotLog, landmark_subjects, rate: str = "full", x0=None,
                 t_start: float | None = None, t_end: float | None = None) -> EventStream:
    """Turn one robot's log into the filter's time-ordered steps.

    Every step ``k`` is: propagate the pose from ``t[k-1]`` to ``t[k]`` with
    the command ``u[k] = (v, ω)`` over ``dt[k] = t[k] - t[k-1]``, then
    apply the measurements ``z = (r, φ)`` of step ``k``. Step 0 only
    measures (``dt[0] = 0``, ``u[0] = (0, 0)`` at full rate).

    ``rate="full"`` — the log's own time stamps
        * ``t`` = the sorted union of the odometry times and the measurement
          times (repeated times merged), so several measurements at one
          instant form one step, and a measurement at an odometry time shares
          that step.
        * ``u[k]`` = the latest odometry row at or before ``t[k-1]`` (the
          command is held until the next row: a zero-order hold); before the
          first odometry row ``u = (0, 0)``. This is exact for commands that
          stay constant between rows: integrating the unicycle over each step
          reproduces the commanded path.
        * Within a step, measurements keep the order of the log.

    ``rate="1hz"`` — the cleaning of the FastSLAM-on-MR.CLAM write-up
        * Times are rounded to the nearest whole second, ``s = ⌊t + 0.5⌋``
          (:func:`round_to_second`), so second ``s`` gathers ``[s-0.5, s+0.5)``.
        * Odometry: ``v`` and ``ω`` averaged over the rows of each second.
        * Measurements: ``r`` and ``φ`` averaged per (second, subject)
          (bearings as angles, see :func:`clean_1hz_table`); within a second
          they are ordered by subject.
        * One step per whole second from the first to the last second that
          has odometry or a measurement; ``dt = 1`` s (``dt[0] = 0``).
        * ``u[k]`` = the averaged command of second ``t[k]`` itself, as in the
          write-up's loop ``propagate(u_t, dt=1)`` then ``reweight(z_t)``; a
          second without odometry gets ``u = (0, 0)`` (robot assumed still).
          The average over ``[t-0.5, t+0.5)`` is applied over ``(t-1, t]``: a
          half-second lag the write-up accepts.
        * ``u[0]`` holds second ``t[0]``'s average but is not used (``dt[0] = 0``):
          the stream starts at ``x0`` at ``t[0]``.

    Parameters
    ----------
    log : RobotLog
    landmark_subjects : array_like of int, shape (N,)
        Subject of each filter index; measurements of other subjects raise.
    rate : {"full", "1hz"}
    x0 : array_like, shape (3,), optional
        Initial pose; default the groundtruth at ``t[0]``
        (:func:`groundtruth_at`), or None if the log has no groundtruth.
    t_start, t_end : float, optional
        Keep only events (for ``"1hz"``: whole seconds) with
        ``t_start <= t <= t_end``. At full rate the command in force at
        ``t_start`` may come from an odometry row before it.

    Returns
    -------
    EventStream
    """
    if rate == "full":
        return full_rate_stream(log, landmark_subjects, x0, t_start, t_end)
    if rate == "1hz":
        return one_hz_stream(log, landmark_subjects, x0, t_start, t_end)
    raise ValueError(f"rate must be one of {RATES}, got {rate!r}")


__all__ = [
    "RATES",
    "clean_1hz_table",
    "event_stream",
    "full_rate_stream",
    "groundtruth_at",
    "one_hz_stream",
    "round_to_second",
]
