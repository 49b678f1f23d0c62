"""Data sources: where data lives, and readers that produce :mod:`.log` structures.

The project finds data through one setting, the environment variable
``FASTSLAM_EDU_DATA`` (default ``./data``, relative to the working directory).
"""

from __future__ import annotations

import os
from pathlib import Path

from .log import Dataset, EventStream, RobotLog

ENV_VAR = "FASTSLAM_EDU_DATA"


def data_root() -> Path:
    """The data folder: ``$FASTSLAM_EDU_DATA`` if set, else ``./data``."""
    return Path(os.environ.get(ENV_VAR, "data")).expanduser().resolve()


def mrclam_path(n: int, *, download: bool = False) -> Path:
    """Folder of MR.CLAM dataset ``n``: ``<data_root>/mrclam/MRCLAM_Dataset{n}``.

    With ``download=True`` a missing dataset is fetched from its official page
    first (:func:`fastslam_edu.datasets.fetch.fetch_mrclam`) — what a notebook on
    Colab or Binder, which has no local data, needs. Otherwise a missing folder
    raises FileNotFoundError, saying how to get the data.
    """
    p = data_root() / "mrclam" / f"MRCLAM_Dataset{n}"
    if not p.is_dir() and download:
        from .fetch import fetch_mrclam

        return fetch_mrclam(n, data_root() / "mrclam")
    if not p.is_dir():
        raise FileNotFoundError(
            f"MR.CLAM dataset {n} not found at {p}. Set {ENV_VAR} to the folder that holds "
            f"'mrclam/MRCLAM_Dataset{n}', or download it with "
            f"`python -m fastslam_edu.datasets.fetch {n} {data_root() / 'mrclam'}`."
        )
    return p


__all__ = ["Dataset", "EventStream", "RobotLog", "data_root", "mrclam_path", "ENV_VAR"]
