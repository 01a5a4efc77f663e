"""Writers of optional report inputs round-trip through build_report; the two statistics."""

from __future__ import annotations

import json

import numpy as np
import pytest

from panoptic_bench.reports.index import build_report
from panoptic_bench.reports.inputs import (
    centres_per_voxel_by_distance,
    learned_bandwidth,
    write_analysis,
    write_bev,
    write_run_meta,
    write_shift_iterations,
)
from panoptic_bench.reports.runs import load_run


def test_writers_feed_build_report(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "scores.json").write_text(json.dumps({"all": {"PQ": 0.5, "SQ": 0.8, "RQ": 0.625}}))
    write_run_meta(run, {"method": "DS-Net", "dataset": "semantickitti", "iterations": 4})
    assert load_run(run).meta.iterations == 4
    write_analysis(
        run,
        centres_per_voxel={"distance_m": np.array([5.0, 15.0]), "counts": np.array([4.0, 2.0])},
        bandwidth_per_iteration={"bandwidth_m": {"car": np.array([1.0, 0.4])}, "lower_limit": 0.2},
    )
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(50, 3))
    write_shift_iterations(run, pts, np.stack([pts, pts / 2]), rng.random((2, 50)))
    sem = np.repeat([1, 9], 25)
    write_bev(run, pts, sem, sem == 1, sem, sem == 1, range(1, 9))
    build_report([run], tmp_path / "out")
    names = sorted(p.name for p in (tmp_path / "out" / "figures").iterdir())
    assert names == [
        "bev_panoptic_run.png",
        "fig3a_centres_vs_distance_run.png",
        "fig6_shift_iterations_run.png",
        "fig7_bandwidth_vs_iteration_run.png",
    ]
    with pytest.raises(ValueError, match="unknown"):
        write_analysis(run, fig3=[1])
    with pytest.raises(ValueError, match="shape"):
        write_bev(run, pts, sem[:3], sem, sem, sem, [1])


def test_learned_bandwidth():
    w = np.array([[1.0, 0.0, 0.0], [0.0, 0.5, 0.5], [0.2, 0.3, 0.5]])
    np.testing.assert_allclose(learned_bandwidth(w, [0.2, 1.7, 3.2]), [0.2, 2.45, 2.15])
    with pytest.raises(ValueError):
        learned_bandwidth(w, [0.2, 1.7])


def test_centres_per_voxel_by_distance_by_hand():
    # instance 1 at ~5 m: 4 centres in 1 voxel; instance 2 at ~25 m: 4 centres in 4 voxels;
    # instance 3 at ~27 m: 2 centres in 1 voxel; instance 0 ignored; nothing in 40-60 m.
    near = np.full((4, 3), 0.05)
    far = np.array([[0.05, 0.05, 0.05], [1.05, 0.05, 0.05], [2.05, 0.05, 0.05], [3.05, 0, 0]])
    far3 = np.full((2, 3), 7.05)
    centres = np.concatenate([near, far, far3, np.zeros((3, 3))])
    inst = np.array([1] * 4 + [2] * 4 + [3] * 2 + [0] * 3)
    dist = np.array([5.0] * 4 + [24, 26, 25, 25] + [27, 27] + [1] * 3)
    got = centres_per_voxel_by_distance(centres, inst, dist, [0, 20, 40, 60], voxel_size=0.5)
    np.testing.assert_allclose(got[:2], [4.0, 6 / 5])
    assert np.isnan(got[2])
