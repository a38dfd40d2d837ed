"""Figures drawn without a display: matplotlib's object API (no pyplot), so importing a module that
draws never changes a notebook's backend and no figure outlives its file."""

from __future__ import annotations

from matplotlib.figure import Figure

DPI = 100


def figure(**kwargs) -> Figure:
    """A new figure, not registered with pyplot (keyword arguments as for matplotlib's Figure)."""
    return Figure(**kwargs)


def save(fig, path, dpi=DPI) -> Figure:
    """Write the figure as a PNG and return it (for a caller that wants to look at or reuse it)."""
    fig.savefig(path, dpi=dpi)
    return fig
