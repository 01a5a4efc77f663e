"""Heuristic clusterings of regressed instance centres (appendix §1 of the DS-Net paper).

Each estimator is small and scikit-learn shaped: ``__init__`` stores hyper-parameters, ``fit(X)``
returns ``self`` and sets ``labels_`` (int64, ``0..K-1``), ``fit_predict(X)`` returns them.
``-1`` never leaks out: points that DBSCAN/HDBSCAN call noise (and mean-shift orphans with
``cluster_all=False``) are resolved by the ``noise`` policy (:class:`Noise`): by default each
becomes a one-point cluster, which panoptic assembly then drops through ``min_points`` (so a noise
point ends without an instance); ``Noise.NEAREST`` attaches it to its nearest clustered point
instead. ``noise_mask_`` always marks the points the algorithm itself called noise.

Paper presets (appendix §4) are module constants; :func:`make_clusterer` builds an estimator
from a method name and keyword parameters (used by the CLI).
"""

from __future__ import annotations

from enum import StrEnum
from typing import Any, Protocol

import numpy as np

from panoptic_bench.baselines.meanshift import MeanShift, Noise, resolve_noise
from panoptic_bench.baselines.radius_graph import radius_components

__all__ = [
    "BACKBONE_MEANSHIFT_BANDWIDTH",
    "BFS",
    "DBSCAN",
    "DS_MEANSHIFT_BANDWIDTH_SEMANTICKITTI",
    "DS_BFS_RADIUS_NUSCENES",
    "HDBSCAN",
    "MIN_POINTS_NUSCENES",
    "MIN_POINTS_SEMANTICKITTI",
    "Clusterer",
    "Method",
    "MeanShift",
    "Noise",
    "make_clusterer",
]

#: Mean-shift bandwidth of the DS-Net backbone ("Backbone with Fusion"), metres.
BACKBONE_MEANSHIFT_BANDWIDTH = 1.2
#: Final mean shift after dynamic shifting on SemanticKITTI, metres.
DS_MEANSHIFT_BANDWIDTH_SEMANTICKITTI = 0.65
#: Final BFS radius after dynamic shifting on nuScenes, metres.
DS_BFS_RADIUS_NUSCENES = 1.2
#: Minimum number of points of a valid predicted instance.
MIN_POINTS_SEMANTICKITTI = 50
MIN_POINTS_NUSCENES = 5


class Clusterer(Protocol):
    """Anything with ``fit_predict(X) -> labels`` (labels ``0..K-1``, shape (n,))."""

    def fit_predict(self, X: np.ndarray) -> np.ndarray: ...


def _check_points(X: np.ndarray) -> np.ndarray:
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 2:
        raise ValueError(f"X must have shape (n_samples, n_features), got {X.shape}")
    if not np.isfinite(X).all():
        raise ValueError("X contains NaN or infinite values")
    return X


class _Estimator:
    """Shared ``fit_predict`` and ``repr`` (hyper-parameters are the ``__init__`` arguments)."""

    _params: tuple[str, ...] = ()

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={getattr(self, k)!r}" for k in self._params)
        return f"{type(self).__name__}({args})"

    def fit(self, X: np.ndarray, y: None = None) -> _Estimator:  # pragma: no cover - abstract
        raise NotImplementedError

    def fit_predict(self, X: np.ndarray, y: None = None) -> np.ndarray:
        """``fit(X).labels_``: array of shape (n_samples,), int64."""
        return self.fit(X).labels_


class BFS(_Estimator):
    """Connected components of the radius graph (PointGroup's BFS clustering).

    Points closer than ``radius`` (inclusive) are linked; each connected component is a cluster.
    Components are numbered by their lowest point index. There is no noise: an isolated point is
    its own cluster. Computed without listing every close pair
    (:func:`~panoptic_bench.baselines.radius_graph.radius_components`: grid cells of side
    ``radius / sqrt(d)`` merged first, exact same components).

    Parameters
    ----------
    radius : float
        Linking distance, > 0.

    Attributes
    ----------
    labels_ : ndarray of shape (n_samples,), int64
    noise_mask_ : ndarray of shape (n_samples,), bool (all False)
    """

    _params = ("radius",)

    def __init__(self, radius: float) -> None:
        self.radius = radius

    def fit(self, X: np.ndarray, y: None = None) -> BFS:
        """Cluster ``X`` (array of shape (n_samples, n_features)); returns self."""
        if not self.radius > 0:
            raise ValueError(f"radius must be > 0, got {self.radius}")
        X = _check_points(X)
        n = len(X)
        self.noise_mask_ = np.zeros(n, dtype=bool)
        if n == 0:
            self.labels_ = np.zeros(0, dtype=np.int64)
            return self
        self.labels_ = radius_components(X, self.radius)
        return self


class DBSCAN(_Estimator):
    """DBSCAN with noise resolved by ``noise``; before that, labels equal to sklearn's.

    :func:`~panoptic_bench.baselines.dbscan.dbscan_labels` computes exactly the ``labels_`` of
    ``sklearn.cluster.DBSCAN(eps=eps, min_samples=min_samples)`` (same core points, clusters
    numbered by lowest core point, a border point next to several clusters in the lowest-numbered
    one) on a grid with numba kernels, without listing neighbourhoods: dense regressed centres
    cost milliseconds instead of seconds.

    Parameters
    ----------
    eps : float
        Neighbourhood radius (> 0, inclusive).
    min_samples : int
        Points (self included) within ``eps`` needed for a core point (>= 1).
    noise : Noise
        Fate of the points DBSCAN labels ``-1`` (default: one singleton cluster each).

    Attributes
    ----------
    labels_ : ndarray of shape (n_samples,), int64
        sklearn's clusters ``0..K-1`` first, then the resolved noise points.
    noise_mask_ : ndarray of shape (n_samples,), bool
    core_sample_indices_ : ndarray of shape (n_core_samples,), int64
        Indices of the core points (as in sklearn).
    """

    _params = ("eps", "min_samples", "noise")

    def __init__(self, eps: float = 0.5, min_samples: int = 5, noise: Noise = Noise.SINGLETON):
        self.eps = eps
        self.min_samples = min_samples
        self.noise = noise

    def fit(self, X: np.ndarray, y: None = None) -> DBSCAN:
        """Cluster ``X`` (array of shape (n_samples, n_features)); returns self."""
        from panoptic_bench.baselines.dbscan import dbscan_labels  # numba: imported when used

        X = _check_points(X)
        raw, core = dbscan_labels(X, self.eps, self.min_samples)
        self.core_sample_indices_ = np.flatnonzero(core)
        self.noise_mask_ = raw < 0
        self.labels_ = resolve_noise(X, raw, Noise(self.noise))
        return self


class HDBSCAN(_Estimator):
    """HDBSCAN (the ``hdbscan`` package's stages) with noise resolved by ``noise``.

    Labels come from :func:`~panoptic_bench.baselines.hdbscan_tree.hdbscan_labels`: the stages
    of ``hdbscan.HDBSCAN()`` with a stable edge sort, so they are the same on every machine
    (plain ``hdbscan.HDBSCAN`` orders tied edges differently on AVX-512 and other CPUs).

    Parameters
    ----------
    min_cluster_size : int
        Smallest cluster size (>= 2).
    min_samples : int, optional
        Core-distance neighbours (defaults to ``min_cluster_size``, as in ``hdbscan``).
    cluster_selection_epsilon : float
        Clusters closer than this are merged.
    allow_single_cluster : bool
        Allow a single cluster as the result.
    noise : Noise
        Fate of the points HDBSCAN labels ``-1`` (default: one singleton cluster each).

    Attributes
    ----------
    labels_ : ndarray of shape (n_samples,), int64
    noise_mask_ : ndarray of shape (n_samples,), bool
    """

    _params = (
        "min_cluster_size",
        "min_samples",
        "cluster_selection_epsilon",
        "allow_single_cluster",
        "noise",
    )

    def __init__(
        self,
        min_cluster_size: int = 5,
        min_samples: int | None = None,
        cluster_selection_epsilon: float = 0.0,
        allow_single_cluster: bool = False,
        noise: Noise = Noise.SINGLETON,
    ) -> None:
        self.min_cluster_size = min_cluster_size
        self.min_samples = min_samples
        self.cluster_selection_epsilon = cluster_selection_epsilon
        self.allow_single_cluster = allow_single_cluster
        self.noise = noise

    def fit(self, X: np.ndarray, y: None = None) -> HDBSCAN:
        """Cluster ``X`` (array of shape (n_samples, n_features)); returns self."""
        X = _check_points(X)
        n = len(X)
        if n == 0:
            raw = np.zeros(0, dtype=np.int64)
        elif n < max(2, self.min_samples or self.min_cluster_size):
            raw = np.full(n, -1, dtype=np.int64)  # hdbscan cannot run: every point is noise
        else:
            from panoptic_bench.baselines.hdbscan_tree import hdbscan_labels

            raw = hdbscan_labels(
                X,
                min_cluster_size=self.min_cluster_size,
                min_samples=self.min_samples,
                cluster_selection_epsilon=self.cluster_selection_epsilon,
                allow_single_cluster=self.allow_single_cluster,
            )
        self.noise_mask_ = raw < 0
        self.labels_ = resolve_noise(X, raw, Noise(self.noise))
        return self


class Method(StrEnum):
    """Clustering methods selectable by name (CLI ``--method``)."""

    BFS = "bfs"
    DBSCAN = "dbscan"
    HDBSCAN = "hdbscan"
    MEANSHIFT = "meanshift"


_FACTORIES = {
    Method.BFS: BFS,
    Method.DBSCAN: DBSCAN,
    Method.HDBSCAN: HDBSCAN,
    Method.MEANSHIFT: MeanShift,
}


def make_clusterer(method: Method | str, **params: Any) -> Clusterer:
    """Build the estimator of ``method`` with ``params`` (``None`` values are left at defaults).

    Examples
    --------
    >>> make_clusterer("meanshift", bandwidth=1.2, bin_seeding=True)
    MeanShift(bandwidth=1.2, bin_seeding=True)
    """
    factory = _FACTORIES[Method(method)]
    return factory(**{k: v for k, v in params.items() if v is not None})
