"""Weight averaging along a training run (``optim.swa_epochs``): the mean by hand, BatchNorm
re-measured, the stage ends on the mean of exactly its last k epochs' steps, resume bit for bit."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch
from torch import nn

from panoptic_bench.cli import main as cli
from panoptic_bench.dsnet.checkpoint import load_checkpoint
from panoptic_bench.dsnet.config import DSNetConfig
from panoptic_bench.dsnet.training import averaging
from panoptic_bench.dsnet.training import train as train_mod
from panoptic_bench.dsnet.training.averaging import (
    StepAverage,
    averaging_starts,
    recalibrate_batchnorm,
)
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


def test_averaging_window():
    assert averaging_starts(10, 0) == 10  # off: no epoch averages
    assert averaging_starts(10, 5) == 5
    assert averaging_starts(10, 10) == 0
    assert averaging_starts(3, 7) == 0  # more than the stage: the whole stage


def test_step_average_by_hand():
    net = nn.Linear(2, 1)
    avg = StepAverage(net)
    with pytest.raises(ValueError, match="no optimiser step"):
        avg.copy_to(net)
    for value in (1.0, 2.0, 6.0):
        with torch.no_grad():
            net.weight.fill_(value)
            net.bias.fill_(-value)
        avg.update(net)
    assert avg.count == 3
    other = nn.Linear(2, 1)
    avg.copy_to(other)
    assert torch.allclose(other.weight, torch.full((1, 2), 3.0))
    assert torch.allclose(other.bias, torch.tensor([-3.0]))
    again = StepAverage(nn.Linear(2, 1), avg.state_dict())  # a resumed average
    assert again.count == 3
    again.update(net)  # (1 + 2 + 6 + 6) / 4
    again.copy_to(other)
    assert torch.allclose(other.weight, torch.full((1, 2), 3.75))


def test_batchnorm_statistics_are_the_mean_of_the_samples():
    net = nn.Sequential(nn.BatchNorm1d(2))
    net.eval()
    net[0].running_mean.fill_(9.0)
    gen = torch.Generator().manual_seed(0)
    samples = [torch.randn(n, 2, generator=gen) * (i + 1) + i for i, n in enumerate((5, 8, 3))]
    recalibrate_batchnorm(net, samples, lambda m, x: m(x))
    assert not net.training  # mode restored
    want_mean = torch.stack([s.mean(0) for s in samples]).mean(0)
    want_var = torch.stack([s.var(0, unbiased=True) for s in samples]).mean(0)
    assert torch.allclose(net[0].running_mean, want_mean, atol=1e-6)
    assert torch.allclose(net[0].running_var, want_var, atol=1e-5)
    assert net[0].momentum == 0.1  # momentum restored


def test_stage_ends_on_the_mean_of_its_last_epochs(world: Path, tmp_path: Path, monkeypatch):
    seen: list[dict] = []
    real_update = StepAverage.update

    def spy(self, module):
        seen.append({k: v.detach().clone() for k, v in module.named_parameters()})
        real_update(self, module)

    monkeypatch.setattr(StepAverage, "update", spy)
    steps = []
    real_epoch = train_mod.train_one_epoch

    def count(*args, **kw):
        before = len(seen)
        out = real_epoch(*args, **kw)
        steps.append(len(seen) - before)
        return out

    monkeypatch.setattr(train_mod, "train_one_epoch", count)
    cfg = _cfg(swa_epochs=2)
    train(cfg, world, tmp_path / "avg", stage="semantic", epochs=3, progress=False)
    assert steps == [0, 2, 2]  # 4 scans, batch 2: two steps an epoch, the last two epochs
    ck = load_checkpoint(tmp_path / "avg" / "checkpoints" / "semantic.pt")
    assert ck.average is None  # a finished stage keeps only the mean network
    for name in seen[0]:
        want = torch.stack([s[name] for s in seen]).mean(0)
        assert torch.allclose(ck.backbone[name], want, atol=1e-6), name
    # the same run without averaging ends on the last step's weights, other BatchNorm stats
    train(_cfg(), world, tmp_path / "plain", stage="semantic", epochs=3, progress=False)
    plain = load_checkpoint(tmp_path / "plain" / "checkpoints" / "semantic.pt")
    for name in seen[-1]:
        assert torch.equal(plain.backbone[name], seen[-1][name]), name
    bn = [k for k in ck.backbone if k.endswith("running_mean")]
    assert bn and any(not torch.equal(ck.backbone[k], plain.backbone[k]) for k in bn)
    assert ck.metrics[-1]["val_mIoU"] >= 0.0  # validation ran on the mean network


def test_resume_inside_the_window_is_bit_for_bit(world: Path, tmp_path: Path, monkeypatch):
    cfg = _cfg(swa_epochs=2, swa_bn_scans=2)
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    train(cfg, world, straight, stage="semantic", epochs=3, progress=False)
    real_epoch = train_mod.train_one_epoch

    def crash_in_third(stage, model, backbone, shift, optimizer, ctx, epoch, average=None):
        if epoch == 2:
            raise KeyboardInterrupt
        return real_epoch(stage, model, backbone, shift, optimizer, ctx, epoch, average)

    monkeypatch.setattr(train_mod, "train_one_epoch", crash_in_third)
    with pytest.raises(KeyboardInterrupt):
        train(cfg, world, resumed, stage="semantic", epochs=3, progress=False)
    half = load_checkpoint(resumed / "checkpoints" / "semantic.pt")
    assert half.epoch == 2 and half.average is not None  # one epoch of the window stored
    assert int(half.average["n_averaged"]) == 2
    monkeypatch.setattr(train_mod, "train_one_epoch", real_epoch)
    train(cfg, world, resumed, stage="semantic", epochs=3, resume=True, progress=False)
    a = load_checkpoint(straight / "checkpoints" / "semantic.pt").backbone
    b = load_checkpoint(resumed / "checkpoints" / "semantic.pt").backbone
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    # a release copy drops the stored mean
    src = resumed / "checkpoints" / "half.pt"
    src.write_bytes((resumed / "checkpoints" / "semantic.pt").read_bytes())
    torch.save({**torch.load(src, weights_only=True), "average": half.average}, src)
    assert load_checkpoint(src).average is not None
    assert cli(["checkpoint", "export", str(src), "--out", str(tmp_path / "x.pt")]) == 0
    assert load_checkpoint(tmp_path / "x.pt").average is None


def test_no_mean_is_stored_before_the_window(world: Path, tmp_path: Path, monkeypatch):
    real_epoch = train_mod.train_one_epoch

    def crash_in_second(stage, model, backbone, shift, optimizer, ctx, epoch, average=None):
        if epoch == 1:
            raise KeyboardInterrupt
        return real_epoch(stage, model, backbone, shift, optimizer, ctx, epoch, average)

    monkeypatch.setattr(train_mod, "train_one_epoch", crash_in_second)
    with pytest.raises(KeyboardInterrupt):
        train(_cfg(swa_epochs=1), world, tmp_path, stage="semantic", epochs=2, progress=False)
    first = load_checkpoint(tmp_path / "checkpoints" / "semantic.pt")
    assert first.epoch == 1 and first.average is None


def test_an_averaged_stage_is_not_trained_on(world: Path, tmp_path: Path):
    cfg = _cfg(swa_epochs=1)
    train(cfg, world, tmp_path, stage="semantic", epochs=1, progress=False)
    ck = load_checkpoint(tmp_path / "checkpoints" / "semantic.pt")
    assert ck.metrics[-1]["swa_steps"] == 2
    with pytest.raises(InputError, match="already ended on its weight average") as err:
        train(cfg, world, tmp_path, stage="semantic", epochs=2, resume=True, progress=False)
    assert "semantic.pt" in str(err.value)
    # resuming a finished stage to the same length changes nothing
    train(cfg, world, tmp_path, stage="semantic", epochs=1, resume=True, progress=False)
    again = load_checkpoint(tmp_path / "checkpoints" / "semantic.pt")
    assert all(torch.equal(again.backbone[k], ck.backbone[k]) for k in ck.backbone)


def test_bad_averaging_settings():
    for key in ("swa_epochs", "swa_bn_scans"):
        with pytest.raises(InputError, match=f"optim.{key}"):
            _cfg(**{key: -1})
    assert averaging.__doc__ and "swa_epochs" in averaging.__doc__
