"""``panoptic-bench ablate``: run directories of every variant and baseline, and the report.

A tiny random-weight stage-2 checkpoint (its semantic head biased towards *car*, so that there
are predicted things points to shift) on the tiny hand-made world of ``dsnet_tiny_world``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from panoptic_bench.cli import main as cli
from panoptic_bench.dsnet.ablation.cache import TrainScan
from panoptic_bench.dsnet.ablation.run import paper_bandwidth_sets, train_variant, variants
from panoptic_bench.dsnet.checkpoint import Checkpoint, build_backbone, save_checkpoint
from panoptic_bench.dsnet.config import DSNetConfig
from panoptic_bench.dsnet.data.datasets import SemanticKittiDataset
from panoptic_bench.reports.runs import load_run

sys.path.insert(0, str(Path(__file__).parent))
from dsnet_tiny_world import write_tiny_world  # noqa: E402
from test_dsnet_train import TINY  # noqa: E402

BASELINES = {"backbone", "backbone-fusion", "bfs", "dbscan", "hdbscan"}


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def setup(tmp_path_factory) -> tuple[Path, Path]:
    tmp = tmp_path_factory.mktemp("ablate")
    world = write_tiny_world(tmp / "world", {"00": 3, "01": 1, "08": 2})
    cfg = DSNetConfig.from_dict(TINY)
    cmap = SemanticKittiDataset(world, sequences=["00"]).class_map
    torch.manual_seed(0)
    state = build_backbone(cfg, cmap.num_classes).state_dict()
    state["semantic_head.logits.bias"][1] += 3.0  # car: predicted things points exist
    ckpt = tmp / "offset.pt"
    save_checkpoint(Checkpoint("offset", 0, cfg, cmap, state), ckpt)
    out = tmp / "out"
    args = ["ablate", "--checkpoint", str(ckpt), "--data", str(world), "--out", str(out)]
    # no --train-sequences / --val-sequences: the checkpoint's own split (00 / 08) is the default
    args += ["--steps", "2", "--no-progress", "--data-label", "tiny"]
    assert cli(args) == 0
    return out, world


def test_paper_sets_and_variants():
    sets = paper_bandwidth_sets()
    assert len(sets) == 6 and (0.2, 1.7, 3.2) in sets and all(len(s) == 3 for s in sets)
    full = variants()
    assert sum(v.table4 for v in full) == 6
    assert sorted(v.iterations for v in full if v.table5) == [1, 2, 3, 4, 5]
    assert [v.name for v in full if v.is_default] == ["dsnet"]
    assert len({v.name for v in full}) == len(full) == 11


def test_run_dirs_and_tags(setup):
    out, _ = setup
    names = {p.name for p in (out / "runs").iterdir()}
    expected = {v.name for v in variants()} | BASELINES
    assert names == expected
    meta = (out / "runs" / "dsnet" / "run.json").read_text()
    assert "3 scans of seq 00 (" in meta and "seq 08 (2 scans)" in meta
    runs = {n: load_run(out / "runs" / n) for n in names}
    t4 = sorted(r.meta.bandwidths for r in runs.values() if r.meta.bandwidths)
    assert t4 == sorted(paper_bandwidth_sets())
    t5 = sorted(r.meta.iterations for r in runs.values() if r.meta.iterations is not None)
    assert t5 == [1, 2, 3, 4, 5]
    bars = {
        key: {r.meta.ablation[key] for r in runs.values() if key in r.meta.ablation}
        for key in ("framework", "clustering", "bandwidth_learning")
    }
    assert bars["framework"] == {"backbone", "+ fusion", "+ DS"}
    assert bars["clustering"] == {"BFS", "DBSCAN", "HDBSCAN", "Mean Shift", "DS"}
    assert bars["bandwidth_learning"] == {"weighted candidates", "direct regression"}
    for run in runs.values():
        assert run.meta.dataset == "semantickitti" and run.meta.data == "tiny seq 08 (2 scans)"
        assert 0.0 <= run.overall["PQ"] <= 1.0 and run.by_range
    assert runs["backbone-fusion"].overall["mIoU"] > 0  # car is predicted and present
    # per-seed diagnostics of the default variant
    diag = out / "runs" / "dsnet"
    seeds = sorted((diag / "dynamic_shift").glob("*.npz"))
    assert len(seeds) == 2
    with np.load(seeds[0]) as z:
        assert z["positions"].shape[0] == 5 and z["weights"].shape[2] == 3
        np.testing.assert_allclose(z["weights"].sum(-1), 1.0, rtol=1e-5)
        implied = z["weights"] @ z["candidates"]
        np.testing.assert_allclose(implied, z["bandwidths"], rtol=1e-5)
    analysis = json.loads((diag / "analysis.json").read_text())
    assert len(analysis["bandwidth_per_iteration"]["bandwidth_m"]["car"]) == 4
    assert analysis["learned_bandwidth"]["size_m"]["car"] > 0
    assert (diag / "shift_iterations.npz").is_file()


def test_report_tables_and_figures(setup):
    out, _ = setup
    report = out / "report"
    assert (report / "index.md").is_file()
    t4 = (report / "tables" / "table4_bandwidths.md").read_text()
    assert t4.count("| **ours** |") == 6 and "**0.2, 2.1, 4.0**" in t4
    t5 = (report / "tables" / "table5_iterations.md").read_text()
    assert t5.count("| **ours** |") == 5
    figs = {p.stem for p in (report / "figures").glob("*.png")}
    for stem in ("fig4a_framework", "fig4b_clustering", "fig4c_bandwidth_learning"):
        assert stem in figs
    for prefix in ("fig5_", "fig6_", "fig7_"):
        assert any(f.startswith(prefix) for f in figs), prefix
    # the report command rebuilds the same tables from the run directories alone
    runs = sorted(str(p) for p in (out / "runs").iterdir())
    assert cli(["report", "--results", *runs, "--out", str(out / "again")]) == 0
    assert (out / "again" / "tables" / "table4_bandwidths.md").read_text() == t4


def test_training_lowers_the_loss():
    rng = np.random.default_rng(0)
    centres = np.concatenate([rng.normal(c, 0.8, (40, 3)) for c in ((0, 0, 0), (8, 0, 0))])
    gt = np.repeat(np.array([[0, 0, 0], [8, 0, 0]], dtype=np.float32), 40, axis=0)
    feats = rng.normal(size=(80, 4)).astype(np.float32)
    scan = TrainScan(("00", "000000"), centres.astype(np.float32), feats, gt)
    v = variants()[0]
    _, losses = train_variant(v, [scan], steps=40, lr=0.05, progress=False)
    assert losses[-1] < losses[0]
    _, again = train_variant(v, [scan], steps=40, lr=0.05, progress=False)
    assert again == losses  # fixed seed: deterministic


def test_errors(setup, tmp_path, capsys):
    _, world = setup
    args = ["ablate", "--checkpoint", str(tmp_path / "missing.pt"), "--data", str(world)]
    assert cli([*args, "--out", str(tmp_path / "o")]) == 2
    assert "missing.pt" in capsys.readouterr().err
