"""Panoptic assembly shared by the clustering baselines and DS-Net.

semantic prediction + regressed centres + a clusterer → per-point ``(sem, inst)``:

1. things mask from the semantic prediction (``sem`` in ``thing_ids``);
2. the regressed centres of the things points are clustered (any estimator with
   ``fit_predict``, see :mod:`panoptic_bench.baselines.clustering`);
3. clusters with fewer than ``min_points`` points are dropped. Their points keep their own
   semantic class and get instance 0 (``SmallInstance.NO_INSTANCE``, default), or become
   unlabelled, class 0 and instance 0 (``SmallInstance.UNLABELED``). Note: the SemanticKITTI
   evaluator counts all instance-0 points of one things class in a scan as *one* segment, an FP if it
   reaches 50 points and matches nothing; ``UNLABELED`` avoids that at the cost of mIoU;
4. kept clusters get instance ids ``1..K`` in the order of their cluster labels;
5. consensus-driven fusion (paper §3.3, switchable off): every point of an instance takes the
   instance's majority semantic class, ties going to the smallest class id;
6. stuff points (and things points without instance) have instance 0.

Encoders turn the result into the official files: SemanticKITTI ``.label`` (raw id | inst << 16)
and Panoptic nuScenes (``class * 1000 + inst``, uint16).
"""

from __future__ import annotations

from collections.abc import Sequence
from enum import StrEnum

import numpy as np

from panoptic_bench.baselines.clustering import Clusterer

__all__ = [
    "SmallInstance",
    "assemble_panoptic",
    "consensus_fusion",
    "filter_small_instances",
    "nuscenes_panoptic",
    "orphans_to_stuff",
    "semantickitti_label",
]


class SmallInstance(StrEnum):
    """Fate of the points of a cluster smaller than ``min_points`` (see module docstring)."""

    NO_INSTANCE = "no-instance"
    UNLABELED = "unlabeled"


def filter_small_instances(labels: np.ndarray, min_points: int) -> np.ndarray:
    """Number the clusters with at least ``min_points`` points ``1..K``; the others get 0.

    Parameters
    ----------
    labels : array of shape (m,), int >= 0
        Cluster labels of the things points.
    min_points : int
        Smallest valid instance.

    Returns
    -------
    ndarray of shape (m,), uint32
        Instance ids, 0 = dropped; kept clusters numbered in increasing label order.
    """
    labels = np.asarray(labels, dtype=np.int64)
    if labels.size == 0:
        return np.zeros(0, dtype=np.uint32)
    if labels.min() < 0:
        raise ValueError("cluster labels must be >= 0 (resolve noise first)")
    counts = np.bincount(labels)
    keep = counts >= max(int(min_points), 1)
    new_id = np.zeros(len(counts), dtype=np.uint32)
    new_id[keep] = np.arange(1, int(keep.sum()) + 1, dtype=np.uint32)
    return new_id[labels]


def consensus_fusion(
    sem: np.ndarray, inst: np.ndarray, num_classes: int | None = None
) -> np.ndarray:
    """Majority vote of the semantic class inside each instance (instance 0 is left alone).

    Parameters
    ----------
    sem : array of shape (n,), int >= 0
        Semantic class per point.
    inst : array of shape (n,), int >= 0
        Instance id per point, 0 = no instance.
    num_classes : int, optional
        Number of classes (defaults to ``sem.max() + 1``).

    Returns
    -------
    ndarray of shape (n,), same dtype as ``sem``
        Every point of instance ``i > 0`` carries the most frequent class of instance ``i``; ties
        are broken towards the smallest class id.

    Examples
    --------
    >>> consensus_fusion(np.array([1, 1, 2, 2, 3, 5]), np.array([1, 1, 1, 0, 2, 2]))
    array([1, 1, 1, 2, 3, 3])
    """
    sem = np.asarray(sem)
    inst = np.asarray(inst, dtype=np.int64)
    if sem.shape != inst.shape:
        raise ValueError(f"sem {sem.shape} and inst {inst.shape} must have the same shape")
    if sem.size == 0 or inst.max() == 0:
        return sem.copy()
    c = int(num_classes) if num_classes is not None else int(sem.max()) + 1
    votes = np.bincount(inst * c + sem.astype(np.int64), minlength=(int(inst.max()) + 1) * c)
    majority = votes.reshape(-1, c).argmax(axis=1)  # argmax: first maximum = smallest class
    out = sem.copy()
    has = inst > 0
    out[has] = majority[inst[has]].astype(sem.dtype)
    return out


def assemble_panoptic(
    points: np.ndarray,
    sem: np.ndarray,
    offset: np.ndarray,
    clusterer: Clusterer,
    *,
    thing_ids: Sequence[int],
    min_points: int,
    fusion: bool = True,
    small: SmallInstance = SmallInstance.NO_INSTANCE,
    num_classes: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Semantic prediction + regressed centres + clustering → panoptic prediction.

    Parameters
    ----------
    points : array of shape (n, >=3), float
        Point coordinates (only x, y, z are used).
    sem : array of shape (n,), integer
        Predicted semantic train ids.
    offset : array of shape (n, 3), float
        Predicted point → centre vectors; only rows of things points are used.
    clusterer : Clusterer
        Estimator with ``fit_predict`` (e.g. ``MeanShift(1.2)``).
    thing_ids : sequence of int
        Train ids of the things classes.
    min_points : int
        Clusters smaller than this are dropped (see :class:`SmallInstance`).
    fusion : bool
        Consensus-driven fusion (majority vote per instance); False = ablation "no fusion".
    small : SmallInstance
        Fate of the points of dropped clusters.
    num_classes : int, optional
        Number of semantic classes (for the vote).

    Returns
    -------
    sem : ndarray of shape (n,), uint8
        Semantic train ids after fusion.
    inst : ndarray of shape (n,), uint32
        Instance ids: 1..K on things points of kept clusters, 0 elsewhere.
    """
    points = np.asarray(points)
    sem = np.asarray(sem)
    offset = np.asarray(offset)
    n = len(sem)
    if points.ndim != 2 or points.shape[1] < 3 or len(points) != n or offset.shape != (n, 3):
        raise ValueError(
            f"points {points.shape}, sem {sem.shape} and offset {offset.shape} disagree: "
            "expected (n, >=3), (n,), (n, 3)"
        )
    things = np.isin(sem, np.asarray(thing_ids))
    inst = np.zeros(n, dtype=np.uint32)
    out_sem = sem.astype(np.uint8)
    if not things.any():
        return out_sem, inst
    centers = points[things, :3].astype(np.float64) + offset[things].astype(np.float64)
    if not np.isfinite(centers).all():
        raise ValueError("regressed centres of things points contain NaN or inf")
    labels = np.asarray(clusterer.fit_predict(centers))
    inst[things] = filter_small_instances(labels, min_points)
    if SmallInstance(small) is SmallInstance.UNLABELED:
        out_sem[things & (inst == 0)] = 0
    if fusion:
        out_sem = consensus_fusion(out_sem, inst, num_classes)
    return out_sem, inst


def orphans_to_stuff(
    sem: np.ndarray, inst: np.ndarray, scores: np.ndarray, thing_ids: Sequence[int]
) -> np.ndarray:
    """Give every orphan thing point (a things class, instance 0) its best-scoring stuff class.

    Parameters
    ----------
    sem : array of shape (n,), integer
        Semantic classes after the panoptic assembly.
    inst : array of shape (n,), integer
        Instance ids, 0 = no instance.
    scores : array of shape (m, c), float
        Class scores (logits or probabilities) of the orphans only, in the order of
        ``np.flatnonzero(orphans)``; classes that must never be predicted (the ignored class)
        hold ``-inf``.
    thing_ids : sequence of int
        The things classes.

    Returns
    -------
    ndarray of shape (n,), same dtype as ``sem``
        A copy in which each orphan carries the argmax of its scores over the classes that are
        not things (ties to the smallest class id); every other point is unchanged.

    Examples
    --------
    >>> sem, inst = np.array([1, 1, 9, 2]), np.array([3, 0, 0, 0])
    >>> scores = np.array([[0.0, 5.0, 1.0, 2.0], [0.0, 1.0, 9.0, 0.5]])
    >>> orphans_to_stuff(sem, inst, scores, thing_ids=[1, 2])
    array([1, 3, 9, 3])
    """
    sem = np.asarray(sem)
    orphans = np.flatnonzero(np.isin(sem, np.asarray(thing_ids)) & (np.asarray(inst) == 0))
    scores = np.asarray(scores, dtype=np.float64)
    if scores.ndim != 2 or len(scores) != len(orphans):
        raise ValueError(
            f"scores {scores.shape} must hold one row per orphan thing point ({len(orphans)})"
        )
    out = sem.copy()
    if len(orphans):
        stuff = scores.copy()
        stuff[:, [t for t in thing_ids if t < stuff.shape[1]]] = -np.inf
        out[orphans] = stuff.argmax(axis=1).astype(sem.dtype)
    return out


def semantickitti_label(sem: np.ndarray, inst: np.ndarray) -> np.ndarray:
    """SemanticKITTI ``.label`` content: raw semantic id | instance id << 16.

    Parameters
    ----------
    sem : array of shape (n,), integer train ids 0..19
    inst : array of shape (n,), integer < 65536

    Returns
    -------
    ndarray of shape (n,), uint32
    """
    from panoptic_bench.datasets.semantickitti import make_label, to_raw

    return make_label(to_raw(sem), inst)


def nuscenes_panoptic(sem: np.ndarray, inst: np.ndarray) -> np.ndarray:
    """Panoptic nuScenes prediction array: ``class * 1000 + instance``.

    Parameters
    ----------
    sem : array of shape (n,), integer class ids 0..16 (nuScenes lidarseg eval classes)
    inst : array of shape (n,), integer < 1000

    Returns
    -------
    ndarray of shape (n,), uint16 (saved as key ``data`` of ``<token>_panoptic.npz``)
    """
    sem = np.asarray(sem, dtype=np.int64)
    inst = np.asarray(inst, dtype=np.int64)
    if inst.size and (inst.min() < 0 or inst.max() >= 1000):
        raise ValueError(
            f"nuScenes panoptic instance ids must lie in [0, 1000), got max {inst.max()}; "
            "raise min_points or use a coarser clustering"
        )
    if sem.size and (sem.min() < 0 or sem.max() > 65):
        raise ValueError("nuScenes class ids must lie in [0, 65]")
    return (sem * 1000 + inst).astype(np.uint16)
