"""The course map: the chapters, what each one needs first, and two paths through them.

Each chapter's "Prerequisites" line names exactly the chapters in :data:`PREREQUISITES` (a test reads the
notebooks and checks this), so :func:`draw_chapter_map` draws the dependencies the chapters really have.
"""

from __future__ import annotations

import math

import matplotlib.pyplot as plt
from matplotlib.patches import Patch
from matplotlib.figure import Figure

__all__ = ["CHAPTERS", "PREREQUISITES", "PATHS", "PARTS", "WRITEUPS_PART", "LECTURE_PLAN", "chapter_number", "check_path", "draw_chapter_map"]

#: The chapters in reading order: notebook name -> short title.
CHAPTERS: dict[str, str] = {
    "01_mrclam_data": "The MR.CLAM data",
    "02_motion_model": "The motion model",
    "03_measurement_model": "The measurement model",
    "04_one_landmark_ekf": "One landmark, one EKF",
    "05_ekf_slam": "EKF-SLAM",
    "06_importance_weights": "Importance weights",
    "07_resampling": "Resampling",
    "08_putting_it_together": "Putting it together",
    "09_textbook_to_real_data": "From textbook to real data",
    "10_graph_slam": "Graph SLAM: the whole log at once",
    "11_five_robots": "Five robots, one map",
    "12_fastslam_on_mrclam": "FastSLAM 1.0 on MR.CLAM",
    "13_fastslam2_proposal": "FastSLAM 2.0's proposal",
    "14_consistency": "Is the uncertainty honest?",
    "15_landmark_tree": "The tree trick",
    "16_occupancy_grid": "Occupancy grids",
    "17_grid_slam": "Grid SLAM",
    "18_thor_humanoid": "SLAM on a humanoid (THOR)",
    "19_hidden_barcodes": "When the barcodes are hidden",
    "20_writeup_models": "The write-up's data and models",
    "21_writeup_filter": "The write-up's filter",
    "22_writeup_experiments": "The write-up's experiments",
}

#: Chapter -> the chapters it builds on directly (each of them comes earlier).
PREREQUISITES: dict[str, tuple[str, ...]] = {
    "01_mrclam_data": (),
    "02_motion_model": ("01_mrclam_data",),
    "03_measurement_model": ("01_mrclam_data",),
    "04_one_landmark_ekf": ("03_measurement_model",),
    "05_ekf_slam": ("02_motion_model", "04_one_landmark_ekf"),
    "06_importance_weights": ("02_motion_model", "04_one_landmark_ekf"),
    "07_resampling": ("06_importance_weights",),
    "08_putting_it_together": ("02_motion_model", "07_resampling"),
    "09_textbook_to_real_data": ("08_putting_it_together",),
    "10_graph_slam": ("05_ekf_slam", "08_putting_it_together"),
    "11_five_robots": ("10_graph_slam",),
    "12_fastslam_on_mrclam": ("09_textbook_to_real_data",),
    "13_fastslam2_proposal": ("12_fastslam_on_mrclam",),
    "14_consistency": ("05_ekf_slam", "10_graph_slam", "12_fastslam_on_mrclam"),
    "15_landmark_tree": ("08_putting_it_together",),
    "16_occupancy_grid": ("02_motion_model",),
    "17_grid_slam": ("07_resampling", "16_occupancy_grid"),
    "18_thor_humanoid": ("17_grid_slam",),
    "19_hidden_barcodes": ("05_ekf_slam", "12_fastslam_on_mrclam"),
    "20_writeup_models": ("01_mrclam_data", "03_measurement_model"),
    "21_writeup_filter": ("08_putting_it_together",),
    "22_writeup_experiments": ("09_textbook_to_real_data",),
}

#: The book's parts, for the map's columns: caption -> chapters.
PARTS: dict[str, tuple[str, ...]] = {
    "Getting started": ("01_mrclam_data",),
    "FastSLAM 1.0, one equation at a time": ("02_motion_model", "03_measurement_model", "04_one_landmark_ekf",
                                             "05_ekf_slam", "06_importance_weights", "07_resampling",
                                             "08_putting_it_together"),
    "Landmark SLAM on MR.CLAM": ("09_textbook_to_real_data", "10_graph_slam", "11_five_robots",
                                "12_fastslam_on_mrclam", "13_fastslam2_proposal", "14_consistency"),
    "The tree trick": ("15_landmark_tree",),
    "Grid SLAM with LiDAR": ("16_occupancy_grid", "17_grid_slam", "18_thor_humanoid"),
    "Beyond FastSLAM": ("19_hidden_barcodes",),
    "Reproducing the write-ups": ("20_writeup_models", "21_writeup_filter", "22_writeup_experiments"),
}

#: The part whose chapters examine the published write-ups: any chapter may point to it (a link, not a
#: prerequisite), and it is not part of the core's reading-time budget.
WRITEUPS_PART = "Reproducing the write-ups"

#: Two ways through the book: path -> sessions -> chapters (reading before the first session included).
PATHS: dict[str, dict[str, tuple[str, ...]]] = {
    "three lectures": {
        "reading before lecture 1": ("01_mrclam_data",),
        "lecture 1: the two models and one landmark's EKF": ("02_motion_model", "03_measurement_model",
                                                            "04_one_landmark_ekf"),
        "lecture 2: weights, resampling, the whole filter": ("06_importance_weights", "07_resampling",
                                                            "08_putting_it_together"),
        "lecture 3: on real data": ("09_textbook_to_real_data", "12_fastslam_on_mrclam"),
    },
    "full course": {f"week {i + 1}": pair for i, pair in enumerate(
        tuple(tuple(list(CHAPTERS)[j:j + 2]) for j in range(0, len(CHAPTERS), 2)))},
}


#: The three-lecture path, per lecture: the graded lab that follows it (``labs/<lab>/``) and what the instructor
#: shows live in class (each a figure or a run a chapter computes).
LECTURE_PLAN: dict[str, dict[str, str]] = {
    "lecture 1: the two models and one landmark's EKF": {
        "lab": "lab1_models",
        "live": "the banana of sampled poses with the noise sliders (ch. 2); a sighting's ellipse through h⁻¹ (ch. 3); "
                "thirty sightings shrinking one landmark's EKF, checked against filterpy (ch. 4)",
    },
    "lecture 2: weights, resampling, the whole filter": {
        "lab": "lab2_landmarks",
        "live": "N_eff falling and the log-sum-exp fix (ch. 6); the four resamplers' offspring counts (ch. 7); "
                "the first minute of robot 2 step by step, then the animation (ch. 8)",
    },
    "lecture 3: on real data": {
        "lab": "lab3_fastslam",
        "live": "the ablation from the textbook filter to the real-data one (ch. 9); the full run's map and path "
                "against groundtruth, raw and aligned (ch. 12)",
    },
}


def chapter_number(name: str) -> int:
    """The chapter number of notebook ``name`` (``"08_putting_it_together"`` -> 7)."""
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


def _depths() -> dict[str, int]:
    """Each chapter's depth: the length of the longest chain of prerequisites that leads to it."""
    depth: dict[str, int] = {}
    for name in CHAPTERS:  # reading order: prerequisites come first
        depth[name] = 1 + max((depth[p] for p in PREREQUISITES[name]), default=-1)
    return depth


#: one row per part in the map, listed top to bottom
_ROWS = {"Getting started": 0, "FastSLAM 1.0, one equation at a time": 0, "Landmark SLAM on MR.CLAM": 1,
         "The tree trick": 2, "Grid SLAM with LiDAR": 3, "Beyond FastSLAM": 2, "Reproducing the write-ups": 3}


def _positions() -> dict[str, tuple[float, float]]:
    """Columns by depth (left to right), one row per part; chapters of a part at one depth stack downwards."""
    depth, xy, used = _depths(), {}, {}
    for caption, chapters in PARTS.items():
        for name in chapters:
            key = (_ROWS[caption], depth[name])
            offset = used.get(key, 0)
            used[key] = offset + 1
            xy[name] = (depth[name] * 3.0, -(_ROWS[caption] * 2.0 + offset * 1.0))
    return xy


def draw_chapter_map(path: str | None = None) -> Figure:
    """The chapters as boxes, an arrow from each prerequisite; ``path`` shades one path's chapters."""
    xy = _positions()
    chosen = set() if path is None else {c for chapters in PATHS[path].values() for c in chapters}
    colours = dict(zip(PARTS, ["#fdf6d3", "#e8eef7", "#e6f2e6", "#f2e6f2", "#f7efe1", "#e3f1f4", "#eeeeee"]))
    fig, ax = plt.subplots(figsize=(16, 6.5))
    boxes = {}
    for caption, chapters in PARTS.items():
        for name in chapters:
            label = f"{chapter_number(name)}. {CHAPTERS[name]}"
            boxes[name] = ax.text(*xy[name], "\n".join(_wrap(label)), ha="center", va="center", fontsize=8,
                                  zorder=3, bbox=dict(boxstyle="round,pad=0.35", fc=colours[caption],
                                                      ec="#c0392b" if name in chosen else "#44546a",
                                                      lw=2.2 if name in chosen else 0.8))
    for name, before in PREREQUISITES.items():
        for b in before:  # arrows clipped at the boxes' edges, so that their heads show
            ax.annotate("", xy=xy[name], xytext=xy[b], zorder=4,
                        arrowprops=dict(arrowstyle="-|>", color="#5d6d7e", shrinkA=1, shrinkB=1, mutation_scale=14,
                                        patchA=boxes[b].get_bbox_patch(), patchB=boxes[name].get_bbox_patch(),
                                        # a long arrow bends round the boxes between
                                        connectionstyle=f"arc3,rad={_bend(xy[b], xy[name])}"))
    ax.legend(handles=[Patch(fc=colours[c], ec="#44546a", label=c) for c in PARTS], loc="lower right",
              fontsize=8, frameon=False)
    xs = [x for x, _ in xy.values()]
    ax.set_xlim(min(xs) - 1.4, max(xs) + 1.4)
    ax.set_ylim(-7.6, 0.8)
    ax.axis("off")
    ax.set_title("Chapters and what each builds on" + ("" if path is None else f" (outlined in red: {path})"))
    return fig


def _wrap(label: str, width: int = 15) -> list[str]:
    """``label`` in lines of at most about ``width`` characters, for a box."""
    lines: list[str] = []
    for word in label.split():
        if lines and len(lines[-1]) + 1 + len(word) <= width:
            lines[-1] += " " + word
        else:
            lines.append(word)
    return lines


def _bend(start: tuple[float, float], end: tuple[float, float]) -> float:
    """How much an arrow bends: long arrows curve round the boxes between (a long drop to the right)."""
    if math.dist(start, end) <= 3.7:
        return 0.0
    return -0.22 if end[1] - start[1] < -5 else 0.22
