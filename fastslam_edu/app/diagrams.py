"""Figures a lecturer needs, drawn by code: the FastSLAM factorisation, one particle, one filter step.

Each function draws one figure with matplotlib alone and returns it; nothing is read from disk. The nodes, boxes
and arrows are ordinary patches of the figure's axes (circles, :class:`~matplotlib.patches.FancyBboxPatch`,
polygons, :class:`~matplotlib.patches.FancyArrowPatch`), so a test can count them.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.path import Path
from matplotlib.patches import Circle, FancyArrowPatch, FancyBboxPatch, Polygon, Rectangle

from fastslam_edu.app.plotting import covariance_ellipse

__all__ = ["draw_factorisation", "draw_particle_anatomy", "draw_filter_step", "FACTORISATION"]

#: The FastSLAM factorisation, in matplotlib's mathtext.
FACTORISATION = (r"$p(x_{1:t}, m \mid z_{1:t}, u_{1:t}) = p(x_{1:t} \mid z_{1:t}, u_{1:t})"
                 r"\;\prod_{k}\; p(m_k \mid x_{1:t}, z_{1:t}, u_{1:t})$")

_OBSERVED = "#d9d9d9"  # face of a node whose value is known (controls, measurements)
_HIDDEN = "white"
_PATH = "#ffe3b3"  # the path, drawn by a particle


def _node(ax, xy, label, face, radius=0.42):
    ax.add_patch(Circle(xy, radius, fc=face, ec="k", lw=1.2, zorder=3))
    ax.text(*xy, label, ha="center", va="center", fontsize=13, zorder=4)


def _arrow(ax, a, b, radius=0.42):
    """An arrow from the rim of the node at ``a`` to the rim of the node at ``b`` (axes of equal aspect)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    d = (b - a) / np.hypot(*(b - a))
    ax.add_patch(FancyArrowPatch(a + radius * d, b - (radius + 0.02) * d, arrowstyle="-|>", mutation_scale=14,
                                 color="k", lw=1.1, shrinkA=0, shrinkB=0, zorder=2))


def draw_factorisation() -> Figure:
    """The FastSLAM factorisation as a graphical model (a dynamic Bayes network).

    Three poses :math:`x_{t-1} \\to x_t \\to x_{t+1}`, each moved by its control :math:`u`, each producing a
    measurement :math:`z` of one of two landmarks :math:`m_1, m_2` (here :math:`m_1` is seen at :math:`t-1` and
    :math:`t`, :math:`m_2` at :math:`t+1`). Grey: known (controls, measurements); white: unknown. The band marks the
    path :math:`x_{1:t}`: every connection between :math:`m_1` and :math:`m_2` runs through a pose, so once the path
    is given (as it is inside one particle) the landmarks are independent, and the posterior factorises as in the
    title. Eleven circles (nodes), eleven arrows.
    """
    fig, ax = plt.subplots(figsize=(8.6, 5.4))
    xs = (-3.0, 0.0, 3.0)
    names = ("t-1", "t", "t+1")
    ax.add_patch(FancyBboxPatch((-4.1, 1.45), 8.2, 1.1, boxstyle="round,pad=0.05,rounding_size=0.3", fc=_PATH,
                                ec="#c98a00", lw=1.0, zorder=1))
    ax.text(4.3, 2.0, "the path $x_{1:t}$\n(one per particle)", ha="left", va="center", fontsize=10,
            color="#8a5a00")
    for x, n in zip(xs, names):
        _node(ax, (x, 3.6), f"$u_{{{n}}}$", _OBSERVED)
        _node(ax, (x, 2.0), f"$x_{{{n}}}$", _HIDDEN)
        _node(ax, (x, 0.2), f"$z_{{{n}}}$", _OBSERVED)
        _arrow(ax, (x, 3.6), (x, 2.0))
        _arrow(ax, (x, 2.0), (x, 0.2))
    for a, b in zip(xs[:-1], xs[1:]):
        _arrow(ax, (a, 2.0), (b, 2.0))
    landmarks = {"$m_1$": (-1.5, -1.7), "$m_2$": (1.5, -1.7)}
    for label, xy in landmarks.items():
        _node(ax, xy, label, _HIDDEN)
    for x, m in zip(xs, ("$m_1$", "$m_1$", "$m_2$")):  # which landmark each measurement sees
        _arrow(ax, landmarks[m], (x, 0.2))
    ax.text(-4.35, 3.6, "controls", ha="right", va="center", fontsize=10)
    ax.text(-4.35, 0.2, "measurements", ha="right", va="center", fontsize=10)
    ax.text(-4.35, -1.7, "landmarks", ha="right", va="center", fontsize=10)
    ax.text(0.0, -2.55, r"given the path, $m_1$ and $m_2$ are independent: one small EKF per landmark"
            "\ngrey: known (controls, measurements); white: to be estimated", ha="center", va="top", fontsize=10.5,
            linespacing=1.6)
    ax.set_title(FACTORISATION, fontsize=12, pad=12)
    ax.set_xlim(-6.2, 6.2)
    ax.set_ylim(-3.6, 4.3)
    ax.set_aspect("equal")
    ax.axis("off")
    fig.tight_layout()
    return fig


def _synthetic_particles(n_particles: int, seed: int):
    """A small made-up particle set: paths around one arc, three landmarks each with a 2x2 Gaussian, weights."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, 25)
    base = np.column_stack([3.0 * np.sin(1.6 * s), 2.2 * (1 - np.cos(1.6 * s)), 1.6 * s])  # an arc to the left
    truth = np.array([[1.2, 2.6], [3.6, 0.4], [2.6, 3.4]])
    paths, mus, sigmas, loglik = [], [], [], []
    for _ in range(n_particles):
        drift = np.cumsum(rng.normal(0.0, [0.05, 0.05, 0.02], (len(s), 3)), axis=0)
        path = base + drift
        paths.append(path)
        mus.append(truth + drift[-1, :2] + rng.normal(0.0, 0.05, truth.shape))
        axes = rng.uniform(0.04, 0.14, (len(truth), 2))
        angle = rng.uniform(0.0, np.pi, len(truth))
        rot = np.stack([np.column_stack([np.cos(angle), -np.sin(angle)]),
                        np.column_stack([np.sin(angle), np.cos(angle)])], axis=1)
        sigmas.append(rot @ (axes[:, :, None] ** 2 * np.eye(2)) @ np.swapaxes(rot, 1, 2))
        loglik.append(-np.sum(drift[-1, :2] ** 2) / (2 * 0.3**2))
    w = np.exp(np.array(loglik) - np.max(loglik))
    return np.array(paths), np.array(mus), np.array(sigmas), w / w.sum()


def draw_particle_anatomy(paths=None, mu=None, sigma=None, weights=None, seen=None, *, n_particles: int = 3,
                          seed: int = 0) -> Figure:
    """What one particle of FastSLAM 1.0 holds: a sampled path, one small EKF per landmark, and a weight.

    One panel per particle, side by side: its path :math:`x_{1:t}^{[m]}` (line, with the last pose as an arrow),
    and for each landmark it has seen the mean :math:`\\mu_k^{[m]}` (cross, labelled :math:`k`) and the 2σ ellipse
    of :math:`\\Sigma_k^{[m]}`; the title gives its weight :math:`w^{[m]}`. The particles share nothing: each map
    is drawn from its own path, which is why the maps differ where the paths do.

    Parameters
    ----------
    paths : (n, T, 3), optional
        The particles' paths (x, y, θ). Without it, a small made-up set drawn with ``seed`` is shown.
    mu, sigma : (n, N, 2), (n, N, 2, 2), optional
        Their landmark means and covariances (with ``paths``).
    weights : (n,), optional
        Their weights (default: equal).
    seen : (n, N) bool, optional
        Which landmarks each particle has seen (default: all).
    n_particles, seed : int
        Size and seed of the made-up set.
    """
    if paths is None:
        paths, mu, sigma, weights = _synthetic_particles(n_particles, seed)
    paths, mu, sigma = np.asarray(paths, float), np.asarray(mu, float), np.asarray(sigma, float)
    n = len(paths)
    weights = np.full(n, 1.0 / n) if weights is None else np.asarray(weights, float)
    seen = np.ones(mu.shape[:2], bool) if seen is None else np.asarray(seen, bool)
    fig, axes = plt.subplots(1, n, figsize=(3.3 * n, 4.1), sharex=True, sharey=True, squeeze=False)
    for m, ax in enumerate(axes[0]):
        path = paths[m]
        ax.plot(path[:, 0], path[:, 1], color="C0", lw=1.5)
        x, y, theta = path[-1]
        ax.add_patch(FancyArrowPatch((x, y), (x + 0.35 * np.cos(theta), y + 0.35 * np.sin(theta)),
                                     arrowstyle="-|>", mutation_scale=12, color="C0", lw=1.5))
        for k in np.flatnonzero(seen[m]):
            ellipse = covariance_ellipse(mu[m, k], sigma[m, k])
            ax.plot(ellipse[:, 0], ellipse[:, 1], color="C3", lw=1.0)
            ax.plot(*mu[m, k], "+", color="C3", ms=8, mew=1.5)
            ax.annotate(f"{k + 1}", mu[m, k], xytext=(7, 6), textcoords="offset points", fontsize=8, color="C3")
        ax.set_title(f"particle {m + 1}: weight $w^{{[{m + 1}]}}$ = {weights[m]:.2f}", fontsize=10)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.tick_params(labelsize=8)
    axes[0, 0].set_ylabel("y [m]")
    handles = [Line2D([], [], color="C0", lw=1.5), Line2D([], [], color="C3", marker="+", ms=8, lw=1.0)]
    fig.suptitle("one particle = a sampled path + one 2×2 EKF per landmark + a weight", fontsize=11, y=0.98)
    fig.legend(handles, [r"path $x_{1:t}^{[m]}$", r"landmark EKF: mean $\mu_k^{[m]}$, 2σ ellipse of $\Sigma_k^{[m]}$"],
               loc="lower center", ncol=2, fontsize=9, frameon=False)
    fig.subplots_adjust(left=0.07, right=0.99, bottom=0.22, top=0.84, wspace=0.1)
    return fig


def _box(ax, xy, text, width=3.6, height=0.85, face="#e8eef7"):
    x, y = xy
    ax.add_patch(FancyBboxPatch((x - width / 2, y - height / 2), width, height, boxstyle="round,pad=0.06",
                                fc=face, ec="#44546a", lw=1.1, zorder=3))
    ax.text(x, y, text, ha="center", va="center", fontsize=9.5, zorder=4, linespacing=1.5)


def _diamond(ax, xy, text, width=3.6, height=1.2):
    x, y = xy
    corners = [(x, y + height / 2), (x + width / 2, y), (x, y - height / 2), (x - width / 2, y)]
    ax.add_patch(Polygon(corners, closed=True, fc="#fff2cc", ec="#8a6d00", lw=1.1, zorder=3))
    ax.text(x, y, text, ha="center", va="center", fontsize=9.5, zorder=4)


def _flow(ax, a, b, label=None, label_at=None, **style):
    style = {"arrowstyle": "-|>", "mutation_scale": 13, "color": "#44546a", "lw": 1.2, **style}
    ax.add_patch(FancyArrowPatch(a, b, shrinkA=0, shrinkB=0, zorder=2, **style))
    if label:
        ax.text(*(label_at or ((a[0] + b[0]) / 2 + 0.12, (a[1] + b[1]) / 2)), label, fontsize=9, ha="left",
                va="center", color="#44546a", style="italic")


def draw_filter_step() -> Figure:
    """The block diagram of one FastSLAM 1.0 step, for every particle.

    Sample the motion model; then, for each sighting of the instant (dashed frame): a landmark the particle knows
    gets its EKF update and multiplies the weight by the likelihood of the innovation, a new one is initialised
    from the measurement; then the weights are normalised, the set is resampled if the effective sample size
    :math:`N_\\mathrm{eff}` has fallen below :math:`\\tau M`, and the particles are combined into one estimate.
    Six boxes, two decisions (diamonds), ten arrows (the dashed one closes the loop to the next step).
    """
    fig, ax = plt.subplots(figsize=(8.2, 8.6))
    ax.add_patch(Rectangle((-4.4, 3.15), 8.8, 3.9, fc="none", ec="0.45", ls="--", lw=1.0, zorder=1))
    ax.text(-4.25, 6.9, r"for each sighting $z = (r, \phi)$ of a landmark $k$", ha="left", va="top", fontsize=9.5,
            color="0.3")
    _box(ax, (0, 8.3), "1. sample the motion\n" r"$x_t^{[m]} \sim p(x_t \mid x_{t-1}^{[m]}, u_t)$", width=4.2,
         height=1.05)
    _diamond(ax, (0, 5.6), "2. landmark $k$ known\nto the particle?")
    _box(ax, (-2.25, 3.95), "EKF update of $(\\mu_k, \\Sigma_k)$\n"
         r"$w^{[m]} \leftarrow w^{[m]}\,\mathcal{N}(\nu; 0, Q)$", width=3.7, height=1.05)
    _box(ax, (2.25, 3.95), "initialise $\\mu_k = h^{-1}(x, z)$\n"
         r"$\Sigma_k = G R G^\top$, weight kept", width=3.7, height=1.05)
    _box(ax, (0, 2.25), r"normalise the weights $w^{[m]}$", width=4.2, height=0.7)
    _diamond(ax, (0, 0.75), r"3. $N_\mathrm{eff} < \tau M$ ?", width=2.8, height=1.05)
    _box(ax, (3.5, 0.75), "resample: draw $M$ particles\n" r"with prob. $w^{[m]}$, then $w = 1/M$", width=3.4,
         height=1.05, face="#fde2d0")
    _box(ax, (0, -1.1), "4. combined estimate\nweighted-mean pose, mixture map", width=4.2, height=1.05,
         face="#dff0d8")
    _flow(ax, (0, 7.77), (0, 6.2))
    _flow(ax, (-1.8, 5.6), (-2.25, 4.48), "yes", (-2.55, 5.35), connectionstyle="angle,angleA=180,angleB=90,rad=0")
    _flow(ax, (1.8, 5.6), (2.25, 4.48), "no", (2.35, 5.35), connectionstyle="angle,angleA=0,angleB=90,rad=0")
    _flow(ax, (-2.25, 3.36), (-0.6, 2.66))
    _flow(ax, (2.25, 3.36), (0.6, 2.66))
    _flow(ax, (0, 1.84), (0, 1.28))
    _flow(ax, (1.4, 0.75), (1.72, 0.75), "yes", (1.3, 1.1))
    _flow(ax, (0, 0.22), (0, -0.5), "no", (0.15, -0.14))
    _flow(ax, (3.5, 0.16), (2.17, -1.1), connectionstyle="angle,angleA=-90,angleB=0,rad=0")
    loop = Path([(-2.1, -1.1), (-4.75, -1.1), (-4.75, 8.3), (-2.17, 8.3)],
                [Path.MOVETO, Path.LINETO, Path.LINETO, Path.LINETO])
    ax.add_patch(FancyArrowPatch(path=loop, arrowstyle="-|>", mutation_scale=13, color="#44546a", lw=1.2, ls="--",
                                 zorder=2))
    ax.text(-4.9, 2.25, "next time step", rotation=90, ha="right", va="center", fontsize=9, color="#44546a",
            style="italic")
    ax.set_xlim(-5.5, 5.5)
    ax.set_ylim(-1.9, 9.0)
    ax.set_aspect("equal")
    ax.axis("off")
    ax.set_title("One step of FastSLAM 1.0 (every particle $m$)", fontsize=11)
    fig.tight_layout()
    return fig
