"""Test-time augmentation (inference.tta_views): views, averaging, offsets back in the scan frame."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch import nn

from panoptic_bench.dsnet.config import DSNetConfig
from panoptic_bench.dsnet.data.datasets import LidarSample
from panoptic_bench.dsnet.inference.tta import tta_forward, view_matrices
from panoptic_bench.dsnet.model.forward import backbone_forward
from panoptic_bench.dsnet.model.network import BackboneOutput
from panoptic_bench.dsnet.model.voxelize import CylinderGrid
from panoptic_bench.errors import InputError


class _CentreAtOrigin(nn.Module):
    """Offsets point at the sensor (equivariant); logits favour class 1 where y > 0."""

    def forward(self, batch):
        xyz = batch.xyz
        logits = torch.zeros(len(xyz), 3)
        logits[:, 1] = 2.0 * (xyz[:, 1] > 0).float()
        return BackboneOutput(logits, -xyz, xyz[:, :2].clone(), logits[:1])


def _sample(n=500, seed=0):
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-20, 20, (n, 3)).astype(np.float32)
    xyz[:, 2] = rng.uniform(-2, 1, n)
    z = np.zeros(n, np.int64)
    return LidarSample(xyz, rng.uniform(0, 1, n).astype(np.float32), z, z, ("00", "000000"))


GRID = CylinderGrid(size=(40, 36, 8))


def test_views_are_orthogonal_and_start_with_the_identity():
    views = view_matrices(4, math.radians(10.0))
    assert len(views) == 4 and np.array_equal(views[0], np.eye(3))
    for a in views:
        assert np.allclose(a @ a.T, np.eye(3))
        assert a[2, 2] == 1.0  # z untouched
    assert np.linalg.det(views[1]) < 0 < np.linalg.det(views[2])  # odd views mirror
    # view 1 of 4: 90 degrees plus a quarter of a 10-degree cell, after mirroring y
    angle = math.radians(90 + 2.5)
    rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    assert np.allclose(views[1][:2, :2], rot @ np.diag([1.0, -1.0]))
    with pytest.raises(ValueError):
        view_matrices(0, 0.1)


def test_one_view_is_the_plain_forward_pass():
    model, s = _CentreAtOrigin(), _sample()
    a = tta_forward(model, s, GRID, torch.device("cpu"), 1)
    b = backbone_forward(model, [s], GRID, torch.device("cpu"))
    assert torch.equal(a.sem_logits, b.sem_logits) and torch.equal(a.offsets, b.offsets)


def test_offsets_come_back_to_the_scan_frame():
    model, s = _CentreAtOrigin(), _sample()
    out = tta_forward(model, s, GRID, torch.device("cpu"), 4)
    # every view regresses the sensor origin: averaged offsets are still -xyz in the scan frame
    assert np.allclose(out.offsets.numpy(), -s.xyz, atol=1e-4)
    # view-0 features are kept
    assert np.allclose(out.point_features.numpy(), s.xyz[:, :2])


def test_class_probabilities_are_averaged_over_views():
    model, s = _CentreAtOrigin(), _sample(n=300, seed=1)
    k = 4
    out = tta_forward(model, s, GRID, torch.device("cpu"), k)
    probs = torch.exp(out.sem_logits)
    assert torch.allclose(probs.sum(1), torch.ones(len(probs)), atol=1e-5)
    expected = np.zeros((len(s.xyz), 3))
    for a in view_matrices(k, math.radians(10.0)):
        y = (s.xyz @ a.T)[:, 1]
        logit = np.stack([np.zeros_like(y), 2.0 * (y > 0), np.zeros_like(y)], 1)
        e = np.exp(logit)
        expected += e / e.sum(1, keepdims=True) / k
    assert np.allclose(probs.numpy(), expected, atol=1e-5)


def test_config_range():
    assert DSNetConfig.from_dict({"inference": {"tta_views": 4}}).inference.tta_views == 4
    for bad in (0, 17):
        with pytest.raises(InputError):
            DSNetConfig.from_dict({"inference": {"tta_views": bad}})
