"""Cylindrical voxelization, point features, collate and the point-to-voxel encoder."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from panoptic_bench.dsnet.model.voxelize import (
    CylinderGrid,
    PointVoxelEncoder,
    collate,
    point_features,
    voxel_indices,
)

GRID = CylinderGrid(size=(10, 8, 4), rho_range=(2, 12), z_range=(-2, 2))  # cells 1 m, 45 deg, 1 m


def test_paper_defaults_and_round_trip():
    g = CylinderGrid()
    assert g.size == (480, 360, 32)
    assert g.min_bound == pytest.approx((3.0, -math.pi, -3.0))
    assert g.max_bound == pytest.approx((50.0, math.pi, 1.5))
    assert CylinderGrid.from_dict(GRID.to_dict()) == GRID
    with pytest.raises(ValueError, match="unknown grid keys"):
        CylinderGrid.from_dict({"sizes": [1, 2, 3]})
    with pytest.raises(ValueError, match="increasing"):
        CylinderGrid(z_range=(1, -1))


def test_features_by_hand():
    xyz = torch.tensor([[5.5, 0.0, 0.25]])
    feats, idx = point_features(xyz, torch.tensor([0.7]), GRID)
    assert idx.tolist() == [[3, 4, 2]]
    expected = [0.0, -math.pi / 8, -0.25, 5.5, 0.0, 0.25, 5.5, 0.0, 0.7]
    assert feats[0].tolist() == pytest.approx(expected, abs=1e-6)


def test_outside_points_clip_to_border_cells():
    xyz = torch.tensor(
        [
            [100.0, 0.0, 0.0],  # beyond rho max -> last rho cell
            [0.5, 0.0, 0.0],  # inside rho min -> first rho cell
            [5.0, 0.0, 10.0],  # above z -> top cell
            [5.0, 0.0, -10.0],  # below z -> bottom cell
            [-5.0, 0.0, 0.0],  # phi = +pi exactly -> last phi cell
        ]
    )
    idx = voxel_indices(xyz, GRID)
    assert idx[:, 0].tolist() == [9, 0, 3, 3, 3]
    assert idx[:, 2].tolist() == [2, 2, 3, 0, 2]
    assert idx[4, 1] == 7
    feats, _ = point_features(xyz, torch.zeros(5), GRID)
    assert feats[0, 0].item() == pytest.approx(100.0 - 11.5)  # offset of the unclipped point


def test_collate_two_scans():
    rng = np.random.default_rng(0)
    a = rng.uniform(-12, 12, (50, 4)).astype(np.float32)
    b = torch.from_numpy(rng.uniform(-12, 12, (30, 4)).astype(np.float32))
    batch = collate([a, b], GRID)
    assert batch.batch_size == 2 and batch.num_points == 80
    assert batch.point_batch.tolist() == [0] * 50 + [1] * 30
    keys = batch.voxel_coords.long()
    assert torch.equal(torch.unique(keys, dim=0), keys)  # sorted and unique
    idx = voxel_indices(batch.xyz, GRID)
    got = batch.voxel_coords[batch.point_voxel].long()
    assert torch.equal(got[:, 0], batch.point_batch) and torch.equal(got[:, 1:], idx)
    assert batch.to("cpu").voxel_coords.dtype == torch.int32


def test_encoder_max_pools_points_into_voxels():
    torch.manual_seed(0)
    pts = torch.rand(60, 4) * torch.tensor([8.0, 8.0, 3.0, 1.0])
    batch = collate([pts], GRID)
    enc = PointVoxelEncoder(hidden=(8,), point_feature_dim=6, voxel_feature_dim=5).eval()
    out = enc(batch)
    pf = enc.point_mlp(batch.point_features)
    for v in range(len(out)):
        pooled = pf[batch.point_voxel == v].max(0).values
        torch.testing.assert_close(out.features[v], enc.compress(pooled))
    assert out.features.shape == (batch.voxel_coords.shape[0], 5)
