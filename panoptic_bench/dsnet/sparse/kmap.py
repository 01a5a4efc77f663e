"""Kernel maps: which input site feeds which output site through which kernel offset.

Sites are found by integer-key sort + ``searchsorted`` (no hash table, no compiled extension),
or, on the CPU for grids up to :data:`~panoptic_bench.dsnet.sparse.kmap_dense.MAX_CELLS` cells,
through a dense site-index volume (:mod:`~panoptic_bench.dsnet.sparse.kmap_dense`, same maps).
Maps are cached in the tensor's shared ``cache`` dict:

- ``("sorted", stride)``: sorted site keys and the permutation that sorts them;
- ``("offset", stride, delta)``: (in, out) pairs of one submanifold offset, shared by every
  kernel shape that contains the offset (a 1x3x3 and a 3x3x3 kernel reuse the same lookups) and
  swapped for the opposite offset;
- ``("dense", stride)``: the site-index volume of the dense path;
- ``("subm", stride, kernel)``: the submanifold :class:`KernelMap`;
- ``("down", stride, kernel, conv_stride, padding)``: the strided convolution's output sites and
  map, which the inverse convolution reuses to go back up.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import torch

from panoptic_bench.dsnet.sparse import kmap_dense
from panoptic_bench.dsnet.sparse.tensor import Shape3, SparseTensor, decode_keys, encode_keys


@dataclass(frozen=True)
class KernelMap:
    """Input/output site pairs grouped by kernel offset.

    Attributes
    ----------
    in_idx, out_idx : torch.Tensor
        Arrays of shape (n_pairs,), int64: pair ``i`` adds ``features[in_idx[i]] @ W[k]`` to
        output ``out_idx[i]``, where ``k`` is the offset whose slice ``splits[k]:splits[k+1]``
        contains ``i``.
    splits : tuple of ints
        ``n_offsets + 1`` boundaries of the per-offset slices.
    identity : int or None
        Offset whose pairs are the identity (submanifold centre); its pairs are *not* in the
        arrays and it is applied as one dense matmul.
    n_out : int
        Number of output sites.
    """

    in_idx: torch.Tensor
    out_idx: torch.Tensor
    splits: tuple[int, ...]
    identity: int | None
    n_out: int

    def transposed(self, n_out: int) -> KernelMap:
        """The map of the transposed (inverse) convolution, with ``n_out`` output sites."""
        return KernelMap(self.out_idx, self.in_idx, self.splits, self.identity, n_out)


@dataclass(frozen=True)
class DownsampleEntry:
    """A strided convolution's result sites, kept so the inverse convolution can go back."""

    in_coords: torch.Tensor
    in_shape: Shape3
    out_coords: torch.Tensor
    out_shape: Shape3
    kmap: KernelMap


def kernel_offsets(kernel_size: Shape3) -> list[tuple[int, int, int]]:
    """Kernel positions ``(dx, dy, dz)`` in ``0..k-1`` in row-major order (dense weight order)."""
    return list(itertools.product(*(range(k) for k in kernel_size)))


def _sorted_keys(x: SparseTensor) -> tuple[torch.Tensor, torch.Tensor]:
    key = ("sorted", x.stride)
    entry = x.cache.get(key)
    if entry is not None and entry[0] is x.coords:
        return entry[1], entry[2]
    keys = encode_keys(x.coords, x.spatial_shape)
    sorted_keys, order = torch.sort(keys)
    if entry is None:
        x.cache[key] = (x.coords, sorted_keys, order)
    return sorted_keys, order


def _lookup(
    x: SparseTensor, query: torch.Tensor, valid: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Positions (in x) of the query coords that are active sites; returns (query_i, site_i)."""
    sorted_keys, order = _sorted_keys(x)
    rows = torch.nonzero(valid).squeeze(1)
    if rows.numel() == 0 or sorted_keys.numel() == 0:
        empty = torch.empty(0, dtype=torch.long, device=query.device)
        return empty, empty
    qkeys = encode_keys(query[rows], x.spatial_shape)
    pos = torch.searchsorted(sorted_keys, qkeys).clamp_(max=sorted_keys.numel() - 1)
    hit = sorted_keys[pos] == qkeys
    return rows[hit], order[pos[hit]]


def _offset_pairs(x: SparseTensor, delta: tuple[int, int, int]) -> tuple[torch.Tensor, ...]:
    """(in_idx, out_idx) with ``coords[in] == coords[out] + delta``, cached per stride."""
    key = ("offset", x.stride, delta)
    entry = x.cache.get(key)
    if entry is not None and entry[0] is x.coords:
        return entry[1], entry[2]
    neg = ("offset", x.stride, tuple(-d for d in delta))
    other = x.cache.get(neg)
    volume = None if other is not None and other[0] is x.coords else _dense_volume(x)
    if other is not None and other[0] is x.coords:
        pairs = (other[2], other[1])
    elif volume is not None:
        i, o = kmap_dense.offset_pairs(x.coords.numpy(), volume, x.spatial_shape, delta)
        pairs = (torch.from_numpy(i), torch.from_numpy(o))
    else:
        shift = torch.tensor((0, *delta), dtype=torch.int32, device=x.coords.device)
        query = x.coords + shift
        bound = torch.tensor(x.spatial_shape, dtype=torch.int32, device=x.coords.device)
        valid = ((query[:, 1:] >= 0) & (query[:, 1:] < bound)).all(dim=1)
        out_idx, in_idx = _lookup(x, query, valid)
        pairs = (in_idx, out_idx)
    if entry is None:
        x.cache[key] = (x.coords, *pairs)
    return pairs


def submanifold_map(x: SparseTensor, kernel_size: Shape3) -> KernelMap:
    """Map of a submanifold convolution (outputs = inputs, centred odd kernel), cached."""
    if any(k % 2 == 0 for k in kernel_size):
        raise ValueError(f"submanifold kernels must be odd, got {kernel_size}")
    key = ("subm", x.stride, kernel_size)
    entry = x.cache.get(key)
    if entry is not None and entry[0] is x.coords:
        return entry[1]
    ins, outs, splits, identity = [], [], [0], None
    for k, pos in enumerate(kernel_offsets(kernel_size)):
        delta = tuple(p - s // 2 for p, s in zip(pos, kernel_size))
        if delta == (0, 0, 0):
            identity = k
            splits.append(splits[-1])
            continue
        i, o = _offset_pairs(x, delta)
        ins.append(i)
        outs.append(o)
        splits.append(splits[-1] + i.numel())
    kmap = _concat_map(ins, outs, splits, identity, len(x), x.coords.device)
    if entry is None:
        x.cache[key] = (x.coords, kmap)
    return kmap


def _dense_volume(x: SparseTensor):
    """The site-index volume of ``x``'s sites (cached), or None off the dense path."""
    key = ("dense", x.stride)
    entry = x.cache.get(key)
    if entry is not None and entry[0] is x.coords:
        return entry[1]
    batch = x.batch_size()
    if not kmap_dense.usable(x.coords, batch, x.spatial_shape):
        return None
    coords = x.coords.numpy()
    if coords.dtype != np.int32 or not coords.flags.c_contiguous:
        return None
    volume = kmap_dense.index_volume(coords, batch, x.spatial_shape)
    if entry is None:
        x.cache[key] = (x.coords, volume)
    return volume


def _concat_map(ins, outs, splits, identity, n_out, device) -> KernelMap:
    if ins:
        in_idx, out_idx = torch.cat(ins), torch.cat(outs)
    else:
        in_idx = out_idx = torch.empty(0, dtype=torch.long, device=device)
    return KernelMap(in_idx, out_idx, tuple(splits), identity, n_out)


def output_shape(in_shape: Shape3, kernel_size: Shape3, stride: Shape3, padding: Shape3) -> Shape3:
    """Grid size after a strided convolution: ``(n + 2p - k) // s + 1`` per axis."""
    return tuple(
        (n + 2 * p - k) // s + 1 for n, k, s, p in zip(in_shape, kernel_size, stride, padding)
    )  # type: ignore[return-value]


def downsample_map(
    x: SparseTensor, kernel_size: Shape3, stride: Shape3, padding: Shape3
) -> DownsampleEntry:
    """Output sites and map of a strided sparse convolution (spconv ``SparseConv3d`` sites).

    An output site ``o`` is active when some active input ``i = o * stride - padding + d``
    exists for a kernel position ``d`` in ``0..k-1``.
    """
    key = ("down", x.stride, kernel_size, stride, padding)
    entry = x.cache.get(key)
    if entry is not None and entry.in_coords is x.coords:
        return entry
    device = x.coords.device
    out_shape = output_shape(x.spatial_shape, kernel_size, stride, padding)
    if min(out_shape) < 1:
        raise ValueError(f"grid {x.spatial_shape} too small for kernel {kernel_size}")
    batch = x.batch_size()
    out_stride = tuple(a * b for a, b in zip(x.stride, stride))
    dense = None
    if kmap_dense.usable(x.coords, batch, out_shape):
        coords = x.coords.numpy()
        if coords.dtype == np.int32 and coords.flags.c_contiguous:
            dense = kmap_dense.strided_map(
                coords, batch, kernel_offsets(kernel_size), stride, padding, out_shape
            )
    if dense is not None:
        uniq_np, rows, inverse_np, splits, volume = dense
        uniq = torch.from_numpy(uniq_np)
        out_coords = decode_keys(uniq, out_shape)
        kmap = KernelMap(
            torch.from_numpy(rows), torch.from_numpy(inverse_np), tuple(splits), None, len(uniq)
        )
        x.cache.setdefault(("dense", out_stride), (out_coords, volume))
    else:
        uniq, out_coords, kmap = _strided_sorted(x, kernel_size, stride, padding, out_shape)
    entry = DownsampleEntry(x.coords, x.spatial_shape, out_coords, out_shape, kmap)
    x.cache.setdefault(key, entry)
    order = torch.arange(uniq.numel(), device=device)
    x.cache.setdefault(("sorted", out_stride), (out_coords, uniq, order))
    return entry


def _strided_sorted(x, kernel_size, stride, padding, out_shape):
    """Output keys (sorted), coords and map of a strided conv through key sort + unique."""
    device = x.coords.device
    s = torch.tensor(stride, dtype=torch.int32, device=device)
    bound = torch.tensor(out_shape, dtype=torch.int32, device=device)
    base = x.coords[:, 1:] + torch.tensor(padding, dtype=torch.int32, device=device)
    all_keys, all_in, counts = [], [], []
    for pos in kernel_offsets(kernel_size):
        num = base - torch.tensor(pos, dtype=torch.int32, device=device)
        o = torch.div(num, s, rounding_mode="floor")
        ok = ((num - o * s) == 0).all(1) & (o >= 0).all(1) & (o < bound).all(1)
        rows = torch.nonzero(ok).squeeze(1)
        oc = torch.cat([x.coords[rows, :1], o[rows]], dim=1)
        all_keys.append(encode_keys(oc, out_shape))
        all_in.append(rows)
        counts.append(rows.numel())
    keys = torch.cat(all_keys)
    uniq, inverse = torch.unique(keys, sorted=True, return_inverse=True)
    out_coords = decode_keys(uniq, out_shape)
    splits = [0]
    for c in counts:
        splits.append(splits[-1] + c)
    kmap = KernelMap(torch.cat(all_in), inverse, tuple(splits), None, uniq.numel())
    return uniq, out_coords, kmap


def find_downsample(
    x: SparseTensor, kernel_size: Shape3, stride: Shape3, padding: Shape3
) -> DownsampleEntry:
    """The cached strided convolution whose output sites are ``x``'s sites (for inverse conv)."""
    if any(a % b for a, b in zip(x.stride, stride)):
        raise ValueError(f"tensor stride {x.stride} is not a multiple of {stride}")
    in_stride = tuple(a // b for a, b in zip(x.stride, stride))
    entry = x.cache.get(("down", in_stride, kernel_size, stride, padding))
    if entry is None or entry.out_coords is not x.coords:
        raise ValueError(
            f"no strided convolution (kernel {kernel_size}, stride {stride}, padding {padding}) "
            f"produced these sites at stride {x.stride}; the inverse convolution can only undo a "
            "SparseConv3d applied earlier to a tensor sharing this cache"
        )
    return entry
