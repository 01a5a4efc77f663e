"""Batch Renormalization (``model.norm: renorm``): hand-worked forward, BatchNorm's running
update, r and d constant to the gradient, clipping, eval = BatchNorm, and a network converted in
place that keeps its state dict and its eval outputs."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F
from torch import nn

from panoptic_bench.dsnet.checkpoint import build_backbone
from panoptic_bench.dsnet.config import DSNetConfig
from panoptic_bench.dsnet.model.renorm import BatchRenorm1d, batch_renorm, renormalise_batchnorms
from panoptic_bench.dsnet.model.voxelize import CylinderGrid, collate
from panoptic_bench.dsnet.training.train import train
from panoptic_bench.errors import InputError

sys.path.insert(0, str(Path(__file__).parent))
from dsnet_tiny_world import tiny_model, write_tiny_world  # noqa: E402
from test_dsnet_model import scene  # noqa: E402
from test_dsnet_train import TINY  # noqa: E402

GRID = CylinderGrid(size=(32, 32, 8), rho_range=(1, 20), z_range=(-2, 2))


def _data(seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(12, 3, generator=g) * torch.tensor([1.0, 2.0, 0.5]) + torch.tensor(
        [0.3, -1.0, 2.0]
    )


def test_forward_is_the_running_normalisation_and_update_is_batchnorms():
    x = _data()
    rm, rv = torch.tensor([0.2, -0.5, 1.5]), torch.tensor([1.5, 3.0, 0.5])
    w, b = torch.tensor([2.0, 0.5, -1.0]), torch.tensor([0.1, 0.0, 0.3])
    mean, var = rm.clone(), rv.clone()
    out = batch_renorm(x, mean, var, w, b, momentum=0.1, eps=1e-5)
    want = (x - rm) / torch.sqrt(rv + 1e-5) * w + b  # within the limits
    assert torch.allclose(out, want, atol=1e-5)
    bn_mean, bn_var = rm.clone(), rv.clone()
    F.batch_norm(x, bn_mean, bn_var, w, b, training=True, momentum=0.1, eps=1e-5)
    assert torch.allclose(mean, bn_mean) and torch.allclose(var, bn_var)


def test_clipped_correction_by_hand():
    x = _data(1)
    rm, rv = torch.zeros(3), torch.full((3,), 1e-4)  # r = std_B / 0.01 far above r_max
    out = batch_renorm(x, rm.clone(), rv.clone(), None, None, r_max=2.0, d_max=0.5)
    std_b = torch.sqrt(x.var(0, unbiased=False) + 1e-5)
    d = (x.mean(0) / torch.sqrt(rv + 1e-5)).clamp(-0.5, 0.5)
    assert torch.allclose(out, (x - x.mean(0)) / std_b * 2.0 + d, atol=1e-5)
    with pytest.raises(ValueError, match="n >= 2"):
        batch_renorm(x[:1], rm, rv, None, None)


def test_r_and_d_are_constants_to_the_gradient():
    x = _data(2).requires_grad_(True)
    g = _data(3)
    rm, rv = torch.tensor([0.0, 0.0, 1.0]), torch.tensor([2.0, 4.0, 1.0])
    (batch_renorm(x, rm.clone(), rv.clone(), None, None) * g).sum().backward()
    x2 = x.detach().clone().requires_grad_(True)
    bn = F.batch_norm(x2, None, None, training=True, eps=1e-5)
    (bn * g).sum().backward()
    r = torch.sqrt(x2.detach().var(0, unbiased=False) + 1e-5) / torch.sqrt(rv + 1e-5)
    assert torch.allclose(x.grad, x2.grad * r, atol=1e-5)


def test_module_eval_is_batchnorm_and_training_counts_batches():
    torch.manual_seed(0)
    plain = nn.BatchNorm1d(3)
    plain.running_mean.uniform_(-1, 1)
    plain.weight.data.uniform_(0.5, 2.0)
    renorm = BatchRenorm1d(3)
    renorm.load_state_dict(plain.state_dict())
    x = _data(4)
    assert torch.equal(renorm.eval()(x), plain.eval()(x))
    renorm.train()(x)
    assert int(renorm.num_batches_tracked) == 1
    assert not torch.equal(renorm.running_mean, plain.running_mean)


def test_converted_network_keeps_state_and_eval_outputs():
    torch.manual_seed(0)
    base = tiny_model(4, GRID)
    n_bn = sum(type(m) is nn.BatchNorm1d for m in base.modules())
    torch.manual_seed(0)
    conv = tiny_model(4, GRID, norm="renorm")
    assert sum(isinstance(m, BatchRenorm1d) for m in conv.modules()) == n_bn > 10
    assert not any(type(m) is nn.BatchNorm1d for m in conv.modules())
    assert conv.state_dict().keys() == base.state_dict().keys()
    base.train()(collate([scene(0)[0]], GRID))  # move the running statistics off their start
    conv.load_state_dict(base.state_dict())  # a BatchNorm checkpoint loads strictly
    batch = collate([scene(1)[0]], GRID)
    with torch.no_grad():
        a, b = base.eval()(batch), conv.eval()(batch)
    assert torch.equal(a.sem_logits, b.sem_logits) and torch.equal(a.offsets, b.offsets)
    assert renormalise_batchnorms(conv) == 0  # nothing plain left
    assert "norm=renorm" in repr(conv)


def test_config_builds_and_rejects(tmp_path: Path):
    cfg = DSNetConfig.from_dict({**TINY, "model": {**TINY["model"], "norm": "renorm"}})
    net = build_backbone(cfg, 4)
    assert any(isinstance(m, BatchRenorm1d) for m in net.modules())
    with pytest.raises(InputError, match="model.norm"):
        DSNetConfig.from_dict({"model": {"norm": "group"}})


@pytest.mark.usefixtures("one_torch_thread")
def test_training_stage_renormalises(tmp_path: Path, monkeypatch):
    world = write_tiny_world(tmp_path / "w", {"00": 2, "08": 1})
    calls: list[bool] = []
    real = BatchRenorm1d.forward

    def spy(self, x):
        calls.append(self.training)
        return real(self, x)

    monkeypatch.setattr(BatchRenorm1d, "forward", spy)
    cfg = DSNetConfig.from_dict({**TINY, "model": {**TINY["model"], "norm": "renorm"}})
    train(cfg, world, tmp_path / "run", stage="semantic", epochs=1, progress=False)
    assert any(calls) and not all(calls)  # training steps, then eval-mode validation
