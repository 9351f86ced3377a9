"""The figure :meth:`bondc.api.Simulation.plot` returns: a matplotlib Figure that shows itself.

A :class:`matplotlib.figure.Figure` made without pyplot (so that a script's figures are not kept
by pyplot and a notebook does not show each twice) has no picture in Jupyter unless the inline
backend has been set up (``%matplotlib inline`` or importing pyplot): a fresh kernel printed
``<Figure size 700x480 with 2 Axes>``. :class:`SimulationFigure` gives Jupyter its PNG itself.
"""

from __future__ import annotations

import io

from matplotlib.figure import Figure

__all__ = ["SimulationFigure"]


class SimulationFigure(Figure):
    """A :class:`~matplotlib.figure.Figure` with ``_repr_png_``: a notebook cell ending in
    ``sim.plot()`` shows the picture, with or without ``%matplotlib``."""

    def _repr_png_(self) -> bytes:
        buffer = io.BytesIO()
        self.savefig(buffer, format="png", bbox_inches="tight")
        return buffer.getvalue()
