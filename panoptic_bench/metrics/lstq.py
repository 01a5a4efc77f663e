"""4D panoptic segmentation (LSTQ): a pure per-frame kernel plus addable per-sequence accumulators.

LSTQ = sqrt(S_assoc * S_cls) (Aygün et al., CVPR 2021). ``S_cls`` is a mean IoU over one
confusion matrix of every frame; ``S_assoc`` scores how well predicted tubes (points sharing one
predicted id along a sequence) cover ground-truth tubes::

    S_assoc = 1/|T| sum_t 1/|t| sum_{p: |p ∩ t| > 0} |p ∩ t| * IoU(p, t)

Two rule sets (:class:`LSTQMode`); every rule below is a test in ``tests/test_eval_4d*.py``.

``REFERENCE`` — the SemanticKITTI 4D benchmark code (4D-PLS ``Panoptic4DEval``), quirks included:

R1. Points whose ground-truth class is ignored are removed (the confusion matrix keeps them, with
    the ignored columns zeroed, as single-scan mIoU).
R2. Ground-truth tubes are (class, instance id) pairs of every included class, instance id 0 being
    "no instance"; in each frame a segment joins its tube only if it has **more than**
    ``min_points`` points (single-scan PQ uses ``>=``).
R3. Predicted tubes are class-agnostic: the instance id alone (``label >> 16``), consistent along a
    sequence; id 0 is no tube. A tube's size counts its points predicted as an included class,
    while intersections count its points whatever their predicted class.
R4. ``S_assoc`` sums the tube scores of every included class and divides by the number of
    ground-truth tubes of the thing classes; per-class ``AQ`` divides by the class's own tubes.
R5. ``S_cls`` averages the IoU of every class with a non-zero union, so predicting class 0 on
    non-ignored points adds a phantom class of IoU 0 (4D-PLS issue 17).

``CORRECTED`` — ground truth scored against itself gives 1.0 (4D-PLS issue 14). Differences:

C1. Predicted tubes are (predicted thing class, id): SemanticKITTI ground-truth ids are unique per
    class only (sequence 06 uses id 1 for a car and for a person). Stuff predictions form no tube.
C2. Only thing classes have ground-truth tubes, in the numerator as in the denominator of S_assoc.
C3. A segment joins its tube with **at least** ``min_points`` points, as in single-scan PQ.
C4. Points of a ground-truth segment too small to join its tube in that frame are void for the
    predicted tubes too (the reference counts them in the predicted tube only, so even a perfect
    prediction loses association).
C5. A tube's size and its intersections count the same points, so IoU <= 1 always (R3 allows
    IoU > 1 when points of a predicted id are predicted as class 0).
C6. ``S_cls`` averages the included classes with a non-zero union: no phantom class 0.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

EPS = 1e-15
_ID_BITS = 16  # SemanticKITTI instance ids: the high 16 bits of the uint32 label

__all__ = ["LSTQMode", "LSTQResult", "LSTQStats", "SequenceTubes", "lstq_frame_stats"]


class LSTQMode(enum.Enum):
    """Rule set of the 4D evaluation (see the module docstring)."""

    REFERENCE = "reference"
    CORRECTED = "corrected"


def _reduce(keys: np.ndarray, counts: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Distinct int64 ``keys`` (sorted) and their summed counts (int64)."""
    if counts is None:
        uniq, cnt = np.unique(keys, return_counts=True)
        return uniq.astype(np.int64), cnt.astype(np.int64)
    uniq, inv = np.unique(keys, return_inverse=True)
    return uniq.astype(np.int64), np.bincount(inv, weights=counts, minlength=len(uniq)).astype(
        np.int64
    )


def _empty() -> np.ndarray:
    return np.zeros(0, dtype=np.int64)


@dataclass(frozen=True)
class SequenceTubes:
    """Tube sizes and intersections of one sequence (or part of it); add frames with ``+``.

    Attributes
    ----------
    gt_keys, gt_sizes : arrays of shape (n_gt,), int64
        Ground-truth tube ``class << 16 | id`` (sorted) and its number of points.
    pred_keys, pred_sizes : arrays of shape (n_pred,), int64
        Predicted tube key (``id``; corrected mode ``class << 16 | id``) and its size.
    inter_keys, inter_sizes : arrays of shape (n_inter,), int64
        ``gt_key << 32 | pred_key`` and the number of points in both tubes.
    """

    gt_keys: np.ndarray = field(default_factory=_empty)
    gt_sizes: np.ndarray = field(default_factory=_empty)
    pred_keys: np.ndarray = field(default_factory=_empty)
    pred_sizes: np.ndarray = field(default_factory=_empty)
    inter_keys: np.ndarray = field(default_factory=_empty)
    inter_sizes: np.ndarray = field(default_factory=_empty)

    def __add__(self, other: SequenceTubes) -> SequenceTubes:
        return SequenceTubes.concat([self, other])

    @staticmethod
    def concat(parts: Sequence[SequenceTubes]) -> SequenceTubes:
        """The sum of many (e.g. every frame of a sequence) in one reduction."""
        out = []
        for name in ("gt", "pred", "inter"):
            k = np.concatenate([getattr(p, f"{name}_keys") for p in parts] or [_empty()])
            c = np.concatenate([getattr(p, f"{name}_sizes") for p in parts] or [_empty()])
            out.extend(_reduce(k, c))
        return SequenceTubes(*out)


def _checked(name: str, arr: np.ndarray, limit: int, what: str) -> np.ndarray:
    """``arr`` raveled, checked to be integers in [0, limit) (one pass for unsigned input)."""
    arr = np.asarray(arr).ravel()
    if not np.issubdtype(arr.dtype, np.integer):
        raise TypeError(f"{name} must be an integer array, got {arr.dtype}")
    if arr.size:
        signed = np.issubdtype(arr.dtype, np.signedinteger)
        if arr.max() >= limit or (signed and arr.min() < 0):
            raise ValueError(
                f"{name} holds {what} outside [0, {limit if limit != 65536 else '2**16'})"
            )
    return arr


def lstq_frame_stats(
    sem_pred: np.ndarray,
    inst_pred: np.ndarray,
    sem_gt: np.ndarray,
    inst_gt: np.ndarray,
    *,
    num_classes: int,
    ignore: Sequence[int] = (0,),
    things: Sequence[int] = tuple(range(1, 9)),
    min_points: int = 50,
    mode: LSTQMode = LSTQMode.REFERENCE,
) -> tuple[np.ndarray, SequenceTubes]:
    """Confusion matrix and tube counts of one frame.

    Parameters
    ----------
    sem_pred, sem_gt : array of shape (n_points,), integer in [0, num_classes)
        Predicted and ground-truth train ids.
    inst_pred, inst_gt : array of shape (n_points,), integer in [0, 2**16)
        Instance ids (0 = no instance); predicted ids must be consistent along the sequence.
    num_classes : int
        Number of classes C including the ignored ones.
    ignore : sequence of int
        Ignored class ids.
    things : sequence of int
        Thing class ids (the S_assoc denominator; corrected mode: the only tubes).
    min_points : int
        Segment size threshold (reference: ``>``, corrected: ``>=``).
    mode : LSTQMode

    Returns
    -------
    conf : ndarray of shape (C, C), int64
        Rows = prediction, columns = ground truth, every point.
    tubes : SequenceTubes
    """
    C = int(num_classes)
    sp = _checked("sem_pred", sem_pred, C, "class ids")
    sg = _checked("sem_gt", sem_gt, C, "class ids")
    ip = _checked("inst_pred", inst_pred, 1 << _ID_BITS, "instance ids")
    ig = _checked("inst_gt", inst_gt, 1 << _ID_BITS, "instance ids")
    if not (len(sp) == len(ip) == len(sg) == len(ig)):
        raise ValueError("the four label arrays must have the same length")
    small = sp.dtype.itemsize == sg.dtype.itemsize == 1 and C * C <= 1 << 16
    code = sp.astype(np.uint16 if small else np.int64)  # uint8 class ids: 2-byte arithmetic
    code *= C
    code += sg
    conf = np.bincount(code, minlength=C * C).reshape(C, C).astype(np.int64)
    ignored = np.zeros(C, dtype=bool)
    ignored[list(ignore)] = True
    is_thing = np.zeros(C, dtype=bool)
    is_thing[list(things)] = True
    # only points carrying an instance id on either side (and a non-ignored gt class) matter
    sub = (ig > 0) | (ip > 0)
    sub &= ~ignored[sg]
    idx = np.flatnonzero(sub)
    sp, sg = sp[idx].astype(np.int64), sg[idx].astype(np.int64)
    ip, ig = ip[idx].astype(np.int64), ig[idx].astype(np.int64)

    corrected = mode is LSTQMode.CORRECTED
    gt_pt = ig > 0
    if corrected:
        gt_pt &= is_thing[sg]
        pred_pt = (ip > 0) & is_thing[sp]
        pred_key = (sp << _ID_BITS) | ip
        inter_pred = np.where(pred_pt, pred_key, 0)
    else:
        pred_pt = (ip > 0) & ~ignored[sp]
        pred_key = ip
        inter_pred = ip  # intersections count a predicted id whatever its class (R3)
    # one sort of the ground-truth points by (segment, predicted tube or 0) gives the segment
    # sizes and the intersections together
    gkey = (sg[gt_pt] << _ID_BITS) | ig[gt_pt]
    pair, pair_n = _reduce((gkey << 32) | inter_pred[gt_pt])
    seg = pair >> 32
    starts = np.flatnonzero(np.r_[True, seg[1:] != seg[:-1]]) if len(seg) else _empty()
    gkeys = seg[starts]
    gsizes = np.add.reduceat(pair_n, starts) if len(starts) else _empty()
    big = gsizes >= min_points if corrected else gsizes > min_points
    pair_big = np.repeat(big, np.diff(np.r_[starts, len(seg)]))
    pred_part = pair & 0xFFFFFFFF
    hit = pair_big & (pred_part > 0)
    ikeys, isizes = pair[hit], pair_n[hit]
    if corrected:  # C4: predicted points on too-small ground-truth segments are void
        pkeys, psizes = _reduce(pred_key[pred_pt])
        void = ~pair_big & (pred_part > 0)
        np.subtract.at(psizes, np.searchsorted(pkeys, pred_part[void]), pair_n[void])
        keep = psizes > 0
        pkeys, psizes = pkeys[keep], psizes[keep]
    else:
        counts = np.bincount(pred_key[pred_pt], minlength=1 << _ID_BITS)
        pkeys = np.flatnonzero(counts).astype(np.int64)
        psizes = counts[pkeys].astype(np.int64)
    return conf, SequenceTubes(gkeys[big], gsizes[big], pkeys, psizes, ikeys, isizes)


@dataclass(frozen=True)
class LSTQResult:
    """LSTQ metrics (fractions). ``iou`` and ``aq`` have shape (C,), float64."""

    LSTQ: float
    S_assoc: float
    S_cls: float
    iou: np.ndarray
    aq: np.ndarray
    n_tubes: np.ndarray
    AQ_precision: float
    AQ_recall: float
    phantom_class_0: bool


@dataclass(frozen=True)
class LSTQStats:
    """Accumulated 4D statistics: one confusion matrix and the tubes of every sequence.

    Add frame or sequence statistics with ``+`` (tubes of the same sequence name are merged);
    :meth:`compute` gives the metrics.
    """

    num_classes: int
    ignore: tuple[int, ...]
    things: tuple[int, ...]
    mode: LSTQMode
    conf: np.ndarray
    sequences: Mapping[str, SequenceTubes]

    @classmethod
    def zeros(
        cls,
        num_classes: int,
        ignore: Sequence[int] = (0,),
        things: Sequence[int] = tuple(range(1, 9)),
        mode: LSTQMode = LSTQMode.REFERENCE,
    ) -> LSTQStats:
        """Empty statistics."""
        conf = np.zeros((num_classes, num_classes), dtype=np.int64)
        return cls(num_classes, tuple(ignore), tuple(things), mode, conf, {})

    def add_frame(self, sequence: str, conf: np.ndarray, tubes: SequenceTubes) -> LSTQStats:
        """Statistics with one frame (the output of :func:`lstq_frame_stats`) added."""
        one = LSTQStats(
            self.num_classes, self.ignore, self.things, self.mode, conf, {sequence: tubes}
        )
        return self + one

    def __add__(self, other: LSTQStats) -> LSTQStats:
        same = (self.num_classes, self.ignore, self.things, self.mode)
        if same != (other.num_classes, other.ignore, other.things, other.mode):
            raise ValueError("cannot add LSTQ statistics of different settings")
        seqs = dict(self.sequences)
        for name, tubes in other.sequences.items():
            seqs[name] = seqs[name] + tubes if name in seqs else tubes
        return LSTQStats(*same, self.conf + other.conf, seqs)

    def _iou(self) -> tuple[np.ndarray, float, bool]:
        conf = self.conf.astype(np.float64)
        conf[:, list(self.ignore)] = 0
        tp = conf.diagonal()
        union = conf.sum(axis=1) + conf.sum(axis=0) - tp
        iou = tp / np.maximum(union, EPS)
        present = union > 0
        phantom = bool(present[list(self.ignore)].any())
        if self.mode is LSTQMode.CORRECTED:
            present[list(self.ignore)] = False
        n = int(np.count_nonzero(present))
        mean = float(iou[present].sum() / n) if n else math.nan
        return iou, mean, phantom

    def compute(self) -> LSTQResult:
        """LSTQ, S_assoc, S_cls, per-class IoU and AQ.

        Empty denominators give NaN for S_assoc / S_cls / LSTQ (as the reference), 0 for a
        class without tubes.
        """
        C = self.num_classes
        aq_sum = np.zeros(C)
        n_tubes = np.zeros(C, dtype=np.int64)
        precs, recalls = [], []
        for tubes in self.sequences.values():
            n_tubes += np.bincount(tubes.gt_keys >> _ID_BITS, minlength=C)
            gkey = tubes.inter_keys >> 32
            pkey = tubes.inter_keys & 0xFFFFFFFF
            ppos = np.searchsorted(tubes.pred_keys, pkey).clip(max=max(len(tubes.pred_keys) - 1, 0))
            known = (
                tubes.pred_keys[ppos] == pkey if len(tubes.pred_keys) else np.zeros(len(pkey), bool)
            )
            gpos = np.searchsorted(tubes.gt_keys, gkey[known])
            tpa = tubes.inter_sizes[known].astype(np.float64)
            g = tubes.gt_sizes[gpos].astype(np.float64)
            p = tubes.pred_sizes[ppos[known]].astype(np.float64)
            precs.append(tpa / p)
            recalls.append(tpa / g)
            inner = np.bincount(
                gpos, weights=tpa * (tpa / (g + p - tpa)), minlength=len(tubes.gt_keys)
            )
            tube_score = inner / tubes.gt_sizes
            aq_sum += np.bincount(tubes.gt_keys >> _ID_BITS, weights=tube_score, minlength=C)
        things = list(self.things)
        n_things = int(n_tubes[things].sum())
        total = (
            float(aq_sum.sum()) if self.mode is LSTQMode.REFERENCE else float(aq_sum[things].sum())
        )
        s_assoc = total / n_things if n_things else math.nan
        aq = aq_sum / np.maximum(n_tubes, EPS)
        iou, s_cls, phantom = self._iou()
        lstq = (
            math.sqrt(s_assoc * s_cls)
            if not (math.isnan(s_assoc) or math.isnan(s_cls))
            else math.nan
        )
        pr = np.concatenate(precs) if precs else np.zeros(0)
        rc = np.concatenate(recalls) if recalls else np.zeros(0)
        return LSTQResult(
            LSTQ=lstq,
            S_assoc=s_assoc,
            S_cls=s_cls,
            iou=iou,
            aq=aq,
            n_tubes=n_tubes,
            AQ_precision=float(pr.mean()) if len(pr) else math.nan,
            AQ_recall=float(rc.mean()) if len(rc) else math.nan,
            phantom_class_0=phantom,
        )
