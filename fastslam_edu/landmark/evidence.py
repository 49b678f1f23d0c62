"""The tempering exponent β: the fraction of independent evidence a sighting carries, for sightings of one landmark
close in time.

Readings of one landmark within a second are near-copies whose error changes only as the viewpoint does: counted as
independent, they make the filter several times too confident. Each sighting's log-likelihood is weighted by
:math:`\\beta = \\min(1, \\Delta t / \\tau)`
(:attr:`fastslam_edu.landmark.fastslam.FastSLAMParams.measurement_correlation_s`).

One name for one concept: the tempering exponent β. :func:`tempering_exponents` is the teaching form (it returns β);
:func:`tempering_exponents_kernel` its compiled twin, the one the filter runs (it writes β into an array it is given).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def tempering_exponents_kernel(t, j, last_seen, tau, beta):
    """Tempering exponents ``beta[i] = min(1, (t - last_seen[j[i]]) / tau)`` (n,) of the sightings of landmarks
    ``j`` (n,) at time ``t`` [s], then ``last_seen[j] = t``; ``tau`` [s] <= 0: all 1 (the textbook)."""
    if tau <= 0.0:
        beta[:] = 1.0
        return
    for i in range(j.shape[0]):
        beta[i] = min(1.0, (t - last_seen[j[i]]) / tau)
    for i in range(j.shape[0]):
        last_seen[j[i]] = t


def tempering_exponents(t, landmarks, last_seen, tau: float | None) -> np.ndarray:
    """Tempering exponents :math:`\\beta = \\min(1, \\Delta t / \\tau)` of the likelihoods of sightings at time ``t``.

    :math:`\\Delta t` is the time since the previous sighting of the same landmark
    (``last_seen`` (N,) [s], ``-inf`` if none; updated in place to ``t``).

    Why: FastSLAM multiplies the likelihoods of all sightings as if their errors
    were independent. MR.CLAM's are not: a landmark's range and bearing errors
    persist for seconds (correlation of the residuals against groundtruth,
    Dataset 6: range 0.87 after 1 s, 0.59 after 4 s; bearing 0.61 and 0.50),
    and a landmark in view is read 2–3 times per second. Counted as
    independent, a few seconds of near-copies make the weights far too peaked,
    resampling throws away particles that were right, and the heading
    hypotheses die out (particle depletion). Raising each likelihood to the
    power β — a "tempered" likelihood — counts a sighting :math:`\\Delta t` after the
    previous one as the fraction :math:`\\Delta t / \\tau` of an independent one. For an
    AR(1) error with one-second correlation ρ, the new information per reading is
    about :math:`(1-\\rho)/(1+\\rho)`: 0.24 for the bearing (:math:`\\tau \\approx 4` s), 0.07 for the
    range (~14 s). ``tau=None`` gives β = 1 (the textbook).

    Returns ``beta`` (n,) for ``landmarks`` (n,).
    """
    landmarks = np.asarray(landmarks, dtype=np.int64).reshape(-1)
    beta = np.empty(len(landmarks))
    tempering_exponents_kernel(float(t), landmarks, last_seen, 0.0 if tau is None else float(tau), beta)
    return beta


__all__ = ["tempering_exponents", "tempering_exponents_kernel"]
