"""Bird's-eye panoptic rendering of one scan, the style of the paper's Figs. 9-11.

Things points are coloured per instance (colours are arbitrary, so predicted and ground-truth
instances of the same object need not share a colour), stuff points are grey, unlabelled /
ignored points light grey.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from pathlib import Path

import numpy as np

from panoptic_bench.reports.style import figure, instance_colours

STUFF_GREY = (0.62, 0.62, 0.62)
IGNORE_GREY = (0.86, 0.86, 0.86)
THING_NO_INSTANCE = (0.25, 0.25, 0.25)


def panoptic_colours(
    semantic: np.ndarray,
    instance: np.ndarray,
    thing_classes: Collection[int],
    *,
    ignore_classes: Collection[int] = (0,),
) -> np.ndarray:
    """RGB colour per point: one colour per things instance, grey stuff.

    Parameters
    ----------
    semantic : array of shape (n_points,), integer
        Semantic class id per point.
    instance : array of shape (n_points,), integer
        Instance id per point (0 = none); instances are told apart by (class, id) pairs.
    thing_classes : collection of int
        Semantic ids of things classes.
    ignore_classes : collection of int
        Ids drawn in light grey (unlabelled).

    Returns
    -------
    numpy.ndarray of shape (n_points, 3), float64 in [0, 1]
        Deterministic: the k-th instance in (class, id) order always gets the same colour.
    """
    sem = np.asarray(semantic).astype(np.int64).ravel()
    inst = np.asarray(instance).astype(np.int64).ravel()
    if sem.shape != inst.shape:
        raise ValueError(f"semantic {sem.shape} and instance {inst.shape} differ in length")
    rgb = np.tile(np.asarray(STUFF_GREY), (sem.size, 1))
    rgb[np.isin(sem, list(ignore_classes))] = IGNORE_GREY
    things = np.isin(sem, list(thing_classes))
    rgb[things & (inst == 0)] = THING_NO_INSTANCE
    mask = things & (inst != 0)
    if mask.any():
        keys = np.stack([sem[mask], inst[mask]], axis=1)
        uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
        rgb[mask] = instance_colours(len(uniq))[inverse.ravel()]
    return rgb


def plot_bev_panoptic(
    xy: np.ndarray,
    panels: Sequence[tuple[str, np.ndarray, np.ndarray]],
    thing_classes: Collection[int],
    path: str | Path,
    *,
    extent: tuple[float, float, float, float] | None = None,
    title: str | None = None,
    ignore_classes: Collection[int] = (0,),
) -> Path:
    """Side-by-side bird's-eye panoptic views of one scan (e.g. prediction | ground truth).

    Parameters
    ----------
    xy : array of shape (n_points, >=2), float
        Point coordinates in metres; columns 0 and 1 (x forward, y left) are drawn.
    panels : sequence of (title, semantic, instance)
        One panel per entry, left to right, e.g. ``[("DS-Net", sem_pred, inst_pred),
        ("ground truth", sem_gt, inst_gt)]``; ``semantic`` and ``instance`` are integer arrays of
        shape (n_points,) (learning ids, instance 0 = none).
    thing_classes : collection of int
        Semantic ids of things classes (1-8 for SemanticKITTI learning ids).
    path : str or Path
        Output PNG.
    extent : (xmin, xmax, ymin, ymax), optional
        Region drawn; default: the points' 1st-99th percentile box, made square.
    title : str, optional
        Figure title (e.g. the scan name).
    ignore_classes : collection of int
        Semantic ids drawn light grey.
    """
    pts = np.asarray(xy, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] < 2:
        raise ValueError(f"xy must have shape (n_points, >=2), got {pts.shape}")
    if not panels:
        raise ValueError("at least one panel is needed")
    if extent is None:
        lo = np.percentile(pts[:, :2], 1, axis=0)
        hi = np.percentile(pts[:, :2], 99, axis=0)
        centre, half = (lo + hi) / 2, float((hi - lo).max()) / 2 + 1.0
        extent = (centre[0] - half, centre[0] + half, centre[1] - half, centre[1] + half)
    n = len(panels)
    with figure(path, ncols=n, size=(4.2 * n, 4.5)) as (fig, axes):
        for ax, (name, sem, inst) in zip(axes[0], panels):
            sem = np.asarray(sem)
            if sem.shape[0] != pts.shape[0]:
                raise ValueError(f"panel '{name}': {sem.shape[0]} labels for {pts.shape[0]} points")
            rgb = panoptic_colours(sem, inst, thing_classes, ignore_classes=ignore_classes)
            things = np.isin(np.asarray(sem), list(thing_classes))
            # stuff first, small; things on top, larger
            ax.scatter(pts[~things, 0], pts[~things, 1], s=0.15, c=rgb[~things], linewidths=0)
            ax.scatter(pts[things, 0], pts[things, 1], s=1.2, c=rgb[things], linewidths=0)
            ax.set_title(name)
            ax.set_xlim(extent[0], extent[1])
            ax.set_ylim(extent[2], extent[3])
            ax.set_aspect("equal")
            ax.grid(False)
            ax.set_xlabel("x (m)")
        axes[0, 0].set_ylabel("y (m)")
        if title:
            fig.suptitle(title)
    return Path(path)
