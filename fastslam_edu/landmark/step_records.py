"""The named tuples the compiled FastSLAM step takes and writes (:mod:`fastslam_edu.landmark.fastslam_step`): the
particle set's arrays, one instant's sightings, the event stream, the run's settings and its record, with the names
of the record's counters and of the compiled resamplers. One small module, imported by the kernels and by the code
that calls them.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Particles(NamedTuple):
    """The particle set's arrays (shapes in the module docstring); the kernels change them in place."""

    poses: np.ndarray
    mu: np.ndarray
    sigma: np.ndarray
    seen: np.ndarray
    count: np.ndarray
    logw: np.ndarray


class Sightings(NamedTuple):
    """The n landmark sightings of one instant.

    z (n, 2) ``(r, φ)`` [m, rad]; j (n,) landmark indices; R (n, 2, 2) noise
    covariances; escape (n,) bool: applied without the gate; beta (n,): exponent
    of the likelihood; loglik (M, n): where not NaN, the log-likelihood to weigh
    particle m with instead of FastSLAM 1.0's (FastSLAM 2.0's proposal).
    """

    z: np.ndarray
    j: np.ndarray
    R: np.ndarray
    escape: np.ndarray
    beta: np.ndarray
    loglik: np.ndarray


#: The resamplers the compiled run has (:func:`fastslam_edu.landmark.particle_resampling.resampling_indices`), by name.
RESAMPLER_CODES = {"systematic": 0, "stratified": 1, "roulette": 2, "multinomial": 2}


class Log(NamedTuple):
    """The event stream as the compiled run takes it (:class:`fastslam_edu.datasets.log.EventStream`).

    t (N,) [s]; u (N, 2) commands; dt (N,) [s]; offsets (N + 1,): the sightings of
    step k are ``offsets[k]:offsets[k + 1]`` of z (n, 2), j (n,), R (n, 2, 2).
    """

    t: np.ndarray
    u: np.ndarray
    dt: np.ndarray
    offsets: np.ndarray
    z: np.ndarray
    j: np.ndarray
    R: np.ndarray


class Settings(NamedTuple):
    """noise (4,) densities; n_draws 2 or 3; gate_chi2 (inf: none); escape_s; tau (0: no tempering);
    update_map; resample_threshold; resampler (:data:`RESAMPLER_CODES`); proposal 0 (FastSLAM 1.0) or
    1 (2.0, :mod:`fastslam_edu.landmark.proposal`); min_count: sightings of a landmark before 2.0 uses it."""

    noise: np.ndarray
    n_draws: int
    gate_chi2: float
    escape_s: float
    tau: float
    update_map: bool
    resample_threshold: float
    resampler: int
    proposal: int = 0
    min_count: int = 2


#: The counters of :attr:`Record.totals` (one int64 array, so that the compiled run counts in place), by name:
#: measurement steps done, sightings used, sightings rejected by the gate, resamplings.
STEPS_DONE, SIGHTINGS_USED, SIGHTINGS_REJECTED, RESAMPLES = 0, 1, 2, 3
N_TOTALS = 4


class Record(NamedTuple):
    """What the run writes: pose_mean, pose_best (N, 3); ess_t, ess (one per measurement step);
    w (M,) the current normalised weights; unexplained_since, last_seen (N,) the gate's and the
    tempering's memory; totals (:data:`N_TOTALS`,) int, read by name: ``totals[STEPS_DONE]``,
    ``totals[SIGHTINGS_USED]``, ``totals[SIGHTINGS_REJECTED]``, ``totals[RESAMPLES]``."""

    pose_mean: np.ndarray
    pose_best: np.ndarray
    ess_t: np.ndarray
    ess: np.ndarray
    w: np.ndarray
    unexplained_since: np.ndarray
    last_seen: np.ndarray
    totals: np.ndarray


__all__ = ["Particles", "Sightings", "RESAMPLER_CODES", "Log", "Settings", "STEPS_DONE", "SIGHTINGS_USED",
           "SIGHTINGS_REJECTED", "RESAMPLES", "N_TOTALS", "Record"]
