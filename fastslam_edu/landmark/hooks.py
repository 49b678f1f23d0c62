"""Hooks: code run alongside the filter (:func:`fastslam_edu.landmark.fastslam.run_fastslam`), between its steps
or between compiled chunks of steps."""

from __future__ import annotations

import numpy as np

from fastslam_edu.landmark.particle_set import ParticleSet


class Hook:
    """Something run alongside the filter, without changing it unless that is its purpose.

    ``after_motion(run, s, e)`` is called after step 1 of each segment of steps
    ``s..e``; ``after_resampling(run, parents, before)`` after step 3 at each
    measurement step, with the indices drawn (``parents`` (M,): particle ``m``
    is a copy of ``before``'s ``parents[m]``; None when :math:`N_\text{eff}` was
    high enough) and the set as it was before; ``after_step(run, s, e)`` after the
    whole step (with ``run.measured`` True when it had sightings); ``close(run)``
    at the end. ``cut_times``: times at which a segment must end (a hook that acts
    at a time).

    ``chunk_steps``: a hook that uses only ``after_step`` and ``close`` sets it to the
    number of steps it lets the compiled run make between two calls; the run then
    stays compiled (:meth:`FilterRun.run_compiled`) and calls ``after_step(run, s, e)``
    once per chunk of steps ``s..e`` (whole segments; ``run.measured``: whether step
    ``e`` had sightings). None (the default): the hook needs the step-by-step Python loop.
    """

    cut_times: tuple = ()
    chunk_steps: int | None = None

    def after_motion(self, run: "FilterRun", s: int, e: int) -> None:
        pass

    def after_resampling(self, run: "FilterRun", parents: np.ndarray | None, before: ParticleSet) -> None:
        pass

    def after_step(self, run: "FilterRun", s: int, e: int) -> None:
        pass

    def close(self, run: "FilterRun") -> None:
        pass


class Kidnap(Hook):
    """The write-up's kidnapped-robot test: at the first step at or after ``t`` every particle jumps to ``pose``."""

    def __init__(self, t: float, pose):
        self.t, self.pose = float(t), np.asarray(pose, dtype=float)
        self.cut_times = (self.t,)

    def after_motion(self, run, s, e):
        k = int(np.searchsorted(run.stream.t, self.t, side="left"))
        if s <= k <= e:  # segments end at the kidnap step
            run.particles.poses[:] = self.pose
            run.pose_mean[k : e + 1] = run.pose_best[k : e + 1] = self.pose
            run.x_start = None


class Monitor(Hook):
    """Calls ``callback(t, particles, w)`` after every measurement step (after resampling).

    With the step's time, the particle set as stored and the normalised weights
    the step's estimate used: a way to look inside the filter (chapter "Is the
    filter's uncertainty honest?") without changing it. The callback must not
    modify them; its time counts in ``filter_seconds``. Served by the compiled run after each
    measurement step (chunks of one segment).
    """

    chunk_steps = 1

    def __init__(self, callback):
        self.callback = callback

    def after_step(self, run, s, e):
        if run.measured:
            self.callback(run.stream.t[e], run.particles, run.w)

#: Steps the compiled run makes between two updates of the progress bar (a few hundredths of a second).
PROGRESS_CHUNK_STEPS = 4096


class ProgressBar(Hook):
    """A tqdm progress bar over the steps, updated between compiled chunks of :data:`PROGRESS_CHUNK_STEPS` steps
    (as fast as no bar)."""

    chunk_steps = PROGRESS_CHUNK_STEPS

    def __init__(self):
        # here, before the run and its timer: importing tqdm (15-50 ms) and its first bar's lock (it imports
        # multiprocessing, 3-4 ms) are not the filter's time
        from tqdm.auto import tqdm

        tqdm.get_lock()
        self.tqdm, self.bar = tqdm, None

    def after_step(self, run, s, e):
        if self.bar is None:
            self.bar = self.tqdm(total=len(run.stream), unit="step", desc=f"FastSLAM M={len(run.particles)}",
                                 mininterval=0.5)
        self.bar.update(e - s + 1)

    def close(self, run):
        if self.bar is not None:
            self.bar.close()


__all__ = ["Hook", "Kidnap", "Monitor", "ProgressBar", "PROGRESS_CHUNK_STEPS"]
