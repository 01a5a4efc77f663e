"""Sparse convolutions against a dense ``conv3d`` / ``conv_transpose3d`` reference."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as tnf

from panoptic_bench.dsnet import sparse
from panoptic_bench.dsnet.sparse import (
    SparseConv3d,
    SparseInverseConv3d,
    SparseTensor,
    SubMConv3d,
    dense_to_weight,
    weight_to_dense,
)

SHAPE = (7, 6, 5)
KERNELS = [(3, 3, 3), (1, 3, 3), (3, 1, 3), (3, 1, 1), (1, 3, 1), (1, 1, 3), (5, 3, 1)]
STRIDES = [(2, 2, 2), (2, 2, 1)]


def random_tensor(seed: int, channels: int = 3, density: float = 0.3) -> SparseTensor:
    g = torch.Generator().manual_seed(seed)
    occ = torch.rand((2, *SHAPE), generator=g) < density
    coords = torch.nonzero(occ).to(torch.int32)
    coords = coords[torch.randperm(coords.shape[0], generator=g)]  # unsorted on purpose
    feats = torch.randn(coords.shape[0], channels, generator=g, dtype=torch.float64)
    return SparseTensor(feats.requires_grad_(True), coords, SHAPE)


def at_sites(dense: torch.Tensor, coords: torch.Tensor) -> torch.Tensor:
    c = coords.long()
    return dense[c[:, 0], :, c[:, 1], c[:, 2], c[:, 3]]


def grads(out: torch.Tensor, inputs: list[torch.Tensor], seed: int) -> list[torch.Tensor]:
    r = torch.randn(out.shape, generator=torch.Generator().manual_seed(seed), dtype=out.dtype)
    return list(torch.autograd.grad((out * r).sum(), inputs))


def check(out, ref, x, w_ours, w_ref, seed=5):
    torch.testing.assert_close(out, ref, atol=1e-5, rtol=1e-5)
    g_ours = grads(out, [x.features, w_ours], seed)
    g_ref = grads(ref, [x.features, w_ref], seed)
    torch.testing.assert_close(g_ours[0], g_ref[0], atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(g_ours[1], dense_to_weight(g_ref[1]), atol=1e-5, rtol=1e-5)


def test_weight_layout_round_trip():
    w = torch.randn(4, 3, 3, 1, 5)
    assert torch.equal(weight_to_dense(dense_to_weight(w), (3, 1, 5)), w)


@pytest.mark.parametrize("kernel", KERNELS)
def test_submanifold_matches_dense(kernel):
    x = random_tensor(1)
    w_ref = torch.randn(4, 3, *kernel, dtype=torch.float64, requires_grad=True)
    w = dense_to_weight(w_ref.detach()).clone().requires_grad_(True)
    bias = torch.randn(4, dtype=torch.float64)
    out = sparse.submanifold_conv3d(x, w, kernel, bias)
    pad = tuple(k // 2 for k in kernel)
    ref = at_sites(tnf.conv3d(x.dense(), w_ref, bias, padding=pad), x.coords)
    assert out.coords is x.coords and out.cache is x.cache
    check(out.features, ref, x, w, w_ref)


@pytest.mark.parametrize("stride", STRIDES)
def test_strided_matches_dense_with_spconv_sites(stride):
    x = random_tensor(2)
    w_ref = torch.randn(4, 3, 3, 3, 3, dtype=torch.float64, requires_grad=True)
    w = dense_to_weight(w_ref.detach()).clone().requires_grad_(True)
    out = sparse.sparse_conv3d(x, w, 3, stride, 1)
    # output sites: receptive field holds an active input
    occ = (x.dense().detach().abs().sum(1, keepdim=True) > 0).double()
    hit = tnf.conv3d(occ, torch.ones(1, 1, 3, 3, 3, dtype=torch.float64), stride=stride, padding=1)
    expected = {tuple(c) for c in torch.nonzero(hit[:, 0] > 0).tolist()}
    assert {tuple(c) for c in out.coords.tolist()} == expected
    assert out.spatial_shape == tuple(hit.shape[2:])
    assert out.stride == stride
    ref = at_sites(tnf.conv3d(x.dense(), w_ref, stride=stride, padding=1), out.coords)
    check(out.features, ref, x, w, w_ref)


@pytest.mark.parametrize("stride", STRIDES)
def test_inverse_is_transpose_on_original_sites(stride):
    x = random_tensor(3)
    down = sparse.sparse_conv3d(x, torch.randn(27, 3, 3, dtype=torch.float64), 3, stride, 1)
    y = down.replace_features(down.features.detach().clone().requires_grad_(True))
    w_ref = torch.randn(3, 2, 3, 3, 3, dtype=torch.float64, requires_grad=True)  # (in, out, k)
    w = w_ref.detach().permute(2, 3, 4, 0, 1).reshape(27, 3, 2).clone().requires_grad_(True)
    up = sparse.inverse_conv3d(y, w, 3, stride, 1)
    assert up.coords is x.coords and up.spatial_shape == SHAPE and up.stride == (1, 1, 1)
    full = tnf.conv_transpose3d(y.dense(), w_ref, stride=stride)  # padding applied by cropping
    need = [s + 1 - f for s, f in zip(SHAPE, full.shape[2:])]
    full = tnf.pad(full, [0, max(need[2], 0), 0, max(need[1], 0), 0, max(need[0], 0)])
    ref = at_sites(full[:, :, 1 : 1 + SHAPE[0], 1 : 1 + SHAPE[1], 1 : 1 + SHAPE[2]], x.coords)
    torch.testing.assert_close(up.features, ref, atol=1e-5, rtol=1e-5)
    g_ours = grads(up.features, [y.features, w], 9)
    g_ref = grads(ref, [y.features, w_ref], 9)
    torch.testing.assert_close(g_ours[0], g_ref[0], atol=1e-5, rtol=1e-5)
    g_w = g_ref[1].permute(2, 3, 4, 0, 1).reshape(27, 3, 2)
    torch.testing.assert_close(g_ours[1], g_w, atol=1e-5, rtol=1e-5)


def test_modules_chain_and_cache_reuse():
    x = random_tensor(4)
    x = x.replace_features(x.features.float().detach())
    c1, c2 = SubMConv3d(3, 8, (1, 3, 3)), SubMConv3d(8, 8, 3)
    down, up = SparseConv3d(8, 8, 3, (2, 2, 1), 1), SparseInverseConv3d(8, 4, 3, (2, 2, 1), 1)
    bn = sparse.SparseBatchNorm(8)
    act = sparse.SparseActivation(torch.nn.LeakyReLU())
    h = act(bn(c2(c1(x))))
    h2 = c2(h)  # same kernel at the same stride: map reused
    assert sum(1 for k in x.cache if k[0] == "subm") == 2
    y = up(down(h2))
    assert y.coords is x.coords and y.features.shape == (len(x), 4)
    y.features.sum().backward()
    assert all(p.grad is not None for m in (c1, c2, down, up) for p in m.parameters())
    assert "kernel_size=(1, 3, 3)" in repr(c1) and "stride=(2, 2, 1)" in repr(down)


def test_inverse_without_matching_down_is_an_error():
    x = random_tensor(5)
    with pytest.raises(ValueError, match="no strided convolution"):
        sparse.inverse_conv3d(
            SparseTensor(x.features, x.coords, SHAPE, (2, 2, 2)), torch.zeros(27, 3, 3), 3, 2, 1
        )


def test_empty_tensor():
    x = SparseTensor(torch.zeros(0, 3), torch.zeros(0, 4, dtype=torch.int32), SHAPE)
    y = SubMConv3d(3, 5)(x)
    z = SparseConv3d(5, 5)(y)
    assert y.features.shape == (0, 5) and z.features.shape == (0, 5)
