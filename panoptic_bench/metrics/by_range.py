"""Panoptic and semantic metrics per range bin (distance from the sensor).

Each bin ``[edges[i], edges[i+1])`` is scored as its own point set: both the prediction and the
ground truth are restricted to the points whose range lies in the bin, and
:func:`~panoptic_bench.metrics.panoptic.panoptic_stats` runs on that subset. A segment that crosses
a bin edge is therefore split: each part is matched, counted (``min_points`` applies to the part)
and averaged within its own bin. Points outside every bin are not scored. The bins of all scans are
accumulated independently, so bin ``i`` over a split equals scoring the union of every scan's bin
``i`` points.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from panoptic_bench.metrics.panoptic import PanopticResult, PanopticStats, panoptic_stats

__all__ = ["RangeStats", "panoptic_stats_by_range", "parse_edges", "point_range"]


def point_range(points: np.ndarray) -> np.ndarray:
    """Euclidean distance of each point from the sensor origin.

    Parameters
    ----------
    points : array of shape (n_points, >=3)
        ``x, y, z`` in the first three columns (sensor frame).

    Returns
    -------
    ndarray of shape (n_points,), float64
    """
    xyz = np.asarray(points)[:, :3].astype(np.float64)
    return np.sqrt(np.einsum("ij,ij->i", xyz, xyz))


def parse_edges(edges: Sequence[float] | str) -> tuple[float, ...]:
    """Validate bin edges (strictly increasing, >= 2 values, non-negative); ``"0,10,20"`` accepted."""
    if isinstance(edges, str):
        try:
            edges = [float(e) for e in edges.split(",") if e.strip()]
        except ValueError:
            raise ValueError(
                f"range edges must be numbers separated by commas, got {edges!r}"
            ) from None
    out = tuple(float(e) for e in edges)
    if len(out) < 2 or any(b <= a for a, b in zip(out, out[1:])) or out[0] < 0:
        raise ValueError(
            f"range edges must be >= 2 increasing non-negative numbers, e.g. 0,10,20; got {out}"
        )
    return out


@dataclass(eq=False)
class RangeStats:
    """One :class:`PanopticStats` per range bin; adds bin-wise with ``+``.

    Attributes
    ----------
    edges : tuple of float
        Bin edges in metres; bin ``i`` is ``[edges[i], edges[i+1])``.
    bins : tuple of PanopticStats
        ``len(edges) - 1`` accumulators.
    """

    edges: tuple[float, ...]
    bins: tuple[PanopticStats, ...]

    def __post_init__(self) -> None:
        self.edges = parse_edges(self.edges)
        self.bins = tuple(self.bins)
        if len(self.bins) != len(self.edges) - 1:
            raise ValueError("RangeStats needs len(edges) - 1 bins")

    @classmethod
    def zeros(
        cls, edges: Sequence[float], num_classes: int, ignore: Sequence[int] = (0,)
    ) -> RangeStats:
        """Empty accumulators for the bins of ``edges``."""
        edges = parse_edges(edges)
        return cls(edges, tuple(PanopticStats.zeros(num_classes, ignore) for _ in edges[1:]))

    def __add__(self, other: RangeStats) -> RangeStats:
        if not isinstance(other, RangeStats):
            return NotImplemented
        if other.edges != self.edges:
            raise ValueError("cannot add RangeStats with different bin edges")
        return RangeStats(self.edges, tuple(a + b for a, b in zip(self.bins, other.bins)))

    def __radd__(self, other: object) -> RangeStats:
        if other == 0:
            return self
        return NotImplemented

    def compute(self) -> list[tuple[float, float, PanopticResult]]:
        """``[(low, high, PanopticResult), ...]`` per bin."""
        return [
            (lo, hi, stats.compute())
            for lo, hi, stats in zip(self.edges[:-1], self.edges[1:], self.bins)
        ]

    def point_counts(self) -> list[int]:
        """Number of scored points per bin (all gt classes, from the confusion matrices)."""
        return [int(b.confusion.sum()) for b in self.bins]


def panoptic_stats_by_range(
    sem_pred: np.ndarray,
    inst_pred: np.ndarray,
    sem_gt: np.ndarray,
    inst_gt: np.ndarray,
    ranges: np.ndarray,
    edges: Sequence[float],
    *,
    num_classes: int,
    ignore: Sequence[int] = (0,),
    min_points: int = 30,
) -> RangeStats:
    """:func:`panoptic_stats` restricted to each range bin.

    Parameters
    ----------
    sem_pred, inst_pred, sem_gt, inst_gt : arrays of shape (n_points,)
        As for :func:`~panoptic_bench.metrics.panoptic.panoptic_stats`.
    ranges : array of shape (n_points,), float
        Range of each point (see :func:`point_range`).
    edges : sequence of float
        Increasing bin edges; bin ``i`` holds ``edges[i] <= range < edges[i+1]``.
    num_classes, ignore, min_points
        As for :func:`~panoptic_bench.metrics.panoptic.panoptic_stats`.

    Returns
    -------
    RangeStats
    """
    edges = parse_edges(edges)
    ranges = np.asarray(ranges).ravel()
    if ranges.shape[0] != np.size(sem_gt):
        raise ValueError(f"ranges has {ranges.shape[0]} values for {np.size(sem_gt)} points")
    arrays = [np.asarray(a).ravel() for a in (sem_pred, inst_pred, sem_gt, inst_gt)]
    which = np.searchsorted(np.asarray(edges), ranges, side="right") - 1
    bins = []
    for i in range(len(edges) - 1):
        sel = which == i
        bins.append(
            panoptic_stats(
                *(a[sel] for a in arrays),
                num_classes=num_classes,
                ignore=ignore,
                min_points=min_points,
            )
        )
    return RangeStats(edges, tuple(bins))
