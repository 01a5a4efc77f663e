"""The paper's analysis figures (Figs. 3-7) and PQ by range, from plain arrays and dicts.

Each function takes numbers only (arrays, mappings, DataFrames), draws one PNG in the common
style of :mod:`panoptic_bench.reports.style` and returns its path. Fractions (PQ, RQ in [0, 1])
are drawn in percent. Nothing here reads result files; see :mod:`panoptic_bench.reports.index`.

=====  ==========================================  ===========================================
Fig.   function                                    inputs
=====  ==========================================  ===========================================
3a     :func:`plot_centres_vs_distance`            distance bins, centres per valid voxel
3b     :func:`plot_bandwidth_vs_rq`                bandwidths, RQ per things class
4a-c   :func:`plot_ablation`                       variant -> {"PQ", "PQ_th"}
5      :func:`plot_bandwidth_vs_size`              class -> size, class -> learned bandwidth
6      :func:`plot_shift_iterations`               points, seeds per iteration, bandwidths
7      :func:`plot_bandwidth_vs_iteration`         class -> learned bandwidth per iteration
ours   :func:`plot_pq_vs_range`                    method -> (range bins, PQ per bin)
ours   :func:`plot_confusion`                      true x predicted point counts
9-11   :func:`panoptic_bench.reports.bev.plot_bev_panoptic`
=====  ==========================================  ===========================================
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib as mpl
import numpy as np
import pandas as pd

from panoptic_bench.reports.style import colour, figure

ArrayLike = Sequence[float] | np.ndarray


def _series(values: ArrayLike | Mapping[str, ArrayLike], default: str) -> dict[str, np.ndarray]:
    if isinstance(values, Mapping):
        return {str(k): np.asarray(v, dtype=np.float64) for k, v in values.items()}
    return {default: np.asarray(values, dtype=np.float64)}


def _check_len(x: np.ndarray, series: Mapping[str, np.ndarray], what: str) -> None:
    for name, y in series.items():
        if y.shape != x.shape:
            raise ValueError(f"{what} '{name}' has shape {y.shape}, expected {x.shape}")


def plot_centres_vs_distance(
    distance_m: ArrayLike,
    centres_per_voxel: ArrayLike | Mapping[str, ArrayLike],
    path: str | Path,
) -> Path:
    """Fig. 3a: average number of regressed centres per valid voxel vs distance to the sensor.

    Parameters
    ----------
    distance_m : array of shape (n_bins,), float
        Distance bin centres in metres.
    centres_per_voxel : array of shape (n_bins,) or mapping label -> array (n_bins,)
        Mean regressed centres per valid (non-empty) instance voxel in each bin; one line per
        label (e.g. per class or per model). NaN marks empty bins.
    path : str or Path
        Output PNG.
    """
    x = np.asarray(distance_m, dtype=np.float64)
    series = _series(centres_per_voxel, "regressed centres")
    _check_len(x, series, "series")
    with figure(path) as (_, axes):
        ax = axes[0, 0]
        for i, (name, y) in enumerate(series.items()):
            ax.plot(x, y, marker="o", color=colour(i), label=name)
        ax.set_xlabel("distance to sensor (m)")
        ax.set_ylabel("regressed centres per valid voxel")
        ax.set_title("Fig. 3a: density of regressed centres vs distance")
        ax.set_ylim(bottom=0)
        if len(series) > 1:
            ax.legend()
    return Path(path)


def plot_bandwidth_vs_rq(
    bandwidths_m: ArrayLike, rq: Mapping[str, ArrayLike], path: str | Path
) -> Path:
    """Fig. 3b: mean-shift bandwidth vs recognition quality per things class.

    Parameters
    ----------
    bandwidths_m : array of shape (n_bw,), float
        Mean-shift bandwidths in metres.
    rq : mapping class name -> array of shape (n_bw,), fractions in [0, 1]
        RQ of each things class at each bandwidth.
    path : str or Path
        Output PNG.
    """
    x = np.asarray(bandwidths_m, dtype=np.float64)
    series = _series(rq, "RQ")
    _check_len(x, series, "class")
    with figure(path, size=(5.6, 3.6)) as (_, axes):
        ax = axes[0, 0]
        for i, (name, y) in enumerate(series.items()):
            ax.plot(x, 100 * y, marker="o", color=colour(i), label=name)
        ax.set_xlabel("mean-shift bandwidth (m)")
        ax.set_ylabel("RQ (%)")
        ax.set_title("Fig. 3b: bandwidth vs RQ per things class")
        ax.legend(loc="center left", bbox_to_anchor=(1.0, 0.5))
    return Path(path)


def plot_ablation(
    results: Mapping[str, Mapping[str, float]] | pd.DataFrame,
    path: str | Path,
    *,
    title: str,
    metrics: Sequence[str] = ("PQ", "PQ_th"),
) -> Path:
    """Figs. 4a/4b/4c: grouped bars of PQ and PQ_Th per variant.

    Parameters
    ----------
    results : mapping variant -> {metric: fraction} or DataFrame (index variants, metric columns)
        Variants in drawing order, e.g. ``{"backbone": {...}, "+ fusion": {...}, "+ DS": {...}}``
        (4a), clustering algorithms (4b), bandwidth learning styles (4c).
    path : str or Path
        Output PNG.
    title : str
        Axes title, e.g. ``"Fig. 4b: clustering algorithms"``.
    metrics : sequence of str
        Keys of ``results`` to draw (``scores.json`` names); missing values are left out.
    """
    frame = results if isinstance(results, pd.DataFrame) else pd.DataFrame(results).T
    frame = frame.reindex(columns=list(metrics)).astype(np.float64)
    labels = {"PQ_th": "PQ$^{Th}$", "PQ_st": "PQ$^{St}$", "PQ_dagger": "PQ$^{\\dagger}$"}
    n_var, n_met = frame.shape
    width = 0.8 / max(n_met, 1)
    with figure(path, size=(max(3.8, 1.1 * n_var + 1.5), 3.4)) as (_, axes):
        ax = axes[0, 0]
        x = np.arange(n_var)
        for j, metric in enumerate(frame.columns):
            vals = 100 * frame[metric].to_numpy()
            bars = ax.bar(
                x + (j - (n_met - 1) / 2) * width,
                np.nan_to_num(vals),
                width,
                color=colour(j),
                label=labels.get(metric, metric),
            )
            for bar, v in zip(bars, vals):
                if not math.isnan(v):
                    ax.annotate(
                        f"{v:.1f}",
                        (bar.get_x() + bar.get_width() / 2, bar.get_height()),
                        ha="center",
                        va="bottom",
                        fontsize=7,
                        xytext=(0, 1),
                        textcoords="offset points",
                    )
        ax.set_xticks(x, [str(i) for i in frame.index])
        ax.set_ylabel("%")
        ax.set_title(title)
        ax.grid(axis="x", visible=False)
        ax.legend(loc="upper left")
        top = np.nanmax(100 * frame.to_numpy()) if np.isfinite(frame.to_numpy()).any() else 1.0
        ax.set_ylim(0, top * 1.2 + 1)
    return Path(path)


def plot_bandwidth_vs_size(
    sizes_m: Mapping[str, float], bandwidths_m: Mapping[str, float], path: str | Path
) -> Path:
    """Fig. 5: average learned bandwidth vs class-wise average instance size.

    Parameters
    ----------
    sizes_m : mapping things class -> float
        Class-wise average size (m) of the instances' regressed centres.
    bandwidths_m : mapping things class -> float
        Average learned bandwidth (m) of the class; classes missing from either map are skipped.
    path : str or Path
        Output PNG. A dashed least-squares line through the origin guides the eye.
    """
    names = [n for n in sizes_m if n in bandwidths_m]
    if not names:
        raise ValueError("sizes_m and bandwidths_m share no class")
    x = np.array([sizes_m[n] for n in names], dtype=np.float64)
    y = np.array([bandwidths_m[n] for n in names], dtype=np.float64)
    with figure(path, size=(4.6, 3.6)) as (_, axes):
        ax = axes[0, 0]
        ax.scatter(x, y, color=[colour(i) for i in range(len(names))], zorder=3)
        for name, xi, yi in zip(names, x, y):
            ax.annotate(name, (xi, yi), xytext=(4, 3), textcoords="offset points", fontsize=8)
        if float(x @ x) > 0:
            slope = float(x @ y) / float(x @ x)
            xs = np.array([0.0, x.max() * 1.1])
            ax.plot(xs, slope * xs, "--", color="0.5", lw=1, label=f"y = {slope:.2f} x")
            ax.legend(loc="upper left")
        ax.set_xlim(left=0)
        ax.set_ylim(bottom=0)
        ax.set_xlabel("average instance size of regressed centres (m)")
        ax.set_ylabel("average learned bandwidth (m)")
        ax.set_title("Fig. 5: learned bandwidth vs class size")
    return Path(path)


def plot_shift_iterations(
    points: np.ndarray,
    seeds: np.ndarray | Sequence[np.ndarray],
    bandwidths: np.ndarray | Sequence[np.ndarray],
    path: str | Path,
    *,
    titles: Sequence[str] | None = None,
) -> Path:
    """Fig. 6: seed points over the dynamic-shifting iterations, bird's-eye view.

    Parameters
    ----------
    points : array of shape (n_points, >=2), float
        Original things points (x, y[, z]) drawn in black in every panel.
    seeds : array of shape (n_panels, n_seeds, >=2) or list of (n_seeds, >=2) arrays
        Seed positions shown in each panel, left to right (e.g. before iteration 1..I, then final).
    bandwidths : array of shape (n_panels, n_seeds) or list of (n_seeds,) arrays
        Learned bandwidth (m) of each seed in that panel (weights x candidates); red = high.
    titles : sequence of str, optional
        Panel titles; default ``"iteration 0"``, ``"iteration 1"``...
    path : str or Path
        Output PNG.
    """
    pts = np.asarray(points, dtype=np.float64)
    seeds = [np.asarray(s, dtype=np.float64) for s in seeds]
    bws = [np.asarray(b, dtype=np.float64) for b in bandwidths]
    if len(seeds) != len(bws) or not seeds:
        raise ValueError("seeds and bandwidths need the same, non-zero number of panels")
    for s, b in zip(seeds, bws):
        if s.ndim != 2 or s.shape[1] < 2 or b.shape != (s.shape[0],):
            raise ValueError(f"seeds panel {s.shape} does not match bandwidths {b.shape}")
    titles = list(titles) if titles is not None else [f"iteration {i}" for i in range(len(seeds))]
    allb = np.concatenate(bws)
    norm = mpl.colors.Normalize(
        vmin=float(allb.min()), vmax=float(max(allb.max(), allb.min() + 1e-6))
    )
    xy = np.concatenate([pts[:, :2], *[s[:, :2] for s in seeds]])
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    pad = 0.05 * float((hi - lo).max() + 1e-6)
    n = len(seeds)
    with figure(path, ncols=n, size=(2.4 * n + 0.8, 2.9)) as (fig, axes):
        sc = None
        for i, ax in enumerate(axes[0]):
            ax.scatter(pts[:, 0], pts[:, 1], s=1.5, color="black", linewidths=0, alpha=0.5)
            sc = ax.scatter(
                seeds[i][:, 0], seeds[i][:, 1], s=7, c=bws[i], cmap="Spectral_r", norm=norm,
                linewidths=0,
            )  # fmt: skip
            ax.set_title(titles[i])
            ax.set_aspect("equal")
            ax.set_xlim(lo[0] - pad, hi[0] + pad)
            ax.set_ylim(lo[1] - pad, hi[1] + pad)
            ax.grid(False)
            ax.set_xticks([])
            ax.set_yticks([])
        fig.colorbar(sc, ax=list(axes[0]), label="learned bandwidth (m)", shrink=0.85)
        fig.suptitle("Fig. 6: seeds over the dynamic shifting iterations (BEV)")
    return Path(path)


def plot_bandwidth_vs_iteration(
    bandwidths_m: Mapping[str, ArrayLike],
    path: str | Path,
    *,
    lower_limit: float | None = None,
) -> Path:
    """Fig. 7: average learned bandwidth per things class at each iteration.

    Parameters
    ----------
    bandwidths_m : mapping class -> array of shape (n_iterations,), float
        Average learned bandwidth (m) at iterations 1..n_iterations.
    lower_limit : float, optional
        Smallest bandwidth candidate, drawn as a dotted line (0.2 m in the paper).
    path : str or Path
        Output PNG.
    """
    series = _series(bandwidths_m, "bandwidth")
    with figure(path, size=(5.6, 3.6)) as (_, axes):
        ax = axes[0, 0]
        for i, (name, y) in enumerate(series.items()):
            ax.plot(np.arange(1, y.size + 1), y, marker="o", color=colour(i), label=name)
        if lower_limit is not None:
            ax.axhline(lower_limit, ls=":", color="0.4", lw=1, label="smallest candidate")
        n_max = max(y.size for y in series.values())
        ax.set_xticks(np.arange(1, n_max + 1))
        ax.set_xlabel("iteration")
        ax.set_ylabel("average learned bandwidth (m)")
        ax.set_title("Fig. 7: learned bandwidth vs iteration")
        ax.legend(loc="center left", bbox_to_anchor=(1.0, 0.5))
    return Path(path)


def _range_label(lo: float, hi: float) -> str:
    return f">={lo:g}" if not np.isfinite(hi) else f"{lo:g}-{hi:g}"


def plot_pq_vs_range(
    series: Mapping[str, tuple[ArrayLike, ArrayLike]],
    path: str | Path,
    *,
    metric: str = "PQ",
) -> Path:
    """PQ (or another metric) per distance bin, one line per method (ours, not in the paper).

    Parameters
    ----------
    series : mapping method -> (ranges, values)
        ``ranges``: array of shape (n_bins, 2), float, bin ``[lo, hi)`` in metres (``hi`` inf or
        NaN for an open last bin); ``values``: array of shape (n_bins,), fractions in [0, 1]
        (NaN = no data). Bins are aligned across methods by their bounds.
    metric : str
        Axis label.
    path : str or Path
        Output PNG.
    """
    parsed = {}
    for name, (ranges, values) in series.items():
        r = np.asarray(ranges, dtype=np.float64).reshape(-1, 2)
        r[:, 1] = np.where(np.isnan(r[:, 1]), np.inf, r[:, 1])
        v = np.asarray(values, dtype=np.float64)
        if v.shape != (r.shape[0],):
            raise ValueError(f"'{name}': {r.shape[0]} bins but values of shape {v.shape}")
        parsed[name] = (r, v)
    bins = sorted({(float(lo), float(hi)) for r, _ in parsed.values() for lo, hi in r})
    pos = {b: i for i, b in enumerate(bins)}
    with figure(path, size=(max(4.6, 0.7 * len(bins) + 2.5), 3.4)) as (_, axes):
        ax = axes[0, 0]
        for i, (name, (r, v)) in enumerate(parsed.items()):
            x = [pos[(float(lo), float(hi))] for lo, hi in r]
            ax.plot(x, 100 * v, marker="o", color=colour(i), label=name)
        ax.set_xticks(range(len(bins)), [_range_label(lo, hi) for lo, hi in bins])
        ax.set_xlabel("distance to sensor (m)")
        ax.set_ylabel(f"{metric} (%)")
        ax.set_ylim(0, 100)
        ax.set_title(f"{metric} by distance (ours)")
        ax.legend(loc="best")
    return Path(path)


def plot_confusion(
    conf: np.ndarray, class_names: Sequence[str], path: str | Path, *, title: str = ""
) -> Path:
    """Where each true class's points go: the confusion matrix normalised by row (ours).

    Parameters
    ----------
    conf : array of shape (C, C), int
        ``[t, p]`` = points of true class ``t`` predicted as ``p``; all-zero rows (ignored true
        classes) are left out.
    class_names : sequence of str, length C
    path : str or Path
        Output PNG.
    title : str
        Axes title.
    """
    conf = np.asarray(conf, dtype=np.float64)
    if conf.shape != (len(class_names), len(class_names)):
        raise ValueError(f"conf has shape {conf.shape}, expected {len(class_names)} square")
    rows = np.flatnonzero(conf.sum(axis=1) > 0)
    share = 100 * conf[rows] / conf[rows].sum(axis=1, keepdims=True)
    n = len(class_names)
    with figure(path, size=(0.32 * n + 2.2, 0.3 * len(rows) + 1.6)) as (fig, axes):
        ax = axes[0, 0]
        im = ax.imshow(share, cmap="Blues", vmin=0, vmax=100, aspect="auto")
        ax.set_xticks(range(n), class_names, rotation=90, fontsize=7)
        ax.set_yticks(range(len(rows)), [class_names[r] for r in rows], fontsize=7)
        ax.set_xlabel("predicted as")
        ax.set_ylabel("true class")
        ax.set_title(title or "confusion (% of each true class)")
        fig.colorbar(im, ax=ax, label="% of the true class's points")
    return Path(path)
