"""Per-range-bin metrics: each bin is scored as its own point set."""

from __future__ import annotations

import numpy as np
import pytest

from panoptic_bench.metrics.by_range import (
    RangeStats,
    panoptic_stats_by_range,
    parse_edges,
    point_range,
)
from panoptic_bench.metrics.panoptic import panoptic_stats


def scene(rng: np.random.Generator, n: int = 4000) -> tuple[np.ndarray, ...]:
    sg = rng.integers(0, 5, n)
    ig = (sg * 100 + rng.integers(0, 4, n) * (sg < 3)).astype(np.uint32)
    sp = np.where(rng.random(n) < 0.2, rng.integers(0, 5, n), sg)
    ip = np.where(rng.random(n) < 0.1, 999, ig).astype(np.uint32)
    return sp, ip, sg, ig, rng.random(n) * 60


def test_bins_equal_scoring_each_subset() -> None:
    sp, ip, sg, ig, rng_ = scene(np.random.default_rng(0))
    edges = (0, 10, 25, 50)
    rs = panoptic_stats_by_range(sp, ip, sg, ig, rng_, edges, num_classes=5, min_points=3)
    assert rs.edges == (0.0, 10.0, 25.0, 50.0) and len(rs.bins) == 3
    for (lo, hi), b in zip(zip(edges, edges[1:]), rs.bins):
        sel = (rng_ >= lo) & (rng_ < hi)
        ref = panoptic_stats(sp[sel], ip[sel], sg[sel], ig[sel], num_classes=5, min_points=3)
        for name in ("tp", "fp", "fn", "confusion", "iou_sum"):
            np.testing.assert_array_equal(getattr(b, name), getattr(ref, name))
    # points beyond the last edge (50-60 m) are not scored
    assert sum(rs.point_counts()) == int((rng_ < 50).sum())
    results = rs.compute()
    assert [(lo, hi) for lo, hi, _ in results] == [(0, 10), (10, 25), (25, 50)]


def test_segment_crossing_a_bin_edge_is_split() -> None:
    # one car of 20 points, 10 on each side of 10 m; the prediction only has the near half
    sg = np.full(20, 1)
    ig = np.full(20, 7, np.uint32)
    sp = np.array([1] * 10 + [0] * 10)
    ranges = np.array([5.0] * 10 + [15.0] * 10)
    rs = panoptic_stats_by_range(sp, ig, sg, ig, ranges, (0, 10, 20), num_classes=2, min_points=1)
    near, far = rs.bins
    assert (near.tp[1], near.fp[1], near.fn[1], near.iou_sum[1]) == (1, 0, 0, 1.0)
    assert (far.tp[1], far.fp[1], far.fn[1]) == (0, 0, 1)
    whole = panoptic_stats(sp, ig, sg, ig, num_classes=2, min_points=1)
    assert (whole.tp[1], whole.fn[1]) == (0, 1)  # IoU exactly 0.5 over the whole scan


def test_range_stats_add_and_edges() -> None:
    rng = np.random.default_rng(1)
    a = panoptic_stats_by_range(*scene(rng), (0, 20, 60), num_classes=5)
    b = panoptic_stats_by_range(*scene(rng), (0, 20, 60), num_classes=5)
    total = RangeStats.zeros((0, 20, 60), 5) + a + b
    np.testing.assert_array_equal(total.bins[1].tp, a.bins[1].tp + b.bins[1].tp)
    assert sum([a, b]).bins[0].confusion.sum() == total.bins[0].confusion.sum()
    with pytest.raises(ValueError):
        a + RangeStats.zeros((0, 30, 60), 5)
    assert parse_edges("0,10,20") == (0.0, 10.0, 20.0)
    for bad in ("10,5", "0", "a,b", (-1, 2)):
        with pytest.raises(ValueError):
            parse_edges(bad)
    pts = np.array([[3.0, 4.0, 0.0, 0.5], [0.0, 0.0, 2.0, 0.1]], np.float32)
    np.testing.assert_allclose(point_range(pts), [5.0, 2.0])
