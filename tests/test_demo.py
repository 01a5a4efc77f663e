"""The demo end to end on a tiny world, and the committed report sets regenerate exactly."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from panoptic_bench.cli import main
from panoptic_bench.demo.config import QUICK, TINY, DemoSize
from panoptic_bench.demo.pipeline import run_demo
from panoptic_bench.demo.real import run_real_scans
from panoptic_bench.reports.runs import load_run

REPO = Path(__file__).resolve().parents[1]
COMMITTED_REAL = REPO / "reports" / "real-scans-simulated"
METRICS = ("PQ", "PQ_dagger", "SQ", "RQ", "PQ_th", "PQ_st", "mIoU")
LINK = re.compile(r"\]\(([^)\s]+)\)")


@pytest.fixture(scope="module")
def tiny_demo(tmp_path_factory):
    """The synthetic demo on TINY, report-only (temporary data), simulated regression."""
    out = tmp_path_factory.mktemp("demo") / "report"
    result = run_demo(out, size=TINY, workers=1, keep_work=False, use_checkpoint=False)
    return out, result


def test_every_run_dir_has_scores_and_labels(tiny_demo):
    out, result = tiny_demo
    names = sorted(p.name for p in result.runs)
    expected = [
        f"{d}-{m}"
        for d in ("nuscenes", "semantickitti")
        for m in ("bfs", "boxmerge", "dbscan", "hdbscan", "meanshift")
    ]
    assert names == expected
    assert sorted(p.name for p in (out / "runs").iterdir()) == expected
    for run_dir in result.runs:
        run = load_run(run_dir)
        for metric in METRICS:
            value = run.overall[metric]
            assert isinstance(value, float) and 0.0 <= value <= 1.0, (run_dir, metric)
        assert run.by_range, run_dir
        meta = json.loads((run_dir / "run.json").read_text())
        assert meta["dataset"] in ("semantickitti", "nuscenes")
        # never presented as a network result
        assert "simulated" in meta["method"] and "not a" in meta["notes"]
        assert meta["command"].startswith("panoptic-bench eval ")
        assert "$WORK/" in meta["command"]
    assert result.regression == "simulated regression"


def test_index_links_existing_files_and_no_generated_data(tiny_demo):
    out, result = tiny_demo
    assert result.index == out / "index.md"
    text = result.index.read_text()
    links = LINK.findall(text)
    assert any(link.startswith("tables/table1_") for link in links)
    assert any(link.startswith("tables/table3_") for link in links)
    for name in ("fig3a_centres", "fig3b_bandwidth", "fig4b_clustering", "bev_panoptic"):
        assert any(name in link for link in links), name
    for link in links:
        assert (out / link).is_file(), link
    assert not (out / "work").exists()
    assert not list(out.rglob("bev.npz")) and not list(out.rglob("segmentation-result.json"))
    assert not list(out.rglob("*.bin")) and not list(out.rglob("*.label"))


def test_summary_lists_every_run(tiny_demo):
    _, result = tiny_demo
    lines = result.summary.splitlines()
    assert lines[0].split()[:2] == ["Method", "Dataset"]
    assert sum("Box-merge (simulated detector)" in line for line in lines) == 2
    assert len([line for line in lines if "simulated" in line]) == len(result.runs)


def test_committed_real_scans_table_regenerates_exactly(kitti_root, tmp_path):
    """Rebuild reports/real-scans-simulated (simulated regression) and compare with git."""
    committed = COMMITTED_REAL / "tables" / "table1_semantickitti_val.md"
    assert committed.is_file(), "reports/real-scans-simulated is committed"
    out = tmp_path / "real"
    result = run_real_scans(kitti_root, out, workers=1, use_checkpoint=False)
    fresh = out / "tables" / "table1_semantickitti_val.md"
    committed_runs = sorted(p.name for p in (COMMITTED_REAL / "runs").iterdir())
    if committed_runs == sorted(p.name for p in result.runs):
        assert fresh.read_text() == committed.read_text()
    else:  # the committed set has DS-Net rows too: every regenerated row appears verbatim
        old = committed.read_text().splitlines()
        ours = [line for line in fresh.read_text().splitlines() if "**ours**" in line]
        assert len(ours) == len(result.runs)
        for line in ours:
            assert line in old, line
    for run in result.runs:
        assert (run / "scores.json").read_text() == (
            COMMITTED_REAL / "runs" / run.name / "scores.json"
        ).read_text(), run.name


def test_demo_size_round_trip_and_bad_keys():
    for size in (TINY, QUICK):
        assert DemoSize.from_dict(size.to_dict()) == size
    with pytest.raises(ValueError, match="unknown"):
        DemoSize.from_dict({"val_frame": 3})
    with pytest.raises(ValueError, match="nus_scenes"):
        DemoSize(nus_scenes=2)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--real-scans", "missing-root", "--quick"], "--quick applies"),
        (["--real-scans", "no/such/root"], "real-scan root not found"),
        (["--workers", "0"], "--workers: must be an integer >= 1"),
    ],
)
def test_cli_errors_are_one_line(argv, message, tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path / "o"), *argv]) == 2
    err = capsys.readouterr().err
    # one error line (argparse's option errors print their usage above it)
    assert message in err.strip().splitlines()[-1] and "Traceback" not in err


def _random_dsnet_checkpoint(path: Path) -> Path:
    """A DS-Net checkpoint with random weights and a tiny network (exercises the DS-Net path)."""
    from panoptic_bench.datasets.semantickitti import LABELS
    from panoptic_bench.dsnet.checkpoint import (
        Checkpoint,
        build_backbone,
        build_shift,
        save_checkpoint,
    )
    from panoptic_bench.dsnet.config import DSNetConfig, load_config
    from panoptic_bench.dsnet.data.datasets import ClassMap

    raw = load_config(REPO / "configs" / "dsnet_semantickitti.yaml").to_dict()
    raw["grid"]["size"] = [32, 32, 8]
    raw["model"].update(init_size=4, point_hidden=[8], point_feature_dim=8, offset_hidden=8)
    raw["dynamic_shift"]["max_seeds"] = 200
    cfg = DSNetConfig.from_dict(raw)
    cmap = ClassMap(
        "semantickitti", LABELS.class_names, LABELS.thing_ids, LABELS.stuff_ids, LABELS.ignore_ids
    )
    import torch

    torch.manual_seed(0)
    backbone = build_backbone(cfg, cmap.num_classes)
    shift = build_shift(cfg, cfg.model.init_size)
    ckpt = Checkpoint("ds", 1, cfg, cmap, backbone.state_dict(), shift.state_dict())
    save_checkpoint(ckpt, path)
    return path


def test_dsnet_path_labels_network_rows(tmp_path, monkeypatch):
    """With a (here random) shipped checkpoint: DS-Net row, clusterings on its centres, Fig. 4a."""
    from dsnet_tiny_world import write_tiny_world

    from panoptic_bench.demo import steps
    from panoptic_bench.demo.kitti import DemoResult, KittiTarget, run_kitti_methods
    from panoptic_bench.demo.pipeline import prepare_workspace
    from panoptic_bench.demo.summary import Stages

    ckpt = _random_dsnet_checkpoint(tmp_path / "dsnet.pt")
    monkeypatch.setattr(steps, "find_checkpoint", lambda name: ckpt)
    world = write_tiny_world(tmp_path / "world", {"08": 2})
    ws = prepare_workspace(tmp_path / "report", tmp_path / "work")
    target = KittiTarget(world, ("08",), "tiny world", "tiny", bandwidth_scans=1)
    result = DemoResult(ws.out / "index.md", [])
    run_kitti_methods(ws, target, Stages(), result)
    assert result.regression == "DS-Net" and not result.missing
    metas = {p.name: json.loads((p / "run.json").read_text()) for p in result.runs}
    assert metas["tiny-dsnet"]["method"] == "DS-Net"
    assert metas["tiny-dsnet"]["ablation"] == {
        "clustering": "Dynamic Shifting",
        "framework": "+ DS",
    }
    assert metas["tiny-meanshift"]["method"] == "Backbone with Fusion"
    assert metas["tiny-meanshift-nofusion"]["ablation"] == {"framework": "Backbone"}
    assert metas["tiny-bfs"]["method"] == "Backbone + BFS"
    for name, meta in metas.items():
        assert "simulated regression" not in meta["method"], name
        assert (ws.runs / name / "scores.json").is_file()
