"""Functional kernels of dynamic shifting: exact radius sums without an M x M matrix.

The flat kernel of bandwidth δ maps a seed x_i to the mean of the seeds within distance δ of it
(itself included): ``mean_δ(X)[i] = Σ_{j: ‖x_i − x_j‖² ≤ δ²} x_j / #{j: ‖x_i − x_j‖² ≤ δ²}``.

All bandwidths are served by one pass of a numba kernel (:func:`ball_sums`): the seeds are hashed
to a uniform grid whose cell edge is the largest radius (sorted by cell key, so every cell and
every run of z-adjacent cells is a contiguous slice), and every seed scans the forward half of the
3 x 3 columns of z-adjacent cells around its own, computing each pair's squared distance once as
``(x_i − x_j)² + (y_i − y_j)² + (z_i − z_j)²`` in float64, exactly as the dense formulation does
(the value is symmetric in i and j). The pair is added to both seeds, in the ring of the smallest
radius that contains it; cumulative ring sums give the counts and coordinate sums of every ball.
No pair list is materialised, the neighbour sets are exactly those of ``d² ≤ δ²`` (inclusive,
self included) and only the summation order of the coordinate sums differs from a matrix product.

The Gaussian kernel of the direct-regression ablation (appendix eq. 19) uses the same grid with
the cell edge ``cutoff × max δ_i`` (see :func:`gaussian_kernel_means`); its gradient with respect
to the per-seed bandwidth comes from sums gathered in the same pass.

Threads: numba's default (``NUMBA_NUM_THREADS``, one per core) on the ``workqueue`` threading
layer unless ``NUMBA_THREADING_LAYER`` says otherwise (numba's OpenMP pool spins between
parallel regions and fights torch's for the cores; measured 15-20 % slower on 2 shared cores).
The workqueue layer must not be entered from two Python threads at once. The kernels are
compiled on first use and cached on disk (``cache=True``), so the compile cost is paid once per
machine.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numba
import numpy as np
import torch
from torch.autograd.function import once_differentiable

if "NUMBA_THREADING_LAYER" not in os.environ:
    numba.config.THREADING_LAYER = "workqueue"

#: Cell edge as a multiple of the largest radius: the margin keeps every pair with
#: ``d² ≤ δ²`` in adjacent cells despite the rounding of ``(x − min) / cell``.
CELL_MARGIN = 1.0 + 1e-6
#: Seeds per work item of the parallel loops (dynamic scheduling balances dense cells).
CHUNK = 64


def _compress(q: np.ndarray) -> np.ndarray:
    """Renumber occupied integer cell coordinates keeping adjacency: gaps > 1 become 2.

    Neighbouring cells stay neighbours and distant ones stay apart, while the coordinate range
    is bounded by ``2 M`` whatever the extent of the seeds (so keys never overflow int64).
    """
    u, inverse = np.unique(q, return_inverse=True)
    new = np.concatenate([[0], np.cumsum(np.minimum(np.diff(u), 2))])
    return new[inverse].reshape(q.shape)


@numba.njit(cache=True)
def _column_ranges(keys, cell_ijk, dims):  # pragma: no cover - compiled
    """Per occupied cell (i, j, k), the [start, end) slices of the sorted seeds in the 9 columns
    (i + a, j + b, k − 1 … k + 1), a, b ∈ {−1, 0, 1}, at index ``3 (a + 1) + (b + 1)``: the own
    column is 4 and the columns after it (5 … 8) are the forward half used by symmetric scans."""
    n_cells = cell_ijk.shape[0]
    nx, ny, nz = dims[0], dims[1], dims[2]
    ranges = np.zeros((n_cells, 9, 2), dtype=np.int64)
    for c in range(n_cells):
        i, j, k = cell_ijk[c, 0], cell_ijk[c, 1], cell_ijk[c, 2]
        k0, k1 = max(k - 1, 0), min(k + 1, nz - 1)
        for a in range(-1, 2):
            for b in range(-1, 2):
                if 0 <= i + a < nx and 0 <= j + b < ny:
                    base = ((i + a) * ny + j + b) * nz
                    q = 3 * (a + 1) + b + 1
                    ranges[c, q, 0] = np.searchsorted(keys, base + k0, side="left")
                    ranges[c, q, 1] = np.searchsorted(keys, base + k1, side="right")
    return ranges


def _grid(x: np.ndarray, cell: float):
    """Sort the seeds into a uniform grid of edge ``cell``.

    Returns
    -------
    order : (M,) int64, the permutation sorting the seeds by cell key
    xs : (M, 3) float64, the sorted seeds (C-contiguous)
    seed_cell : (M,) int64, cell number of every sorted seed
    ranges : (n_cells, 9, 2) int64, slices of the sorted seeds to scan for each cell
    """
    q = np.floor((x - x.min(axis=0)) / cell).astype(np.int64)
    q = np.stack([_compress(c) for c in q.T], axis=1)
    dims = q.max(axis=0) + 1
    keys = (q[:, 0] * dims[1] + q[:, 1]) * dims[2] + q[:, 2]
    order = np.argsort(keys, kind="stable")
    keys = keys[order]
    first = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    seed_cell = np.cumsum(np.r_[True, keys[1:] != keys[:-1]]) - 1
    ranges = _column_ranges(keys, np.ascontiguousarray(q[order][first]), dims.astype(np.int64))
    return order, np.ascontiguousarray(x[order]), seed_cell, ranges


@numba.njit(parallel=True, cache=True)
def _ball_kernel(xs, seed_cell, ranges, r2, acc):  # pragma: no cover - compiled
    """Ring sums ``acc[thread, seed, ring] += [1, x, y, z]`` over ascending squared radii ``r2``.

    Symmetric half scan: seed i visits the seeds after it in its own column and the forward
    columns, so every unordered pair's distance is computed once and added to both seeds (each
    thread into its own slice of ``acc``, summed by the caller).
    """
    m, n_r = xs.shape[0], r2.shape[0]
    outer = r2[n_r - 1]
    for i in numba.prange(m):
        t = numba.get_thread_id()
        own = np.zeros((n_r, 4))
        xi, yi, zi = xs[i, 0], xs[i, 1], xs[i, 2]
        own[0, 0], own[0, 1], own[0, 2], own[0, 3] = 1.0, xi, yi, zi  # self, d² = 0
        c = seed_cell[i]
        for q in range(4, 9):
            start = i + 1 if q == 4 else ranges[c, q, 0]
            for j in range(start, ranges[c, q, 1]):
                xj, yj, zj = xs[j, 0], xs[j, 1], xs[j, 2]
                dx = xi - xj
                dy = yi - yj
                dz = zi - zj
                d2 = dx * dx + dy * dy + dz * dz
                if d2 <= outer:
                    r = 0  # smallest ring containing the pair, without branches
                    for k in range(n_r - 1):
                        r += d2 > r2[k]
                    own[r, 0] += 1.0
                    own[r, 1] += xj
                    own[r, 2] += yj
                    own[r, 3] += zj
                    acc[t, j, r, 0] += 1.0
                    acc[t, j, r, 1] += xi
                    acc[t, j, r, 2] += yi
                    acc[t, j, r, 3] += zi
        for r in range(n_r):
            for d in range(4):
                acc[t, i, r, d] += own[r, d]


def _as_points(points) -> np.ndarray:
    x = np.ascontiguousarray(points, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"need points of shape (M, 3), got {x.shape}")
    if not np.isfinite(x).all():
        raise ValueError("points contain NaN or infinite coordinates")
    return x


def ball_sums(points: np.ndarray, radii: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Count and coordinate sum of the points within each radius of every point (self included).

    Parameters
    ----------
    points : np.ndarray of shape (M, 3), float
        Seed positions (converted to float64).
    radii : sequence of float, length l
        Ball radii δ_j > 0 in any order; point k is a neighbour of i for radius δ_j iff
        ``Σ_d (x_id − x_kd)² ≤ δ_j ** 2`` (float64, as the dense formulation).

    Returns
    -------
    counts : np.ndarray of shape (M, l), int64
        Number of neighbours (≥ 1: the point itself).
    sums : np.ndarray of shape (M, l, 3), float64
        Sum of the neighbours' coordinates.
    """
    x = _as_points(points)
    radii = np.asarray(radii, dtype=np.float64).reshape(-1)
    if len(radii) == 0 or radii.min() <= 0:
        raise ValueError(f"radii must be positive, got {radii.tolist()}")
    m, n_r = len(x), len(radii)
    if m == 0:
        return np.zeros((0, n_r), np.int64), np.zeros((0, n_r, 3))
    rank = np.argsort(radii, kind="stable")
    r2 = np.array([float(r) ** 2 for r in radii[rank]])
    order, xs, seed_cell, ranges = _grid(x, float(radii.max()) * CELL_MARGIN)
    acc = np.zeros((numba.get_num_threads(), m, n_r, 4))
    with numba.parallel_chunksize(CHUNK):
        _ball_kernel(xs, seed_cell, ranges, r2, acc)
    balls = np.cumsum(acc.sum(axis=0), axis=1)  # rings -> balls
    out = np.empty_like(balls)
    out[order[:, None], rank[None, :]] = balls
    return out[:, :, 0].astype(np.int64), out[:, :, 1:]


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
    counts, sums = ball_sums(points, bandwidths)
    return sums / np.maximum(counts, 1)[:, :, None]


@numba.njit(parallel=True, cache=True)
def _gaussian_kernel(xs, seed_cell, ranges, bw, cut2, out):  # pragma: no cover - compiled
    """Per seed: [Σk, Σk·Δx (3), Σk·d², Σk·d²·Δx (3)] with Δx = x_j − x_i, k = exp(−d²/2δ_i²)."""
    m = xs.shape[0]
    for i in numba.prange(m):
        xi, yi, zi = xs[i, 0], xs[i, 1], xs[i, 2]
        scale = -0.5 / (bw[i] * bw[i])
        c, lim = seed_cell[i], cut2[i]
        for q in range(9):
            for j in range(ranges[c, q, 0], ranges[c, q, 1]):
                dx = xs[j, 0] - xi
                dy = xs[j, 1] - yi
                dz = xs[j, 2] - zi
                d2 = dx * dx + dy * dy + dz * dz
                if d2 <= lim:
                    k = np.exp(d2 * scale)
                    kd = k * d2
                    out[i, 0] += k
                    out[i, 1] += k * dx
                    out[i, 2] += k * dy
                    out[i, 3] += k * dz
                    out[i, 4] += kd
                    out[i, 5] += kd * dx
                    out[i, 6] += kd * dy
                    out[i, 7] += kd * dz


def gaussian_sums(points: np.ndarray, bandwidth: np.ndarray, cutoff: float) -> np.ndarray:
    """Truncated Gaussian-kernel sums of every seed, relative to the seed itself.

    Parameters
    ----------
    points : np.ndarray of shape (M, 3), float
    bandwidth : np.ndarray of shape (M,), float, > 0
        Per-seed bandwidth δ_i; neighbours are the seeds with ``d² ≤ (cutoff · δ_i) ** 2``.
    cutoff : float

    Returns
    -------
    np.ndarray of shape (M, 8), float64
        ``[Σ k, Σ k Δx (3), Σ k d², Σ k d² Δx (3)]`` with ``Δx = x_j − x_i`` and
        ``k = exp(−d² / (2 δ_i²))`` (self included: ``Σ k ≥ 1``).
    """
    x = _as_points(points)
    bw = np.ascontiguousarray(bandwidth, dtype=np.float64).reshape(-1)
    if len(bw) != len(x) or (len(bw) and not bw.min() > 0):
        raise ValueError("need one positive bandwidth per point")
    if not cutoff > 0:
        raise ValueError(f"cutoff must be positive, got {cutoff}")
    out = np.zeros((len(x), 8))
    if len(x) == 0:
        return out
    cut2 = (float(cutoff) * bw) ** 2
    order, xs, seed_cell, ranges = _grid(x, float(cutoff) * float(bw.max()) * CELL_MARGIN)
    sorted_out = np.zeros_like(out)
    with numba.parallel_chunksize(CHUNK):
        _gaussian_kernel(xs, seed_cell, ranges, bw[order], cut2[order], sorted_out)
    out[order] = sorted_out
    return out


class _GaussianShift(torch.autograd.Function):
    """``target_i = x_i + Σ k Δx / Σ k``; ``∂target_i/∂δ_i = (Σ k d² Δx − t_i Σ k d²) / (δ_i³ Σ k)``
    with ``t_i = target_i − x_i`` (from ``∂k/∂δ = k d² / δ³``); positions are constants."""

    @staticmethod
    def forward(ctx, bandwidth: torch.Tensor, points: np.ndarray, cutoff: float) -> torch.Tensor:
        bw = bandwidth.detach().cpu().double().numpy()
        s = torch.from_numpy(gaussian_sums(points, bw, cutoff))
        shift = s[:, 1:4] / s[:, :1]
        ctx.save_for_backward(torch.from_numpy(bw), s[:, :1], shift, s[:, 4:5], s[:, 5:8])
        target = torch.from_numpy(np.asarray(points, dtype=np.float64)) + shift
        return target.to(device=bandwidth.device, dtype=bandwidth.dtype)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad: torch.Tensor):
        bw, k_sum, shift, kd_sum, kd_shift = ctx.saved_tensors
        dt = (kd_shift - shift * kd_sum) / (bw[:, None] ** 3 * k_sum)
        g = (grad.detach().cpu().double() * dt).sum(dim=1)
        return g.to(device=grad.device, dtype=grad.dtype), None, None


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
    target = _GaussianShift.apply(bandwidth, x.cpu().double().numpy(), float(cutoff))
    return target.to(device=x.device, dtype=positions.dtype)
