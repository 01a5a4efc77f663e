"""Figure of the sensor and ground realism measures: real vs synthetic (one PNG, written atomically)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from panoptic_bench.datasets.synthetic.realism import HISTOGRAMS, N_SECTORS, RANGE_BINS
from panoptic_bench.io import atomic_open

__all__ = ["sensor_figure"]

_COLORS = {"real": "#1f77b4", "synthetic": "#ff7f0e"}


def _norm(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, float)
    return v / max(v.sum(), 1.0)


def sensor_figure(real: dict, synth: dict, path: str | Path) -> None:
    """Plot remission, road remission vs range, heights above the road, rings and the ego hole.

    Parameters
    ----------
    real, synth : dict of str to ndarray
        Aggregated histograms of :func:`~panoptic_bench.datasets.synthetic.realism.aggregate`.
    path : str or Path
        PNG to write.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 3, figsize=(13, 7.2), dpi=72)
    pairs = (("real", real), ("synthetic", synth))
    rem_edges = HISTOGRAMS["remission"]
    rem_c = (rem_edges[:-1] + rem_edges[1:]) / 2
    mid = (RANGE_BINS[:-1] + RANGE_BINS[1:]) / 2
    h_edges = HISTOGRAMS["height"]
    h_c = (h_edges[:-1] + h_edges[1:]) / 2
    r_edges = HISTOGRAMS["range"]
    r_c = (r_edges[:-1] + r_edges[1:]) / 2
    for name, h in pairs:
        col = _COLORS[name]
        ax[0, 0].step(rem_c, _norm(h["remission"]), where="mid", color=col, label=name)
        with np.errstate(invalid="ignore", divide="ignore"):
            road = np.where(h["road_rem_n"] > 50, h["road_rem_sum"] / h["road_rem_n"], np.nan)
        ax[0, 1].plot(mid, road, "o-", color=col, label=name)
        ax[0, 2].step(h_c, _norm(h["height"]), where="mid", color=col, label=name)
        ax[1, 0].plot(np.arange(len(h["ring_points"])), h["ring_points"], color=col, label=name)
        ax[1, 1].step(r_c, _norm(h["range"]), where="mid", color=col, label=name)
        ax[1, 2].plot(np.arange(N_SECTORS), h["hole"], "o-", color=col, label=name)
    titles = (
        (ax[0, 0], "remission (fraction of points)", "remission"),
        (ax[0, 1], "road remission (mean) vs range", "horizontal range (m)"),
        (ax[0, 2], "height above the road plane (fraction)", "m"),
        (ax[1, 0], "points per ring (0 = lowest)", "ring"),
        (ax[1, 1], "range histogram (fraction)", "horizontal range (m)"),
        (ax[1, 2], "ego hole: min ground range per 45 deg sector", "sector (0 = ahead, CCW)"),
    )
    for a, title, xlabel in titles:
        a.set_title(title, fontsize=10)
        a.set_xlabel(xlabel)
        a.legend(fontsize=8)
    ax[0, 0].set_yscale("log")
    ax[0, 2].set_yscale("log")
    ax[1, 1].set_yscale("log")
    ax[1, 2].set_xticks(np.arange(N_SECTORS))
    fig.tight_layout()
    with atomic_open(path, "wb") as fh:
        fig.savefig(fh, format="png")
    plt.close(fig)
