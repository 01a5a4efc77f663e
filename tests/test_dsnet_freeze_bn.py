"""Held BatchNorm statistics in training (``optim.freeze_bn``): every BatchNorm of the backbone
normalises with the statistics it started the stage with, in eval mode, and never updates them,
while the rest of the network (BatchNorm affine weights included) trains."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch
from torch import nn

from panoptic_bench.dsnet.checkpoint import load_checkpoint
from panoptic_bench.dsnet.config import DSNetConfig
from panoptic_bench.dsnet.training.batchnorm import hold_batchnorm_statistics
from panoptic_bench.dsnet.training.train import train
from panoptic_bench.errors import InputError

sys.path.insert(0, str(Path(__file__).parent))
from dsnet_tiny_world import write_tiny_world  # noqa: E402
from test_dsnet_train import TINY  # noqa: E402

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> Path:
    return write_tiny_world(tmp_path_factory.mktemp("tiny"), {"00": 4, "08": 2})


def _cfg(**optim) -> DSNetConfig:
    return DSNetConfig.from_dict({**TINY, "optim": {**TINY["optim"], **optim}})


def test_hold_puts_only_the_batchnorms_in_eval_mode():
    net = nn.Sequential(nn.Linear(3, 4), nn.BatchNorm1d(4), nn.Dropout(0.5), nn.BatchNorm1d(4))
    net.train()
    assert hold_batchnorm_statistics(net) == 2
    assert net.training and net[2].training  # the rest keeps training behaviour
    assert not net[1].training and not net[3].training
    before = net[1].running_mean.clone()
    x = torch.randn(16, 3) * 5 + 3
    out = net[1](net[0](x))
    assert torch.equal(net[1].running_mean, before)  # nothing measured
    want = (net[0](x) - before) / torch.sqrt(net[1].running_var + net[1].eps)
    assert torch.allclose(out, want * net[1].weight + net[1].bias, atol=1e-6)


def test_stage_keeps_the_statistics_it_started_with(world: Path, tmp_path: Path, monkeypatch):
    train(_cfg(), world, tmp_path / "start", stage="semantic", epochs=1, progress=False)
    start = load_checkpoint(tmp_path / "start" / "checkpoints" / "semantic.pt")
    modes: list[bool] = []
    real_forward = nn.modules.batchnorm._BatchNorm.forward

    def spy(self, x):
        modes.append(self.training)
        return real_forward(self, x)

    monkeypatch.setattr(nn.modules.batchnorm._BatchNorm, "forward", spy)
    init = tmp_path / "start" / "checkpoints" / "semantic.pt"
    train(
        _cfg(freeze_bn=True),
        world,
        tmp_path / "held",
        stage="semantic",
        epochs=2,
        init=init,
        progress=False,
    )
    assert modes and not any(modes)  # every BatchNorm call normalised with running statistics
    held = load_checkpoint(tmp_path / "held" / "checkpoints" / "semantic.pt")
    stats = [k for k in start.backbone if k.endswith(("running_mean", "running_var"))]
    assert stats
    for k in stats + [k for k in start.backbone if k.endswith("num_batches_tracked")]:
        assert torch.equal(held.backbone[k], start.backbone[k]), k
    affine = [k.replace("running_mean", "weight") for k in stats if k.endswith("running_mean")]
    assert any(not torch.equal(held.backbone[k], start.backbone[k]) for k in affine)
    modes.clear()
    train(_cfg(), world, tmp_path / "plain", stage="semantic", epochs=2, init=init, progress=False)
    assert any(modes)  # the default trains with each batch's statistics
    plain = load_checkpoint(tmp_path / "plain" / "checkpoints" / "semantic.pt")
    assert any(not torch.equal(plain.backbone[k], start.backbone[k]) for k in stats)


def test_freeze_bn_and_weight_averaging_exclude_each_other():
    with pytest.raises(InputError, match="freeze_bn"):
        _cfg(freeze_bn=True, swa_epochs=2)
    with pytest.raises(InputError, match="freeze_bn"):
        _cfg(freeze_bn="yes")
    assert _cfg(freeze_bn=True).optim.freeze_bn is True
    assert DSNetConfig.from_dict(_cfg(freeze_bn=True).to_dict()).optim.freeze_bn is True


def test_a_fresh_network_has_no_statistics_to_hold(world: Path, tmp_path: Path):
    with pytest.raises(InputError, match="--init"):
        train(_cfg(freeze_bn=True), world, tmp_path / "fresh", stage="semantic", progress=False)
    assert not (tmp_path / "fresh" / "checkpoints" / "semantic.pt").exists()


def _stats(backbone: dict) -> dict:
    return {k: v for k, v in backbone.items() if k.endswith(("running_mean", "running_var"))}


def test_statistics_measured_over_the_training_world_are_held(world: Path, tmp_path: Path):
    from panoptic_bench.dsnet import distributed as ddp
    from panoptic_bench.dsnet.checkpoint import build_backbone
    from panoptic_bench.dsnet.model.forward import backbone_forward
    from panoptic_bench.dsnet.training.averaging import recalibrate_batchnorm
    from panoptic_bench.dsnet.training.train import _make_context

    train(_cfg(), world, tmp_path / "start", stage="semantic", epochs=1, progress=False)
    init = tmp_path / "start" / "checkpoints" / "semantic.pt"
    start = load_checkpoint(init)
    cfg = _cfg(freeze_bn=True, freeze_bn_from="train")
    # by hand: the start weights, one cumulative pass over the first epoch's scans in index order
    ctx = _make_context(cfg, world, tmp_path / "hand", ddp.init_from_env("cpu"), False)
    net = build_backbone(cfg, start.class_map.num_classes)
    net.load_state_dict(start.backbone)
    ctx.train_set.set_epoch(0)
    scans = [ctx.train_set[i] for i in range(len(ctx.train_set))]
    recalibrate_batchnorm(net, scans, lambda m, s: backbone_forward(m, [s], ctx.grid, "cpu"))
    want = _stats(net.state_dict())

    train(cfg, world, tmp_path / "one", stage="semantic", epochs=1, init=init, progress=False)
    one = load_checkpoint(tmp_path / "one" / "checkpoints" / "semantic.pt")
    assert one.metrics[0]["bn_scans"] == len(scans)
    got = _stats(one.backbone)
    assert any(not torch.equal(want[k], start.backbone[k]) for k in want)  # measured anew
    for k in want:
        assert torch.allclose(got[k], want[k], rtol=1e-5, atol=1e-6), k
    # resumed to a second epoch: held, not measured again, and bit for bit a straight run
    train(cfg, world, tmp_path / "one", stage="semantic", epochs=2, resume=True, progress=False)
    train(cfg, world, tmp_path / "two", stage="semantic", epochs=2, init=init, progress=False)
    resumed = load_checkpoint(tmp_path / "one" / "checkpoints" / "semantic.pt")
    straight = load_checkpoint(tmp_path / "two" / "checkpoints" / "semantic.pt")
    for k in got:
        assert torch.equal(resumed.backbone[k], got[k]), k
    for k, v in straight.backbone.items():
        assert torch.equal(resumed.backbone[k], v), k
    assert "bn_scans" not in resumed.metrics[1]


def test_measured_statistics_let_a_fresh_network_hold(world: Path, tmp_path: Path):
    cfg = _cfg(freeze_bn=True, freeze_bn_from="train")
    train(cfg, world, tmp_path / "fresh", stage="semantic", epochs=1, progress=False)
    ck = load_checkpoint(tmp_path / "fresh" / "checkpoints" / "semantic.pt")
    means = [v for k, v in _stats(ck.backbone).items() if k.endswith("running_mean")]
    assert any(bool(v.abs().max() > 0) for v in means)  # not the untouched zeros of a new net


def test_freeze_bn_from_needs_freeze_bn():
    with pytest.raises(InputError, match="freeze_bn_from"):
        _cfg(freeze_bn_from="train")
    with pytest.raises(InputError, match="freeze_bn_from"):
        _cfg(freeze_bn=True, freeze_bn_from="world")
    cfg = _cfg(freeze_bn=True, freeze_bn_from="train")
    assert DSNetConfig.from_dict(cfg.to_dict()) == cfg
