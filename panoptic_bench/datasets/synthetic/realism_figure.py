"""Figures of the realism statistics, real vs synthetic (PNG files, written atomically)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from panoptic_bench.datasets.synthetic.realism import HISTOGRAMS, N_SECTORS, RANGE_BINS
from panoptic_bench.io import atomic_open

__all__ = ["overview_figure", "sensor_figure"]

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


def overview_figure(real, synth, rows: list, path: str | Path) -> None:
    """Points per scan, class frequencies, instances, points per car vs range, range histogram.

    Parameters
    ----------
    real, synth : DatasetStats
        Real and synthetic statistics (:mod:`~panoptic_bench.datasets.synthetic.stats`).
    rows : list of (str, float, float)
        Table rows; the first six are printed in the last panel.
    path : str or Path
        PNG to write.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from panoptic_bench.datasets.semantickitti import LABELS
    from panoptic_bench.datasets.synthetic.stats import RANGE_BINS as HIST_BINS

    colors = {"real": "#1f77b4", "synthetic": "#ff7f0e"}
    fig, ax = plt.subplots(2, 3, figsize=(13, 7.2), dpi=72)
    pairs = (("real", real), ("synthetic", synth))
    for i, (name, s) in enumerate(pairs):
        ax[0, 0].bar(
            i,
            s.points_per_scan.mean() / 1e3,
            color=colors[name],
            yerr=s.points_per_scan.std() / 1e3,
        )
        ax[0, 2].bar(
            i, s.instances_per_scan.mean(), color=colors[name], yerr=s.instances_per_scan.std()
        )
    for a, title in (
        (ax[0, 0], "points per scan (thousands)"),
        (ax[0, 2], "thing instances per scan"),
    ):
        a.set_xticks([0, 1], ["real", "synthetic"])
        a.set_title(title)
    k = np.arange(1, len(LABELS.class_names))
    for j, (name, s) in enumerate(pairs):
        ax[0, 1].bar(
            k + (j - 0.5) * 0.4, 100 * s.class_freq[1:], 0.4, color=colors[name], label=name
        )
    ax[0, 1].set_yscale("log")
    ax[0, 1].set_xticks(k, LABELS.class_names[1:], rotation=90, fontsize=7)
    ax[0, 1].set_title("class frequency (% of points)")
    ax[0, 1].legend(fontsize=8)
    xs = np.array([10.0, 50.0])
    for name, s in pairs:
        ax[1, 0].scatter(
            s.car_range,
            s.car_points,
            s=10,
            alpha=0.6,
            color=colors[name],
            label=f"{name} (slope {s.slope:.2f})",
        )
        sel = (s.car_range >= 10) & (s.car_range <= 50)
        if np.isfinite(s.slope) and sel.any():
            b = np.polyfit(np.log(s.car_range[sel]), np.log(s.car_points[sel]), 1)
            ax[1, 0].plot(xs, np.exp(np.polyval(b, np.log(xs))), color=colors[name])
    ax[1, 0].set_xscale("log")
    ax[1, 0].set_yscale("log")
    ax[1, 0].axvspan(10, 50, color="0.9", zorder=0)
    ax[1, 0].set_xlabel("mean range of the car (m)")
    ax[1, 0].set_title("points per car instance vs range")
    ax[1, 0].legend(fontsize=8)
    centers = (HIST_BINS[:-1] + HIST_BINS[1:]) / 2
    for name, s in pairs:
        ax[1, 1].plot(centers, s.range_hist, color=colors[name], label=name)
    ax[1, 1].set_yscale("log")
    ax[1, 1].set_xlabel("horizontal range (m)")
    ax[1, 1].set_title("range histogram (fraction of points)")
    ax[1, 1].legend(fontsize=8)
    ax[1, 2].axis("off")
    text = "\n".join(f"{n[:40]}: {a:.3g} | {b:.3g}" for n, a, b in rows[:6])
    ax[1, 2].text(
        0, 1, "real | synthetic\n\n" + text, va="top", fontsize=8, family="monospace", wrap=True
    )
    fig.tight_layout()
    with atomic_open(path, "wb") as fh:
        fig.savefig(fh, format="png")
    plt.close(fig)
