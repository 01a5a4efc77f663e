"""Functional kernels of dynamic shifting: exact radius sums without an M x M matrix.

The flat kernel of bandwidth δ maps a seed x_i to the mean of the seeds within distance δ of it
(itself included): ``mean_δ(X)[i] = Σ_{j: ‖x_i − x_j‖² ≤ δ²} x_j / #{j: ‖x_i − x_j‖² ≤ δ²}``.
Near-converged seeds are dense (thousands of seeds inside a 3.2 m ball), so enumerating every
neighbour pair costs millions of pairs per iteration. :func:`ball_sums` is exact but cheaper:
the seeds are hashed to a grid of cells (cell size a fraction of δ) and each cell keeps its
count, coordinate sum and tight bounding box. A pair of cells whose bounding boxes are entirely
within δ of each other contributes the aggregate of one to every seed of the other (one
addition instead of n_a × n_b); only boxes straddling the ball surface descend to seed × cell
tests and, if still straddling, to seed × seed tests. Box distances bound the float64 point
distances monotonically, so the neighbour sets are exactly those of the dense formulation;
only the summation order differs.

The Gaussian kernel of the direct-regression ablation (appendix eq. 19) uses explicit radius
pairs cut off at ``cutoff × δ_i`` (see :func:`gaussian_kernel_means`).
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import cKDTree

#: Grid cell size of :func:`ball_sums` as a fraction of the radius (measured best on
#: LiDAR-like seeds: smaller cells mean more cell pairs, larger ones more boundary seeds).
CELL_FRACTION = 1.0
#: Nested grid levels of :func:`ball_sums` above the seeds.
LEVELS = 4


def ragged_arange(starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Concatenate ``arange(s, s + n)`` for every (s, n); int64 array of shape (sum(lengths),)."""
    lengths = np.asarray(lengths, dtype=np.int64)
    total = int(lengths.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    offsets = np.cumsum(lengths) - lengths
    return np.arange(total, dtype=np.int64) + np.repeat(
        np.asarray(starts, dtype=np.int64) - offsets, lengths
    )


def _add_rows(index: np.ndarray, values: list[np.ndarray], size: int) -> list[np.ndarray]:
    """``out[d][index[k]] += values[d][k]`` for every column d; list of float64 (size,)."""
    return [np.bincount(index, weights=v, minlength=size) for v in values]


def _box_dist2(lo_a, hi_a, lo_b, hi_b) -> tuple[np.ndarray, np.ndarray]:
    """Squared min and max distance between axis-aligned boxes given as per-axis columns.

    Points are zero-size boxes (``lo is hi``). Rounded subtraction, squaring and the x, y, z
    summation order are monotone, so for any points inside the boxes
    ``min ≤ Σ_d (p_d − q_d)² ≤ max`` holds in floating point exactly as in the dense test.
    """
    gap2 = np.zeros(len(lo_a[0]))
    span2 = np.zeros(len(lo_a[0]))
    for la, ha, lb, hb in zip(lo_a, hi_a, lo_b, hi_b):
        g = np.maximum(np.maximum(lb - ha, la - hb), 0.0)
        gap2 += g * g
        t = np.maximum(hb - la, ha - lb)
        span2 += t * t
    return gap2, span2


def _take(cols: list[np.ndarray], index: np.ndarray) -> list[np.ndarray]:
    return [c[index] for c in cols]


def _grid_levels(xs: list[np.ndarray], cell: float, levels: int):
    """Nested grids over seed columns ``xs``: level k has cell size ``cell / 2**k``.

    Returns the permutation sorting the seeds so that every cell of every level is a contiguous
    run, and per level (coarse to fine): ``(starts, agg, lo, hi)`` with ``agg = [count, Σx,
    Σy, Σz]`` and per-axis tight bounds; a last level holds the single seeds.
    """
    m = len(xs[0])
    fine = cell / 2 ** (levels - 1)
    q = [np.floor((c - c.min()) / fine).astype(np.int64) for c in xs]
    codes = []
    for k in range(levels):
        qk = [c >> (levels - 1 - k) for c in q]
        dims = [int(c.max()) + 1 for c in qk]
        codes.append((qk[0] * dims[1] + qk[1]) * dims[2] + qk[2])
    order = np.lexsort(codes[::-1])
    xs = _take(xs, order)
    out = []
    for code in codes:
        cs = code[order]
        starts = np.flatnonzero(np.r_[True, cs[1:] != cs[:-1]])
        agg = [np.diff(np.r_[starts, m]).astype(np.float64)]
        agg += [np.add.reduceat(c, starts) for c in xs]
        lo = [np.minimum.reduceat(c, starts) for c in xs]
        hi = [np.maximum.reduceat(c, starts) for c in xs]
        out.append((starts, agg, lo, hi))
    out.append((np.arange(m), [np.ones(m), *xs], xs, xs))
    return order, xs, out


def ball_sums(
    points: np.ndarray,
    radius: float,
    *,
    cell_fraction: float | None = None,
    levels: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Count and coordinate sum of the points within ``radius`` of every point (self included).

    Parameters
    ----------
    points : np.ndarray of shape (M, 3), float
        Seed positions (converted to float64).
    radius : float
        Ball radius δ > 0; point j is a neighbour of i iff ``Σ_d (x_id − x_jd)² ≤ δ²``.
    cell_fraction, levels : float, int, optional
        Coarsest cell size as a fraction of δ and the number of nested grid levels (each
        halves the cell size); defaults :data:`CELL_FRACTION`, :data:`LEVELS`.

    Returns
    -------
    counts : np.ndarray of shape (M,), float64
        Number of neighbours (≥ 1: the point itself).
    sums : np.ndarray of shape (M, 3), float64
        Sum of the neighbours' coordinates.
    """
    x = np.asarray(points, dtype=np.float64)
    m = len(x)
    if m == 0:
        return np.zeros(0), np.zeros((0, 3))
    r2 = float(radius) ** 2
    cell = float(radius) * (CELL_FRACTION if cell_fraction is None else cell_fraction)
    order, xs, nodes = _grid_levels([np.ascontiguousarray(c) for c in x.T], cell, levels or LEVELS)

    # Level 0: coarse cell x coarse cell; a box pair entirely inside the ball is summed once.
    starts, agg, lo, hi = nodes[0]
    n_cells = len(starts)
    centre = np.stack([0.5 * (a + b) for a, b in zip(lo, hi)], axis=1)
    half_diag = 0.5 * np.sqrt(sum((b - a) ** 2 for a, b in zip(lo, hi)))
    pairs = cKDTree(centre).query_pairs(
        float(radius) + 2.0 * float(half_diag.max()) + 1e-9, output_type="ndarray"
    )
    own = np.arange(n_cells, dtype=np.int64)
    na = np.concatenate([pairs[:, 0], pairs[:, 1], own])
    nb = np.concatenate([pairs[:, 1], pairs[:, 0], own])
    gap2, span2 = _box_dist2(_take(lo, na), _take(hi, na), _take(lo, nb), _take(hi, nb))
    full = span2 <= r2
    cell_of = np.repeat(own, np.diff(np.r_[starts, m]))
    acc = [c[cell_of] for c in _add_rows(na[full], _take(agg, nb[full]), n_cells)]
    part = ~full & (gap2 <= r2)
    na, nb = na[part], nb[part]

    # Straddling cell pairs: expand the query side to its seeds, then descend the other side's
    # nested cells (seed x cell) down to single seeds.
    counts = np.diff(np.r_[starts, m])
    seeds = ragged_arange(starts[na], counts[na])
    nb = np.repeat(nb, counts[na])
    for k in range(1, len(nodes)):
        first = np.searchsorted(nodes[k][0], np.r_[nodes[k - 1][0], m])
        n_child = np.diff(first)[nb]
        seeds = np.repeat(seeds, n_child)
        nb = ragged_arange(first[nb], n_child)
        _, agg, lo, hi = nodes[k]
        xq = _take(xs, seeds)
        gap2, span2 = _box_dist2(xq, xq, _take(lo, nb), _take(hi, nb))
        full = span2 <= r2
        for a, b in zip(acc, _add_rows(seeds[full], _take(agg, nb[full]), m)):
            a += b
        part = ~full & (gap2 <= r2)
        seeds, nb = seeds[part], nb[part]
    out = np.empty((m, 4))
    out[order] = np.stack(acc, axis=1)
    return out[:, 0], out[:, 1:]


def flat_kernel_means(points: np.ndarray, bandwidths: tuple[float, ...]) -> np.ndarray:
    """Flat-kernel shift targets ``D_j⁻¹ K_j X`` for every bandwidth candidate (paper eq. 3).

    Parameters
    ----------
    points : np.ndarray of shape (M, 3), float
        Seed positions X.
    bandwidths : tuple of float, length l
        Candidate radii δ_j > 0.

    Returns
    -------
    np.ndarray of shape (M, l, 3), float64
        Mean of the seeds within δ_j of each seed (self included, so never empty).
    """
    x = np.asarray(points, dtype=np.float64)
    out = np.empty((len(x), len(bandwidths), 3))
    for j, delta in enumerate(bandwidths):
        counts, sums = ball_sums(x, delta)
        out[:, j] = sums / np.maximum(counts, 1.0)[:, None]
    return out


def radius_pairs(points: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Directed neighbour pairs within ``radius`` (both directions and every self pair).

    Returns
    -------
    rows, cols : np.ndarray of shape (K,), int64
        ``‖points[rows] − points[cols]‖ ≤ radius``; rows are the query seeds.
    """
    x = np.asarray(points, dtype=np.float64)
    own = np.arange(len(x), dtype=np.int64)
    if len(x) < 2:
        return own, own.copy()
    pairs = cKDTree(x).query_pairs(float(radius), output_type="ndarray").astype(np.int64)
    rows = np.concatenate([pairs[:, 0], pairs[:, 1], own])
    cols = np.concatenate([pairs[:, 1], pairs[:, 0], own])
    return rows, cols


def gaussian_kernel_means(
    positions: torch.Tensor, bandwidth: torch.Tensor, cutoff: float = 3.0
) -> torch.Tensor:
    """Gaussian-kernel shift targets with a learned per-seed bandwidth (appendix eq. 19).

    ``target_i = Σ_j k_ij x_j / Σ_j k_ij`` with ``k_ij = exp(−‖x_i − x_j‖² / (2 δ_i²))`` for
    ``‖x_i − x_j‖ ≤ cutoff · δ_i`` and 0 beyond (the sparse truncation: at 3 δ a neighbour
    weighs exp(−4.5) ≈ 1.1 % of the seed itself). Positions are constants (detached); the
    gradient flows into ``bandwidth`` only, as the weights do for the flat kernel.

    Parameters
    ----------
    positions : torch.Tensor of shape (M, 3), float
    bandwidth : torch.Tensor of shape (M,), float, > 0
    cutoff : float
        Truncation radius in units of each seed's own bandwidth.

    Returns
    -------
    torch.Tensor of shape (M, 3), dtype and device of ``positions``
    """
    x = positions.detach()
    if len(x) == 0:  # keep the graph: the loss of an empty scan must still backpropagate
        return x.to(bandwidth.dtype) + 0.0 * bandwidth[:, None]
    xn = x.cpu().double().numpy()
    delta_max = float(bandwidth.detach().max())
    rows, cols = radius_pairs(xn, cutoff * delta_max)
    d2 = ((xn[rows] - xn[cols]) ** 2).sum(axis=1)
    keep = d2 <= (cutoff * bandwidth.detach().cpu().double().numpy()[rows]) ** 2
    rows_t = torch.from_numpy(rows[keep]).to(x.device)
    cols_t = torch.from_numpy(cols[keep]).to(x.device)
    d2_t = torch.from_numpy(d2[keep]).to(device=x.device, dtype=bandwidth.dtype)
    k = torch.exp(-d2_t / (2.0 * bandwidth[rows_t] ** 2))
    den = torch.zeros(len(x), dtype=k.dtype, device=x.device).index_add_(0, rows_t, k)
    num = torch.zeros(len(x), 3, dtype=k.dtype, device=x.device).index_add_(
        0, rows_t, k[:, None] * x[cols_t].to(k.dtype)
    )
    return (num / den[:, None]).to(positions.dtype)
