"""How step 1 moves the particles, and what step 2 conditions the poses on: the proposal strategies of
:func:`fastslam_edu.landmark.fastslam.run_fastslam`'s Python loop (the compiled run picks the same by its
``Settings.proposal``; both weigh with :func:`fastslam_edu.landmark.fastslam_step.weigh_instant`)."""

from __future__ import annotations

import numpy as np

from fastslam_edu.landmark.particle_set import propagate_segment
from fastslam_edu.landmark.fastslam_step import motion_prediction_through_segment


class MotionProposal:
    """FastSLAM 1.0's proposal: step 1 samples the motion model; the weight is the sighting's likelihood."""

    def move(self, run: "FilterRun", s: int, e: int, n_record: int):
        """Step 1 through steps ``s..e``; returns the estimates ``(mean, best)`` of the first ``n_record`` steps."""
        return propagate_segment(run.particles, run.u[s : e + 1], run.dt[s : e + 1], run.params.motion_noise,
                                 run.rng, run.w, n_record=n_record)

    def prediction(self, run: "FilterRun", s: int, e: int):
        """FastSLAM 2.0's motion prediction :math:`(\\bar x, P)` for the sightings at step ``e`` to correct, or None:
        FastSLAM 1.0 (the poses stay as step 1 drew them; the weights are the sightings' likelihoods)."""
        return None


class ImprovedProposal(MotionProposal):
    """FastSLAM 2.0's proposal: poses drawn given the sightings too (:mod:`fastslam_edu.landmark.proposal`)."""

    def move(self, run, s, e, n_record):
        run.x_start = run.particles.poses.copy()
        return super().move(run, s, e, n_record)

    def prediction(self, run, s, e):
        if run.x_start is None:  # the poses were moved by a hook (a kidnap): no motion to condition on
            return None
        return motion_prediction_through_segment(run.x_start, run.u[s : e + 1], run.dt[s : e + 1], run.settings)


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
