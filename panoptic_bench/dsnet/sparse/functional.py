"""Functional sparse convolutions: gather -> per-offset matmul -> ``index_add_``.

Weights have shape ``(n_offsets, in_channels, out_channels)`` with offsets in row-major kernel
order, i.e. ``weight[k] == dense_weight[:, :, dx, dy, dz].T`` for ``k = (dx * ky + dy) * kz + dz``
of a ``torch.nn.functional.conv3d`` weight of shape (out, in, kx, ky, kz).
"""

from __future__ import annotations

import torch

from panoptic_bench.dsnet.sparse import gemm, pairs, tiles
from panoptic_bench.dsnet.sparse.kmap import (
    KernelMap,
    downsample_map,
    find_downsample,
    submanifold_map,
)
from panoptic_bench.dsnet.sparse.tensor import SparseTensor, _as_triple


class _MapConv(torch.autograd.Function):
    """``out[o] = sum over pairs (i, o, k) of features[i] @ weight[k]`` with explicit backward.

    One offset at a time through two reusable buffers of at most ``max_pairs_per_offset`` rows
    (large fresh CPU allocations cost more than the arithmetic at these channel counts); the
    backward recomputes the gathers instead of saving them.
    """

    @staticmethod
    def forward(ctx, features, weight, in_idx, out_idx, splits, identity, n_out):
        if identity is not None:
            out = features @ weight[identity]
        else:
            out = features.new_zeros((n_out, weight.shape[2]))
        sizes = [splits[k + 1] - splits[k] for k in range(weight.shape[0])]
        most = max(sizes, default=0)
        if most:
            gbuf = features.new_empty((most, weight.shape[1]))
            pbuf = features.new_empty((most, weight.shape[2]))
            for k, n in enumerate(sizes):
                if n:
                    s, e = splits[k], splits[k + 1]
                    torch.index_select(features, 0, in_idx[s:e], out=gbuf[:n])
                    torch.mm(gbuf[:n], weight[k], out=pbuf[:n])
                    out.index_add_(0, out_idx[s:e], pbuf[:n])
        ctx.save_for_backward(features, weight, in_idx, out_idx)
        ctx.splits, ctx.identity = splits, identity
        return out

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_out):
        features, weight, in_idx, out_idx = ctx.saved_tensors
        splits, identity = ctx.splits, ctx.identity
        grad_out = grad_out.contiguous()
        need_f, need_w = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
        weight_t = weight.transpose(1, 2).contiguous()
        grad_f = grad_w = None
        if need_w:
            grad_w = torch.zeros_like(weight)
            if identity is not None:
                torch.mm(features.t(), grad_out, out=grad_w[identity])
        if need_f:
            if identity is not None:
                grad_f = grad_out @ weight_t[identity]
            else:
                grad_f = features.new_zeros(features.shape)
        sizes = [splits[k + 1] - splits[k] for k in range(weight.shape[0])]
        most = max(sizes, default=0)
        if most and (need_f or need_w):
            obuf = grad_out.new_empty((most, weight.shape[2]))
            gbuf = features.new_empty((most, weight.shape[1]))
            for k, n in enumerate(sizes):
                if not n:
                    continue
                s, e = splits[k], splits[k + 1]
                torch.index_select(grad_out, 0, out_idx[s:e], out=obuf[:n])
                if need_w:
                    torch.index_select(features, 0, in_idx[s:e], out=gbuf[:n])
                    torch.mm(gbuf[:n].t(), obuf[:n], out=grad_w[k])
                if need_f:
                    torch.mm(obuf[:n], weight_t[k], out=gbuf[:n])
                    grad_f.index_add_(0, in_idx[s:e], gbuf[:n])
        return grad_f, grad_w, None, None, None, None, None


def apply_kernel_map(
    features: torch.Tensor,
    weight: torch.Tensor,
    kmap: KernelMap,
    bias: torch.Tensor | None = None,
    cache: dict | None = None,
) -> torch.Tensor:
    """Run a convolution given its kernel map.

    Without gradients and when ``cache`` (the tensor's map cache) holds
    :data:`~panoptic_bench.dsnet.sparse.gemm.FAST_KEY`, the convs take inference paths (same
    sums, another order): on the CPU the mask-sorted tiles of
    :mod:`panoptic_bench.dsnet.sparse.tiles` where they pay off
    (:func:`~panoptic_bench.dsnet.sparse.tiles.worth_planning`), else the per-offset GEMMs of
    :mod:`panoptic_bench.dsnet.sparse.pairs`; elsewhere the im2col table of
    :mod:`panoptic_bench.dsnet.sparse.gemm` for dense maps.

    Parameters
    ----------
    features : torch.Tensor
        Array of shape (n_in, in_channels), float.
    weight : torch.Tensor
        Array of shape (n_offsets, in_channels, out_channels), float.
    kmap : KernelMap
        Pairs of the convolution (``len(kmap.splits) == n_offsets + 1``).
    bias : torch.Tensor, optional
        Array of shape (out_channels,).
    cache : dict, optional
        The input tensor's map cache (enables the inference path, keeps its neighbour tables).

    Returns
    -------
    torch.Tensor
        Array of shape (kmap.n_out, out_channels).
    """
    if len(kmap.splits) != weight.shape[0] + 1:
        raise ValueError(f"weight has {weight.shape[0]} offsets, map {len(kmap.splits) - 1}")
    if features.shape[1] != weight.shape[1]:
        raise ValueError(f"features have {features.shape[1]} channels, weight {weight.shape[1]}")
    n_off = weight.shape[0]
    if gemm.fast_enabled(cache, features, weight):
        if tiles.use_tile_path(n_off, features.device):
            n_in = features.shape[0]
            if tiles.worth_planning(kmap, n_in, n_off, *weight.shape[1:]):
                plan = tiles.cached_plan(
                    cache, kmap, gemm.cached_table(cache, kmap, n_in, n_off), n_in
                )
                if tiles.plan_pays_off(plan):
                    return tiles.tile_conv(features, weight.to(features.dtype), plan, bias, cache)
            order = pairs.cached_order(cache, kmap)
            w = weight.to(features.dtype).contiguous()
            return pairs.pair_conv(features.contiguous(), w, kmap, order, bias, cache)
        if gemm.use_table_path(kmap, n_off):
            table = gemm.cached_table(cache, kmap, features.shape[0], n_off)
            return gemm.table_conv(features.contiguous(), weight.to(features.dtype), table, bias)
        if gemm.use_pair_path(kmap, n_off, features.device):
            order = pairs.cached_order(cache, kmap)
            w = weight.to(features.dtype).contiguous()
            return pairs.pair_conv(features.contiguous(), w, kmap, order, bias, cache)
    out = _MapConv.apply(
        features.contiguous(),
        weight.to(features.dtype),
        kmap.in_idx,
        kmap.out_idx,
        kmap.splits,
        kmap.identity,
        kmap.n_out,
    )
    return out if bias is None else out + bias


def submanifold_conv3d(
    x: SparseTensor,
    weight: torch.Tensor,
    kernel_size: int | tuple[int, int, int],
    bias: torch.Tensor | None = None,
) -> SparseTensor:
    """Submanifold convolution: a dense ``conv3d`` (odd kernel, 'same' padding) at ``x``'s sites.

    Parameters
    ----------
    x : SparseTensor
        Input with ``in_channels`` features.
    weight : torch.Tensor
        Array of shape (kx * ky * kz, in_channels, out_channels).
    kernel_size : int or tuple of 3 odd ints
    bias : torch.Tensor, optional
        Array of shape (out_channels,).

    Returns
    -------
    SparseTensor
        Same sites and cache as ``x``, ``out_channels`` features.
    """
    kmap = submanifold_map(x, _as_triple(kernel_size, "kernel_size"))
    return x.replace_features(apply_kernel_map(x.features, weight, kmap, bias, x.cache))


def sparse_conv3d(
    x: SparseTensor,
    weight: torch.Tensor,
    kernel_size: int | tuple[int, int, int],
    stride: int | tuple[int, int, int],
    padding: int | tuple[int, int, int] = 0,
    bias: torch.Tensor | None = None,
) -> SparseTensor:
    """Strided sparse convolution (spconv ``SparseConv3d`` output sites).

    Equals ``conv3d(dense(x), stride=stride, padding=padding)`` at every output site ``o`` whose
    receptive field ``o * stride - padding + [0, k)`` contains an active input site.

    Returns
    -------
    SparseTensor
        New sites on the grid ``(n + 2p - k) // s + 1``, stride ``x.stride * stride``, shared
        cache.
    """
    ks, st, pad = (
        _as_triple(v, n)
        for v, n in ((kernel_size, "kernel_size"), (stride, "stride"), (padding, "padding"))
    )
    entry = downsample_map(x, ks, st, pad)
    feats = apply_kernel_map(x.features, weight, entry.kmap, bias, x.cache)
    out_stride = tuple(a * b for a, b in zip(x.stride, st))
    return SparseTensor(feats, entry.out_coords, entry.out_shape, out_stride, x.cache)


def inverse_conv3d(
    x: SparseTensor,
    weight: torch.Tensor,
    kernel_size: int | tuple[int, int, int],
    stride: int | tuple[int, int, int],
    padding: int | tuple[int, int, int] = 0,
    bias: torch.Tensor | None = None,
) -> SparseTensor:
    """Inverse of an earlier :func:`sparse_conv3d`: back to its input sites, reusing its map.

    Equals ``conv_transpose3d(dense(x), stride=stride, padding=padding)`` at the input sites of
    the strided convolution (same kernel, stride, padding) that produced ``x``'s sites.
    """
    ks, st, pad = (
        _as_triple(v, n)
        for v, n in ((kernel_size, "kernel_size"), (stride, "stride"), (padding, "padding"))
    )
    entry = find_downsample(x, ks, st, pad)
    kmap = entry.kmap.transposed(entry.in_coords.shape[0])
    feats = apply_kernel_map(x.features, weight, kmap, bias, x.cache)
    in_stride = tuple(a // b for a, b in zip(x.stride, st))
    return SparseTensor(feats, entry.in_coords, entry.in_shape, in_stride, x.cache)


def dense_to_weight(dense_weight: torch.Tensor) -> torch.Tensor:
    """Convert a ``conv3d`` weight (out, in, kx, ky, kz) to our layout (kx*ky*kz, in, out)."""
    o, i = dense_weight.shape[:2]
    return dense_weight.permute(2, 3, 4, 1, 0).reshape(-1, i, o)


def weight_to_dense(weight: torch.Tensor, kernel_size: tuple[int, int, int]) -> torch.Tensor:
    """Inverse of :func:`dense_to_weight`: (kx*ky*kz, in, out) -> (out, in, kx, ky, kz)."""
    _, i, o = weight.shape
    return weight.reshape(*kernel_size, i, o).permute(4, 3, 0, 1, 2)
