"""Inference-only sparse convolution: neighbour table -> im2col rows -> one GEMM per row block.

The training path (:class:`~panoptic_bench.dsnet.sparse.functional._MapConv`) runs one small
matmul per kernel offset and scatters with ``index_add_``, which is single-threaded on CPU. Without
gradients the same sum can be computed output-stationary: each output site's ``K`` neighbour
rows (a zero row where the neighbour is missing) are gathered side by side into a buffer of
shape (rows, K * in_channels), and one ``torch.mm`` with the weight reshaped to
(K * in_channels, out_channels) gives the outputs of those rows. The GEMM is large and
multi-threaded; it does ``1 / density`` times the useful work, where ``density`` is the fraction
of (output, offset) slots that have a neighbour, so sparse maps, and every map at one thread, stay on the
per-offset path (:func:`use_table_path`).

Results equal the per-offset path up to float round-off (the sum runs in another order); the
network enables this path only where it is asked to (``PanopticBackbone(fast_inference=True)``,
the official network) so that the pinned nominal outputs stay bit for bit. On the CPU the
mask-sorted tiles of :mod:`panoptic_bench.dsnet.sparse.tiles` replace it (the same GEMMs without
most zero rows); the table path remains for other devices, and its neighbour tables are what
the tiles are planned from.
"""

from __future__ import annotations

import torch

from panoptic_bench.dsnet.sparse.kmap import KernelMap

FAST_KEY = ("fast_inference",)
"""Key of a tensor cache that enables this path for every conv sharing the cache."""

MIN_DENSITY = 0.5
"""Smallest pair density (pairs / (n_out * K)) routed to the table path; sparser maps go to
:mod:`~panoptic_bench.dsnet.sparse.pairs`. At one thread the table path costs about ``1 /
density`` times the per-offset path (measured per layer on the official network), at two its
single large GEMM runs ~1.2x faster than per-offset-sized ones (``torch.mm`` 9335x4608x512 vs
9335x512x512), so it pays off only on the denser maps. Whole official frame, 2 threads, idle machine: threshold
0.75 -> 6.9 s backbone, 0.5 -> 6.0 s, 0.4 -> 5.7 / 6.0 s, 0.25 -> 6.7 s (benchmarks/bench_infer.py)."""

MIN_THREADS = 2
"""Fewest torch threads for the table path: at one thread the per-offset path was faster on
every layer of the official network (its ``index_add_`` costs nothing extra there), at two the
table path's multi-threaded GEMM wins (``benchmarks/README.md``)."""

BLOCK_FLOATS = 1 << 22
"""Size of the im2col buffer in floats (16 MiB in float32): rows per GEMM block."""


def fast_enabled(cache: dict | None, features: torch.Tensor, weight: torch.Tensor) -> bool:
    """True when ``cache`` asks for the inference path and no gradient is needed."""
    if cache is None or not cache.get(FAST_KEY, False):
        return False
    return not (torch.is_grad_enabled() and (features.requires_grad or weight.requires_grad))


def density(kmap: KernelMap, n_offsets: int) -> float:
    """Fraction of (output site, offset) slots that have an input site."""
    pairs = kmap.in_idx.numel() + (kmap.n_out if kmap.identity is not None else 0)
    return pairs / max(1, kmap.n_out * n_offsets)


def use_table_path(kmap: KernelMap, n_offsets: int) -> bool:
    """Whether the im2col GEMM pays off for this map (dense enough, several threads; measured)."""
    if n_offsets < 2 or torch.get_num_threads() < MIN_THREADS:
        return False
    return density(kmap, n_offsets) >= MIN_DENSITY


def use_pair_path(kmap: KernelMap, n_offsets: int, device: torch.device) -> bool:
    """Whether a sparse map goes to :mod:`~panoptic_bench.dsnet.sparse.pairs` (CPU, threads)."""
    if device.type != "cpu" or n_offsets < 2 or torch.get_num_threads() < MIN_THREADS:
        return False
    return density(kmap, n_offsets) < MIN_DENSITY


def neighbour_table(kmap: KernelMap, n_in: int, n_offsets: int) -> torch.Tensor:
    """Input site of every (output site, offset) slot, ``n_in`` where there is none.

    Returns
    -------
    torch.Tensor
        Array of shape (kmap.n_out, n_offsets), int64. Each slot holds at most one input site
        (true of submanifold, strided and inverse maps).
    """
    device = kmap.in_idx.device
    table = torch.full((kmap.n_out, n_offsets), n_in, dtype=torch.long, device=device)
    flat = table.view(-1)
    for k in range(n_offsets):
        s, e = kmap.splits[k], kmap.splits[k + 1]
        if e > s:
            flat.index_copy_(0, kmap.out_idx[s:e] * n_offsets + k, kmap.in_idx[s:e])
    if kmap.identity is not None:
        table[:, kmap.identity] = torch.arange(kmap.n_out, device=device)
    return table


def cached_table(cache: dict, kmap: KernelMap, n_in: int, n_offsets: int) -> torch.Tensor:
    """:func:`neighbour_table`, built once per map in ``cache`` (maps sharing pairs share it)."""
    key = ("table", id(kmap.in_idx), id(kmap.out_idx), kmap.n_out, n_in, n_offsets)
    entry = cache.get(key)
    if entry is not None and entry[0] is kmap.in_idx and entry[1] is kmap.out_idx:
        return entry[2]
    table = neighbour_table(kmap, n_in, n_offsets)
    cache[key] = (kmap.in_idx, kmap.out_idx, table)
    return table


def table_conv(
    features: torch.Tensor,
    weight: torch.Tensor,
    table: torch.Tensor,
    bias: torch.Tensor | None = None,
) -> torch.Tensor:
    """``out[o] = sum_k features[table[o, k]] @ weight[k]`` (+ bias), missing slots adding 0.

    Parameters
    ----------
    features : torch.Tensor
        Array of shape (n_in, in_channels), float.
    weight : torch.Tensor
        Array of shape (K, in_channels, out_channels), same dtype.
    table : torch.Tensor
        Array of shape (n_out, K), int64, values in ``0..n_in`` (``n_in``: no neighbour).
    bias : torch.Tensor, optional
        Array of shape (out_channels,).

    Returns
    -------
    torch.Tensor
        Array of shape (n_out, out_channels).
    """
    n_off, c_in, c_out = weight.shape
    n_out = table.shape[0]
    padded = torch.cat([features, features.new_zeros((1, c_in))])
    w2 = weight.reshape(n_off * c_in, c_out)
    out = features.new_empty((n_out, c_out))
    rows = max(64, BLOCK_FLOATS // (n_off * c_in))
    buf = features.new_empty((min(rows, n_out) * n_off, c_in))
    for r0 in range(0, n_out, rows):
        r1 = min(n_out, r0 + rows)
        n = (r1 - r0) * n_off
        torch.index_select(padded, 0, table[r0:r1].reshape(-1), out=buf[:n])
        cols = buf[:n].view(r1 - r0, n_off * c_in)
        if bias is None:
            torch.mm(cols, w2, out=out[r0:r1])
        else:
            torch.addmm(bias, cols, w2, out=out[r0:r1])
    return out
