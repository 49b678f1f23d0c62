"""Knobs on a figure: sliders in JupyterLab, the default figure in the static book.

:func:`knobs` draws a figure with the default value of every control and shows it as the cell's ordinary
output, so the rendered book (and nbmake) sees the default figure. In a live notebook the controls appear
under it; turning one draws the figure again in place. The controls are plain ``ipywidgets`` widgets, e.g.::

    from ipywidgets import IntSlider, FloatLogSlider, Dropdown
    knobs(draw_particles, M=IntSlider(100, 10, 1000, 10, description="particles M"),
          resampler=Dropdown(options=["roulette", "systematic"], value="systematic"))

``draw(**values)`` must return a :class:`matplotlib.figure.Figure`.
"""

from __future__ import annotations

from collections.abc import Callable

import matplotlib.pyplot as plt
from matplotlib.figure import Figure

__all__ = ["knobs"]


def _drawn(draw: Callable[..., Figure], values: dict) -> Figure:
    fig = draw(**values)
    if not isinstance(fig, Figure):
        raise TypeError(f"knobs: {getattr(draw, '__name__', draw)!r} must return a matplotlib Figure, got {type(fig).__name__}")
    plt.close(fig)  # shown through the display handle only, not again by the inline backend
    return fig


def knobs(draw: Callable[..., Figure], **controls):
    """Show ``draw(**defaults)`` and, under it, one control per keyword that redraws the figure.

    Parameters
    ----------
    draw : callable
        ``draw(**values) -> Figure``, called with one keyword per control.
    **controls : ipywidgets.ValueWidget
        The controls; each one's ``value`` at the call is the default the static figure is drawn with.

    Returns
    -------
    ipywidgets.VBox
        The controls (already displayed), for tests and for reading their values.
    """
    import ipywidgets
    from IPython.display import display

    if not controls:
        raise ValueError("knobs: give at least one control, e.g. M=IntSlider(100, 10, 1000)")
    for name, control in controls.items():
        if not hasattr(control, "value") or not hasattr(control, "observe"):
            raise TypeError(f"knobs: control {name!r} is a {type(control).__name__}, not an ipywidgets widget")
    values = {name: control.value for name, control in controls.items()}
    handle = display(_drawn(draw, values), display_id=True)

    def redraw(_change) -> None:
        handle.update(_drawn(draw, {name: control.value for name, control in controls.items()}))

    for control in controls.values():
        control.observe(redraw, names="value")
    box = ipywidgets.VBox(list(controls.values()))
    display(box)
    return box
