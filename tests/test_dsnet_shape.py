"""Local shape features (``model.shape_features``): the descriptors, the density rule, the wiring.

Hand-worked cubes (a square, a line, a flat patch) give the exact eigenvalue ratios; a model that
takes the features appends exactly :func:`shape_features` of the frame it voxelizes; a wider model
started from a narrower one computes exactly what the start computed; a training run from a
narrower start works from the command line's code path.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from panoptic_bench.dsnet.checkpoint import build_backbone, widen_point_inputs
from panoptic_bench.dsnet.config import DSNetConfig
from panoptic_bench.dsnet.data.datasets import LidarSample
from panoptic_bench.dsnet.data.shape import N_SHAPE_FEATURES, shape_features
from panoptic_bench.dsnet.model.forward import backbone_forward
from panoptic_bench.dsnet.model.voxelize import CylinderGrid, collate
from panoptic_bench.errors import InputError

sys.path.insert(0, str(Path(__file__).parent))
from dsnet_tiny_world import tiny_model  # noqa: E402

GRID = CylinderGrid(size=(32, 32, 8), rho_range=(1, 30), z_range=(-3, 2))


def test_hand_worked_cubes():
    # a vertical square in the plane y = 0.25 of cube (0, 0, 0): l1 = l2 = 0.0225, l3 = 0
    square = np.array([[0.1, 0.25, 0.1], [0.4, 0.25, 0.1], [0.1, 0.25, 0.4], [0.4, 0.25, 0.4]])
    np.testing.assert_allclose(shape_features(square), [[0, 1, 0, 1]] * 4, atol=1e-6)
    # the same square lying flat (z = 0.25): planar, normal up, verticality 0
    flat = square[:, [0, 2, 1]]
    np.testing.assert_allclose(shape_features(flat), [[0, 1, 0, 0]] * 4, atol=1e-6)
    # five points on a line along x: linearity 1, nothing else (l2 = l3 = 0)
    line = np.c_[np.linspace(0.05, 0.45, 5), np.full(5, 0.2), np.full(5, 0.3)]
    np.testing.assert_allclose(shape_features(line)[:, :3], [[1, 0, 0]] * 5, atol=1e-6)
    # the eight corners of a 0.3 m cube: isotropic, scattering 1
    corners = np.array([[x, y, z] for x in (0.1, 0.4) for y in (0.1, 0.4) for z in (0.1, 0.4)])
    np.testing.assert_allclose(shape_features(corners)[:, :3], [[0, 0, 1]] * 8, atol=1e-6)
    # three points in a cube are too few (min_points 4): zeros; each cube is measured alone
    both = np.concatenate([square, square[:3] + [1.0, 0.0, 0.0]])
    f = shape_features(both)
    np.testing.assert_allclose(f[:4], [[0, 1, 0, 1]] * 4, atol=1e-6)
    assert not f[4:].any()


def test_properties_and_density_rule():
    rng = np.random.default_rng(0)
    pts = rng.normal(0, 3, size=(5000, 3))
    f = shape_features(pts)
    assert f.shape == (5000, N_SHAPE_FEATURES) and f.dtype == np.float32
    assert f.min() >= 0 and f.max() <= 1
    np.testing.assert_allclose(f[:, :3].sum(1)[f[:, 0] + f[:, 2] > 0], 1.0, atol=1e-5)
    perm = rng.permutation(len(pts))
    np.testing.assert_array_equal(shape_features(pts[perm]), f[perm])  # order does not matter
    mirrored = pts * [1, -1, 1]  # mirroring y moves the cube boundaries only by the floor rule
    assert np.abs(shape_features(mirrored)[:, 3] - f[:, 3]).mean() < 0.1
    # max_points: a seeded subset, the same each call; >= n means every point
    a, b = shape_features(pts, max_points=2000), shape_features(pts, max_points=2000)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, f)
    np.testing.assert_array_equal(shape_features(pts, max_points=5000), f)
    assert shape_features(np.zeros((0, 3))).shape == (0, N_SHAPE_FEATURES)
    for bad in (dict(cell=0), dict(max_points=-1), dict(min_points=1)):
        with pytest.raises(ValueError):
            shape_features(pts, **bad)
    with pytest.raises(ValueError, match="shape"):
        shape_features(pts[:, :2])


def test_density_rule_matches_a_thinned_scan():
    """Full scan measured on max_points = thinned scan measured on everything, in distribution."""
    rng = np.random.default_rng(1)
    wall = np.c_[rng.uniform(0, 20, 40000), rng.normal(10, 0.02, 40000), rng.uniform(-1, 2, 40000)]
    bush = rng.normal([5, -6, 0], 0.8, size=(40000, 3))
    pts = np.concatenate([wall, bush])
    thin = pts[np.sort(rng.choice(len(pts), 20000, replace=False))]
    full_rule = shape_features(pts, max_points=20000).mean(0)
    every = shape_features(pts).mean(0)
    thinned = shape_features(thin).mean(0)
    assert np.abs(full_rule - thinned).max() < 0.02
    assert np.abs(every - thinned).max() > np.abs(full_rule - thinned).max()


def _sample(pts: np.ndarray) -> LidarSample:
    n = len(pts)
    rem = np.linspace(0, 1, n, dtype=np.float32)
    return LidarSample(
        pts.astype(np.float32), rem, np.ones(n, np.int64), np.zeros(n, np.int64), ("00", "a")
    )


def _scan(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    ground = np.c_[rng.uniform(-20, 20, (3000, 2)), rng.normal(-1.7, 0.02, 3000)]
    wall = np.c_[rng.uniform(-15, 15, 1500), np.full(1500, 8.0), rng.uniform(-1.7, 1.5, 1500)]
    return np.concatenate([ground, wall])


def test_model_appends_exactly_the_features_and_widening_keeps_outputs():
    torch.manual_seed(0)
    plain = tiny_model(4, GRID).eval()
    torch.manual_seed(0)
    shaped = tiny_model(4, GRID, shape_features=True).eval()
    assert "shape_features=True" in repr(shaped)
    assert shaped.encoder.point_mlp[1].in_features == 9 + N_SHAPE_FEATURES
    sample = _sample(_scan(0))
    before = sample.xyz.copy()
    # widened from the plain model: the same outputs, bit for bit, until training moves them
    shaped.load_state_dict(widen_point_inputs(plain.state_dict(), shaped))
    with torch.no_grad():
        a = backbone_forward(plain, [sample], GRID, "cpu")
        b = backbone_forward(shaped, [sample], GRID, "cpu")
    assert torch.equal(a.sem_logits, b.sem_logits) and torch.equal(a.offsets, b.offsets)
    np.testing.assert_array_equal(sample.xyz, before)
    # the appended columns are shape_features of the scan: feeding them by hand gives the same
    with torch.no_grad():
        shaped.encoder.point_mlp[1].weight.normal_()
        out = backbone_forward(shaped, [sample], GRID, "cpu")
        cols = np.c_[sample.xyz, sample.remission, shape_features(sample.xyz)]
        ref = shaped(collate([cols], GRID))
        zero = shaped(
            collate([np.c_[sample.xyz, sample.remission, np.zeros((len(cols), 4))]], GRID)
        )
    assert torch.equal(out.sem_logits, ref.sem_logits)
    assert not torch.equal(out.sem_logits, zero.sem_logits)


def test_remission_switch_still_zeroes_remission_not_a_shape_column():
    torch.manual_seed(0)
    model = tiny_model(4, GRID, shape_features=True, remission_input=False).eval()
    pts = _scan(1)
    cols = np.c_[pts, np.full(len(pts), 0.3), shape_features(pts)].astype(np.float32)
    other = cols.copy()
    other[:, 3] = 0.9
    no_shape = cols.copy()
    no_shape[:, 4:] = 0
    with torch.no_grad():
        a, b, c = (model(collate([x], GRID)).sem_logits for x in (cols, other, no_shape))
    assert torch.equal(a, b)
    assert not torch.equal(a, c)


def test_collate_rejects_scans_with_different_columns():
    with pytest.raises(ValueError, match="columns"):
        collate([np.zeros((10, 4)), np.zeros((10, 8))], GRID)


def test_config_key_round_trips_and_reaches_the_network():
    cfg = DSNetConfig()
    assert cfg.model.shape_features is False and build_backbone(cfg, 20).shape_features is False
    on = cfg.replace(model={"shape_features": True}, augment={"max_points": 60000})
    assert DSNetConfig.from_dict(on.to_dict()) == on
    net = build_backbone(on, 20)
    assert net.shape_features is True and net.shape_points == 60000
    with pytest.raises(InputError, match="shape_features"):
        DSNetConfig.from_dict({"model": {"shape_features": True, "variant": "official"}})
    shipped = (
        Path(__file__).parents[1] / "configs" / "dsnet_semantickitti_cpu_paste_level_shape.yaml"
    )
    from panoptic_bench.dsnet.config import load_config

    assert load_config(shipped).model.shape_features is True


@pytest.mark.usefixtures("one_torch_thread")
def test_training_from_a_start_without_shape_inputs(tmp_path: Path):
    """`train --init` from a plain checkpoint: the widened network starts where the start was."""
    from dsnet_tiny_world import write_tiny_world

    from panoptic_bench.dsnet.checkpoint import load_checkpoint
    from panoptic_bench.dsnet.training.train import train

    sys.path.insert(0, str(Path(__file__).parent))
    from test_dsnet_train import TINY

    world = write_tiny_world(tmp_path / "w", {"00": 2, "08": 1})
    plain = DSNetConfig.from_dict(TINY)
    train(plain, world, tmp_path / "a", stage="semantic", epochs=1, progress=False)
    start = tmp_path / "a" / "checkpoints" / "semantic.pt"
    shaped = plain.replace(model={"shape_features": True})
    train(shaped, world, tmp_path / "zero", stage="offset", epochs=0, init=start, progress=False)
    train(shaped, world, tmp_path / "b", stage="offset", epochs=1, init=start, progress=False)
    a, z, b = (
        load_checkpoint(p)
        for p in (
            start,
            tmp_path / "zero/checkpoints/offset.pt",
            tmp_path / "b/checkpoints/offset.pt",
        )
    )
    key = "encoder.point_mlp.1.weight"
    assert a.backbone[key].shape[1] == 9 and b.backbone[key].shape[1] == 13
    assert not z.backbone[key][:, 9:].any()  # zero columns before any step
    assert torch.equal(z.backbone[key][:, :9], a.backbone[key])
    assert b.backbone[key][:, 9:].abs().sum() > 0  # and training moves them
    assert b.config.model.shape_features is True
