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
from panoptic_bench.dsnet.training import train as train_mod
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


def test_restyle_by_hand():
    from panoptic_bench.dsnet.training.batchnorm import restyle

    x = torch.tensor([[1.0, 10.0], [3.0, 14.0]])
    mean, std = torch.tensor([2.0, 12.0]), torch.tensor([1.0, 2.0])
    out = restyle(x, mean, std, torch.tensor([2.0, 0.5]), torch.tensor([0.0, 1.0]))
    # channel 0: normalised -1, 1 -> -2, 2 -> 0, 4; channel 1: -1, 1 -> 0.5, 1.5 -> 13, 15
    assert torch.equal(out, torch.tensor([[0.0, 13.0], [4.0, 15.0]]))
    same = restyle(x, mean, std, torch.ones(2), torch.zeros(2))
    assert torch.equal(same, x)


def test_statistics_noise_restyles_held_batchnorms_only_while_active():
    from panoptic_bench.dsnet.training.batchnorm import restyle, statistics_noise

    torch.manual_seed(0)
    net = nn.Sequential(nn.Linear(3, 4), nn.BatchNorm1d(4), nn.ReLU(), nn.BatchNorm1d(4))
    net.train()
    hold_batchnorm_statistics(net)
    net[1].running_mean.uniform_(-1, 1)
    net[1].running_var.uniform_(0.5, 2)
    x = torch.randn(32, 3)
    plain = net(x)
    with statistics_noise(net, 0.0) as n:
        assert n == 0
        assert torch.equal(net(x), plain)
    with statistics_noise(net, 0.3) as n:
        assert n == 2
        state = torch.get_rng_state()
        noisy = net(x)
        assert not torch.allclose(noisy, plain)
        # the same draws by hand: per BatchNorm, one (2, C) normal draw times sigma
        torch.set_rng_state(state)
        h = net[0](x)
        for bn in (net[1], net[3]):
            a, b = torch.randn(2, 4) * 0.3
            std = torch.sqrt(bn.running_var + bn.eps)
            h = bn.forward(restyle(h, bn.running_mean, std, 1 + a, b))
            if bn is net[1]:
                h = net[2](h)
        assert torch.allclose(noisy, h, atol=1e-6)
        assert net(x).requires_grad
    assert torch.equal(net(x), plain)  # hooks removed on exit
    with pytest.raises(RuntimeError), statistics_noise(net, 0.3):
        raise RuntimeError
    assert torch.equal(net(x), plain)  # also on error


def test_bn_noise_trains_under_restyled_inputs_and_resumes_bit_for_bit(
    world: Path, tmp_path: Path, monkeypatch
):
    train(_cfg(), world, tmp_path / "start", stage="semantic", epochs=1, progress=False)
    init = tmp_path / "start" / "checkpoints" / "semantic.pt"
    cfg = _cfg(freeze_bn=True, bn_noise=0.2)
    hooks_in_validation: list[int] = []
    real_validate = train_mod._validate

    def validate(stage, backbone, shift, ctx):
        norms = [m for m in backbone.modules() if isinstance(m, nn.modules.batchnorm._BatchNorm)]
        hooks_in_validation.append(sum(len(m._forward_pre_hooks) for m in norms))
        return real_validate(stage, backbone, shift, ctx)

    monkeypatch.setattr(train_mod, "_validate", validate)
    train(cfg, world, tmp_path / "a", stage="semantic", epochs=2, init=init, progress=False)
    assert hooks_in_validation == [0, 0]  # validation sees the network without noise
    train(cfg, world, tmp_path / "b", stage="semantic", epochs=1, init=init, progress=False)
    train(cfg, world, tmp_path / "b", stage="semantic", epochs=2, resume=True, progress=False)
    train(
        _cfg(freeze_bn=True),
        world,
        tmp_path / "c",
        stage="semantic",
        epochs=2,
        init=init,
        progress=False,
    )
    a, b, c = (load_checkpoint(tmp_path / n / "checkpoints" / "semantic.pt") for n in "abc")
    for k, v in a.backbone.items():
        assert torch.equal(b.backbone[k], v), k
    weights = [k for k in a.backbone if k.endswith("weight")]
    assert any(not torch.equal(a.backbone[k], c.backbone[k]) for k in weights)  # noise moved it
    for k in _stats(a.backbone):
        assert torch.equal(a.backbone[k], c.backbone[k]), k  # still held


def test_bn_noise_needs_held_statistics():
    with pytest.raises(InputError, match="bn_noise"):
        _cfg(bn_noise=0.1)
    with pytest.raises(InputError, match="bn_noise"):
        _cfg(freeze_bn=True, bn_noise=-0.1)
    assert _cfg(freeze_bn=True, bn_noise=0.15).optim.bn_noise == 0.15
