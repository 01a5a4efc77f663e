"""The inference-only im2col GEMM path against the straightforward per-offset path."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from panoptic_bench.dsnet.checkpoint import build_backbone, build_grid
from panoptic_bench.dsnet.config import load_config
from panoptic_bench.dsnet.model.voxelize import collate
from panoptic_bench.dsnet.sparse import (
    SparseConv3d,
    SparseInverseConv3d,
    SparseTensor,
    SubMConv3d,
    apply_kernel_map,
    gemm,
    pairs,
    submanifold_map,
    tiles,
)

SHAPE = (9, 8, 6)


@pytest.fixture
def table_everywhere(monkeypatch):
    """Route every map with more than one offset to the table path, at any thread count."""
    monkeypatch.setattr(gemm, "MIN_DENSITY", 0.0)
    monkeypatch.setattr(gemm, "MIN_THREADS", 1)
    monkeypatch.setattr(tiles, "use_tile_path", lambda n_offsets, device: False)


@pytest.fixture
def pairs_everywhere(monkeypatch):
    """Route every map with more than one offset to the pair path, at any thread count."""
    monkeypatch.setattr(gemm, "MIN_DENSITY", 1.01)
    monkeypatch.setattr(gemm, "MIN_THREADS", 1)
    monkeypatch.setattr(tiles, "use_tile_path", lambda n_offsets, device: False)


def random_tensor(
    seed: int, channels: int, occupancy: float = 0.35, fast: bool = False
) -> SparseTensor:
    """Two random scans on SHAPE, shuffled rows; ``fast`` marks it for the inference paths."""
    g = torch.Generator().manual_seed(seed)
    coords = torch.nonzero(torch.rand((2, *SHAPE), generator=g) < occupancy).to(torch.int32)
    coords = coords[torch.randperm(coords.shape[0], generator=g)]
    cache = {gemm.FAST_KEY: True} if fast else None
    feats = torch.randn(coords.shape[0], channels, generator=g)
    return SparseTensor(feats, coords, SHAPE, cache=cache)


def fresh(x: SparseTensor, fast: bool) -> SparseTensor:
    cache = {gemm.FAST_KEY: True} if fast else {}
    return SparseTensor(x.features, x.coords, x.spatial_shape, x.stride, cache)


def run(layers, x: SparseTensor, fast: bool) -> tuple[torch.Tensor, dict]:
    """Down, submanifold, up: the three map kinds, on one cache."""
    down, subm, up = layers
    h = fresh(x, fast)
    with torch.no_grad():
        y = up(subm(down(h)))
    return y.features, h.cache


def test_neighbour_table_holds_every_pair_once():
    x = random_tensor(0, 2)
    kmap = submanifold_map(x, (3, 3, 3))
    table = gemm.neighbour_table(kmap, len(x), 27)
    assert table.shape == (len(x), 27)
    assert torch.equal(table[:, kmap.identity], torch.arange(len(x)))
    for k in range(27):
        s, e = kmap.splits[k], kmap.splits[k + 1]
        assert torch.equal(table[kmap.out_idx[s:e], k], kmap.in_idx[s:e])
    pairs = kmap.in_idx.numel() + len(x)
    assert int((table < len(x)).sum()) == pairs
    assert gemm.density(kmap, 27) == pytest.approx(pairs / (27 * len(x)))


@pytest.mark.parametrize("bias", [False, True])
def test_table_conv_equals_per_offset(bias):
    x = random_tensor(1, 5)
    kmap = submanifold_map(x, (1, 3, 3))
    g = torch.Generator().manual_seed(2)
    w = torch.randn(9, 5, 7, generator=g)
    b = torch.randn(7, generator=g) if bias else None
    ref = apply_kernel_map(x.features, w, kmap, b)
    got = gemm.table_conv(x.features, w, gemm.neighbour_table(kmap, len(x), 9), b)
    torch.testing.assert_close(got, ref, atol=1e-5, rtol=1e-5)


def test_small_blocks_equal_one_block(table_everywhere, monkeypatch):
    x = random_tensor(3, 4)
    kmap = submanifold_map(x, (3, 3, 3))
    w = torch.randn(27, 4, 6, generator=torch.Generator().manual_seed(4))
    table = gemm.neighbour_table(kmap, len(x), 27)
    whole = gemm.table_conv(x.features, w, table)
    monkeypatch.setattr(gemm, "BLOCK_FLOATS", 1)  # 64-row blocks, a ragged last one
    assert len(x) > 64 and len(x) % 64
    torch.testing.assert_close(gemm.table_conv(x.features, w, table), whole, atol=0, rtol=0)


def test_strided_submanifold_inverse_equal_per_offset(table_everywhere):
    torch.manual_seed(0)
    layers = (
        SparseConv3d(4, 8, 3, (2, 2, 1), 1, bias=True),
        SubMConv3d(8, 8, (3, 3, 3), effective_kernel=(1, 3, 3)),
        SparseInverseConv3d(8, 3, 3, (2, 2, 1), 1),
    )
    x = random_tensor(5, 4)
    ref, ref_cache = run(layers, x, fast=False)
    got, cache = run(layers, x, fast=True)
    torch.testing.assert_close(got, ref, atol=1e-5, rtol=1e-5)
    assert not any(k[0] == "table" for k in ref_cache)
    assert sum(k[0] == "table" for k in cache) == 3  # one table per map, built once


def test_pair_path_equals_per_offset(pairs_everywhere):
    torch.manual_seed(1)
    layers = (
        SparseConv3d(3, 6, 3, (2, 2, 2), 1),
        SubMConv3d(6, 6, (3, 1, 3), bias=True),
        SparseInverseConv3d(6, 2, 3, (2, 2, 2), 1, bias=True),
    )
    x = random_tensor(8, 3)
    ref, _ = run(layers, x, fast=False)
    got, cache = run(layers, x, fast=True)
    torch.testing.assert_close(got, ref, atol=1e-5, rtol=1e-5)
    assert sum(k[0] == "pair_order" for k in cache) == 3
    assert not any(k[0] == "table" for k in cache)


def test_output_order_groups_pairs_by_site():
    x = random_tensor(9, 1)
    kmap = submanifold_map(x, (3, 3, 1))
    indptr, order = pairs.output_order(kmap)
    out_idx = kmap.out_idx.numpy()
    assert indptr[0] == 0 and indptr[-1] == len(out_idx) == len(order)
    for o in range(kmap.n_out):
        assert np.all(out_idx[order[indptr[o] : indptr[o + 1]]] == o)
    np.testing.assert_array_equal(order, np.argsort(out_idx, kind="stable"))  # stable, exactly
    assert np.array_equal(np.diff(indptr), np.bincount(out_idx, minlength=kmap.n_out))


def test_gradients_and_one_thread_keep_the_per_offset_path(monkeypatch):
    x = random_tensor(6, 3)
    kmap = submanifold_map(x, (3, 3, 3))
    w = torch.randn(27, 3, 2, requires_grad=True)
    cache = {gemm.FAST_KEY: True}
    assert not gemm.fast_enabled(cache, x.features, w)  # w needs a gradient
    with torch.no_grad():
        assert gemm.fast_enabled(cache, x.features, w)
    assert not gemm.fast_enabled({}, x.features, w.detach())
    monkeypatch.setattr(gemm, "MIN_DENSITY", 0.0)
    monkeypatch.setattr(torch, "get_num_threads", lambda: 1)
    assert not gemm.use_table_path(kmap, 27)
    monkeypatch.setattr(torch, "get_num_threads", lambda: 2)
    assert gemm.use_table_path(kmap, 27)
    assert not gemm.use_table_path(kmap, 1)
    monkeypatch.setattr(gemm, "MIN_DENSITY", 1.01)
    assert gemm.use_pair_path(kmap, 27, torch.device("cpu"))
    assert not gemm.use_pair_path(kmap, 27, torch.device("meta"))


def test_training_step_uses_no_table(table_everywhere):
    x = random_tensor(7, 3)
    h = fresh(x, fast=True)
    conv = SubMConv3d(3, 4, 3)
    conv(h).features.sum().backward()  # with gradients: the per-offset autograd path
    assert conv.weight.grad is not None
    assert not any(k[0] == "table" for k in h.cache)


def test_official_backbone_fast_equals_straightforward(table_everywhere, kitti_root):
    """Official network (random weights), a 2000-point cut of a real scan: same argmax."""
    cfg = load_config("configs/dsnet_semantickitti.yaml")
    cfg = cfg.replace(model={"init_size": 4})
    torch.manual_seed(0)
    net = build_backbone(cfg, 20).eval()
    assert net.fast_inference
    pts = np.fromfile(
        kitti_root / "sequences" / "00" / "velodyne" / "000000.bin", dtype=np.float32
    ).reshape(-1, 4)[::60]
    outs = {}
    for fast in (False, True):
        net.fast_inference = fast
        with torch.inference_mode():
            outs[fast] = net(collate([pts], build_grid(cfg), torch.device("cpu")))
    ref, got = outs[False], outs[True]
    for key in ("sem_logits", "offsets", "point_features"):
        a, b = getattr(ref, key), getattr(got, key)
        scale = float(a.abs().max())
        assert float((a - b).abs().max()) <= 1e-4 * scale, key
    assert torch.equal(ref.sem_logits.argmax(1), got.sem_logits.argmax(1))


def test_nominal_network_never_takes_the_fast_path():
    cfg = load_config("configs/dsnet_synthetic_cpu.yaml")
    assert not build_backbone(cfg, 20).fast_inference
