"""Realism of synthetic scans against the real SemanticKITTI scans in ../shared/data."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from panoptic_bench.datasets.semantickitti import make_label
from panoptic_bench.datasets.synthetic import Sequence
from panoptic_bench.datasets.synthetic.stats import (
    DatasetStats,
    car_slope,
    compare,
    dataset_stats,
    scan_stats,
)


@pytest.fixture(scope="module")
def synthetic_stats() -> DatasetStats:
    scans = []
    for key in range(4):
        seq = Sequence(seed=0, key=key, n_frames=11)
        for i in (0, 10):
            sw = seq.frame(i).sweep
            pts = np.column_stack([sw.xyz, sw.remission])
            scans.append(scan_stats(pts, make_label(sw.label, sw.instance)))
    return DatasetStats.from_scans(scans)


def test_car_slope_on_known_power_law():
    r = np.array([5.0, 10.0, 20.0, 40.0, 50.0, 80.0])
    assert car_slope(r, 1e6 * r**-3.0) == pytest.approx(-3.0)
    assert np.isnan(car_slope(r[:2], r[:2]))


def test_real_scans_fall_steeply(kitti_root: Path):
    real = dataset_stats(kitti_root, progress=False)
    assert real.n_scans == 3
    assert -5.0 < real.slope < -3.0


def test_synthetic_points_per_car_fall_like_real(synthetic_stats: DatasetStats):
    s = synthetic_stats
    assert ((s.car_range >= 10) & (s.car_range <= 50)).sum() >= 30
    assert -5.0 <= s.slope <= -1.5
    assert 110_000 < s.points_per_scan.mean() < 131_072
    assert s.instances_per_scan.min() >= 5
    # class imbalance: road and buildings dominate, persons are rare but present
    from panoptic_bench.datasets.semantickitti import LABELS

    freq = dict(zip(LABELS.class_names, s.class_freq))
    assert freq["road"] > 0.15 and freq["building"] > 0.03 and freq["vegetation"] > 0.03
    assert 0 < freq["person"] < 0.02 and 0.02 < freq["car"] < 0.25
    # density falls with range: most points within 20 m, some beyond 50 m
    cum = np.cumsum(s.range_hist)
    assert cum[9] > 0.6 and cum[24] < 0.995


def test_compare_writes_table_and_figure(kitti_root: Path, tmp_path: Path):
    from panoptic_bench.datasets.synthetic.writers import generate_semantickitti

    synth = generate_semantickitti(tmp_path / "synth", {"01": 2}, progress=False)
    fig = tmp_path / "docs" / "realism.png"
    real, _ = compare(kitti_root, synth, tmp_path / "stats", figure=fig, progress=False)
    md = (tmp_path / "stats" / "realism.md").read_text()
    assert "log-log slope" in md and "class frequency % car" in md
    assert (tmp_path / "stats" / "realism.csv").read_text().startswith("statistic,real,synthetic")
    for png in (fig, tmp_path / "stats" / "realism.png"):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert real.slope < -3.0
