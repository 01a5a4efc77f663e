"""``demo --real-scans`` with a chosen checkpoint and sequences, and the nuScenes DS-Net rows."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from panoptic_bench.cli import main

REPO = Path(__file__).resolve().parents[1]


def _random_checkpoint(path: Path, config: str, class_map) -> Path:
    """A DS-Net checkpoint with random weights and a tiny network."""
    import torch

    from panoptic_bench.dsnet.checkpoint import (
        Checkpoint,
        build_backbone,
        build_shift,
        save_checkpoint,
    )
    from panoptic_bench.dsnet.config import DSNetConfig, load_config

    raw = load_config(REPO / "configs" / config).to_dict()
    raw["grid"]["size"] = [32, 32, 8]
    raw["model"].update(init_size=4, point_hidden=[8], point_feature_dim=8, offset_hidden=8)
    raw["dynamic_shift"]["max_seeds"] = 200
    cfg = DSNetConfig.from_dict(raw)
    torch.manual_seed(0)
    backbone = build_backbone(cfg, class_map.num_classes)
    shift = build_shift(cfg, cfg.model.init_size)
    save_checkpoint(
        Checkpoint("ds", 1, cfg, class_map, backbone.state_dict(), shift.state_dict()), path
    )
    return path


def _kitti_class_map():
    from panoptic_bench.datasets.semantickitti import LABELS
    from panoptic_bench.dsnet.data.datasets import ClassMap

    lab = LABELS
    return ClassMap("semantickitti", lab.class_names, lab.thing_ids, lab.stuff_ids, lab.ignore_ids)


def test_real_scans_checkpoint_sequences_and_per_sequence_rows(tmp_path):
    from dsnet_tiny_world import write_tiny_world

    from panoptic_bench.demo.real import run_real_scans

    world = write_tiny_world(tmp_path / "world", {"05": 1, "06": 1, "07": 1})
    ckpt = _random_checkpoint(tmp_path / "dsnet.pt", "dsnet_semantickitti.yaml", _kitti_class_map())
    out = tmp_path / "report"
    result = run_real_scans(world, out, checkpoint=ckpt, sequences=("05", "06"), keep_work=False)
    names = {p.name for p in result.runs}
    assert {"real-dsnet", "real-dsnet-seq05", "real-dsnet-seq06"} <= names
    assert not any("seq07" in n for n in names)
    main_run = json.loads((out / "runs" / "real-dsnet" / "scores.json").read_text())
    assert main_run["n_scans"] == 2 and main_run["sequences"] == ["05", "06"]
    per_seq = json.loads((out / "runs" / "real-dsnet-seq06" / "scores.json").read_text())
    assert per_seq["n_scans"] == 1 and per_seq["sequences"] == ["06"]
    meta = json.loads((out / "runs" / "real-dsnet-seq06" / "run.json").read_text())
    assert meta["method"] == "DS-Net (seq 06)"
    # the paper config trains on the official train split, which includes 05 and 06
    assert "include the scored 05, 06" in meta["notes"]
    assert (out / "index.md").read_text().count("DS-Net (seq 0") >= 2


def test_training_overlap_note_names_shipped_and_foreign_checkpoints(tmp_path):
    from panoptic_bench.demo import steps

    shipped = steps.find_checkpoint("dsnet_synthetic.pt")
    assert steps.training_overlap_note(shipped, ("00",)) == "; trained on the synthetic world only"
    ckpt = _random_checkpoint(tmp_path / "d.pt", "dsnet_synthetic_cpu.yaml", _kitti_class_map())
    assert "none of the scored" in steps.training_overlap_note(ckpt, ("08",))
    assert "include the scored 00" in steps.training_overlap_note(ckpt, ("00", "08"))


@pytest.mark.parametrize(
    "argv, message",
    [
        (["demo", "--checkpoint", "x.pt"], "apply to --real-scans only"),
        (["demo", "--sequences", "05"], "apply to --real-scans only"),
        (["demo", "--split", "valid"], "apply to --real-scans only"),
        (["demo", "--real-scans", "R", "--sequences", "05,05"], "sequence 05 given twice"),
        (
            ["demo", "--real-scans", "R", "--checkpoint", "x.pt", "--no-checkpoint"],
            "exclude each other",
        ),
    ],
)
def test_demo_option_errors(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err.strip().splitlines()[-1] and "Traceback" not in err


def test_nuscenes_dsnet_rows_from_a_shipped_checkpoint(tmp_path, monkeypatch):
    """With a (random) nuScenes checkpoint: a DS-Net row and the clusterings on its centres."""
    from panoptic_bench.demo import nuscenes as demo_nus
    from panoptic_bench.demo import steps
    from panoptic_bench.demo.config import TINY
    from panoptic_bench.demo.kitti import DemoResult
    from panoptic_bench.demo.pipeline import prepare_workspace
    from panoptic_bench.demo.summary import Stages
    from panoptic_bench.dsnet.data.datasets import NuScenesDataset

    ws = prepare_workspace(tmp_path / "report", tmp_path / "work")
    steps.synthesize_nuscenes(ws, TINY)
    steps.build_nuscenes_labels(ws)
    cmap = NuScenesDataset(ws.nuscenes, "mini_val", steps.NUS_VERSION).class_map
    ckpt = _random_checkpoint(tmp_path / "nus.pt", "dsnet_nuscenes_synthetic_cpu.yaml", cmap)
    monkeypatch.setattr(steps, "find_checkpoint", lambda name: ckpt)
    result = DemoResult(ws.out / "index.md", [])
    demo_nus.run_nuscenes_methods(ws, TINY, 1, Stages(), result)
    metas = {p.name: json.loads((p / "run.json").read_text()) for p in result.runs}
    assert metas["nuscenes-dsnet"]["method"] == "DS-Net"
    assert "BFS 1.2 m" in metas["nuscenes-dsnet"]["notes"]
    assert metas["nuscenes-backbone-meanshift"]["method"] == "Backbone with Fusion"
    assert metas["nuscenes-backbone-bfs"]["method"] == "Backbone + BFS"
    assert metas["nuscenes-bfs"]["method"] == "BFS (simulated regression)"
    assert "nuscenes-boxmerge" in metas and not result.missing
    for name in metas:
        assert (ws.runs / name / "scores.json").is_file(), name
