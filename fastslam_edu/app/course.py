"""The course map: the chapters, what each one needs first, and two paths through them.

Each chapter's "Prerequisites" line names exactly the chapters in :data:`PREREQUISITES` (a test reads the
notebooks and checks this), so :func:`draw_chapter_map` draws the dependencies the chapters really have.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
from matplotlib.figure import Figure

__all__ = ["CHAPTERS", "PREREQUISITES", "PATHS", "PARTS", "chapter_number", "check_path", "draw_chapter_map"]

#: The chapters in reading order: notebook name -> short title.
CHAPTERS: dict[str, str] = {
    "01_mrclam_data": "The MR.CLAM data",
    "02_motion_model": "The motion model",
    "03_measurement_model": "The measurement model",
    "04_one_landmark_ekf": "One landmark, one EKF",
    "05_importance_weights": "Importance weights",
    "06_resampling": "Resampling",
    "07_putting_it_together": "Putting it together",
    "08_writeup_experiments": "The write-up's experiments",
    "09_textbook_to_real_data": "From textbook to real data",
    "10_fastslam_on_mrclam": "FastSLAM 1.0 on MR.CLAM",
    "11_fastslam2_proposal": "FastSLAM 2.0's proposal",
    "12_consistency": "Is the uncertainty honest?",
    "13_landmark_tree": "The tree trick",
    "14_occupancy_grid": "Occupancy grids",
    "15_grid_slam": "Grid SLAM",
    "16_thor_humanoid": "SLAM on a humanoid (THOR)",
}

#: Chapter -> the chapters it builds on directly (each of them comes earlier).
PREREQUISITES: dict[str, tuple[str, ...]] = {
    "01_mrclam_data": (),
    "02_motion_model": ("01_mrclam_data",),
    "03_measurement_model": ("01_mrclam_data",),
    "04_one_landmark_ekf": ("03_measurement_model",),
    "05_importance_weights": ("04_one_landmark_ekf",),
    "06_resampling": ("05_importance_weights",),
    "07_putting_it_together": ("02_motion_model", "06_resampling"),
    "08_writeup_experiments": ("07_putting_it_together",),
    "09_textbook_to_real_data": ("07_putting_it_together",),
    "10_fastslam_on_mrclam": ("09_textbook_to_real_data",),
    "11_fastslam2_proposal": ("10_fastslam_on_mrclam",),
    "12_consistency": ("10_fastslam_on_mrclam",),
    "13_landmark_tree": ("07_putting_it_together",),
    "14_occupancy_grid": ("02_motion_model",),
    "15_grid_slam": ("06_resampling", "14_occupancy_grid"),
    "16_thor_humanoid": ("15_grid_slam",),
}

#: The book's parts, for the map's columns: caption -> chapters.
PARTS: dict[str, tuple[str, ...]] = {
    "Getting started": ("01_mrclam_data",),
    "FastSLAM 1.0, one equation at a time": ("02_motion_model", "03_measurement_model", "04_one_landmark_ekf",
                                             "05_importance_weights", "06_resampling", "07_putting_it_together"),
    "Landmark SLAM on MR.CLAM": ("08_writeup_experiments", "09_textbook_to_real_data", "10_fastslam_on_mrclam",
                                "11_fastslam2_proposal", "12_consistency"),
    "The tree trick": ("13_landmark_tree",),
    "Grid SLAM with LiDAR": ("14_occupancy_grid", "15_grid_slam", "16_thor_humanoid"),
}

#: Two ways through the book: path -> sessions -> chapters (reading before the first session included).
PATHS: dict[str, dict[str, tuple[str, ...]]] = {
    "three lectures": {
        "reading before lecture 1": ("01_mrclam_data",),
        "lecture 1: the two models and one landmark's EKF": ("02_motion_model", "03_measurement_model",
                                                            "04_one_landmark_ekf"),
        "lecture 2: weights, resampling, the whole filter": ("05_importance_weights", "06_resampling",
                                                            "07_putting_it_together"),
        "lecture 3: on real data": ("09_textbook_to_real_data", "10_fastslam_on_mrclam"),
    },
    "full course": {f"week {i + 1}": pair for i, pair in enumerate(
        tuple(tuple(list(CHAPTERS)[j:j + 2]) for j in range(0, len(CHAPTERS), 2)))},
}


def chapter_number(name: str) -> int:
    """The chapter number of notebook ``name`` (``"07_putting_it_together"`` -> 7)."""
    if name not in CHAPTERS:
        raise ValueError(f"unknown chapter {name!r}; the chapters are {', '.join(CHAPTERS)}")
    return int(name[:2])


def check_path(sessions: dict[str, tuple[str, ...]]) -> None:
    """Raise ValueError if a chapter of a path comes before one of its prerequisites (or without it)."""
    seen: list[str] = []
    for session, chapters in sessions.items():
        for name in chapters:
            missing = [p for p in PREREQUISITES[name] if p not in seen]
            if missing:
                raise ValueError(f"{session}: chapter {name} needs {', '.join(missing)} first")
            seen.append(name)


def _positions() -> dict[str, tuple[float, float]]:
    """One column per part, chapters top to bottom in reading order."""
    xy = {}
    for column, chapters in enumerate(PARTS.values()):
        for row, name in enumerate(chapters):
            xy[name] = (column * 2.6, -row * 1.0)
    return xy


def draw_chapter_map(path: str | None = None) -> Figure:
    """The chapters as boxes in their parts, an arrow from each prerequisite; ``path`` shades one path's chapters."""
    xy = _positions()
    chosen = set() if path is None else {c for chapters in PATHS[path].values() for c in chapters}
    fig, ax = plt.subplots(figsize=(13, 6.2))
    for column, caption in enumerate(PARTS):
        ax.text(column * 2.6, 0.75, caption.replace(", ", ",\n"), ha="center", va="bottom", fontsize=9,
                fontweight="bold")
    for name, (x, y) in xy.items():
        face = "#ffd27f" if name in chosen else "#e8eef7"
        ax.text(x, y, f"{chapter_number(name)}. {CHAPTERS[name]}", ha="center", va="center", fontsize=8.5,
                bbox=dict(boxstyle="round,pad=0.35", fc=face, ec="#44546a"), zorder=3)
        for before in PREREQUISITES[name]:
            bx, by = xy[before]
            ax.annotate("", xy=(x, y), xytext=(bx, by), zorder=1,
                        arrowprops=dict(arrowstyle="-|>", color="#7f8c9d", shrinkA=14, shrinkB=14,
                                        connectionstyle="arc3,rad=0.18" if bx == x else "arc3,rad=0.05"))
    ax.set_xlim(-1.4, 2.6 * (len(PARTS) - 1) + 1.4)
    ax.set_ylim(-6.6, 1.5)
    ax.axis("off")
    ax.set_title("Chapters and what each builds on" + ("" if path is None else f" (shaded: {path})"))
    return fig
