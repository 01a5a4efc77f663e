"""Activation-statistics gap between two datasets for one network (``checkpoint bn-gap``)."""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from panoptic_bench.cli import main
from panoptic_bench.dsnet.checkpoint import build_backbone, build_grid, load_checkpoint
from panoptic_bench.dsnet.data.datasets import SemanticKittiDataset
from panoptic_bench.dsnet.statistics_gap import (
    ScanStatistics,
    evenly_spaced,
    held_unit_statistics,
    layer_gaps,
)

sys.path.insert(0, str(Path(__file__).parent))
from dsnet_tiny_checkpoints import write_tiny_checkpoint  # noqa: E402
from dsnet_tiny_world import write_tiny_world  # noqa: E402

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_layer_gaps_by_hand():
    # reference: 3 scans x 2 channels; other: 2 scans
    ref = ScanStatistics(
        {"a": np.array([[0.0, 1.0], [1.0, 1.0], [2.0, 1.0]])},
        {"a": np.array([[1.0, 2.0], [1.0, 2.0], [1.0, 2.0]])},
    )
    other = ScanStatistics(
        {"a": np.array([[3.0, 0.0], [3.0, 1.0]]), "b": np.zeros((2, 2))},
        {"a": np.array([[2.0, 2.0], [2.0, 2.0]]), "b": np.ones((2, 2))},
    )
    rows = layer_gaps(ref, other)
    assert [r["layer"] for r in rows] == ["a", "median"]  # "b" is not in the reference
    a = rows[0]
    # channel means: ref 1, 1; other 3, 0.5 -> offsets 2, 0.5 -> median 1.25
    assert a["offset"] == pytest.approx(1.25)
    # ref spread: std(0, 1, 2) = 0.8165 and 0 -> median 0.408; ratio only over channel 0
    assert a["spread"] == pytest.approx(np.std([0, 1, 2]) / 2)
    assert a["ratio"] == pytest.approx(2 / np.std([0, 1, 2]))
    # std ratios 2/1 and 2/2 -> |log| ln 2 and 0 -> median ln2 / 2
    assert a["log_std"] == pytest.approx(np.log(2) / 2)
    assert a["channels"] == 2
    assert rows[1]["offset"] == pytest.approx(1.25)
    same = layer_gaps(ref, ref)[0]
    assert same["offset"] == 0 and same["log_std"] == 0


def test_evenly_spaced():
    assert evenly_spaced(5, 10) == [0, 1, 2, 3, 4]
    assert evenly_spaced(10, 3) == [0, 4, 9]
    assert evenly_spaced(100, 30)[-1] == 99 and len(evenly_spaced(100, 30)) == 30


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    base = tmp_path_factory.mktemp("gap")
    ck = write_tiny_checkpoint(base / "ck.pt", seed=0)
    world = write_tiny_world(base / "a", {"00": 3})
    other = write_tiny_world(base / "b", {"00": 3}, seed=5)
    return ck, world, other


def test_first_layer_in_held_units(tiny, tmp_path):
    ck_path, world, _ = tiny
    ck = load_checkpoint(ck_path)
    net = build_backbone(ck.config, ck.class_map.num_classes)
    net.load_state_dict(ck.backbone)
    ds = SemanticKittiDataset(world, None, ["00"])
    grid = build_grid(ck.config)
    first = next(n for n, m in net.named_modules() if isinstance(m, torch.nn.BatchNorm1d))
    bn = dict(net.named_modules())[first]
    seen = []
    bn.register_forward_pre_hook(lambda m, a: seen.append(a[0].detach().double()))
    before = {k: v.clone() for k, v in net.state_dict().items()}
    stats = held_unit_statistics(net, (ds.load(i) for i in range(3)), grid)
    assert stats.means[first].shape == (3, bn.num_features)
    sd = torch.sqrt(bn.running_var.double() + bn.eps)
    for i, x in enumerate(seen):
        z = (x - bn.running_mean.double()) / sd
        assert np.allclose(stats.means[first][i], z.mean(0).numpy())
        assert np.allclose(stats.stds[first][i], z.std(0).numpy())
    for k, v in net.state_dict().items():
        assert torch.equal(v, before[k]), k  # nothing measured into the network


def test_cli_writes_table_and_figure(tiny, tmp_path, capsys):
    ck, world, other = tiny
    out = tmp_path / "same"
    argv = ["checkpoint", "bn-gap", str(ck), "--data", str(world), "--split", "00"]
    assert main([*argv, "--other", str(world), "--out", str(out), "--no-progress"]) == 0
    rows = list(csv.DictReader(open(out / "gap.csv")))
    assert rows[-1]["layer"] == "median" and len(rows) > 10
    assert all(float(r["offset"]) == 0 for r in rows)  # a root against itself
    assert (out / "gap.png").stat().st_size > 1000
    out2 = tmp_path / "other"
    assert main([*argv, "--other", str(other), "--out", str(out2), "--no-progress"]) == 0
    rows = list(csv.DictReader(open(out2 / "gap.csv")))
    assert float(rows[-1]["offset"]) > 0
    assert "median" in capsys.readouterr().out


def test_cli_bad_input(tiny, tmp_path, capsys):
    ck, world, _ = tiny
    empty = tmp_path / "empty"
    (empty / "sequences" / "00").mkdir(parents=True)
    base = ["checkpoint", "bn-gap", str(ck), "--data", str(world), "--split", "00"]
    assert main([*base, "--other", str(world), "--out", str(tmp_path / "o"), "--scans", "1"]) == 2
    assert "--scans" in capsys.readouterr().err
    assert main([*base, "--other", str(empty), "--out", str(tmp_path / "o2")]) == 2
    err = capsys.readouterr().err
    assert str(empty) in err
    assert not (tmp_path / "o2" / "gap.csv").exists()
