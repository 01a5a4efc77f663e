"""Where one true class's points go, bin by bin of a per-point quantity (``eval breakdown``).

A confusion matrix says *that* real terrain is called sidewalk; a breakdown says *which* terrain:
the predicted classes of one true class's points, counted separately in bins of a per-point
quantity (range, height above the road plane, roughness, remission; see
:mod:`panoptic_bench.metrics.point_features`). The kernel is a pure function on arrays and the
counts add up over scans with ``+``, like :class:`~panoptic_bench.metrics.panoptic.PanopticStats`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["BinnedCounts", "binned_counts", "check_edges"]


def check_edges(edges: Sequence[float]) -> tuple[float, ...]:
    """Validate bin edges: >= 2 finite, strictly increasing numbers (negative allowed).

    Raises
    ------
    ValueError
        Naming the edges received.
    """
    out = tuple(float(e) for e in edges)
    if (
        len(out) < 2
        or not all(math.isfinite(e) for e in out)
        or any(b <= a for a, b in zip(out, out[1:]))
    ):
        raise ValueError(f"bin edges must be >= 2 finite, increasing numbers; got {out}")
    return out


def binned_counts(
    values: np.ndarray, predicted: np.ndarray, edges: Sequence[float], num_classes: int
) -> np.ndarray:
    """Count the predicted classes of points in each bin ``[edges[i], edges[i+1])``.

    Parameters
    ----------
    values : array of shape (n,), float
        The binned quantity of each point; NaN and values outside ``[edges[0], edges[-1])`` are
        not counted.
    predicted : array of shape (n,), int
        Predicted class (train id) of each point, in ``[0, num_classes)``.
    edges : sequence of float, length B + 1
        Increasing bin edges (:func:`check_edges`).
    num_classes : int

    Returns
    -------
    numpy.ndarray of shape (B, num_classes), int64
        ``[b, c]`` = points in bin ``b`` predicted as class ``c``.
    """
    edges = np.asarray(check_edges(edges))
    values = np.asarray(values, dtype=np.float64)
    predicted = np.asarray(predicted, dtype=np.int64)
    if values.shape != predicted.shape or values.ndim != 1:
        raise ValueError(f"values {values.shape} and predicted {predicted.shape} must be (n,)")
    if predicted.size and (predicted.min() < 0 or predicted.max() >= num_classes):
        raise ValueError(f"predicted classes must lie in [0, {num_classes})")
    n_bins = len(edges) - 1
    ok = np.isfinite(values) & (values >= edges[0]) & (values < edges[-1])
    b = np.searchsorted(edges, values[ok], side="right") - 1
    flat = np.bincount(b * num_classes + predicted[ok], minlength=n_bins * num_classes)
    return flat.reshape(n_bins, num_classes).astype(np.int64)


@dataclass(frozen=True, eq=False)
class BinnedCounts:
    """Predicted-class counts of one true class per bin, summed over scans with ``+``.

    Attributes
    ----------
    edges : tuple of float, length B + 1
    counts : array of shape (B, C), int64
        ``[b, c]`` = points of the true class in bin ``b`` predicted as ``c``.
    unbinned : int
        Points of the true class with no value (NaN) or one outside every bin.
    """

    edges: tuple[float, ...]
    counts: np.ndarray
    unbinned: int = 0

    @classmethod
    def of_scan(
        cls,
        values: np.ndarray,
        predicted: np.ndarray,
        edges: Sequence[float],
        num_classes: int,
    ) -> BinnedCounts:
        """The counts of one scan's points of the true class (:func:`binned_counts`)."""
        counts = binned_counts(values, predicted, edges, num_classes)
        return cls(check_edges(edges), counts, int(len(values) - counts.sum()))

    def __add__(self, other: BinnedCounts) -> BinnedCounts:
        if self.edges != other.edges or self.counts.shape != other.counts.shape:
            raise ValueError("only counts over the same bins and classes add up")
        return BinnedCounts(self.edges, self.counts + other.counts, self.unbinned + other.unbinned)

    def points(self) -> np.ndarray:
        """Points per bin, shape (B,), int64."""
        return self.counts.sum(axis=1)

    def shares(self) -> np.ndarray:
        """Share of each bin's points predicted as each class, shape (B, C), float64 (NaN: empty bin)."""
        n = self.points()[:, None].astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(n > 0, self.counts / n, np.nan)
