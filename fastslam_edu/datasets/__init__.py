"""Data sources: where data lives, and readers that produce :mod:`.log` structures.

The project finds data through one setting, the environment variable
``FASTSLAM_EDU_DATA`` (default ``./data``, relative to the working directory).
The files that belong there, their pinned sources and sha256s are in
:mod:`.registry` (:func:`fetch_datasets`, :func:`dataset_path`; ``fastslam-edu data``).
"""

from __future__ import annotations

import os
from pathlib import Path

from fastslam_edu.datasets.log import Dataset, EventStream, RobotLog

ENV_VAR = "FASTSLAM_EDU_DATA"


def data_root() -> Path:
    """The data folder: ``$FASTSLAM_EDU_DATA`` if set, else ``./data``."""
    return Path(os.environ.get(ENV_VAR, "data")).expanduser().resolve()


def mrclam_path(n: int, *, download: bool = False) -> Path:
    """Folder of MR.CLAM dataset ``n``: ``<data_root>/mrclam/MRCLAM_Dataset{n}``.

    With ``download=True`` a missing dataset is fetched first — what a notebook
    on Colab or Binder, which has no local data, needs: datasets 1 and 6 file by
    file from the registry's pinned sources, checked by sha256
    (:func:`fastslam_edu.datasets.registry.fetch_datasets`, which also replaces
    altered files), the others as the official UTIAS zip
    (:func:`fastslam_edu.datasets.fetch.fetch_mrclam`). Otherwise a missing
    folder raises FileNotFoundError, saying how to get the data.
    """
    p = data_root() / "mrclam" / f"MRCLAM_Dataset{n}"
    if download and f"mrclam{n}" in _registry_names():
        from fastslam_edu.datasets.registry import dataset_path

        return dataset_path(f"mrclam{n}", download=True)
    if not p.is_dir() and download:
        from fastslam_edu.datasets.fetch import fetch_mrclam

        return fetch_mrclam(n, data_root() / "mrclam")
    if not p.is_dir():
        how = (f"`fastslam-edu data mrclam{n}` (or `make data`)" if f"mrclam{n}" in _registry_names()
               else f"`python -m fastslam_edu.datasets.fetch {n} {data_root() / 'mrclam'}`")
        raise FileNotFoundError(
            f"MR.CLAM dataset {n} not found at {p}. Set {ENV_VAR} to the folder that holds "
            f"'mrclam/MRCLAM_Dataset{n}', or download it with {how}."
        )
    return p


def _registry_names() -> tuple[str, ...]:
    """Names of the registered datasets (``mrclam1``, ``intel``, ...)."""
    from fastslam_edu.datasets.registry import REGISTRY

    return tuple(REGISTRY)


_FROM_REGISTRY = ("DataFetchError", "DataFile", "DatasetEntry", "MIRROR_ENV_VAR", "REGISTRY",
                  "dataset_path", "fetch_dataset", "fetch_datasets")


def __getattr__(name: str):
    """The registry's names, imported on first use (so ``python -m fastslam_edu.datasets.registry`` runs cleanly)."""
    if name in _FROM_REGISTRY:
        from fastslam_edu.datasets import registry

        return getattr(registry, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["Dataset", "EventStream", "RobotLog", "data_root", "mrclam_path", "ENV_VAR", *_FROM_REGISTRY]
