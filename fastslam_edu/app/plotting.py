"""Figures of a FastSLAM run: paths, maps with covariance ellipses, errors over time.

Used by the command line (``--plot``) and by the book, so a figure in the book
is the figure a student gets from the command line.
"""

from __future__ import annotations

import numpy as np


def covariance_ellipse(mu, sigma, n_std: float = 2.0, n_points: int = 60) -> np.ndarray:
    """Points (n_points, 2) of the ``n_std``-sigma ellipse of ``N(mu, sigma)``.

    The ellipse is ``mu + n_std · L (cos t, sin t)`` with ``L`` the Cholesky
    factor of ``sigma`` (so ``L Lᵀ = Σ``).
    """
    t = np.linspace(0.0, 2.0 * np.pi, n_points)
    L = np.linalg.cholesky(np.asarray(sigma, dtype=float))
    return np.asarray(mu, dtype=float) + n_std * (L @ np.stack([np.cos(t), np.sin(t)])).T


def plot_map(ax, result, landmarks_truth=None, groundtruth=None, *, title: str | None = None):
    """Estimated path and map (2σ ellipses) with groundtruth path and landmarks if given."""
    if groundtruth is not None:
        ax.plot(groundtruth["x"], groundtruth["y"], color="0.6", lw=1.0, label="groundtruth path")
    ax.plot(result.pose_mean[:, 0], result.pose_mean[:, 1], color="C0", lw=1.0, label="FastSLAM (weighted mean)")
    if landmarks_truth is not None:
        ax.scatter(*np.asarray(landmarks_truth).T, marker="s", facecolor="none", edgecolor="k", s=40, label="true landmarks")
    obs = result.observed
    ax.scatter(*result.landmarks_mean[obs].T, marker="+", color="C3", s=60, label="estimated landmarks")
    for k in np.flatnonzero(obs):
        e = covariance_ellipse(result.landmarks_mean[k], result.landmarks_cov[k])
        ax.plot(e[:, 0], e[:, 1], color="C3", lw=0.8)
        ax.annotate(str(result.landmark_subjects[k]), result.landmarks_mean[k], fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="best", fontsize=7)
    if title:
        ax.set_title(title)
    return ax


def run_figure(result, landmarks_truth=None, groundtruth=None, path_errors=None, title=None):
    """A two-panel figure: map and path (left), path error and N_eff over time (right)."""
    import matplotlib.pyplot as plt

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12, 5), gridspec_kw={"width_ratios": [1.3, 1]})
    plot_map(ax0, result, landmarks_truth, groundtruth, title=title)
    t0 = result.t[0]
    if path_errors is not None:
        t_err, err = path_errors
        ax1.plot(t_err - t0, err, color="C0", lw=0.8, label="position error [m]")
        ax1.set_ylabel("position error [m]")
    ax1.set_xlabel("time [s]")
    ax2 = ax1.twinx()
    ax2.plot(result.ess_t - t0, result.ess, color="C2", lw=0.5, alpha=0.6, label="$N_{eff}$")
    ax2.set_ylabel("effective sample size")
    ax1.set_title("error and effective sample size over time")
    fig.tight_layout()
    return fig
