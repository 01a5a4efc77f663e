"""Per-point segment matching for the viewer: which segment each point is in, and its fate.

The evaluator (:func:`panoptic_bench.metrics.panoptic.panoptic_stats`) only returns counts. The
viewer needs the same matching *per segment and per point* to colour TP / FP / FN segments, so this
module applies the evaluator's rules to label arrays and keeps the segment tables:

- points whose ground-truth class is ignored belong to no segment on either side;
- a segment is a ``(class, instance id)`` pair of an included class (stuff classes too);
- a prediction and a ground-truth segment of the same class match when IoU > 0.5 (strictly);
- unmatched segments with fewer than ``min_points`` points are neither FP nor FN ("small").

``tests/test_viewer_matching.py`` checks that the per-class TP / FP / FN counts of these tables equal
the evaluator's and the nuScenes-devkit reference's on every input it tries.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["GT_STATUS", "PRED_STATUS", "SegmentMatch", "SegmentTable", "match_segments"]

#: Status codes of prediction segments.
PRED_STATUS = {"TP": 0, "FP": 1, "small": 2}
#: Status codes of ground-truth segments.
GT_STATUS = {"TP": 0, "FN": 1, "small": 2}


@dataclass(frozen=True, eq=False)
class SegmentTable:
    """The segments of one side (prediction or ground truth).

    Attributes
    ----------
    cls : ndarray of shape (n_segments,), int64
        Class id of each segment.
    inst : ndarray of shape (n_segments,), int64
        Instance id (the matching id) of each segment.
    size : ndarray of shape (n_segments,), int64
        Points of the segment (points on ignored ground truth excluded).
    status : ndarray of shape (n_segments,), uint8
        :data:`PRED_STATUS` or :data:`GT_STATUS` code.
    iou : ndarray of shape (n_segments,), float64
        IoU with the matched segment, else the best IoU with any same-class segment (0 if none).
    match : ndarray of shape (n_segments,), int64
        Index of the matched segment in the other table, -1 if unmatched.
    """

    cls: np.ndarray
    inst: np.ndarray
    size: np.ndarray
    status: np.ndarray
    iou: np.ndarray
    match: np.ndarray

    def __len__(self) -> int:
        return len(self.cls)

    def counts(self, code: int, num_classes: int) -> np.ndarray:
        """Segments with status ``code`` per class: int64 array of shape (num_classes,)."""
        return np.bincount(self.cls[self.status == code], minlength=num_classes)


@dataclass(frozen=True, eq=False)
class SegmentMatch:
    """Result of :func:`match_segments`.

    Attributes
    ----------
    pred, gt : SegmentTable
        Segment tables of the prediction and the ground truth.
    pred_segment, gt_segment : ndarray of shape (n_points,), int64
        Segment index of each point, -1 where the point is in no segment.
    """

    pred: SegmentTable
    gt: SegmentTable
    pred_segment: np.ndarray
    gt_segment: np.ndarray


def _segments(cls: np.ndarray, inst: np.ndarray, mask: np.ndarray):
    """Segment index per point (-1 outside ``mask``) and the (class, id, size) of each segment."""
    seg = np.full(len(cls), -1, dtype=np.int64)
    keys = (cls[mask].astype(np.int64) << 32) | inst[mask].astype(np.int64)
    uniq, inverse, size = np.unique(keys, return_inverse=True, return_counts=True)
    seg[mask] = inverse.ravel()
    return seg, uniq >> 32, uniq & 0xFFFFFFFF, size.astype(np.int64)


def match_segments(
    sem_pred: np.ndarray,
    inst_pred: np.ndarray,
    sem_gt: np.ndarray,
    inst_gt: np.ndarray,
    *,
    num_classes: int,
    ignore: Sequence[int] = (0,),
    min_points: int = 30,
) -> SegmentMatch:
    """Match prediction and ground-truth segments of one scan with the evaluator's rules.

    Parameters
    ----------
    sem_pred, sem_gt : array of shape (n_points,), integer in [0, num_classes)
        Predicted and ground-truth class ids.
    inst_pred, inst_gt : array of shape (n_points,), integer in [0, 2**32)
        Instance ids used for matching (for SemanticKITTI the full uint32 label).
    num_classes : int
        Number of classes including the ignored ones.
    ignore : sequence of int
        Ignored class ids.
    min_points : int
        Unmatched segments smaller than this are "small" (neither FP nor FN).

    Returns
    -------
    SegmentMatch
    """
    sp = np.asarray(sem_pred).astype(np.int64).ravel()
    sg = np.asarray(sem_gt).astype(np.int64).ravel()
    ip = np.asarray(inst_pred).astype(np.int64).ravel()
    ig = np.asarray(inst_gt).astype(np.int64).ravel()
    n = len(sp)
    if not (len(sg) == len(ip) == len(ig) == n):
        raise ValueError(f"label arrays differ in length: {n}, {len(ip)}, {len(sg)}, {len(ig)}")
    for name, arr in (("sem_pred", sp), ("sem_gt", sg)):
        if n and (arr.min() < 0 or arr.max() >= num_classes):
            raise ValueError(f"{name} holds class ids outside [0, {num_classes})")
    for name, arr in (("inst_pred", ip), ("inst_gt", ig)):
        if n and (arr.min() < 0 or arr.max() > 0xFFFFFFFF):
            raise ValueError(f"{name} holds instance ids outside [0, 2**32)")
    ignored = np.zeros(num_classes, dtype=bool)
    ignored[list(ignore)] = True
    keep = ~ignored[sg]
    p_seg, p_cls, p_inst, p_size = _segments(sp, ip, keep & ~ignored[sp])
    g_seg, g_cls, g_inst, g_size = _segments(sg, ig, keep)

    both = (p_seg >= 0) & (g_seg >= 0) & (sp == sg)
    n_g = max(len(g_cls), 1)
    pairs, inter = np.unique(p_seg[both] * n_g + g_seg[both], return_counts=True)
    pp, gg = np.divmod(pairs, n_g)
    iou = inter / (p_size[pp] + g_size[gg] - inter).astype(np.float64)

    p_iou = np.zeros(len(p_cls))
    g_iou = np.zeros(len(g_cls))
    np.maximum.at(p_iou, pp, iou)
    np.maximum.at(g_iou, gg, iou)
    p_match = np.full(len(p_cls), -1, dtype=np.int64)
    g_match = np.full(len(g_cls), -1, dtype=np.int64)
    ok = iou > 0.5  # at most one match per segment: two IoUs > 0.5 would need shared points
    p_match[pp[ok]] = gg[ok]
    g_match[gg[ok]] = pp[ok]

    def status(match: np.ndarray, size: np.ndarray, miss: int) -> np.ndarray:
        out = np.full(len(match), 2, dtype=np.uint8)
        out[(match < 0) & (size >= min_points)] = miss
        out[match >= 0] = 0
        return out

    pred = SegmentTable(p_cls, p_inst, p_size, status(p_match, p_size, 1), p_iou, p_match)
    gt = SegmentTable(g_cls, g_inst, g_size, status(g_match, g_size, 1), g_iou, g_match)
    return SegmentMatch(pred, gt, p_seg, g_seg)
