"""Fast flat-kernel mean shift, cluster-for-cluster equal to :class:`sklearn.cluster.MeanShift`.

scikit-learn shifts one seed at a time in Python (one ball-tree query per seed per iteration).
Here every unconverged seed is shifted at once per iteration:

1. neighbour lists of all current seed positions come from one KD-tree radius query
   (:meth:`scipy.spatial.cKDTree.query_pairs` on the first iteration when every point is a seed,
   :meth:`~scipy.spatial.cKDTree.sparse_distance_matrix` afterwards), never an N×N dense matrix;
2. neighbour sums and counts are sparse products (``np.bincount`` over the pair lists);
3. seeds whose balls hold exactly the same set of points get exactly the same new position
   (the sets are identified by their count and an exact integer hash of the member indices), so
   from then on they are shifted once. Converging seeds collapse quickly, and later iterations
   touch only a handful of distinct positions.

The rules are sklearn's (``sklearn/cluster/_mean_shift.py``, version 1.9):

- a seed stops when its shift is ``<= 1e-3 * bandwidth``, after ``max_iter`` iterations, or when
  its ball is empty (it is then discarded); its *intensity* is the number of points in the ball
  at its last position before the final shift;
- converged positions are de-duplicated exactly (the last seed's intensity wins), sorted by
  ``(intensity, coordinates)`` descending, and a position is kept unless it lies within
  ``bandwidth`` of an already kept one;
- every point takes the label of its nearest kept mode; with ``cluster_all=False`` points
  farther than ``bandwidth`` from every mode are orphans;
- ``bin_seeding=True`` seeds from the grid ``round(X / bandwidth)`` (bins holding at least
  ``min_bin_freq`` points, in order of first occurrence, as float32 times the bandwidth); when
  binning leaves as many seeds as points, the points themselves are the seeds.

Arithmetic is float64 throughout (sklearn keeps float32 inputs in float32), so centres agree to
rounding, and labels agree except for points equidistant to two modes.
"""

from __future__ import annotations

import warnings
from enum import StrEnum

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["MeanShift", "Noise", "get_bin_seeds", "resolve_noise"]

_HASH_SEED = 0x5EED


class Noise(StrEnum):
    """What becomes of points an algorithm calls noise (DBSCAN/HDBSCAN ``-1``, mean-shift orphans).

    ``SINGLETON``: each noise point becomes its own one-point cluster (panoptic assembly then
    drops it through ``min_points``, so it ends with no instance). ``NEAREST``: each noise point
    joins the cluster of its nearest clustered point (all points noise → singletons).
    """

    SINGLETON = "singleton"
    NEAREST = "nearest"


def resolve_noise(X: np.ndarray, labels: np.ndarray, noise: Noise) -> np.ndarray:
    """Replace the ``-1`` labels of ``labels`` according to ``noise``.

    Parameters
    ----------
    X : array of shape (n, d), float
        The clustered points.
    labels : array of shape (n,), int
        Cluster ids ``0..K-1`` and ``-1`` for noise.
    noise : Noise
        Policy (see :class:`Noise`).

    Returns
    -------
    ndarray of shape (n,), int64
        Labels ``0..K'-1``; non-noise points keep their label, singletons are numbered after them
        in point order.
    """
    labels = np.asarray(labels, dtype=np.int64).copy()
    is_noise = labels < 0
    if not is_noise.any():
        return labels
    noise = Noise(noise)
    k = int(labels.max()) + 1 if (~is_noise).any() else 0
    if noise is Noise.NEAREST and k > 0:
        _, idx = cKDTree(X[~is_noise]).query(X[is_noise], k=1)
        labels[is_noise] = labels[~is_noise][idx]
    else:
        labels[is_noise] = k + np.arange(int(is_noise.sum()))
    return labels


def get_bin_seeds(X: np.ndarray, bin_size: float, min_bin_freq: int = 1) -> np.ndarray:
    """Seeds on the grid ``round(X / bin_size)``, exactly as ``sklearn.cluster.get_bin_seeds``.

    Parameters
    ----------
    X : array of shape (n, d), float32 or float64
        Points (binned in their own dtype, as sklearn does).
    bin_size : float
        Grid spacing (the bandwidth).
    min_bin_freq : int
        Bins with fewer points give no seed.

    Returns
    -------
    ndarray of shape (n_seeds, d)
        float32 bin centres in order of first occurrence, or ``X`` itself (with a warning) when
        binning leaves one seed per point.
    """
    if bin_size == 0:
        return X
    binned = np.round(X / bin_size) + 0.0  # + 0.0 folds -0.0 into 0.0, as dict keys do
    _, first, counts = np.unique(binned, axis=0, return_index=True, return_counts=True)
    order = np.argsort(first, kind="stable")
    keep = order[counts[order] >= min_bin_freq]
    seeds = binned[first[keep]].astype(np.float32)
    if len(seeds) == len(X):
        warnings.warn(
            f"Binning data failed with provided bin_size={bin_size:f}, using data points as seeds.",
            stacklevel=2,
        )
        return X
    return seeds * np.float32(bin_size)


class _Neighbours:
    """Radius-ball statistics (count, coordinate sum, exact set hash) over fixed points."""

    def __init__(self, X: np.ndarray, radius: float) -> None:
        self.X = X
        self.columns = np.ascontiguousarray(X.T)  # fast per-coordinate gathers
        self.radius = radius
        self.tree = cKDTree(X)
        # integer weights whose sums stay exact in float64 (< 2**52 for any subset)
        high = max(2, (1 << 52) // max(len(X), 1))
        rng = np.random.default_rng(_HASH_SEED)
        self.weights = rng.integers(1, high, size=len(X)).astype(np.float64)

    def _reduce(self, rows: np.ndarray, cols: np.ndarray, m: int):
        counts = np.bincount(rows, minlength=m)
        sums = np.stack(
            [np.bincount(rows, weights=column[cols], minlength=m) for column in self.columns],
            axis=1,
        )
        hashes = np.bincount(rows, weights=self.weights[cols], minlength=m)
        return counts, sums, hashes

    def at_points(self):
        """Statistics of the balls centred on every point (self-join, pairs i < j listed once)."""
        pairs = self.tree.query_pairs(self.radius, output_type="ndarray")
        n = len(self.X)
        rows = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(n)])
        cols = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(n)])
        return self._reduce(rows, cols, n)

    def at(self, positions: np.ndarray):
        """Statistics of the balls centred on ``positions`` (shape (m, d))."""
        found = cKDTree(positions).sparse_distance_matrix(
            self.tree, self.radius, output_type="ndarray"
        )
        return self._reduce(
            found["i"].astype(np.int64), found["j"].astype(np.int64), len(positions)
        )


def _group_sets(counts: np.ndarray, hashes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Group positions whose balls hold the same point set: (group of each, first member of each)."""
    key = np.stack([counts.astype(np.float64), hashes], axis=1)
    _, first, group = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return group.reshape(-1), first


def _shift_seeds(nbrs: _Neighbours, seeds: np.ndarray, seeds_are_points: bool, max_iter: int):
    """Shift all seeds to convergence; returns (final positions, intensities, iterations)."""
    n_seeds, dim = seeds.shape
    final = np.zeros((n_seeds, dim))
    intensity = np.zeros(n_seeds, dtype=np.int64)
    n_iter = np.zeros(n_seeds, dtype=np.int64)
    stop_thresh = 1e-3 * nbrs.radius
    if seeds_are_points:
        positions, seed_pos = nbrs.X, np.arange(n_seeds)
    else:
        positions, seed_pos = np.unique(seeds, axis=0, return_inverse=True)
        seed_pos = seed_pos.reshape(-1)
    active = np.arange(n_seeds)
    first = True
    for k in range(max_iter + 1):
        counts, sums, hashes = (
            nbrs.at_points() if first and seeds_are_points else nbrs.at(positions)
        )
        first = False
        group, rep = _group_sets(counts, hashes)
        with np.errstate(invalid="ignore", divide="ignore"):
            means = sums[rep] / counts[rep, None]
        pos = seed_pos[active]
        old = positions[pos]
        new = means[group[pos]]
        cnt = counts[pos]
        empty = cnt == 0
        shift = np.linalg.norm(new - old, axis=1)
        done = empty | (shift <= stop_thresh) | (k == max_iter)
        ok = done & ~empty
        final[active[ok]] = new[ok]
        intensity[active[ok]] = cnt[ok]
        n_iter[active[done]] = k
        active = active[~done]
        if not active.size:
            break
        used, inverse = np.unique(group[seed_pos[active]], return_inverse=True)
        positions = means[used]
        seed_pos = np.empty(n_seeds, dtype=np.int64)
        seed_pos[active] = inverse.reshape(-1)
    return final, intensity, n_iter


def _select_modes(final: np.ndarray, intensity: np.ndarray, bandwidth: float) -> np.ndarray:
    """sklearn's mode selection: exact de-dup, sort by (intensity, coords) desc, greedy suppression."""
    valid = np.flatnonzero(intensity > 0)
    centers, inverse = np.unique(final[valid], axis=0, return_inverse=True)
    last = np.full(len(centers), -1, dtype=np.int64)
    np.maximum.at(last, inverse.reshape(-1), valid)  # the last seed's intensity wins
    strength = intensity[last]
    keys = [centers[:, d] for d in range(centers.shape[1] - 1, -1, -1)] + [strength]
    order = np.lexsort(keys)[::-1]
    centers = centers[order]
    pairs = cKDTree(centers).query_pairs(bandwidth, output_type="ndarray")
    unique = np.ones(len(centers), dtype=bool)
    if len(pairs):
        # pairs hold i < j; the earlier (stronger) centre suppresses the later one if still kept
        pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
        starts = np.searchsorted(pairs[:, 0], np.arange(len(centers) + 1))
        later = pairs[:, 1]
        for i in np.unique(pairs[:, 0]):
            if unique[i]:
                unique[later[starts[i] : starts[i + 1]]] = False
    return centers[unique]


class MeanShift:
    """Mean shift clustering with a flat kernel; sklearn's algorithm, vectorised.

    Parameters
    ----------
    bandwidth : float
        Radius of the flat kernel (metres for regressed centres). Must be > 0.
    bin_seeding : bool
        Seed from the bandwidth-spaced grid instead of from every point (what DS-Net's
        official code uses).
    min_bin_freq : int
        With ``bin_seeding``, only bins with at least this many points give seeds.
    cluster_all : bool
        If True every point takes its nearest mode. If False, points farther than
        ``bandwidth`` from every mode are orphans and handled by ``noise``.
    max_iter : int
        Maximum number of shifts per seed.
    noise : Noise
        Fate of orphans when ``cluster_all=False`` (default: one singleton cluster each).

    Attributes
    ----------
    labels_ : ndarray of shape (n_samples,), int64
        Cluster ids ``0..K-1``; id ``i < len(cluster_centers_)`` is mode ``i`` (modes sorted by
        intensity as in sklearn), orphans get the ids after them.
    cluster_centers_ : ndarray of shape (n_modes, n_features), float64
    noise_mask_ : ndarray of shape (n_samples,), bool
        Orphans (always False with ``cluster_all=True``).
    n_iter_ : int
        Maximum number of iterations performed on a seed.

    Examples
    --------
    >>> X = np.array([[1, 1], [2, 1], [1, 0], [4, 7], [3, 5], [3, 6]])
    >>> MeanShift(bandwidth=2).fit(X).labels_
    array([1, 1, 1, 0, 0, 0])
    """

    def __init__(
        self,
        bandwidth: float,
        *,
        bin_seeding: bool = False,
        min_bin_freq: int = 1,
        cluster_all: bool = True,
        max_iter: int = 300,
        noise: Noise = Noise.SINGLETON,
    ) -> None:
        self.bandwidth = bandwidth
        self.bin_seeding = bin_seeding
        self.min_bin_freq = min_bin_freq
        self.cluster_all = cluster_all
        self.max_iter = max_iter
        self.noise = noise

    def __repr__(self) -> str:
        return f"MeanShift(bandwidth={self.bandwidth}, bin_seeding={self.bin_seeding})"

    def fit(self, X: np.ndarray, y: None = None) -> MeanShift:
        """Cluster ``X`` (array of shape (n_samples, n_features)); returns self."""
        if not self.bandwidth > 0:
            raise ValueError(f"bandwidth must be > 0, got {self.bandwidth}")
        if self.max_iter < 0 or self.min_bin_freq < 1:
            raise ValueError("max_iter must be >= 0 and min_bin_freq >= 1")
        X_in = np.asarray(X)
        if X_in.ndim != 2:
            raise ValueError(f"X must have shape (n_samples, n_features), got {X_in.shape}")
        if X_in.dtype not in (np.float32, np.float64):
            X_in = X_in.astype(np.float64)
        if not np.isfinite(X_in).all():
            raise ValueError("X contains NaN or infinite values")
        X64 = X_in.astype(np.float64)
        n = len(X64)
        self.noise_mask_ = np.zeros(n, dtype=bool)
        self.n_iter_ = 0
        if n == 0:
            self.labels_ = np.zeros(0, dtype=np.int64)
            self.cluster_centers_ = np.zeros((0, X64.shape[1]))
            return self
        bandwidth = float(self.bandwidth)
        seeds: np.ndarray = X_in
        if self.bin_seeding:
            seeds = get_bin_seeds(X_in, bandwidth, self.min_bin_freq)
        seeds_are_points = seeds is X_in
        if not len(seeds):
            raise ValueError(f"no bin holds min_bin_freq={self.min_bin_freq} points; lower it")
        nbrs = _Neighbours(X64, bandwidth)
        final, intensity, n_iter = _shift_seeds(
            nbrs, seeds.astype(np.float64), seeds_are_points, int(self.max_iter)
        )
        self.n_iter_ = int(n_iter.max())
        if not (intensity > 0).any():
            raise ValueError(
                f"No point was within bandwidth={bandwidth:f} of any seed; increase the bandwidth."
            )
        centers = _select_modes(final, intensity, bandwidth)
        dist, idx = cKDTree(centers).query(X64, k=1)
        labels = idx.astype(np.int64)
        if not self.cluster_all:
            orphan = dist > bandwidth
            labels[orphan] = -1
            self.noise_mask_ = orphan
            labels = resolve_noise(X64, labels, Noise(self.noise))
        self.cluster_centers_ = centers
        self.labels_ = labels
        return self

    def fit_predict(self, X: np.ndarray, y: None = None) -> np.ndarray:
        """``fit(X).labels_``."""
        return self.fit(X).labels_
