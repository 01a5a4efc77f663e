"""Connected components of the radius graph without listing every close pair.

Definition (the naive one): points ``a`` and ``b`` are linked when
``sum((a - b) ** 2) <= radius ** 2`` (float64); clusters are the connected components, numbered
by their lowest point index.

Listing every linked pair (``cKDTree.query_pairs``) costs the number of pairs, which explodes on
dense regressed centres (a 20k-point scan whose instances collapse to a few spots has tens of
millions of pairs). Here, for up to 3 dimensions:

1. points go to grid cells of side ``radius / sqrt(d)`` (shrunk by 1e-9): two points of one cell
   are always linked, so a cell is one node;
2. pairs of non-empty cells close enough to hold a linked pair are found by key lookup;
3. the bounding boxes of the two cells' points decide most pairs: farther apart than ``radius``
   (no link) or entirely within ``radius`` (linked); both bounds use the same float arithmetic
   as the definition, so they are exact;
4. the remaining pairs are tested point by point, only while their cells are still in different
   components (union-find).

The result equals the naive definition exactly (tests compare against brute force).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = ["radius_components"]

_SHRINK = 1 - 1e-9
_CHUNK = 1 << 22  # elements of one brute-force distance block


def _number_by_first_point(labels: np.ndarray) -> np.ndarray:
    """Renumber component labels 0..K-1 in order of their lowest point index."""
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    return rank[inverse.ravel()]


def _pairs_components(X: np.ndarray, radius: float) -> np.ndarray:
    """Reference route: every close pair from ``cKDTree.query_pairs``."""
    n = len(X)
    pairs = cKDTree(X).query_pairs(radius, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), (n, n))
    return connected_components(graph, directed=False)[1].astype(np.int64)


def _half_offsets(d: int) -> np.ndarray:
    """Cell offsets that may hold a linked pair, one of each +/- pair (lexicographically > 0)."""
    k = int(np.floor(np.sqrt(d))) + 1
    out = []
    for o in itertools.product(range(-k, k + 1), repeat=d):
        gap = np.maximum(np.abs(o) - 1, 0)
        if o > (0,) * d and (gap**2).sum() <= d:
            out.append(o)
    return np.array(out, np.int64).reshape(-1, d)


def _linked(a: np.ndarray, b: np.ndarray, r2: float) -> bool:
    """Whether some point of ``a`` and some point of ``b`` are linked (brute force, chunked)."""
    step = max(1, _CHUNK // max(len(b), 1))
    for i in range(0, len(a), step):
        diff = a[i : i + step, None, :] - b[None, :, :]
        if ((diff**2).sum(-1) <= r2).any():
            return True
    return False


@dataclass(frozen=True)
class GridCells:
    """Points sorted by a uniform grid cell, with each occupied cell's extent.

    ``order`` sorts the points by cell key; cell ``c`` holds sorted points
    ``bounds[c]:bounds[c + 1]`` (``starts = bounds[:-1]``); ``keys`` (sorted) are the cells' integer keys, ``mult`` turns an
    integer cell offset into a key offset; ``lo``/``hi`` are the cells' tight bounding boxes.
    """

    order: np.ndarray
    starts: np.ndarray
    bounds: np.ndarray
    keys: np.ndarray
    mult: np.ndarray
    points: np.ndarray
    lo: np.ndarray
    hi: np.ndarray


def grid_cells(X: np.ndarray, side: float, margin: int) -> GridCells | None:
    """Hash the points of ``X`` (n, d) into cells of ``side``, keys padded by ``margin`` cells.

    Returns None when the integer keys would overflow (points very far apart for ``side``);
    callers then fall back to a pair-list route.
    """
    grid = np.floor((X - X.min(0)) / side)
    extent = grid.max(0) + 1 + 2 * margin
    if np.prod(extent) >= 2.0**62:
        return None
    grid = grid.astype(np.int64) + margin
    mult = np.cumprod(np.concatenate([[1], extent[:-1].astype(np.int64)]))
    key = grid @ mult
    order = np.argsort(key, kind="stable")
    skey = key[order]
    starts = np.flatnonzero(np.concatenate([[True], skey[1:] != skey[:-1]]))
    bounds = np.append(starts, len(X)).astype(np.int64)
    points = np.ascontiguousarray(X[order])
    lo = np.minimum.reduceat(points, starts, axis=0)
    hi = np.maximum.reduceat(points, starts, axis=0)
    return GridCells(order, starts, bounds, skey[starts], mult, points, lo, hi)


def radius_components(X: np.ndarray, radius: float) -> np.ndarray:
    """Cluster labels of the radius graph (definition in the module docstring).

    Parameters
    ----------
    X : array of shape (n_samples, n_features), float64, finite
    radius : float
        Linking distance, > 0 (inclusive).

    Returns
    -------
    ndarray of shape (n_samples,), int64
        Component of each point, 0..K-1 in order of the lowest point index.
    """
    X = np.asarray(X, dtype=np.float64)
    n, d = X.shape
    if n == 0:
        return np.zeros(0, np.int64)
    if d == 0 or d > 3:
        return _number_by_first_point(_pairs_components(X, radius))
    side = radius / np.sqrt(d) * _SHRINK
    offsets = _half_offsets(d)
    k = int(np.abs(offsets).max(initial=0))
    g = grid_cells(X, side, k)
    if g is None:  # keys would overflow: far-apart points, tiny radius
        return _number_by_first_point(_pairs_components(X, radius))
    order, starts, cells, mult, Xs, lo, hi = g.order, g.starts, g.keys, g.mult, g.points, g.lo, g.hi
    n_cells = len(cells)
    cell_of = np.empty(n, np.int64)
    cell_of[order] = np.repeat(np.arange(n_cells), np.diff(np.append(starts, n)))
    # candidate cell pairs
    a = np.repeat(np.arange(n_cells), len(offsets))
    want = cells[a] + np.tile(offsets @ mult, n_cells)
    pos = np.minimum(np.searchsorted(cells, want), n_cells - 1)
    hit = cells[pos] == want
    a, b = a[hit], pos[hit]
    r2 = float(radius) ** 2
    gap = np.maximum(np.maximum(lo[b] - hi[a], lo[a] - hi[b]), 0)
    far = np.maximum(hi[b] - lo[a], hi[a] - lo[b])
    near = (gap**2).sum(1) <= r2
    sure = near & ((far**2).sum(1) <= r2)
    graph = coo_matrix((np.ones(sure.sum(), np.int8), (a[sure], b[sure])), (n_cells, n_cells))
    comp = connected_components(graph, directed=False)[1]
    undecided = near & ~sure
    a, b = a[undecided], b[undecided]
    keep = comp[a] != comp[b]
    parent = np.arange(comp.max() + 1)

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    ends = np.append(starts, n)
    for ca, cb in zip(a[keep].tolist(), b[keep].tolist()):
        ra, rb = find(comp[ca]), find(comp[cb])
        if ra != rb and _linked(Xs[ends[ca] : ends[ca + 1]], Xs[ends[cb] : ends[cb + 1]], r2):
            parent[max(ra, rb)] = min(ra, rb)
    roots = np.array([find(i) for i in range(len(parent))])
    return _number_by_first_point(roots[comp][cell_of])
