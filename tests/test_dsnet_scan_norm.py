"""Per-scan BatchNorm statistics at test time (inference.bn_stats = "scan")."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch
from dsnet_tiny_world import tiny_model
from torch import nn

from panoptic_bench.dsnet.config import DSNetConfig
from panoptic_bench.dsnet.data.datasets import LidarSample
from panoptic_bench.dsnet.inference.scan_norm import scan_statistics
from panoptic_bench.dsnet.model.forward import backbone_forward
from panoptic_bench.dsnet.model.network import PanopticBackbone
from panoptic_bench.dsnet.model.voxelize import CylinderGrid
from panoptic_bench.errors import InputError

GRID = CylinderGrid(size=(24, 24, 8), rho_range=(1.0, 30.0), z_range=(-3.0, 1.5))


def _trained_norm(channels=3, seed=0):
    """A BatchNorm1d in eval mode with running statistics far from any test batch."""
    torch.manual_seed(seed)
    norm = nn.BatchNorm1d(channels)
    norm.running_mean.copy_(torch.tensor([5.0, -2.0, 0.5])[:channels])
    norm.running_var.copy_(torch.tensor([4.0, 0.25, 9.0])[:channels])
    norm.weight.data.uniform_(0.5, 2.0)
    norm.bias.data.uniform_(-1.0, 1.0)
    return norm.eval()


def test_hand_worked_batch_statistics():
    norm = _trained_norm(channels=1)
    x = torch.tensor([[1.0], [2.0], [3.0], [6.0]])  # mean 3, biased variance 3.5
    with scan_statistics(norm):
        y = norm(x)
    expected = (x - 3.0) / np.sqrt(3.5 + norm.eps) * norm.weight + norm.bias
    assert torch.allclose(y, expected, atol=1e-6)
    # outside the block: the running statistics again (mean 5, variance 4)
    expected_running = (x - 5.0) / np.sqrt(4.0 + norm.eps) * norm.weight + norm.bias
    assert torch.allclose(norm(x), expected_running, atol=1e-6)


def test_running_statistics_are_untouched_and_restored_on_error():
    model = nn.Sequential(nn.Linear(4, 3), _trained_norm(), nn.ReLU()).eval()
    before = copy.deepcopy(model.state_dict())
    x = torch.randn(50, 4)
    with scan_statistics(model):
        model(x)
        model(x * 3 + 1)
    with pytest.raises(RuntimeError, match="boom"):
        with scan_statistics(model):
            model(x)
            raise RuntimeError("boom")
    after = model.state_dict()
    assert before.keys() == after.keys()
    for key in before:  # running mean / var / num_batches_tracked bit for bit
        assert torch.equal(before[key], after[key]), key
    assert not any(h for m in model.modules() for h in (m._forward_hooks, m._forward_pre_hooks))


def test_equals_training_mode_batch_norm_and_disabled_is_a_no_op():
    model = nn.Sequential(nn.Linear(4, 3), _trained_norm(), nn.Linear(3, 2)).eval()
    x = torch.randn(40, 4) * 2 + 1
    reference = copy.deepcopy(model).train()
    with torch.no_grad():
        expected = reference(x)
        with scan_statistics(model):
            got = model(x)
        with scan_statistics(model, enabled=False):
            plain = model(x)
    assert torch.allclose(got, expected, atol=1e-6)
    assert torch.equal(plain, model(x))
    assert not torch.allclose(plain, got, atol=1e-3)


def test_a_single_row_falls_back_to_the_running_statistics():
    norm = _trained_norm()
    x = torch.tensor([[1.0, 2.0, 3.0]])
    with scan_statistics(norm):
        y = norm(x)
        z = norm(torch.cat([x, x + 1]))  # the next call uses batch statistics again
    assert torch.equal(y, norm(x))
    # two rows one apart: mean between them, biased variance 0.25, so they sit at -1 and +1
    step = norm.weight / torch.sqrt(torch.tensor(0.25) + norm.eps)
    assert torch.allclose(z[1] - z[0], step, atol=1e-4)
    assert norm.running_mean is not None and norm.running_var is not None


def _sample(seed: int, n: int = 3000, shift: float = 0.0) -> LidarSample:
    rng = np.random.default_rng(seed)
    r = rng.uniform(3, 25, n)
    phi = rng.uniform(-np.pi, np.pi, n)
    xyz = np.stack([r * np.cos(phi), r * np.sin(phi), rng.uniform(-2, 1, n)], 1).astype(np.float32)
    rem = (rng.uniform(0, 1, n) * 0.5 + shift).astype(np.float32)
    z = np.zeros(n, np.int64)
    return LidarSample(xyz, rem, z, z, ("00", f"{seed:06d}"))


def _backbone(fast: bool, seed: int = 0) -> PanopticBackbone:
    torch.manual_seed(seed)
    flags = dict(spconv1_rulebooks=fast, offset_norm_first=fast, fast_inference=fast)
    model = tiny_model(5, GRID, **flags)
    # give every BatchNorm running statistics unlike any scan's
    for m in model.modules():
        if isinstance(m, nn.BatchNorm1d):
            m.running_mean.uniform_(-1, 1)
            m.running_var.uniform_(0.5, 3)
    return model.eval()


def _forward(model, sample, scan):
    with torch.no_grad(), scan_statistics(model, enabled=scan):
        return backbone_forward(model, [sample], GRID, torch.device("cpu"))


def test_backbone_scan_statistics_equal_a_training_mode_forward_and_depend_on_the_scan_only():
    model, a, b = _backbone(False), _sample(1), _sample(2, shift=0.4)
    train = copy.deepcopy(model).train()
    with torch.no_grad():
        expected = backbone_forward(train, [a], GRID, torch.device("cpu"))
    first = _forward(model, a, True)
    _forward(model, b, True)
    again = _forward(model, a, True)
    assert torch.allclose(first.sem_logits, expected.sem_logits, atol=1e-4)
    assert torch.allclose(first.offsets, expected.offsets, atol=1e-4)
    assert torch.equal(first.sem_logits, again.sem_logits)  # nothing carried between scans
    running = _forward(model, a, False)
    assert not torch.allclose(running.sem_logits, first.sem_logits, atol=1e-2)


def test_fast_inference_paths_step_aside_under_scan_statistics():
    threads = torch.get_num_threads()
    torch.set_num_threads(2)  # the shortcuts need two threads
    try:
        fast, s = _backbone(True), _sample(3)
        reference = copy.deepcopy(fast)
        reference.fast_inference = False
        got = _forward(fast, s, True)
        expected = _forward(reference, s, True)
        assert torch.allclose(got.sem_logits, expected.sem_logits, atol=1e-4)
        assert torch.allclose(got.offsets, expected.offsets, atol=1e-4)
        plain = _forward(fast, s, False)  # the shortcuts themselves still run and differ
        assert not torch.allclose(plain.sem_logits, got.sem_logits, atol=1e-2)
    finally:
        torch.set_num_threads(threads)


def test_config_value_is_validated():
    cfg = DSNetConfig.from_dict({"inference": {"bn_stats": "scan"}})
    assert cfg.inference.bn_stats == "scan"
    assert DSNetConfig.from_dict(cfg.to_dict()) == cfg
    assert DSNetConfig().inference.bn_stats == "running"
    with pytest.raises(InputError, match="bn_stats"):
        DSNetConfig.from_dict({"inference": {"bn_stats": "batch"}})
