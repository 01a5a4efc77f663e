"""Inference shortcuts of the official network against the straightforward path.

The mask-sorted tile GEMM (``sparse/tiles.py``) and the in-place BatchNorm / merged convs
(``sparse/fused.py``): same outputs up to float round-off, and never taken with gradients, in
training mode or at one thread.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_sparse_gemm import random_tensor  # noqa: E402

from panoptic_bench.dsnet.checkpoint import build_backbone, build_grid
from panoptic_bench.dsnet.config import load_config
from panoptic_bench.dsnet.model.backbone import (
    ConvActNorm,
    ConvNormAct,
    ReconBlock,
    ResContextBlock,
)
from panoptic_bench.dsnet.model.voxelize import collate
from panoptic_bench.dsnet.sparse import (
    SparseConv3d,
    SparseInverseConv3d,
    SubMConv3d,
    apply_kernel_map,
    downsample_map,
    fused,
    gemm,
    pairs,
    submanifold_map,
    tiles,
)


@pytest.fixture
def tiles_everywhere(monkeypatch):
    """Every map with 2+ offsets through the tile path, small tiles and chunks, any thread count."""
    monkeypatch.setattr(gemm, "MIN_THREADS", 1)
    monkeypatch.setattr(tiles, "MIN_EFFICIENCY", 0.0)
    monkeypatch.setattr(tiles, "worth_planning", lambda kmap, n_in, n_off, c_in, c_out: True)
    monkeypatch.setattr(tiles, "TILE_ROWS", 8)
    monkeypatch.setattr(tiles, "CHUNK_ROWS", 24)


def test_plan_covers_every_pair_once():
    x = random_tensor(0, 1)
    kmap = submanifold_map(x, (3, 3, 3))
    table = gemm.neighbour_table(kmap, len(x), 27)
    plan = tiles.build_plan(table, len(x), tile_rows=8)
    assert torch.equal(plan.order[plan.inverse], torch.arange(len(x)))
    assert plan.segments[0].r0 == 0 and plan.segments[-1].r1 == len(x)
    rebuilt = torch.full_like(table, len(x))
    for a, b in zip(plan.segments, plan.segments[1:]):
        assert a.r1 == b.r0 and b.g0 == a.g0 + (a.r1 - a.r0) * a.width
    for seg in plan.segments:
        cols = [k for k0, k1, _ in seg.runs for k in range(k0, k1)]
        assert len(cols) == seg.width
        slots = plan.gather[seg.g0 : seg.g0 + (seg.r1 - seg.r0) * seg.width]
        rebuilt[plan.order[seg.r0 : seg.r1, None], torch.tensor(cols)] = slots.view(-1, seg.width)
    assert torch.equal(rebuilt, table)  # every slot of the table, nothing else
    assert plan.pairs == int((table < len(x)).sum())
    assert plan.efficiency == pytest.approx(plan.pairs / plan.gather.numel())
    assert gemm.density(kmap, 27) <= plan.efficiency <= 1.0


def test_rows_sharing_a_mask_form_a_segment_without_zero_slots():
    # 40 rows, two masks of 20 rows each: two segments, all slots useful
    table = torch.tensor([[0, 1, 2]] * 20 + [[3, 5, 4]] * 20)
    plan = tiles.build_plan(table, n_in=5, tile_rows=16)
    # mask 0b101 (rows 20-39) sorts first
    assert [(s.r0, s.r1, s.width) for s in plan.segments] == [(0, 20, 2), (20, 40, 3)]
    assert torch.equal(plan.order[:20], torch.arange(20, 40))
    assert plan.segments[0].runs == ((0, 1, 0), (2, 3, 1))  # offsets 0 and 2, apart
    assert plan.segments[1].runs == ((0, 3, 0),)
    assert plan.efficiency == 1.0


@pytest.mark.parametrize("bias", [False, True])
@pytest.mark.parametrize("kernel", [(3, 3, 3), (1, 3, 3), (3, 1, 1)])
def test_tile_conv_equals_per_offset(bias, kernel, tiles_everywhere):
    x = random_tensor(1, 5)
    n = int(np.prod(kernel))
    kmap = submanifold_map(x, kernel)
    g = torch.Generator().manual_seed(2)
    w = torch.randn(n, 5, 7, generator=g)
    b = torch.randn(7, generator=g) if bias else None
    ref = apply_kernel_map(x.features, w, kmap, b)
    plan = tiles.build_plan(gemm.neighbour_table(kmap, len(x), n), len(x), tile_rows=8)
    assert len(plan.segments) > 2
    got = tiles.tile_conv(x.features, w, plan, b)
    torch.testing.assert_close(got, ref, atol=1e-5, rtol=1e-5)
    wide = torch.randn(len(x), 9, generator=g)  # a column slice: any strides are accepted
    torch.testing.assert_close(
        tiles.tile_conv(wide[:, 2:7], w, plan, b),
        apply_kernel_map(wide[:, 2:7].contiguous(), w, kmap, b),
        atol=1e-5,
        rtol=1e-5,
    )


def test_strided_submanifold_inverse_equal_per_offset(tiles_everywhere):
    torch.manual_seed(0)
    layers = (
        SparseConv3d(4, 8, 3, (2, 2, 1), 1, bias=True),
        SubMConv3d(8, 8, (3, 3, 3), effective_kernel=(1, 3, 3)),
        SparseInverseConv3d(8, 3, 3, (2, 2, 1), 1),
    )
    outs = {}
    for fast in (False, True):
        h = random_tensor(5, 4, fast=fast)
        with torch.no_grad():
            outs[fast] = layers[2](layers[1](layers[0](h))).features
        caches = h.cache
    torch.testing.assert_close(outs[True], outs[False], atol=1e-5, rtol=1e-5)
    assert sum(k[0] == "tiles" for k in caches) == 3  # one plan per map


def test_paths_are_chosen_by_width_map_kind_and_useful_fraction(monkeypatch):
    x = random_tensor(11, 1)
    sub = submanifold_map(x, (3, 3, 3))
    entry = downsample_map(x, (3, 3, 3), (2, 2, 2), (1, 1, 1))
    n = len(x)
    dense = gemm.density(sub, 27) >= tiles.MIN_DENSITY
    assert tiles.worth_planning(sub, n, 27, 128, 128) == dense
    assert tiles.worth_planning(sub, n, 27, 64, 256) == dense  # the work per row counts
    assert not tiles.worth_planning(sub, n, 27, 127, 128)  # narrow: pairs
    assert not tiles.worth_planning(entry.kmap, n, 27, 512, 512)  # strided: pairs
    inverse = entry.kmap.transposed(n)
    assert tiles.worth_planning(inverse, entry.kmap.n_out, 27, 512, 512)
    plan = tiles.TilePlan(*(torch.zeros(0, dtype=torch.long),) * 3, (), pairs=0)
    monkeypatch.setattr(tiles.TilePlan, "efficiency", property(lambda self: 0.9))
    assert tiles.plan_pays_off(plan)
    monkeypatch.setattr(tiles.TilePlan, "efficiency", property(lambda self: 0.5))
    assert not tiles.plan_pays_off(plan)
    monkeypatch.setattr(torch, "get_num_threads", lambda: 1)
    assert not tiles.use_tile_path(9, torch.device("cpu"))
    monkeypatch.setattr(torch, "get_num_threads", lambda: 2)
    assert tiles.use_tile_path(9, torch.device("cpu"))
    assert not tiles.use_tile_path(1, torch.device("cpu"))
    assert not tiles.use_tile_path(9, torch.device("meta"))


def _randomise_norms(module: torch.nn.Module, seed: int) -> None:
    g = torch.Generator().manual_seed(seed)
    for m in module.modules():
        if isinstance(m, torch.nn.BatchNorm1d):
            m.running_mean.copy_(torch.randn(m.num_features, generator=g))
            m.running_var.copy_(torch.rand(m.num_features, generator=g) + 0.5)
            m.weight.data.copy_(torch.randn(m.num_features, generator=g))
            m.bias.data.copy_(torch.randn(m.num_features, generator=g))


@pytest.mark.parametrize("layer", [ConvActNorm, ConvNormAct])
def test_in_place_norm_and_activation_equal_the_modules(layer, tiles_everywhere):
    torch.manual_seed(3)
    block = layer(4, 6, (3, 3, 3)).eval()
    _randomise_norms(block, 4)
    with torch.no_grad():
        ref = block(random_tensor(6, 4)).features
        got = block(random_tensor(6, 4, fast=True)).features
    torch.testing.assert_close(got, ref, atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize(
    "make", [lambda: ResContextBlock(4, 6, (1, 3, 3)), lambda: ReconBlock(4, (3, 1, 1))]
)
def test_merged_convs_equal_separate_ones(make, tiles_everywhere, monkeypatch):
    torch.manual_seed(5)
    block = make().eval()
    _randomise_norms(block, 6)
    calls = []
    original = fused.merged_conv
    monkeypatch.setattr(fused, "merged_conv", lambda x, c: calls.append(len(c)) or original(x, c))
    with torch.no_grad():
        ref = block(random_tensor(7, 4)).features
        assert not calls
        got = block(random_tensor(7, 4, fast=True)).features
    assert calls
    torch.testing.assert_close(got, ref, atol=1e-5, rtol=1e-5)


def test_shortcuts_need_eval_mode_no_grad_and_threads(tiles_everywhere, monkeypatch):
    block = ResContextBlock(3, 4, (1, 3, 3))
    x = random_tensor(8, 3, fast=True)
    assert not fused.inference_path(x, block)  # training mode
    block.eval()
    assert not fused.inference_path(x, block)  # gradients recorded
    with torch.no_grad():
        assert fused.inference_path(x, block)
        assert not fused.inference_path(random_tensor(8, 3), block)  # no fast flag
        monkeypatch.setattr(gemm, "MIN_THREADS", 2)
        monkeypatch.setattr(torch, "get_num_threads", lambda: 1)
        assert not fused.inference_path(x, block)
    assert not fused.can_merge([SubMConv3d(3, 4, (1, 3, 3)), SubMConv3d(3, 4, (3, 1, 3))])
    block.train()
    block(x).features.sum().backward()  # the training path, gradients reach both branches
    assert block.branch_a[0].conv.weight.grad is not None
    assert block.branch_b[0].conv.weight.grad is not None


def test_official_backbone_shortcuts_equal_straightforward(tiles_everywhere, kitti_root):
    """Official network (random weights and norms), a 2000-point cut of a real scan."""
    cfg = load_config("configs/dsnet_semantickitti.yaml")
    cfg = cfg.replace(model={"init_size": 4})
    torch.manual_seed(0)
    net = build_backbone(cfg, 20).eval()
    _randomise_norms(net, 1)
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
    for key in ("sem_logits", "offsets", "point_features", "voxel_logits"):
        a, b = getattr(ref, key), getattr(got, key)
        scale = float(a.abs().max())
        assert float((a - b).abs().max()) <= 1e-4 * scale, key
    assert torch.equal(ref.sem_logits.argmax(1), got.sem_logits.argmax(1))
    assert got.voxel_logits.is_contiguous()


def test_folded_mlp_in_blocks_equals_the_stack(monkeypatch):
    """Rows run block by block (a last partial block too); norms at both ends, ReLU last."""
    torch.manual_seed(4)
    mlp = torch.nn.Sequential(
        torch.nn.BatchNorm1d(6),
        torch.nn.ReLU(),
        torch.nn.Linear(6, 8),
        torch.nn.ReLU(),
        torch.nn.BatchNorm1d(8),
    ).eval()
    _randomise_norms(mlp, 3)
    x = torch.randn(45, 6)
    monkeypatch.setattr(fused, "MLP_BLOCK_ROWS", 16)
    with torch.no_grad():
        torch.testing.assert_close(fused.folded_mlp(mlp, x), mlp(x), atol=1e-5, rtol=1e-5)
        relu_only = torch.nn.Sequential(torch.nn.ReLU()).eval()
        torch.testing.assert_close(fused.folded_mlp(relu_only, x), torch.relu(x))
    assert [r for _, _, r in fused.fold_mlp(mlp)] == [True, True, False]


def test_folded_mlp_equals_the_stack():
    torch.manual_seed(9)
    mlp = torch.nn.Sequential(
        torch.nn.BatchNorm1d(5),
        torch.nn.Linear(5, 7),
        torch.nn.BatchNorm1d(7),
        torch.nn.ReLU(),
        torch.nn.BatchNorm1d(7),
        torch.nn.Linear(7, 4, bias=False),
        torch.nn.ReLU(),
        torch.nn.Linear(4, 3),
        torch.nn.BatchNorm1d(3),
    ).eval()
    _randomise_norms(mlp, 10)
    x = torch.randn(50, 5)
    before = x.clone()
    with torch.no_grad():
        torch.testing.assert_close(fused.folded_mlp(mlp, x), mlp(x), atol=1e-5, rtol=1e-5)
        relu_first = torch.nn.Sequential(torch.nn.ReLU(), torch.nn.Linear(5, 2)).eval()
        torch.testing.assert_close(fused.folded_mlp(relu_first, x), relu_first(x))
    assert torch.equal(x, before)  # the input is never overwritten
    with pytest.raises(TypeError, match="Dropout"):
        fused.folded_mlp(torch.nn.Sequential(torch.nn.Dropout()), x)


@pytest.mark.parametrize("c_out", [3, 37])
def test_pair_path_pads_odd_widths(c_out):
    x = random_tensor(12, 4)
    kmap = submanifold_map(x, (3, 3, 3))
    g = torch.Generator().manual_seed(13)
    w, b = torch.randn(27, 4, c_out, generator=g), torch.randn(c_out, generator=g)
    got = pairs.pair_conv(x.features, w, kmap, pairs.output_order(kmap), b, {})
    assert got.shape == (len(x), c_out)
    torch.testing.assert_close(got, apply_kernel_map(x.features, w, kmap, b), atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("share", [0.0, 0.34, 1.0])
def test_pair_path_in_offset_groups_is_bit_identical(share, monkeypatch):
    """Offsets in groups that fit the product budget: the same sums in the same order."""
    x = random_tensor(14, 5)
    kmap = submanifold_map(x, (3, 3, 3))
    g = torch.Generator().manual_seed(15)
    w, b = torch.randn(27, 5, 7, generator=g), torch.randn(7, generator=g)
    whole = pairs.pair_conv(x.features, w, kmap, pairs.output_order(kmap), b, {})
    monkeypatch.setattr(pairs, "PRODUCT_BUDGET", max(1, int(share * kmap.in_idx.numel() * 7)))
    groups = pairs.offset_groups(kmap.splits, 27, 7)
    assert groups[0][0] == 0 and groups[-1][1] == 27
    assert all(a[1] == b_[0] for a, b_ in zip(groups, groups[1:]))  # consecutive, all offsets
    low, high = {0.0: (27, 27), 0.34: (3, 4), 1.0: (1, 1)}[share]  # one offset each ... one group
    assert low <= len(groups) <= high
    cache: dict = {}
    got = pairs.pair_conv(x.features, w, kmap, pairs.output_order(kmap), b, cache)
    assert torch.equal(got, whole)
    again = pairs.pair_conv(
        x.features, w, kmap, pairs.output_order(kmap), b, cache
    )  # cached orders
    assert torch.equal(again, whole)
