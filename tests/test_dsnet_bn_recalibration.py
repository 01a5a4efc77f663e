"""Re-estimated BatchNorm statistics (``checkpoint recalibrate-bn``)."""

from __future__ import annotations

import dataclasses
import hashlib
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from torch.nn.modules.batchnorm import _BatchNorm

from panoptic_bench.cli import main
from panoptic_bench.dsnet.bn_recalibration import (
    VIEWS,
    inference_view,
    recalibrate_checkpoint,
    view_samples,
)
from panoptic_bench.dsnet.checkpoint import build_backbone, build_grid, load_checkpoint
from panoptic_bench.dsnet.config import DSNetConfig
from panoptic_bench.dsnet.data.datasets import SemanticKittiDataset
from panoptic_bench.dsnet.statistics_gap import held_unit_statistics
from panoptic_bench.errors import InputError

sys.path.insert(0, str(Path(__file__).parent))
from dsnet_tiny_checkpoints import write_tiny_checkpoint  # noqa: E402
from dsnet_tiny_world import write_tiny_world  # noqa: E402

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    base = tmp_path_factory.mktemp("recal")
    ck = write_tiny_checkpoint(base / "ck.pt", seed=0)
    world = write_tiny_world(base / "w", {"00": 4})
    return ck, world


def _net(ck_path):
    ck = load_checkpoint(ck_path)
    net = build_backbone(ck.config, ck.class_map.num_classes)
    net.load_state_dict(ck.backbone)
    return ck, net


def _first_norm(net):
    return next((n, m) for n, m in net.named_modules() if isinstance(m, _BatchNorm))


def test_statistics_are_the_mean_of_the_scans_batch_statistics(tiny):
    # the first BatchNorm's input depends on no statistics: record it per scan by hand
    ck_path, world = tiny
    ck, net = _net(ck_path)
    ds = SemanticKittiDataset(world, None, ["00"])
    name, bn = _first_norm(net)
    rows = []
    bn.register_forward_pre_hook(lambda m, a: rows.append(a[0].detach().double()))
    held_unit_statistics(net, (ds.load(i) for i in range(4)), build_grid(ck.config))
    new, seen = recalibrate_checkpoint(ck, view_samples(ck, ds, range(4)), "w")
    assert seen == 4 and int(new.backbone[f"{name}.num_batches_tracked"]) == 4
    mean = torch.stack([x.mean(0) for x in rows]).mean(0)
    var = torch.stack([x.var(0, unbiased=True) for x in rows]).mean(0)
    assert torch.allclose(new.backbone[f"{name}.running_mean"].double(), mean, atol=1e-5)
    assert torch.allclose(new.backbone[f"{name}.running_var"].double(), var, rtol=1e-4)
    changed = {k for k, v in new.backbone.items() if not torch.equal(v, ck.backbone[k])}
    assert changed and all(
        k.endswith(("running_mean", "running_var", "num_batches_tracked")) for k in changed
    )
    assert len(changed) == 3 * sum(isinstance(m, _BatchNorm) for m in net.modules())


def test_first_layer_is_centred_on_its_own_data(tiny):
    # after re-estimation the scans' first-layer channel means, in held units, average to 0
    # (before: off by the random held statistics); the train view centres its own scans
    ck_path, world = tiny
    ck, net = _net(ck_path)
    ds = SemanticKittiDataset(world, None, ["00"])
    grid = build_grid(ck.config)
    name, _ = _first_norm(net)
    for view in VIEWS:
        scans = list(view_samples(ck, ds, range(4), view))
        off = held_unit_statistics(net, scans, grid).means[name].mean(0)
        assert np.abs(off).max() > 0.5
        new, _ = recalibrate_checkpoint(ck, scans)
        net.load_state_dict(new.backbone)
        on = held_unit_statistics(net, scans, grid).means[name].mean(0)
        assert np.abs(on).max() < 1e-3, view
        net.load_state_dict(ck.backbone)


def test_train_view_augments_like_training(tiny):
    ck_path, world = tiny
    ck = load_checkpoint(ck_path)
    ds = SemanticKittiDataset(world, None, ["00"])
    a = list(view_samples(ck, ds, range(2), "train"))
    b = list(view_samples(ck, ds, range(2), "train"))
    assert all(np.array_equal(x.xyz, y.xyz) for x, y in zip(a, b))  # seeded
    assert not np.array_equal(a[0].xyz, ds.load(0).xyz)  # rotated / flipped / scaled
    with pytest.raises(ValueError, match="view"):
        view_samples(ck, ds, range(2), "test")


def test_no_scan_is_an_error(tiny):
    ck_path, _ = tiny
    ck = load_checkpoint(ck_path)
    with pytest.raises(InputError, match="no scans"):
        recalibrate_checkpoint(ck, [])


def test_too_small_scan_names_the_scan(tiny):
    ck_path, world = tiny
    ck = load_checkpoint(ck_path)
    sample = SemanticKittiDataset(world, None, ["00"]).load(1)
    one = dataclasses.replace(
        sample,
        xyz=sample.xyz[:1],
        remission=sample.remission[:1],
        sem=sample.sem[:1],
        inst=sample.inst[:1],
    )
    with pytest.raises(InputError, match="00/000001 \\(1 points\\) is too small"):
        recalibrate_checkpoint(ck, [one])


def test_inference_view_thins_like_infer(tiny):
    ck_path, world = tiny
    ck = load_checkpoint(ck_path)
    sample = SemanticKittiDataset(world, None, ["00"]).load(0)
    assert inference_view(ck, sample) is sample  # the tiny config predicts every point
    raw = ck.config.to_dict()
    raw["inference"]["match_training_density"] = True
    raw["augment"]["max_points"] = len(sample.xyz) // 3
    thin_ck = dataclasses.replace(ck, config=DSNetConfig.from_dict(raw))
    a, b = inference_view(thin_ck, sample), inference_view(thin_ck, sample)
    assert len(a.xyz) == len(sample.xyz) // 3
    assert np.array_equal(a.xyz, b.xyz)  # the inference subset is seeded by the scan


def test_checkpoint_copy_leaves_the_source(tiny):
    ck_path, world = tiny
    ck = load_checkpoint(ck_path)
    ref = {k: v.clone() for k, v in ck.backbone.items()}
    ds = SemanticKittiDataset(world, None, ["00"])
    new, seen = recalibrate_checkpoint(ck, view_samples(ck, ds, range(2)), "w")
    assert seen == 2 and new.metrics[-1] == {"bn_recalibrated_on": "w", "scans": 2}
    assert all(torch.equal(v, ref[k]) for k, v in ck.backbone.items())
    key = next(k for k in ref if k.endswith("running_mean"))
    assert not torch.equal(new.backbone[key], ref[key])
    assert new.optimizer is None and new.shift.keys() == ck.shift.keys()


def test_cli(tiny, tmp_path, capsys):
    ck, world = tiny
    digest = hashlib.sha256(ck.read_bytes()).hexdigest()
    out = tmp_path / "recal.pt"
    argv = ["checkpoint", "recalibrate-bn", str(ck), "--data", str(world), "--split", "00"]
    assert main([*argv, "--scans", "3", "--out", str(out), "--no-progress"]) == 0
    assert "3 scans" in capsys.readouterr().out
    out2 = tmp_path / "train.pt"
    assert main([*argv, "--view", "train", "--out", str(out2), "--no-progress"]) == 0
    assert "train view" in load_checkpoint(out2).metrics[-1]["bn_recalibrated_on"]
    assert hashlib.sha256(ck.read_bytes()).hexdigest() == digest  # input untouched
    new = load_checkpoint(out)
    assert new.metrics[-1]["scans"] == 3 and new.stage == "ds"
    assert main([*argv, "--out", str(out), "--no-progress"]) == 2  # exists, no --overwrite
    assert str(out) in capsys.readouterr().err
    empty = tmp_path / "empty"
    (empty / "sequences" / "00").mkdir(parents=True)
    bad = ["checkpoint", "recalibrate-bn", str(ck), "--data", str(empty), "--split", "00"]
    assert main([*bad, "--out", str(tmp_path / "x.pt"), "--no-progress"]) == 2
    assert str(empty) in capsys.readouterr().err
    assert not (tmp_path / "x.pt").exists()
