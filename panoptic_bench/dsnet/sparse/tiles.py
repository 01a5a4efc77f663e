"""Inference-only sparse convolution: output rows sorted by neighbour mask, one GEMM per tile.

The im2col path of :mod:`panoptic_bench.dsnet.sparse.gemm` multiplies a zero row for every
(output site, offset) slot without a neighbour: ``1 / density`` times the useful work (1.2-3x on
a LiDAR scan). Here the output sites are first sorted by their *neighbour mask* (bit ``k`` set
when offset ``k`` has an input site), so sites with the same mask are adjacent. The sorted rows
are cut into segments: every mask shared by at least ``tile_rows`` sites is a segment of its own
(no zero row at all), the rarer masks are packed into tiles of about ``tile_rows`` sites. A
segment gathers only the offsets of the *union* of its masks and runs one GEMM per run of
consecutive offsets in that union (the weight rows of a run are contiguous, nothing is copied),
so the zero rows left are those of the packed tiles. On the official network (real scan) the
1x3x3 / 3x1x3 maps keep 7-11 % zero slots instead of 16-44 %, the inverse maps 1-6 % instead of
76-88 %, the deep 3x3x3 maps 19-37 % instead of 21-49 %.

Results equal the per-offset path up to float round-off (the sum runs in another order). CPU
only (the plan is built with numpy); enabled like the other inference paths (no gradient, a
network built with ``fast_inference=True``, at least two torch threads).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from panoptic_bench.dsnet.sparse import gemm, pairs
from panoptic_bench.dsnet.sparse.kmap import KernelMap

TILE_ROWS = 512
"""Rows of a tile of rare masks; masks shared by this many sites get a segment of their own.
Per layer at 2 threads (official network, real scan), the planned convs took 5.4 s with 512,
5.5 s with 1024, 5.7 s with 256 and 6.4 s with 128: fewer zero slots did not pay for shorter
GEMMs."""

CHUNK_ROWS = 512
"""Longest GEMM in rows: longer segments are chunked (``torch.mm`` at 2 threads ran 110-130
GFLOP/s with 256-1024 rows, 80-100 with 4096, for the widths of the official network)."""

MIN_EFFICIENCY = 0.85
"""Smallest fraction of useful slots (pairs / gathered slots) routed to this path; less
efficient maps go to :mod:`~panoptic_bench.dsnet.sparse.pairs`. Per layer at 2 threads
(official network, real scan, two sessions on different machines), the three deep 3x3x3 convs
with 0.70-0.81 useful slots ran 10-20 % faster on the pair path (0.13-0.15 s per frame); the
1x3x3 / 3x1x3 maps (0.89-0.93) are faster here."""

MIN_ROW_WORK = 128 * 128
"""Smallest ``in_channels * out_channels`` planned: narrower convs go to the pair path (per
layer at 2 threads on the official network, the pair path was as fast or faster on every
16-64 channel layer with 32-128 outputs; the 64 -> 256 merged conv ran 1.5x faster here)."""

MIN_DENSITY = 0.4
"""Submanifold maps sparser than this are not planned (their tiles keep too many zero slots:
the 3x3x3 map of the full-resolution level, density 0.27, 0.46 useful); nor are strided maps
(thousands of masks, 0.3-0.6 useful). Inverse maps are (a few masks, 0.98-1.0 useful)."""

MAX_OFFSETS = 62
"""Masks are int64 bit sets."""


def use_tile_path(n_offsets: int, device: torch.device) -> bool:
    """Whether the inference paths of this module and the pair path apply (CPU, threads)."""
    if device.type != "cpu" or torch.get_num_threads() < gemm.MIN_THREADS:
        return False
    return 2 <= n_offsets <= MAX_OFFSETS


def worth_planning(
    kmap: KernelMap, n_in: int, n_offsets: int, in_channels: int, out_channels: int
) -> bool:
    """Whether to build a plan for a conv (see :data:`MIN_ROW_WORK`, :data:`MIN_DENSITY`)."""
    if in_channels * out_channels < MIN_ROW_WORK:
        return False
    if kmap.identity is None:
        return kmap.n_out > n_in  # inverse maps only
    return gemm.density(kmap, n_offsets) >= MIN_DENSITY


def plan_pays_off(plan: TilePlan) -> bool:
    """Whether a planned conv runs the plan (else the pair path; measured)."""
    return plan.efficiency >= MIN_EFFICIENCY


@dataclass(frozen=True)
class Segment:
    """Sorted output rows ``r0:r1`` and their im2col slots.

    Attributes
    ----------
    r0, r1 : int
        Row range in the sorted order.
    g0 : int
        Start of the segment's slots in :attr:`TilePlan.gather`; row ``r`` owns the ``width``
        slots from ``g0 + (r - r0) * width``.
    width : int
        Number of offsets in the union of the segment's masks.
    runs : tuple of (k0, k1, c0)
        Consecutive union offsets ``k0:k1``, gathered at slot columns ``c0:c0 + k1 - k0``.
    """

    r0: int
    r1: int
    g0: int
    width: int
    runs: tuple[tuple[int, int, int], ...]


@dataclass(frozen=True)
class TilePlan:
    """Row order, segments and gather indices of one kernel map.

    Attributes
    ----------
    order : torch.Tensor
        Array of shape (n_out,), int64: output site of each sorted row.
    inverse : torch.Tensor
        Array of shape (n_out,), int64: sorted row of each output site.
    gather : torch.Tensor
        Array of shape (n_slots,), int64: input site of every gathered slot (``n_in``: none).
    segments : tuple of Segment
    pairs : int
        Slots that have an input site (the useful ones).
    """

    order: torch.Tensor
    inverse: torch.Tensor
    gather: torch.Tensor
    segments: tuple[Segment, ...]
    pairs: int

    @property
    def efficiency(self) -> float:
        """Useful fraction of the gathered slots, in (0, 1]."""
        return self.pairs / max(1, self.gather.numel())


def _cuts(sorted_bits: np.ndarray, tile_rows: int) -> np.ndarray:
    """Segment starts (and the end) over mask-sorted rows, see the module docstring."""
    n = len(sorted_bits)
    starts = np.flatnonzero(np.r_[True, sorted_bits[1:] != sorted_bits[:-1]])
    sizes = np.diff(np.r_[starts, n])
    cuts, acc = [0], 0
    for s, size in zip(starts.tolist(), sizes.tolist()):
        if size >= tile_rows:
            if s != cuts[-1]:
                cuts.append(s)
            cuts.append(s + size)
            acc = 0
            continue
        if acc and acc + size > tile_rows:
            cuts.append(s)
            acc = 0
        acc += size
    if cuts[-1] != n:
        cuts.append(n)
    return np.asarray(cuts, dtype=np.int64)


def _runs(union: int, n_offsets: int) -> tuple[tuple[int, int, int], ...]:
    runs, c0, k = [], 0, 0
    while k < n_offsets:
        if union >> k & 1:
            k1 = k
            while k1 < n_offsets and union >> k1 & 1:
                k1 += 1
            runs.append((k, k1, c0))
            c0 += k1 - k
            k = k1
        else:
            k += 1
    return tuple(runs)


def build_plan(table: torch.Tensor, n_in: int, tile_rows: int | None = None) -> TilePlan:
    """Sort the rows of a neighbour table by mask and cut them into segments.

    Parameters
    ----------
    table : torch.Tensor
        Array of shape (n_out, K), int64, values in ``0..n_in`` (``n_in``: no neighbour), from
        :func:`~panoptic_bench.dsnet.sparse.gemm.neighbour_table`; ``K <= 62``.
    n_in : int
        Number of input sites.
    tile_rows : int, optional
        See :data:`TILE_ROWS` (the default).

    Returns
    -------
    TilePlan
    """
    tile_rows = TILE_ROWS if tile_rows is None else tile_rows
    t = table.cpu().numpy()
    n_out, n_off = t.shape
    if n_off > MAX_OFFSETS:
        raise ValueError(f"at most {MAX_OFFSETS} offsets, got {n_off}")
    present = t < n_in
    bits = present.astype(np.int64) @ (np.int64(1) << np.arange(n_off, dtype=np.int64))
    order = np.argsort(bits, kind="stable")
    sorted_bits = bits[order]
    cuts = _cuts(sorted_bits, tile_rows) if n_out else np.zeros(1, dtype=np.int64)
    unions = np.bitwise_or.reduceat(sorted_bits, cuts[:-1]) if n_out else []
    segments, parts, g0 = [], [], 0
    for r0, r1, union in zip(cuts[:-1].tolist(), cuts[1:].tolist(), np.asarray(unions).tolist()):
        cols = [k for k in range(n_off) if union >> k & 1]
        segments.append(Segment(r0, r1, g0, len(cols), _runs(union, n_off)))
        parts.append(t[order[r0:r1]][:, cols].reshape(-1))
        g0 += (r1 - r0) * len(cols)
    gather = np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)
    inverse = np.empty_like(order)
    inverse[order] = np.arange(n_out)
    device = table.device
    return TilePlan(
        torch.from_numpy(order).to(device),
        torch.from_numpy(inverse).to(device),
        torch.from_numpy(np.ascontiguousarray(gather, dtype=np.int64)).to(device),
        tuple(segments),
        int(present.sum()),
    )


def cached_plan(cache: dict, kmap: KernelMap, table: torch.Tensor, n_in: int) -> TilePlan:
    """:func:`build_plan`, once per map in ``cache`` (convs sharing a map share the plan)."""
    key = ("tiles", id(kmap.in_idx), id(kmap.out_idx), kmap.n_out, n_in, table.shape[1])
    entry = cache.get(key)
    if entry is not None and entry[0] is kmap.in_idx and entry[1] is kmap.out_idx:
        return entry[2]
    plan = build_plan(table, n_in)
    cache[key] = (kmap.in_idx, kmap.out_idx, plan)
    return plan


def tile_conv(
    features: torch.Tensor,
    weight: torch.Tensor,
    plan: TilePlan,
    bias: torch.Tensor | None = None,
    cache: dict | None = None,
) -> torch.Tensor:
    """``out[o] = sum_k features[table[o, k]] @ weight[k]`` (+ bias) over the plan's segments.

    Parameters
    ----------
    features : torch.Tensor
        Array of shape (n_in, in_channels), float (any strides).
    weight : torch.Tensor
        Array of shape (K, in_channels, out_channels), same dtype.
    plan : TilePlan
        :func:`build_plan` of the map's neighbour table (``n_in`` rows of input).
    bias : torch.Tensor, optional
        Array of shape (out_channels,).
    cache : dict, optional
        The tensors' map cache: scratch arrays come from its
        :func:`~panoptic_bench.dsnet.sparse.pairs.workspace`.

    Returns
    -------
    torch.Tensor
        Array of shape (n_out, out_channels), contiguous.
    """
    n_off, c_in, c_out = weight.shape
    n_out = plan.order.numel()
    n_in = features.shape[0]
    padded = pairs.workspace(cache, "padded", (n_in + 1) * c_in, features).view(n_in + 1, c_in)
    padded[:n_in].copy_(features)
    padded[n_in].zero_()
    w2 = weight.reshape(n_off * c_in, c_out)
    out = features.new_empty((n_out, c_out))
    chunks = []
    for seg in plan.segments:
        step = CHUNK_ROWS
        chunks.extend((seg, a, min(seg.r1, a + step)) for a in range(seg.r0, seg.r1, step))
    most = max((seg.width * (b - a) for seg, a, b in chunks), default=0)
    buf = pairs.workspace(cache, "im2col", most * c_in, features).view(most, c_in)
    for seg, a, b in chunks:
        dst = out[a:b]
        if not seg.runs:
            dst.zero_() if bias is None else dst.copy_(bias.expand_as(dst))
            continue
        g0 = seg.g0 + (a - seg.r0) * seg.width
        slab = buf[: (b - a) * seg.width]
        torch.index_select(padded, 0, plan.gather[g0 : g0 + slab.shape[0]], out=slab)
        cols = slab.view(b - a, seg.width * c_in)
        for i, (k0, k1, c0) in enumerate(seg.runs):
            lhs = cols[:, c0 * c_in : (c0 + k1 - k0) * c_in]
            rhs = w2[k0 * c_in : k1 * c_in]
            if i:
                dst.addmm_(lhs, rhs)
            elif bias is None:
                torch.mm(lhs, rhs, out=dst)
            else:
                torch.addmm(bias, lhs, rhs, out=dst)
    return out.index_select(0, plan.inverse)
