"""CLI: centers simulate → cluster semantickitti → scorable predictions; bad input exits 2."""

from __future__ import annotations

import numpy as np

from panoptic_bench.baselines.centers import read_centers, write_centers
from panoptic_bench.cli import main
from panoptic_bench.datasets.semantickitti import (
    LABELS,
    list_scans,
    prediction_path,
    read_labels,
    to_train,
)
from panoptic_bench.metrics.panoptic import panoptic_stats


def test_simulate_cluster_scores_perfect_things(kitti_root, tmp_path):
    centers = tmp_path / "centers"
    assert main(["centers", "simulate", "--dataset", str(kitti_root), "--output", str(centers),
                 "--zero-noise"]) == 0  # fmt: skip
    refs = list_scans(kitti_root)
    c = read_centers(centers / "sequences/00/centers" / f"{refs[0].frame}.npz")
    assert c.source == "simulated regression"
    pred = tmp_path / "pred"
    argv = ["cluster", "semantickitti", "--dataset", str(kitti_root), "--centers", str(centers),
            "--method", "meanshift", "--bin-seeding", "--min-points", "1", "--output", str(pred)]  # fmt: skip
    assert main(argv) == 0
    total = None
    for ref in refs:
        gt = read_labels(ref.label)
        p = np.fromfile(prediction_path(pred, ref), dtype=np.uint32)
        s = panoptic_stats(to_train(p), p, to_train(gt), gt, num_classes=20, min_points=50)
        total = s if total is None else total + s
    assert total.fp[list(LABELS.thing_ids)].sum() == 0
    assert total.fn[list(LABELS.thing_ids)].sum() == 0


def test_cluster_bad_centres_exit_2(kitti_root, tmp_path, capsys):
    refs = list_scans(kitti_root)
    centers = tmp_path / "centers"
    for ref in refs:
        write_centers(centers / "sequences/00/centers" / f"{ref.frame}.npz",
                      np.zeros(10, np.uint8), np.zeros((10, 3)))  # fmt: skip
    argv = ["cluster", "semantickitti", "--dataset", str(kitti_root), "--centers", str(centers),
            "--method", "bfs", "--output", str(tmp_path / "pred")]  # fmt: skip
    assert main(argv) == 2
    assert "another scan" in capsys.readouterr().err
    assert main(argv[:4] + ["--centers", str(tmp_path / "none")] + argv[6:]) == 2
