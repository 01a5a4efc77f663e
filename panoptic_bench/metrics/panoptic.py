"""Exact LiDAR panoptic quality (PQ/SQ/RQ/PQ†) and mIoU: the pure kernel (accumulator in ``accumulator.py``).

This reproduces the official SemanticKITTI evaluator (semantic-kitti-api ``auxiliary/eval_np.py``,
shipped in nuscenes-devkit as ``nuscenes.eval.panoptic.panoptic_seg_evaluator.PanopticEval``) to
floating-point round-off, with the matching vectorised over all classes at once.

Rules (each one is a test in ``tests/test_metrics_panoptic.py``)
----------------------------------------------------------------
- Points whose **ground-truth** class is ignored are removed before matching; a prediction of an
  ignored class is not removed (it forms no segment but still enlarges the union of the gt segment).
- For each included class, a segment is the set of points of that class sharing one instance id
  (for SemanticKITTI the instance id is the full uint32 label). Stuff classes are segments too.
  Instance ids must be < 2**32; negative ids mark points that belong to no segment (as in the
  reference, where ids are shifted by +1 and only ids > 0 form segments).
- A prediction/gt pair of the same class matches when IoU > 0.5 (strictly). TP and the IoU sum
  count every match; FP and FN count only unmatched segments with at least ``min_points`` points.
- SQ = IoU sum / max(TP, eps), RQ = TP / max(TP + FP/2 + FN/2, eps), PQ = SQ * RQ, eps = 1e-15;
  class means over the included classes.
- Semantic IoU from one confusion matrix (rows = prediction, columns = ground truth) over all
  points, with the columns of ignored classes zeroed; accuracy = sum of the diagonal / (sum of TP
  and FP over included classes).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from panoptic_bench.metrics.accumulator import EPS, PanopticResult, PanopticStats
from panoptic_bench.metrics.cells import point_cells

__all__ = ["EPS", "PanopticResult", "PanopticStats", "panoptic_stats", "stats_from_cells"]


def _class_array(name: str, arr: np.ndarray, num_classes: int) -> np.ndarray:
    arr = np.asarray(arr)
    if not np.issubdtype(arr.dtype, np.integer):
        raise TypeError(f"{name} must be an integer array, got {arr.dtype}")
    arr = arr.ravel()
    if arr.size and (arr.min() < 0 or arr.max() >= num_classes):
        raise ValueError(f"{name} holds class ids outside [0, {num_classes})")
    return arr


def _inst_array(name: str, arr: np.ndarray) -> np.ndarray:
    arr = np.asarray(arr)
    if not np.issubdtype(arr.dtype, np.integer):
        raise TypeError(f"{name} must be an integer array, got {arr.dtype}")
    arr = arr.ravel()
    if arr.size and (arr.min() < 0 or arr.max() > 0xFFFFFFFF):
        raise ValueError(f"{name} holds instance ids outside [0, 2**32)")
    return arr


def _int_sum(index: np.ndarray, weights: np.ndarray, size: int) -> np.ndarray:
    """Exact integer ``bincount`` with integer weights (< 2**53), as int64 of shape (size,)."""
    return np.rint(np.bincount(index, weights=weights, minlength=size)).astype(np.int64)


def _group(keys: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Group cells by ``keys``: (distinct keys, summed integer weights, cell -> group)."""
    uniq, inverse = np.unique(keys, return_inverse=True)
    return uniq, _int_sum(inverse, weights, len(uniq)), inverse


def panoptic_stats(
    sem_pred: np.ndarray,
    inst_pred: np.ndarray,
    sem_gt: np.ndarray,
    inst_gt: np.ndarray,
    *,
    num_classes: int,
    ignore: Sequence[int] = (0,),
    min_points: int = 30,
) -> PanopticStats:
    """Panoptic and semantic counts of one scan (or any batch of points).

    Parameters
    ----------
    sem_pred, sem_gt : array of shape (n_points,), integer in [0, num_classes)
        Predicted and ground-truth class ids (train ids).
    inst_pred, inst_gt : array of shape (n_points,), integer in [0, 2**32)
        Instance ids used for matching, per class; for SemanticKITTI the full uint32 label.
    num_classes : int
        Number of classes C including the ignored ones.
    ignore : sequence of int
        Ignored class ids (``(0,)`` for SemanticKITTI).
    min_points : int
        Unmatched segments smaller than this count neither as FP nor as FN.

    Returns
    -------
    PanopticStats
        Counts to be summed over scans with ``+`` and turned into metrics by ``.compute()``.

    Notes
    -----
    All per-point work is a handful of vectorised passes: the points are reduced to their
    distinct *cells* ``(pred class, pred id, gt class, gt id)`` with their sizes
    (:func:`panoptic_bench.metrics.cells.point_cells`). Confusion matrix, segment sizes and
    intersections are then sums over the (few hundred) cells, for all classes at once
    (:func:`stats_from_cells`).
    """
    n = np.size(sem_pred)
    if not (np.size(inst_pred) == np.size(sem_gt) == np.size(inst_gt) == n):
        raise ValueError(
            "sem_pred, inst_pred, sem_gt and inst_gt must have the same number of points, got "
            f"{n}, {np.size(inst_pred)}, {np.size(sem_gt)}, {np.size(inst_gt)}"
        )
    C = int(num_classes)
    sp = _class_array("sem_pred", sem_pred, C)
    sg = _class_array("sem_gt", sem_gt, C)
    ip = _inst_array("inst_pred", inst_pred)
    ig = _inst_array("inst_gt", inst_gt)
    if n == 0:
        return PanopticStats.zeros(C, ignore)
    cells = point_cells(sp, ip, sg, ig, C)
    return stats_from_cells(
        cells.sem_pred,
        cells.inst_pred,
        cells.sem_gt,
        cells.inst_gt,
        cells.count,
        num_classes=C,
        ignore=ignore,
        min_points=min_points,
    )


def stats_from_cells(
    c_sp: np.ndarray,
    c_ip: np.ndarray,
    c_sg: np.ndarray,
    c_ig: np.ndarray,
    cnt: np.ndarray,
    *,
    num_classes: int,
    ignore: Sequence[int] = (0,),
    min_points: int = 30,
) -> PanopticStats:
    """The counts of :func:`panoptic_stats` from the distinct cells of the points.

    Parameters
    ----------
    c_sp, c_sg : array of shape (k,), int64
        Predicted and ground-truth class of each cell, in [0, num_classes).
    c_ip, c_ig : array of shape (k,), int64
        Predicted and ground-truth instance id of each cell, in [0, 2**32).
    cnt : array of shape (k,), int64
        Points per cell; each (class, id, class, id) tuple appears once, in any order.
    num_classes, ignore, min_points
        As in :func:`panoptic_stats`.

    Returns
    -------
    PanopticStats
    """
    C = int(num_classes)
    stats = PanopticStats.zeros(C, ignore)
    ignored = np.zeros(C, dtype=bool)
    ignored[list(stats.ignore)] = True
    cc = C * C

    # 1. semantic confusion over all points (rows = prediction, cols = gt)
    stats.confusion += _int_sum(c_sp * C + c_sg, cnt, cc).reshape(C, C)

    # 2. drop cells whose ground truth is ignored; segments = (class, id) of included classes
    keep = ~ignored[c_sg]
    c_sp, c_sg, c_ip, c_ig, cnt = c_sp[keep], c_sg[keep], c_ip[keep], c_ig[keep], cnt[keep]
    pvalid = ~ignored[c_sp]
    p_key, p_cnt, p_of = _group((c_sp[pvalid] << 32) | c_ip[pvalid], cnt[pvalid])
    g_key, g_cnt, g_of = _group((c_sg << 32) | c_ig, cnt)
    p_cls, g_cls = p_key >> 32, g_key >> 32

    # 3. a cell with equal classes is exactly one (pred segment, gt segment) intersection
    same = c_sp[pvalid] == c_sg[pvalid]
    pp, gg = p_of[same], g_of[pvalid][same]
    inter = cnt[pvalid][same]
    iou = inter.astype(np.float64) / (p_cnt[pp] + g_cnt[gg] - inter).astype(np.float64)
    match = iou > 0.5
    m_cls = p_cls[pp[match]]
    stats.tp += np.bincount(m_cls, minlength=C)
    # IoU sums per class in the reference's order (by gt id, then pred id) with np.sum's
    # pairwise summation, so the sums are bit-identical to the official evaluator.
    order = np.lexsort((p_key[pp[match]], g_key[gg[match]]))
    m_sorted, iou_sorted = m_cls[order], iou[match][order]
    cuts = np.flatnonzero(np.diff(m_sorted)) + 1
    for cls, part in zip(
        m_sorted[np.r_[0, cuts]] if len(m_sorted) else (), np.split(iou_sorted, cuts)
    ):
        stats.iou_sum[cls] += np.sum(part)

    p_matched = np.zeros(len(p_cnt), dtype=bool)
    g_matched = np.zeros(len(g_cnt), dtype=bool)
    p_matched[pp[match]] = True
    g_matched[gg[match]] = True
    stats.fp += np.bincount(p_cls[~p_matched & (p_cnt >= min_points)], minlength=C)
    stats.fn += np.bincount(g_cls[~g_matched & (g_cnt >= min_points)], minlength=C)
    return stats
