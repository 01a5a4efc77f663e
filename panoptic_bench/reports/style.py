"""One matplotlib style for every report figure, and atomic PNG writing.

Figures are built on :class:`matplotlib.figure.Figure` directly (Agg canvas, no pyplot global
state, no backend switching) inside :func:`figure`, which applies :data:`STYLE` and writes the
PNG through :func:`panoptic_bench.io.write_bytes`. PNG metadata omits the matplotlib version so
the same inputs give the same bytes.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator
from pathlib import Path

import matplotlib as mpl
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from panoptic_bench.io import write_bytes

#: Qualitative colours (matplotlib tab10) used in order for methods / classes.
PALETTE: tuple[str, ...] = (
    "#1f77b4",
    "#ff7f0e",
    "#2ca02c",
    "#d62728",
    "#9467bd",
    "#8c564b",
    "#e377c2",
    "#7f7f7f",
    "#bcbd22",
    "#17becf",
)
DPI = 150
STYLE: dict[str, object] = {
    "font.size": 9,
    "axes.titlesize": 10,
    "axes.labelsize": 9,
    "legend.fontsize": 8,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.6,
    "lines.linewidth": 1.6,
    "lines.markersize": 4.5,
    "legend.frameon": False,
    "axes.prop_cycle": mpl.cycler(color=list(PALETTE)),
    "figure.facecolor": "white",
    "savefig.facecolor": "white",
}


def colour(i: int) -> str:
    """The ``i``-th colour of :data:`PALETTE` (cycling)."""
    return PALETTE[i % len(PALETTE)]


def instance_colours(n: int) -> np.ndarray:
    """``n`` well separated, deterministic colours (golden-ratio hues), array (n, 3) float."""
    hues = (np.arange(n) * 0.6180339887498949 + 0.1) % 1.0
    sat = np.where(np.arange(n) % 2 == 0, 0.85, 0.6)
    val = np.where(np.arange(n) % 3 == 2, 0.75, 0.95)
    return mpl.colors.hsv_to_rgb(np.stack([hues, sat, val], axis=1))


@contextlib.contextmanager
def figure(
    path: str | Path, *, ncols: int = 1, nrows: int = 1, size: tuple[float, float] = (5.0, 3.4)
) -> Iterator[tuple[Figure, np.ndarray]]:
    """Create a styled figure with an ``(nrows, ncols)`` array of axes; save it as PNG on exit.

    Parameters
    ----------
    path : str or Path
        Destination ``.png`` (written atomically, parents created).
    size : (float, float)
        Figure size in inches.

    Yields
    ------
    (Figure, numpy.ndarray of Axes)
        ``axes`` always has shape ``(nrows, ncols)``.
    """
    with mpl.rc_context(STYLE):
        fig = Figure(figsize=size, layout="constrained")
        FigureCanvasAgg(fig)
        axes = np.asarray(fig.subplots(nrows, ncols, squeeze=False))
        yield fig, axes
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None})
    write_bytes(path, buf.getvalue())
