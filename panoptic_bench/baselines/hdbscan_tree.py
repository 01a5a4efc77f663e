"""HDBSCAN labels that are the same on every machine.

Why this exists: ``hdbscan.HDBSCAN`` sorts the edges of its minimum spanning tree with
``np.argsort`` (quicksort, not stable). From numpy 1.26 on, that sort runs the AVX-512
``x86-simd-sort`` kernel on CPUs that have AVX-512 and the scalar introsort elsewhere; the two
order *equal* edge weights differently. Regressed instance centres are full of equal
mutual-reachability distances (points shifted onto the same centre, equal core distances), and
the order in which tied edges enter the single-linkage tree changes the condensed tree and so
the selected clusters: the same input gave different HDBSCAN rows on an AVX-512 and an AVX2
machine.

:func:`hdbscan_labels` runs exactly the stages of ``hdbscan.HDBSCAN()`` for 3-D points (the
Borůvka kd-tree spanning tree that ``algorithm='best'`` picks, ``approx_min_span_tree=True``,
core distances on one thread), with one change: the edges are ordered by weight with a *stable*
sort, so tied edges keep the order the spanning-tree algorithm emitted them in and the result
is one defined array on every CPU. The labels are those of ``hdbscan.HDBSCAN()`` run with a
stable ``argsort``. The spanning tree itself is compiled code without CPU dispatch (the same on
every machine); a future ``hdbscan`` or scikit-learn kd-tree could change its tie choices, which
``tests/test_hostile_reproducible.py`` (rebuilding a committed table) would then report.
"""

from __future__ import annotations

import numpy as np

__all__ = ["hdbscan_labels", "spanning_tree_order"]

#: kd-tree leaf size of ``hdbscan.HDBSCAN`` (its default; Borůvka uses a third of it).
LEAF_SIZE = 40


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
    from hdbscan._hdbscan_boruvka import KDTreeBoruvkaAlgorithm
    from hdbscan._hdbscan_linkage import label
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
    kd = KDTree(X, metric="euclidean", leaf_size=LEAF_SIZE)
    boruvka = KDTreeBoruvkaAlgorithm(
        kd, k, metric="euclidean", leaf_size=LEAF_SIZE // 3, approx_min_span_tree=True, n_jobs=1
    )
    edges = boruvka.spanning_tree()
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
