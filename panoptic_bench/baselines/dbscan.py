"""DBSCAN on a uniform grid, label for label equal to :class:`sklearn.cluster.DBSCAN`.

Definition (scikit-learn's, Euclidean metric, no sample weights): ``a`` and ``b`` are neighbours
when ``sum((a - b) ** 2) <= eps ** 2`` (float64, summed over the features in order: the test of
sklearn's KD-tree leaves); a point is *core* when at least ``min_samples`` points, itself
included, are its neighbours. sklearn's ``dbscan_inner`` then visits the points in index order and
runs a depth-first search from every core point not yet labelled, labelling the core points it
reaches through core neighbours and every still unlabelled neighbour of those. Hence:

- clusters are the connected components of the core points (linked within ``eps``), numbered in
  the order of their lowest core index;
- a non-core point with core neighbours (border point) takes the *lowest* cluster number among
  them (the earliest search reaches it first); one without core neighbours is noise, ``-1``.

sklearn lists every neighbourhood (``radius_neighbors``), which explodes on dense regressed
centres (thousands of points within a few cm). Here, for 1 to 3 dimensions, nothing per pair is
stored:

1. points go to grid cells of side ``eps / sqrt(d)`` (shrunk by 1e-9), sorted by cell key, so
   that the points of one cell are mutually neighbours (checked on each cell's bounding box); the
   non-empty cells that may hold a neighbour of a cell are found by key lookup;
2. neighbour counts (a numba kernel): a cell with ``>= min_samples`` points makes all its points
   core at once; otherwise each point adds whole cells whose bounding box lies within ``eps`` of
   it, skips cells farther than ``eps`` and tests the rest point by point, stopping at
   ``min_samples``. The box bounds use the same float operations as the definition (rounding is
   monotone), so they decide exactly;
3. clusters (a numba kernel): union-find over cells, each cell's core points being one node; a
   pair of neighbouring cells is decided by the bounding boxes of their core points when they are
   entirely apart or entirely within ``eps``, else point by point, and only while the two cells
   are still in different components (the scheme of
   :mod:`~panoptic_bench.baselines.radius_graph`);
4. border points (a numba kernel): the lowest cluster number among core neighbours, with the same
   box shortcuts on each cell's core points.

Some inputs go to sklearn itself, so the labels stay identical: fewer than 12 points (sklearn's
``algorithm="auto"`` then searches by brute force, with distances from the dot-product expansion
that may round differently exactly at ``eps``), more than 3 dimensions, and coordinates the grid
cannot key (so far apart for ``eps`` that keys would overflow, or so large that rounding widens a
cell beyond ``eps``). The kernels are compiled on first use and cached on disk (``cache=True``).
"""

from __future__ import annotations

import numba
import numpy as np

from panoptic_bench.baselines.radius_graph import _half_offsets, grid_cells

__all__ = ["dbscan_labels"]

_SHRINK = 1 - 1e-9
#: Below this many points sklearn's ``algorithm="auto"`` uses brute force (``n_neighbors=5``
#: ``>= n // 2``), whose distances may differ from the definition by rounding: delegate.
_SKLEARN_BELOW = 12
_NO_LABEL = np.iinfo(np.int64).max


@numba.njit(cache=True)
def _box_d2(p, lo, hi):  # pragma: no cover - compiled
    """Squared distances from point ``p`` to the nearest and farthest corner of box ``lo..hi``."""
    near = 0.0
    far = 0.0
    for j in range(p.shape[0]):
        a = lo[j] - p[j]
        b = p[j] - hi[j]
        g = max(a, b, 0.0)
        near += g * g
        f = max(abs(p[j] - lo[j]), abs(p[j] - hi[j]))
        far += f * f
    return near, far


@numba.njit(cache=True)
def _d2(X, i, k):  # pragma: no cover - compiled
    s = 0.0
    for j in range(X.shape[1]):
        t = X[i, j] - X[k, j]
        s += t * t
    return s


@numba.njit(cache=True)
def _neighbour_cells(cells, off_keys, lo, hi, eps2):  # pragma: no cover - compiled
    """CSR lists of the non-empty cells at ``off_keys`` from each cell whose boxes may link."""
    n_cells = cells.shape[0]
    d = lo.shape[1]
    ptr = np.zeros(n_cells + 1, np.int64)
    idx = np.empty(n_cells * off_keys.shape[0], np.int64)
    m = 0
    for c in range(n_cells):
        for t in range(off_keys.shape[0]):
            want = cells[c] + off_keys[t]
            o = np.searchsorted(cells, want)
            if o >= n_cells or cells[o] != want:
                continue
            gap2 = 0.0
            for j in range(d):
                g = max(lo[o, j] - hi[c, j], lo[c, j] - hi[o, j], 0.0)
                gap2 += g * g
            if gap2 <= eps2:
                idx[m] = o
                m += 1
        ptr[c + 1] = m
    return ptr, idx[:m]


@numba.njit(cache=True)
def _core_mask(X, ends, lo, hi, nb_ptr, nb_idx, eps2, min_samples):  # pragma: no cover
    """Core flags of the cell-sorted points ``X`` (cell ``c`` holds ``ends[c]:ends[c + 1]``)."""
    n_cells = ends.shape[0] - 1
    core = np.zeros(X.shape[0], np.bool_)
    for c in range(n_cells):
        a, b = ends[c], ends[c + 1]
        if b - a >= min_samples:  # the cell's points are mutually neighbours (caller checked)
            core[a:b] = True
            continue
        for i in range(a, b):
            count = 0
            for m in range(nb_ptr[c], nb_ptr[c + 1]):
                o = nb_idx[m]
                near, far = _box_d2(X[i], lo[o], hi[o])
                if near > eps2:
                    continue
                if far <= eps2:
                    count += ends[o + 1] - ends[o]
                else:
                    for k in range(ends[o], ends[o + 1]):
                        if _d2(X, i, k) <= eps2:
                            count += 1
                if count >= min_samples:
                    break
            core[i] = count >= min_samples
    return core


@numba.njit(cache=True)
def _core_boxes(X, ends, core):  # pragma: no cover - compiled
    """Bounding box of each cell's core points (empty box ``inf..-inf`` when it has none)."""
    n_cells = ends.shape[0] - 1
    d = X.shape[1]
    clo = np.full((n_cells, d), np.inf)
    chi = np.full((n_cells, d), -np.inf)
    for c in range(n_cells):
        for i in range(ends[c], ends[c + 1]):
            if core[i]:
                for j in range(d):
                    clo[c, j] = min(clo[c, j], X[i, j])
                    chi[c, j] = max(chi[c, j], X[i, j])
    return clo, chi


@numba.njit(cache=True)
def _find(parent, i):  # pragma: no cover - compiled
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@numba.njit(cache=True)
def _core_components(X, ends, core, clo, chi, nb_ptr, nb_idx, eps2):  # pragma: no cover
    """Union-find root of every cell over the radius graph of the core points.

    Every cell's points are mutually neighbours (checked by the caller), so a cell's core points
    are one node. Cell pairs are decided by their core boxes when possible, else point by point.
    """
    n_cells = ends.shape[0] - 1
    d = X.shape[1]
    parent = np.arange(n_cells)
    for c in range(n_cells):
        if clo[c, 0] > chi[c, 0]:  # no core point
            continue
        for m in range(nb_ptr[c], nb_ptr[c + 1]):
            o = nb_idx[m]
            if o <= c or clo[o, 0] > chi[o, 0]:
                continue
            rc, ro = _find(parent, c), _find(parent, o)
            if rc == ro:
                continue
            near = 0.0
            far = 0.0
            for j in range(d):
                g = max(clo[o, j] - chi[c, j], clo[c, j] - chi[o, j], 0.0)
                near += g * g
                f = max(chi[o, j] - clo[c, j], chi[c, j] - clo[o, j])
                far += f * f
            if near > eps2:
                continue
            linked = far <= eps2
            i = ends[c]
            while not linked and i < ends[c + 1]:
                if core[i]:
                    nr, fr = _box_d2(X[i], clo[o], chi[o])
                    if fr <= eps2:
                        linked = True
                    elif nr <= eps2:
                        for k in range(ends[o], ends[o + 1]):
                            if core[k] and _d2(X, i, k) <= eps2:
                                linked = True
                                break
                i += 1
            if linked:
                parent[max(rc, ro)] = min(rc, ro)
    for c in range(n_cells):
        parent[c] = _find(parent, c)
    return parent


@numba.njit(cache=True)
def _border_labels(
    X, ends, core, labels, clo, chi, nb_ptr, nb_idx, eps2, no_label
):  # pragma: no cover
    """Give every non-core point the lowest label among its core neighbours (in place)."""
    n_cells = ends.shape[0] - 1
    cmin = np.full(n_cells, no_label)
    for c in range(n_cells):
        for i in range(ends[c], ends[c + 1]):
            if core[i]:
                cmin[c] = min(cmin[c], labels[i])
    for c in range(n_cells):
        for i in range(ends[c], ends[c + 1]):
            if core[i]:
                continue
            best = no_label
            for m in range(nb_ptr[c], nb_ptr[c + 1]):
                o = nb_idx[m]
                if cmin[o] >= best:  # no core point, or none can lower the label
                    continue
                near, far = _box_d2(X[i], clo[o], chi[o])
                if near > eps2:
                    continue
                if far <= eps2:
                    best = cmin[o]
                    continue
                for k in range(ends[o], ends[o + 1]):
                    if core[k] and labels[k] < best and _d2(X, i, k) <= eps2:
                        best = labels[k]
            labels[i] = best if best != no_label else -1


def _sklearn_labels(X: np.ndarray, eps: float, min_samples: int) -> tuple[np.ndarray, np.ndarray]:
    from sklearn.cluster import DBSCAN as _SkDBSCAN

    model = _SkDBSCAN(eps=eps, min_samples=min_samples).fit(X)
    core = np.zeros(len(X), bool)
    core[model.core_sample_indices_] = True
    return model.labels_.astype(np.int64), core


def dbscan_labels(X: np.ndarray, eps: float, min_samples: int) -> tuple[np.ndarray, np.ndarray]:
    """DBSCAN labels and core flags, identical to ``sklearn.cluster.DBSCAN(eps, min_samples)``.

    Parameters
    ----------
    X : array of shape (n_samples, n_features), float64, finite
    eps : float
        Neighbourhood radius, > 0 (inclusive).
    min_samples : int
        Neighbours (self included) of a core point, >= 1.

    Returns
    -------
    labels : ndarray of shape (n_samples,), int64
        Clusters ``0..K-1`` numbered by lowest core point, ``-1`` for noise (sklearn's ``labels_``).
    core : ndarray of shape (n_samples,), bool
        Core points (sklearn's ``core_sample_indices_`` as a mask).
    """
    X = np.ascontiguousarray(X, dtype=np.float64)
    if not eps > 0:
        raise ValueError(f"eps must be > 0, got {eps}")
    if int(min_samples) != min_samples or min_samples < 1:
        raise ValueError(f"min_samples must be an integer >= 1, got {min_samples}")
    min_samples = int(min_samples)
    n, d = X.shape
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, bool)
    if n < _SKLEARN_BELOW or d == 0 or d > 3:
        return _sklearn_labels(X, eps, min_samples)
    side = eps / np.sqrt(d) * _SHRINK
    half = _half_offsets(d)
    offsets = np.concatenate([np.zeros((1, d), np.int64), half, -half])
    k = int(np.abs(offsets).max())
    g = grid_cells(X, side, k)
    if g is None:  # keys would overflow
        return _sklearn_labels(X, eps, min_samples)
    order, ends, cells, mult, Xs, lo, hi = g.order, g.bounds, g.keys, g.mult, g.points, g.lo, g.hi
    n_cells = len(cells)
    eps2 = float(eps) ** 2
    if not (((hi - lo) ** 2).sum(1) <= eps2).all():
        # a cell wider than eps: rounding of huge coordinates against a tiny eps beat the margin
        return _sklearn_labels(X, eps, min_samples)
    # neighbour cells of every cell (itself first), boxes farther apart than eps dropped
    nb_ptr, nb_idx = _neighbour_cells(cells, offsets @ mult, lo, hi, eps2)
    core_s = _core_mask(Xs, ends, lo, hi, nb_ptr, nb_idx, eps2, min_samples)
    labels_s = np.full(n, -1, np.int64)
    if core_s.any():
        clo, chi = _core_boxes(Xs, ends, core_s)
        root = _core_components(Xs, ends, core_s, clo, chi, nb_ptr, nb_idx, eps2)
        # clusters numbered by their lowest core index (original order)
        comp = np.repeat(root, np.diff(ends))[core_s]
        first = np.full(n_cells, n, np.int64)
        np.minimum.at(first, comp, order[core_s])
        used = np.flatnonzero(first < n)
        rank = np.empty(n_cells, np.int64)
        rank[used[np.argsort(first[used])]] = np.arange(len(used))
        labels_s[core_s] = rank[comp]
        _border_labels(Xs, ends, core_s, labels_s, clo, chi, nb_ptr, nb_idx, eps2, _NO_LABEL)
    labels = np.empty(n, np.int64)
    labels[order] = labels_s
    core = np.empty(n, bool)
    core[order] = core_s
    return labels, core
