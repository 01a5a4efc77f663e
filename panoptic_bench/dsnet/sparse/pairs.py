"""Inference-only sparse convolution for sparse maps: per-offset GEMMs, parallel gather-sum.

Strided and inverse maps fill a small fraction of their (output, offset) slots (about 0.1-0.3 on
a LiDAR scan), so the im2col path of :mod:`panoptic_bench.dsnet.sparse.gemm` would multiply
mostly zero rows. Here each offset's products go into one buffer of shape (n_pairs, out_channels)
(one multi-threaded ``torch.mm`` per offset, no wasted rows), and a parallel numba loop over the
output sites adds each site's products (pairs sorted by output site once per map) in place of the
single-threaded ``index_add_``; maps with more products than :data:`PRODUCT_BUDGET` run their
offsets in groups, summed one group after the other (bit-identical). CPU only; results equal the
per-offset path up to float round-off.
"""

from __future__ import annotations

import os

import numba
import numpy as np
import torch

from panoptic_bench.dsnet.sparse.kmap import KernelMap

if "NUMBA_THREADING_LAYER" not in os.environ:  # as in dsnet.model.shift_ops
    numba.config.THREADING_LAYER = "workqueue"


@numba.njit(parallel=True, cache=True)
def _gather_sum(out, products, indptr, order):  # pragma: no cover - compiled
    n_out, width = out.shape
    for o in numba.prange(n_out):
        for j in range(indptr[o], indptr[o + 1]):
            row = order[j]
            for c in range(width):
                out[o, c] += products[row, c]


@numba.njit(cache=True)
def _counting_order(out_idx, n_out):  # pragma: no cover - compiled
    indptr = np.zeros(n_out + 1, dtype=np.int64)
    for o in out_idx:
        indptr[o + 1] += 1
    for o in range(n_out):
        indptr[o + 1] += indptr[o]
    fill = indptr[:-1].copy()
    order = np.empty(out_idx.shape[0], dtype=np.int64)
    for j in range(out_idx.shape[0]):  # ascending j: a stable sort by output site
        o = out_idx[j]
        order[fill[o]] = j
        fill[o] += 1
    return indptr, order


def output_order(kmap: KernelMap) -> tuple[np.ndarray, np.ndarray]:
    """Pairs grouped by output site: ``(indptr (n_out + 1,), order (n_pairs,))``, int64.

    ``order`` is the stable sort of the pairs by output site (a counting sort: linear in the
    number of pairs; ``np.argsort(kind="stable")`` gives the same array).
    """
    out_idx = np.ascontiguousarray(kmap.out_idx.cpu().numpy(), dtype=np.int64)
    return _counting_order(out_idx, kmap.n_out)


def cached_order(cache: dict, kmap: KernelMap) -> tuple[np.ndarray, np.ndarray]:
    """:func:`output_order`, built once per map in ``cache``."""
    key = ("pair_order", id(kmap.in_idx), id(kmap.out_idx), kmap.n_out)
    entry = cache.get(key)
    if entry is not None and entry[0] is kmap.in_idx and entry[1] is kmap.out_idx:
        return entry[2]
    got = output_order(kmap)
    cache[key] = (kmap.in_idx, kmap.out_idx, got)
    return got


PAD_COLUMNS = 32
"""Output widths above this are padded with zero columns to a multiple of it (148 -> 160: the
per-offset GEMMs of the merged heads ran 1.3x faster, 2 threads)."""


PRODUCT_BUDGET = 1 << 24
"""Most products held at once, in values (64 MB of float32). A map with more (the deep 3x3x3
convs of the official network: up to 0.2 GB) runs its offsets in consecutive groups, each summed
into the output before the next: per output site the same additions in the same order (offset
by offset), so the result is bit-identical; only the peak memory drops."""


def offset_groups(splits: tuple[int, ...], n_offsets: int, width: int) -> list[tuple[int, int]]:
    """Consecutive offset ranges ``(k0, k1)`` whose products fit :data:`PRODUCT_BUDGET`.

    A single offset larger than the budget is a group of its own.
    """
    groups, k0, acc = [], 0, 0
    for k in range(n_offsets):
        n = splits[k + 1] - splits[k]
        if k > k0 and (acc + n) * width > PRODUCT_BUDGET:
            groups.append((k0, k))
            k0, acc = k, 0
        acc += n
    groups.append((k0, n_offsets))
    return groups


def _group_order(cache: dict | None, kmap: KernelMap, g0: int, g1: int):
    """:func:`output_order` of the pairs ``g0:g1`` (indices relative to ``g0``), cached."""
    key = ("pair_group_order", id(kmap.in_idx), id(kmap.out_idx), kmap.n_out, g0, g1)
    entry = None if cache is None else cache.get(key)
    if entry is not None and entry[0] is kmap.in_idx and entry[1] is kmap.out_idx:
        return entry[2]
    out_idx = np.ascontiguousarray(kmap.out_idx[g0:g1].cpu().numpy(), dtype=np.int64)
    got = _counting_order(out_idx, kmap.n_out)
    if cache is not None:
        cache[key] = (kmap.in_idx, kmap.out_idx, got)
    return got


def workspace(cache: dict | None, name: str, numel: int, like: torch.Tensor) -> torch.Tensor:
    """A scratch array of ``numel`` elements (``like``'s dtype and device), kept in ``cache``.

    Successive convs of a frame reuse it instead of mapping (and page-faulting) a fresh
    block of up to a few hundred MB each; the contents are garbage. Without a cache, a fresh
    array.
    """
    if cache is None:
        return like.new_empty(numel)
    key = ("workspace", name, like.dtype, like.device)
    buf = cache.get(key)
    if buf is None or buf.numel() < numel:
        buf = like.new_empty(numel)
        cache[key] = buf
    return buf[:numel]


def pair_conv(
    features: torch.Tensor,
    weight: torch.Tensor,
    kmap: KernelMap,
    order: tuple[np.ndarray, np.ndarray],
    bias: torch.Tensor | None = None,
    cache: dict | None = None,
) -> torch.Tensor:
    """The convolution of ``kmap`` (see :func:`~..functional.apply_kernel_map`), CPU, no grad.

    Parameters
    ----------
    features : torch.Tensor
        Array of shape (n_in, in_channels), float32 or float64, contiguous, on the CPU.
    weight : torch.Tensor
        Array of shape (K, in_channels, out_channels), same dtype.
    kmap : KernelMap
    order : tuple of arrays
        :func:`output_order` of ``kmap``.
    bias : torch.Tensor, optional
        Array of shape (out_channels,).
    cache : dict, optional
        The tensors' map cache: its :func:`workspace` arrays hold the gathered rows and the
        products.

    Returns
    -------
    torch.Tensor
        Array of shape (kmap.n_out, out_channels) (a column slice of a wider array when
        ``out_channels`` was padded, see :data:`PAD_COLUMNS`).
    """
    c_out = weight.shape[2]
    pad = (-c_out) % PAD_COLUMNS if c_out > PAD_COLUMNS else 0
    if pad:  # odd widths (the merged heads: 20 + 128) run slower GEMMs than padded ones
        weight = torch.cat([weight, weight.new_zeros((*weight.shape[:2], pad))], dim=2)
        out = pair_conv(features, weight, kmap, order, None, cache)[:, :c_out]
        return out if bias is None else out + bias
    if kmap.identity is not None:
        out = features @ weight[kmap.identity]
    else:
        out = features.new_zeros((kmap.n_out, c_out))
    c_in, splits = weight.shape[1], kmap.splits
    groups = offset_groups(splits, weight.shape[0], c_out)
    most_pairs = max(splits[k1] - splits[k0] for k0, k1 in groups)
    products = workspace(cache, "products", most_pairs * c_out, features).view(-1, c_out)
    most = max((splits[k + 1] - splits[k] for k in range(weight.shape[0])), default=0)
    rows = workspace(cache, "rows", most * c_in, features).view(most, c_in)
    for k0, k1 in groups:
        g0, g1 = splits[k0], splits[k1]
        for k in range(k0, k1):
            s, e = splits[k], splits[k + 1]
            if e > s:
                torch.index_select(features, 0, kmap.in_idx[s:e], out=rows[: e - s])
                torch.mm(rows[: e - s], weight[k], out=products[s - g0 : e - g0])
        if g1 > g0:
            part = order if len(groups) == 1 else _group_order(cache, kmap, g0, g1)
            _gather_sum(out.numpy(), products[: g1 - g0].numpy(), *part)
    return out if bias is None else out + bias
