"""How step 1 moves the particles and how step 2 weighs them: the proposal strategies of
:func:`fastslam_edu.landmark.fastslam.run_fastslam`'s Python loop (the compiled run picks the same by its
``Settings.proposal``)."""

from __future__ import annotations

import numpy as np

from fastslam_edu.landmark.particle_set import propagate_segment
from fastslam_edu.landmark.proposal import motion_prediction, sample_improved_poses, segment_motion


class MotionProposal:
    """FastSLAM 1.0's proposal: step 1 samples the motion model; the weight is the sighting's likelihood."""

    def move(self, run: "FilterRun", s: int, e: int, n_record: int):
        """Step 1 through steps ``s..e``; returns the estimates ``(mean, best)`` of the first ``n_record`` steps."""
        return propagate_segment(run.particles, run.u[s : e + 1], run.dt[s : e + 1], run.params.motion_noise,
                                 run.rng, run.w, n_record=n_record)

    def weigh(self, run: "FilterRun", s: int, e: int, sightings) -> np.ndarray | None:
        """Log weights (M, n) that replace FastSLAM 1.0's (NaN: keep them); None: all of FastSLAM 1.0's."""
        return None


class ImprovedProposal(MotionProposal):
    """FastSLAM 2.0's proposal: poses drawn given the sightings too (:mod:`fastslam_edu.landmark.proposal`)."""

    def move(self, run, s, e, n_record):
        run.x_start = run.particles.poses.copy()
        return super().move(run, s, e, n_record)

    def weigh(self, run, s, e, sightings):
        if run.x_start is None:  # the poses were moved by a hook (a kidnap): no motion to condition on
            return None
        u, dt = run.u[s : e + 1], run.dt[s : e + 1]
        x_bar, P = motion_prediction(run.x_start, *segment_motion(u, dt, run.params.motion_noise))
        return sample_improved_poses(run.particles, sightings, x_bar, P, gate_chi2=run.gate.chi2,
                                     rng=run.rng, min_count=2 if run.update_map else 1)


class KnownPoses(MotionProposal):
    """Mode ``"map"``: every particle at the groundtruth pose (``groundtruth_poses(t) -> (n, 3)``)."""

    def __init__(self, groundtruth_poses):
        if groundtruth_poses is None:
            raise ValueError('mode="map" needs the groundtruth poses (groundtruth_poses=callable t -> (n, 3))')
        self.groundtruth_poses = groundtruth_poses

    def move(self, run, s, e, n_record):
        truth = np.asarray(self.groundtruth_poses(run.stream.t[s : e + 1]), dtype=float)
        run.particles.poses = np.tile(truth[-1], (len(run.particles), 1))
        return truth[:n_record], truth[:n_record]


__all__ = ["MotionProposal", "ImprovedProposal", "KnownPoses"]
