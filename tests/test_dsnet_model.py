"""PanopticBackbone on a tiny grid: shapes, gradients, device, predict, and that it learns."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

from panoptic_bench.dsnet.model.network import PanopticBackbone
from panoptic_bench.dsnet.model.voxelize import CylinderGrid, collate
from panoptic_bench.dsnet.training.losses import instance_centers, offset_loss, semantic_loss

sys.path.insert(0, str(Path(__file__).parent))
import dsnet_tiny_world  # noqa: E402

GRID = CylinderGrid(size=(32, 32, 8), rho_range=(1, 20), z_range=(-2, 2))


def tiny_model(num_classes: int = 4, remission_input: bool = True) -> PanopticBackbone:
    return dsnet_tiny_world.tiny_model(num_classes, GRID, remission_input=remission_input)


def scene(seed: int, n: int = 600) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Ground (class 1) plus two boxes (class 2, instances 1 and 2) and a wall (class 3)."""
    g = torch.Generator().manual_seed(seed)
    ground = torch.rand(n, 3, generator=g) * torch.tensor([30.0, 30.0, 0.1]) - torch.tensor(
        [15.0, 15.0, 1.7]
    )
    box1 = torch.rand(n // 4, 3, generator=g) * torch.tensor([2.0, 1.0, 1.5]) + torch.tensor(
        [5.0, 3.0, -1.6]
    )
    box2 = torch.rand(n // 4, 3, generator=g) * torch.tensor([1.0, 2.0, 1.5]) + torch.tensor(
        [-6.0, -4.0, -1.6]
    )
    wall = torch.rand(n // 2, 3, generator=g) * torch.tensor([30.0, 0.2, 3.0]) + torch.tensor(
        [-15.0, 10.0, -1.7]
    )
    xyz = torch.cat([ground, box1, box2, wall])
    sem = torch.cat([torch.full((n,), 1), torch.full((n // 2,), 2), torch.full((n // 2,), 3)])
    inst = torch.cat(
        [torch.zeros(n), torch.ones(n // 4), torch.full((n // 4,), 2.0), torch.zeros(n // 2)]
    ).long()
    pts = torch.cat([xyz, torch.rand(xyz.shape[0], 1, generator=g)], 1)
    return pts, sem, inst


def test_forward_shapes_and_all_parameters_get_gradients():
    torch.manual_seed(0)
    model = tiny_model()
    (a, _, _), (b, _, _) = scene(0), scene(1, 300)
    batch = collate([a, b], GRID)
    out = model(batch)
    p = a.shape[0] + b.shape[0]
    assert out.sem_logits.shape == (p, 4)
    assert out.offsets.shape == (p, 3)
    assert out.point_features.shape == (p, 4)
    assert out.voxel_logits.shape == (batch.voxel_coords.shape[0], 4)
    assert out.sem_logits.device == a.device and out.sem_logits.dtype == torch.float32
    (out.sem_logits.square().mean() + out.offsets.abs().mean()).backward()
    missing = [n for n, prm in model.named_parameters() if prm.grad is None]
    assert not missing


def test_points_in_one_voxel_share_logits():
    model = tiny_model().eval()
    pts, _, _ = scene(2)
    batch = collate([pts], GRID)
    out = model(batch)
    v = batch.point_voxel
    same = (v[:, None] == v[None, :]).nonzero()
    same = same[same[:, 0] != same[:, 1]]
    assert same.shape[0] > 0
    torch.testing.assert_close(out.sem_logits[same[:, 0]], out.sem_logits[same[:, 1]])


def test_predict_and_grid_mismatch():
    model = tiny_model().eval()
    pts, _, _ = scene(3)
    batch = collate([pts], GRID)
    pred = model.predict(batch)
    out = model(batch)
    assert (pred.sem_labels != 0).all()
    torch.testing.assert_close(pred.centers, batch.xyz + out.offsets)
    with pytest.raises(ValueError, match="collate with the model's grid"):
        model(collate([pts], CylinderGrid(size=(16, 16, 8))))


def test_overfits_one_scene():
    torch.manual_seed(0)
    model = tiny_model()
    pts, sem, inst = scene(4)
    batch = collate([pts], GRID)
    centers = instance_centers(batch.xyz, inst)
    things = inst > 0
    opt = torch.optim.Adam(model.parameters(), lr=0.01)
    losses = []
    for _ in range(25):
        out = model(batch)
        loss = semantic_loss(out.sem_logits, sem) + offset_loss(
            out.offsets, batch.xyz, centers, things
        )
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.5 * losses[0]
    acc = (out.sem_logits.argmax(1) == sem).float().mean().item()  # train mode: batch stats
    assert acc > 0.8


def test_remission_input_false_ignores_remission_and_keeps_the_batch():
    """``remission_input=False`` zeroes the remission channel; the default network reads it."""
    pts, _, _ = scene(4)
    other = pts.clone()
    other[:, 3] = torch.rand(pts.shape[0], generator=torch.Generator().manual_seed(9))
    outputs = {}
    for use in (True, False):
        torch.manual_seed(0)
        model = tiny_model(remission_input=use).eval()
        a, b = collate([pts], GRID), collate([other], GRID)
        before = b.point_features.clone()
        with torch.no_grad():
            outputs[use] = (model(a).sem_logits, model(b).sem_logits)
        assert torch.equal(b.point_features, before)  # the caller's batch is not modified
    assert not torch.allclose(*outputs[True])
    assert torch.equal(*outputs[False])
    # zero remission in the input gives what remission_input=False gives, weights equal
    zeroed = pts.clone()
    zeroed[:, 3] = 0.0
    torch.manual_seed(0)
    plain = tiny_model().eval()
    with torch.no_grad():
        assert torch.equal(plain(collate([zeroed], GRID)).sem_logits, outputs[False][0])
