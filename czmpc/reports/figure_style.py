"""How every czmpc figure is made: Agg canvas, size and resolution, legends, atomic PNG.

Figures are `matplotlib.figure.Figure` objects on the Agg canvas (no pyplot, no global
figure registry, no display needed); a figure function draws one, writes it with
`save_figure` and returns it, so that tests can inspect titles, labels and lines after
the fact. Figures are about 1000 x 500 px at `DPI` dots per inch.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from czmpc.errors import CzmpcError
from sysid.atomic import atomic_path

#: Resolution of every PNG [dots per inch].
DPI = 110
#: Default size of a one-panel figure [inch].
WIDE_FIGSIZE_IN = (9.0, 4.2)
#: Default size of a figure of stacked panels [inch].
TALL_FIGSIZE_IN = (9.0, 6.0)
#: Line colours, in the order the series of one figure take them.
PALETTE = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")


class FigureError(CzmpcError, ValueError):
    """Arrays handed to a figure function that cannot be drawn (wrong shapes, empty)."""


def vector(values: object, name: str, length: int | None = None) -> np.ndarray:
    """``values`` as a non-empty 1-D float array (of ``length`` samples, if given).

    Raises
    ------
    FigureError
        Not 1-D, empty, or of another length.
    """
    arr = np.asarray(values, dtype=float)
    if arr.ndim != 1 or arr.size == 0:
        raise FigureError(f"figure input {name} must be a non-empty 1-D array; got shape {arr.shape}")
    if length is not None and arr.size != length:
        raise FigureError(f"figure input {name} must have {length} samples like time_s; got {arr.size}")
    return arr


def new_figure(figsize_in: tuple[float, float] = WIDE_FIGSIZE_IN) -> Figure:
    """An empty figure on the Agg canvas, constrained layout, at `DPI`."""
    fig = Figure(figsize=figsize_in, dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def stacked_axes(n_rows: int, *, sharex: bool = True,
                 figsize_in: tuple[float, float] | None = None) -> tuple[Figure, list[Axes]]:
    """A figure of ``n_rows`` panels above each other, gridded, x shared by default."""
    fig = new_figure(figsize_in or (WIDE_FIGSIZE_IN if n_rows == 1 else TALL_FIGSIZE_IN))
    axes = fig.subplots(n_rows, 1, sharex=sharex, squeeze=False)[:, 0]
    for ax in axes:
        ax.grid(True, linewidth=0.5, alpha=0.6)
    return fig, list(axes)


def legend_above(ax: Axes) -> None:
    """Legend above the panel, so it never hides data; long labels get fewer columns."""
    labels = ax.get_legend_handles_labels()[1]
    longest = max((len(label) for label in labels), default=0)
    per_row = 3 if longest <= 28 else 2 if longest <= 48 else 1
    ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncols=max(1, min(len(labels), per_row)),
              frameon=False, borderaxespad=0.2, fontsize="small")


def save_figure(fig: Figure, path: str | os.PathLike[str]) -> Figure:
    """Write ``fig`` as a PNG at `DPI` (folders created; a failed draw leaves no half file)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=DPI)
    return fig


__all__ = ["DPI", "PALETTE", "TALL_FIGSIZE_IN", "WIDE_FIGSIZE_IN", "FigureError", "legend_above",
           "new_figure", "save_figure", "stacked_axes", "vector"]
