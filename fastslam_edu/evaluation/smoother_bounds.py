"""Two references for the smoother's data association, computed from the true correspondences (scoring only).

The smoother (:mod:`fastslam_edu.landmark.smoother_association`) minimises the penalised cost :math:`J` over the
correspondences, the path and the map by alternation from a few starts. When it stops short of the oracle, either the
cost is wrong (a wrong answer costs less than the right one) or the search is (it stopped in a local minimum); and
the search can fail in the path or in the assignment. The two references tell these apart:

* **the true correspondences' cost** :math:`J^*` (:func:`smoother_bounds`, ``truth``): the alternation started from
  the true correspondences (clutter as outliers) at the filter's path. :math:`J > J^*` for the smoother's answer
  means the cost prefers the truth and the search did not reach it;
* **the path-given bound** (``path_given``): at the path solved with the true correspondences, every sighting
  assigned again from an empty map (:func:`~fastslam_edu.landmark.smoother_association.assign_sightings`, nearest
  frames first) and the alternation run from there: the association the smoother reaches when its path is right.
  Near the oracle, the assignment is not what limits it; the path is.

Neither is a start of the smoother: both read the barcodes.
"""

from __future__ import annotations

import time

import numpy as np

from fastslam_edu.datasets.log import EventStream
from fastslam_edu.landmark.smoother_association import (OUTLIER, SmootherAssociationParams, SmootherAssociationResult,
                                                        alternate, assign_sightings, fit_map, prepare_log, result_of,
                                                        without_transients)


def true_labels(true_index) -> np.ndarray:
    """The true correspondences as the smoother's labels (n,): the surveyed landmark of each sighting, clutter
    (``true_index`` -1: other robots, unknown barcodes) an outlier."""
    true_index = np.asarray(true_index, dtype=np.int64)
    return np.where(true_index >= 0, true_index, OUTLIER)


def smoother_bounds(stream: EventStream, true_index, filter_result,
                    settings: SmootherAssociationParams = SmootherAssociationParams()
                    ) -> tuple[SmootherAssociationResult, SmootherAssociationResult]:
    """``(truth, path_given)`` (module docstring), each a
    :class:`~fastslam_edu.landmark.smoother_association.SmootherAssociationResult` to score like the smoother's own:
    ``truth.cost`` is :math:`J^*`. ``stream``: the anonymous stream the filter ran on, ``true_index`` (n,) its
    sightings' surveyed landmarks (-1: clutter), ``filter_result``: the filter's run
    (:class:`~fastslam_edu.landmark.association.AssociationResult`; its mean path is the first path, its parameters
    the noise model)."""
    true_index = np.asarray(true_index)
    if true_index.shape != (len(stream.z),):
        raise ValueError(f"smoother_bounds: true_index has shape {true_index.shape}, the stream has "
                         f"{len(stream.z)} sightings")
    if len(filter_result.t) != len(stream):
        raise ValueError(f"smoother_bounds: the filter ran {len(filter_result.t)} steps but the stream has "
                         f"{len(stream)}: run the filter on the same stream")
    started = time.perf_counter()
    log = prepare_log(stream, filter_result.params.filter, None, filter_result.params)
    labels = true_labels(true_index)
    poses = np.asarray(filter_result.pose_mean, dtype=float)[log.keys]
    landmarks = fit_map(log, poses, labels, int(labels.max(initial=-1)) + 1)[0]
    truth = alternate(log, poses, labels, landmarks, settings)
    truth_result = result_of(log, truth, [truth.cost], time.perf_counter() - started)
    started = time.perf_counter()
    labels, landmarks, _ = assign_sightings(log, truth.poses, np.zeros((0, 2)), np.zeros((0, 2, 2)), settings)
    given = alternate(log, truth.poses, labels, landmarks, settings)
    if settings.transient_objects:  # as the smoother's own answer (the truth's clutter is outliers already)
        given = without_transients(log, given, settings)
    return truth_result, result_of(log, given, [given.cost], time.perf_counter() - started)


__all__ = ["true_labels", "smoother_bounds"]
