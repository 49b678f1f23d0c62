"""Checking a dataset's landmark table against its own measurements.

Every measurement ``z = (r, φ)`` of landmark ``s``, taken from the groundtruth
pose ``x``, should agree with the table position ``m_s``: the range residual
``r − ‖m_s − (x, y)‖`` is a few centimetres for a correct table. If the
residuals of subject ``s`` are metres, but small against the table position
of another subject ``c``, the table (or the barcode list) has ``s`` and ``c``
mixed up.

This is not hypothetical: in the copy of MR.CLAM Dataset 1 used by this book,
the measurements labelled 11 fit the table position of 17 and vice versa
(median range residual ≈ 0.1 m swapped, 1.2–2.8 m as labelled, for both robots
with groundtruth). Evaluating a map against such a table reports errors of
metres for landmarks that the filter placed correctly, and localising against
it fails. :func:`audit_landmarks` finds such mix-ups from the data and
:func:`apply_landmark_audit` corrects them, returning what it changed so that
the correction is reported, never silent.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd

from .events import groundtruth_at
from .log import Dataset

#: A landmark is "consistent" if the median |range residual| against its own
#: table position is below this [m]; MR.CLAM's range noise is ~0.1–0.2 m.
CONSISTENT_M = 0.3


def audit_landmarks(dataset: Dataset, robots=None) -> pd.DataFrame:
    """For each measured landmark, how well its measurements fit each table position.

    Uses every robot (or ``robots``) that has groundtruth; measurements outside
    the groundtruth time span are skipped.

    Returns
    -------
    pandas.DataFrame
        Index ``subject``; columns ``n`` (measurements used),
        ``median_abs_range_residual_m`` against its own table position,
        ``best_subject`` (the table entry its measurements fit best) and
        ``best_median_abs_range_residual_m``. Empty if no robot has groundtruth.
    """
    table = dataset.landmarks[["x", "y"]]
    rows: dict[int, list[np.ndarray]] = {}
    for rid, log in dataset.robots.items():
        if (robots is not None and rid not in robots) or log.groundtruth is None or log.measurements.empty:
            continue
        gt_t = log.groundtruth["time"].to_numpy()
        m = log.measurements
        m = m[(m["time"] >= gt_t[0]) & (m["time"] <= gt_t[-1])]
        if m.empty:
            continue
        pose = groundtruth_at(log, m["time"].to_numpy())
        # |range residual| of every measurement against every table landmark: (n, K)
        d = np.hypot(table["x"].to_numpy()[None, :] - pose[:, :1], table["y"].to_numpy()[None, :] - pose[:, 1:2])
        res = np.abs(m["range"].to_numpy()[:, None] - d)
        for s in np.unique(m["subject"].to_numpy()):
            rows.setdefault(int(s), []).append(res[m["subject"].to_numpy() == s])
    records = []
    subjects = table.index.to_numpy()
    for s, parts in sorted(rows.items()):
        res = np.concatenate(parts)
        med = np.median(res, axis=0)
        best = int(np.argmin(med))
        records.append(
            {
                "subject": s,
                "n": len(res),
                "median_abs_range_residual_m": float(med[list(subjects).index(s)]),
                "best_subject": int(subjects[best]),
                "best_median_abs_range_residual_m": float(med[best]),
            }
        )
    cols = ["n", "median_abs_range_residual_m", "best_subject", "best_median_abs_range_residual_m"]
    if not records:
        return pd.DataFrame(columns=cols, index=pd.Index([], name="subject"))
    return pd.DataFrame.from_records(records, index="subject")[cols]


def landmark_swaps(audit: pd.DataFrame) -> list[tuple[int, int]]:
    """Pairs ``(a, b)`` whose measurements fit each other's table position and not their own."""
    swaps = []
    for a, row in audit.iterrows():
        b = int(row["best_subject"])
        if (
            b != a
            and b in audit.index
            and row["median_abs_range_residual_m"] > CONSISTENT_M
            and row["best_median_abs_range_residual_m"] < CONSISTENT_M
            and int(audit.loc[b, "best_subject"]) == a
            and audit.loc[b, "best_median_abs_range_residual_m"] < CONSISTENT_M
            and a < b
        ):
            swaps.append((int(a), b))
    return swaps


def apply_landmark_audit(dataset: Dataset, robots=None) -> tuple[Dataset, list[str]]:
    """Correct swapped landmark table entries found by :func:`audit_landmarks`.

    Returns the dataset with the table positions of each swapped pair exchanged,
    and one human-readable line per correction (empty when the table is
    consistent, or when no robot has groundtruth to check it with).
    """
    audit = audit_landmarks(dataset, robots)
    swaps = landmark_swaps(audit)
    if not swaps:
        return dataset, []
    table = dataset.landmarks.copy()
    notes = []
    for a, b in swaps:
        table.loc[[a, b]] = table.loc[[b, a]].to_numpy()
        notes.append(
            f"landmark table: subjects {a} and {b} exchanged (their measurements fit each other's "
            f"position: median |range residual| {audit.loc[a, 'median_abs_range_residual_m']:.2f} m and "
            f"{audit.loc[b, 'median_abs_range_residual_m']:.2f} m as labelled, "
            f"{audit.loc[a, 'best_median_abs_range_residual_m']:.2f} m and "
            f"{audit.loc[b, 'best_median_abs_range_residual_m']:.2f} m exchanged)"
        )
    return dataclasses.replace(dataset, landmarks=table), notes
