"""Checking a dataset's landmark table against its own measurements.

Every measurement ``z = (r, φ)`` taken from the groundtruth pose ``x`` puts its
landmark at ``h⁻¹(x, z)``; the median of these implied positions over all of a
landmark's sightings is precise to centimetres
(:func:`fastslam_edu.evaluation.noise_estimation.landmark_check`). If the sightings
labelled ``a`` sit metres from ``a``'s table position but on ``b``'s, and those
labelled ``b`` sit on ``a``'s, the table (or the barcode list) has ``a`` and
``b`` exchanged.

This is not hypothetical: in the copy of MR.CLAM Dataset 1 used by this book,
the sightings labelled 11 land on the table position of 17 and vice versa
(both robots with groundtruth agree, over hundreds of sightings). Scoring a
map against such a table reports errors of metres for landmarks the filter
placed correctly, and localising against it fails. :func:`apply_landmark_audit`
corrects such exchanged pairs and returns what it changed, so that the
correction is reported, never silent; anything else that looks wrong (a
three-way mix-up, a landmark seen too rarely to judge) is left alone.
"""

from __future__ import annotations

import dataclasses

import pandas as pd

from fastslam_edu.evaluation.noise_estimation import OUTLIER_THRESHOLD, landmark_check, measurement_residuals
from fastslam_edu.datasets.log import Dataset

#: Fewest sightings of each landmark of a pair before an exchange is trusted.
MIN_SIGHTINGS = 20

COLUMNS = ["n", "x", "y", "x_seen", "y_seen", "offset", "nearest", "median_range_residual",
           "median_bearing_residual", "suspect"]


def audit_landmarks(dataset: Dataset, robots=None) -> pd.DataFrame:
    """Where each landmark's sightings put it, against the table (one row per measured subject).

    Uses every robot (or those in ``robots``) that has groundtruth. Columns as
    :func:`fastslam_edu.evaluation.noise_estimation.landmark_check`: ``n``, the table ``x, y``,
    the median implied position ``x_seen, y_seen``, their distance ``offset`` [m],
    the table entry ``nearest`` to the implied position, and ``suspect``
    (offset above 0.5 m). Empty when no robot has groundtruth.
    """
    residuals = [
        measurement_residuals(log, dataset)
        for rid, log in dataset.robots.items()
        if (robots is None or rid in robots) and log.groundtruth is not None and not log.measurements.empty
    ]
    if not residuals:
        return pd.DataFrame(columns=COLUMNS, index=pd.Index([], name="subject"))
    return landmark_check(residuals, dataset)[COLUMNS]


def landmark_swaps(audit: pd.DataFrame, min_sightings: int = MIN_SIGHTINGS) -> list[tuple[int, int]]:
    """Pairs ``(a, b)``, ``a < b``, each seen where the other is surveyed (and not where it is)."""
    swaps = []
    for a, row in audit.iterrows():
        b = int(row["nearest"])
        if (
            a < b
            and b in audit.index
            and bool(row["suspect"])
            and bool(audit.loc[b, "suspect"])
            and int(audit.loc[b, "nearest"]) == a
            and min(row["n"], audit.loc[b, "n"]) >= min_sightings
        ):
            swaps.append((int(a), b))
    return swaps


def apply_landmark_audit(dataset: Dataset, robots=None) -> tuple[Dataset, list[str]]:
    """Exchange back the table positions of each swapped pair found by :func:`audit_landmarks`.

    Returns the (possibly corrected) dataset and one human-readable line per
    correction (none when the table is consistent, or when no robot has
    groundtruth to check it with).
    """
    audit = audit_landmarks(dataset, robots)
    swaps = landmark_swaps(audit)
    if not swaps:
        return dataset, []
    table = dataset.landmarks.copy()
    notes = []
    for a, b in swaps:
        table.loc[[a, b], ["x", "y"]] = table.loc[[b, a], ["x", "y"]].to_numpy()
        notes.append(
            f"landmark table: subjects {a} and {b} exchanged (their {int(audit.loc[a, 'n'])} and "
            f"{int(audit.loc[b, 'n'])} sightings put them {audit.loc[a, 'offset']:.2f} m and "
            f"{audit.loc[b, 'offset']:.2f} m from their own table positions, on each other's; "
            f"suspect threshold {OUTLIER_THRESHOLD} m)"
        )
    return dataclasses.replace(dataset, landmarks=table), notes
