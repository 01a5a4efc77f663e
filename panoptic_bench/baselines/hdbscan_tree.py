"""HDBSCAN labels that are the same on every machine.

Why this exists: ``hdbscan.HDBSCAN`` sorts the edges of its minimum spanning tree with
``np.argsort`` (quicksort, not stable). From numpy 1.26 on, that sort runs the AVX-512
``x86-simd-sort`` kernel on CPUs that have AVX-512 and the scalar introsort elsewhere; the two
order *equal* edge weights differently. Regressed instance centres are full of equal
mutual-reachability distances (points shifted onto the same centre, equal core distances), and
the order in which tied edges enter the single-linkage tree changes the condensed tree and so
the selected clusters: the same input gave different HDBSCAN rows on an AVX-512 and an AVX2
machine. The Borůvka spanning tree ``hdbscan`` picks by default (``algorithm='best'``) adds a
second dependence, on the kd-tree layout of the installed scikit-learn.

:func:`hdbscan_labels` runs the same stages with every order fixed: core distances from an exact
k-nearest-neighbour query, the exact spanning tree of Prim's algorithm (``hdbscan``'s own
``mst_linkage_core_vector``; deterministic for a given point order), edges ordered by weight
with a *stable* sort (tied edges keep the order Prim's algorithm found them in: one defined
result on every CPU), then ``hdbscan``'s condensed tree and excess-of-mass selection. The labels
are exactly those of ``hdbscan.HDBSCAN(algorithm='prims_kdtree')`` run with a stable sort.
"""

from __future__ import annotations

import numpy as np

__all__ = ["hdbscan_labels", "spanning_tree_order"]


def spanning_tree_order(edges: np.ndarray) -> np.ndarray:
    """Order of minimum-spanning-tree edges by weight; tied edges keep their order.

    Parameters
    ----------
    edges : ndarray of shape (n_edges, 3), float64
        Rows ``(a, b, weight)`` as ``hdbscan``'s spanning-tree routines return them.

    Returns
    -------
    ndarray of shape (n_edges,), int64
        Stable sort by ``weight``: unique for any input, hence identical on every machine
        (``np.argsort``'s default quicksort orders ties by CPU: AVX-512 kernel or introsort).
    """
    return np.argsort(edges[:, 2], kind="stable")


def hdbscan_labels(
    X: np.ndarray,
    min_cluster_size: int = 5,
    min_samples: int | None = None,
    cluster_selection_epsilon: float = 0.0,
    allow_single_cluster: bool = False,
) -> np.ndarray:
    """HDBSCAN (excess of mass, Euclidean) with a machine-independent spanning-tree order.

    Parameters
    ----------
    X : ndarray of shape (n_samples, n_features), float
        Finite points, ``n_samples >= 2``.
    min_cluster_size : int
        Smallest cluster (>= 2).
    min_samples : int, optional
        Neighbours of the core distance (default ``min_cluster_size``; capped at
        ``n_samples - 1`` as in ``hdbscan``).
    cluster_selection_epsilon : float
        Clusters closer than this (>= 0) are merged.
    allow_single_cluster : bool
        Allow one cluster as the result.

    Returns
    -------
    ndarray of shape (n_samples,), int64
        Cluster ids ``0..K-1``; ``-1`` marks noise.
    """
    from hdbscan._hdbscan_linkage import label, mst_linkage_core_vector
    from hdbscan.dist_metrics import DistanceMetric
    from hdbscan.hdbscan_ import _tree_to_labels
    from sklearn.neighbors import KDTree

    X = np.ascontiguousarray(X, dtype=np.float64)
    n = len(X)
    if n < 2:
        raise ValueError(f"HDBSCAN needs at least 2 points, got {n}")
    if int(min_cluster_size) < 2:
        raise ValueError(f"min_cluster_size must be >= 2, got {min_cluster_size}")
    k = int(min_cluster_size if min_samples is None else min_samples)
    if k < 1:
        raise ValueError(f"min_samples must be >= 1, got {min_samples}")
    if not cluster_selection_epsilon >= 0:
        raise ValueError(f"cluster_selection_epsilon must be >= 0, got {cluster_selection_epsilon}")
    k = max(1, min(n - 1, k))
    core = KDTree(X, metric="euclidean").query(X, k=k + 1)[0][:, -1].copy(order="C")
    edges = mst_linkage_core_vector(X, core, DistanceMetric.get_metric("euclidean"), 1.0)
    tree = label(np.ascontiguousarray(edges[spanning_tree_order(edges)]))
    labels = _tree_to_labels(
        X,
        tree,
        int(min_cluster_size),
        "eom",
        bool(allow_single_cluster),
        False,
        float(cluster_selection_epsilon),
    )[0]
    return np.asarray(labels, dtype=np.int64)
