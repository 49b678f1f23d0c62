"""The lecturer's figures (fastslam_edu.app.diagrams): each is a Figure with the nodes, arrows and labels it promises."""

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.figure import Figure
from matplotlib.patches import Circle, FancyArrowPatch, FancyBboxPatch, Polygon

from fastslam_edu.app.diagrams import FACTORISATION, draw_factorisation, draw_filter_step, draw_particle_anatomy


def patches(fig, kind):
    return [p for ax in fig.axes for p in ax.patches if type(p) is kind]


def texts(fig):
    """Every text of the figure: axes texts, titles, suptitle, legend entries."""
    out = [t.get_text() for ax in fig.axes for t in ax.texts]
    out += [ax.get_title() for ax in fig.axes]
    out += [fig.get_suptitle()]
    out += [t.get_text() for legend in fig.legends for t in legend.get_texts()]
    return out


@pytest.fixture
def drawn():
    figures = []

    def draw(function, *args, **kwargs):
        fig = function(*args, **kwargs)
        figures.append(fig)
        return fig

    yield draw
    for fig in figures:
        plt.close(fig)
    assert not set(plt.get_fignums()) & {f.number for f in figures}


def test_factorisation_is_a_graphical_model_of_poses_controls_measurements_landmarks(drawn):
    fig = drawn(draw_factorisation)
    assert isinstance(fig, Figure)
    nodes = patches(fig, Circle)
    assert len(nodes) == 11  # 3 controls, 3 poses, 3 measurements, 2 landmarks
    labels = texts(fig)
    for name in ("$u_{t-1}$", "$u_{t}$", "$u_{t+1}$", "$x_{t-1}$", "$x_{t}$", "$x_{t+1}$",
                 "$z_{t-1}$", "$z_{t}$", "$z_{t+1}$", "$m_1$", "$m_2$"):
        assert name in labels, name
    # controls -> poses (3), pose chain (2), poses -> measurements (3), landmarks -> measurements (3)
    assert len(patches(fig, FancyArrowPatch)) == 11
    assert fig.axes[0].get_title() == FACTORISATION and r"\prod_{k}" in FACTORISATION
    assert any("independent" in t for t in labels)


def test_factorisation_node_count_includes_the_landmarks(drawn):
    fig = drawn(draw_factorisation)
    centres = {tuple(np.round(c.center, 3)) for c in patches(fig, Circle)}
    assert len(centres) == len(patches(fig, Circle))  # no two nodes on top of each other
    assert {(-1.5, -1.7), (1.5, -1.7)} <= centres


def test_particle_anatomy_synthetic_is_seeded_and_shows_path_ellipses_weight(drawn):
    a, b = drawn(draw_particle_anatomy, seed=3), drawn(draw_particle_anatomy, seed=3)
    assert isinstance(a, Figure) and len(a.axes) == 3
    for ax_a, ax_b in zip(a.axes, b.axes):
        assert ax_a.get_title() == ax_b.get_title()  # same seed, same weights
        for la, lb in zip(ax_a.lines, ax_b.lines):
            assert np.array_equal(la.get_xydata(), lb.get_xydata())
    titles = [ax.get_title() for ax in a.axes]
    weights = [float(t.rsplit("=", 1)[1]) for t in titles]
    assert abs(sum(weights) - 1) < 0.02 and all(t.startswith(f"particle {m + 1}:") for m, t in enumerate(titles))
    for ax in a.axes:
        # one path + per landmark an ellipse and a mean marker
        assert len(ax.lines) == 1 + 2 * 3
        assert [t.get_text() for t in ax.texts] == ["1", "2", "3"]
    assert len(patches(a, FancyArrowPatch)) == 3  # each particle's last pose
    assert any("EKF" in t for t in texts(a)) and any("weight" in t for t in texts(a))
    assert draw_particle_anatomy.__doc__ and "weight" in draw_particle_anatomy.__doc__


def test_particle_anatomy_draws_the_numbers_it_is_given(drawn):
    t = np.linspace(0, 1, 10)
    paths = np.stack([np.column_stack([t, t * s, np.zeros(10)]) for s in (0.0, 0.5)])
    mu = np.array([[[1.0, 1.0], [2.0, 0.0]], [[1.1, 1.2], [5.0, 5.0]]])
    sigma = np.tile(np.eye(2) * 0.01, (2, 2, 1, 1))
    seen = np.array([[True, True], [True, False]])
    fig = drawn(draw_particle_anatomy, paths, mu, sigma, weights=[0.25, 0.75], seen=seen)
    assert len(fig.axes) == 2
    assert fig.axes[1].get_title().endswith("= 0.75")
    assert len(fig.axes[0].lines) == 1 + 2 * 2 and len(fig.axes[1].lines) == 1 + 2 * 1  # unseen landmark not drawn
    assert np.allclose(fig.axes[0].lines[0].get_xydata(), paths[0][:, :2])
    ellipse = fig.axes[0].lines[1].get_xydata()
    assert np.allclose(np.linalg.norm(ellipse - mu[0, 0], axis=1), 0.2)  # 2σ of σ = 0.1 m


def test_filter_step_block_diagram(drawn):
    fig = drawn(draw_filter_step)
    assert isinstance(fig, Figure)
    assert len(patches(fig, FancyBboxPatch)) == 6
    assert len(patches(fig, Polygon)) == 2  # the two decisions
    assert len(patches(fig, FancyArrowPatch)) == 10
    labels = " | ".join(texts(fig))
    for phrase in ("sample the motion", "known", "EKF update", "initialise", "normalise the weights",
                   r"N_\mathrm{eff} < \tau M", "resample", "combined estimate", "next time step", "yes", "no"):
        assert phrase in labels, phrase
