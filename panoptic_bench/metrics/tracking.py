"""Panoptic tracking (PAT, PTQ, sPTQ, LSTQ, MOTSA ...): per-frame kernel, per-scene accumulator.

Reproduces nuscenes-devkit ``PanopticTrackingEval`` (``NuScenesPanopticEval(task='tracking')``),
quirks included. Labels are full panoptic labels (``class * 1000 + instance``); as in the devkit
every label is shifted by +1, so id 1 is a prediction of label 0. Rules (tests in
``tests/test_nuscenes_tracking*.py``):

- Points whose ground-truth class is ignored are removed (the confusion matrix keeps them, ignored
  columns zeroed). Segments are (class, label) pairs of each side; a pair of the same class
  matches when its IoU, computed in **float32**, is > 0.5. TP and the IoU sum (float32 per class
  and frame, then float64) count every match; FP and FN count unmatched segments with **at least**
  ``min_points`` points.
- ID switches (things only): a ground-truth segment matched in two consecutive frames of a scene
  by different predicted labels; the soft variant adds the current IoU.
  PTQ = (IoU sum - IDS) / TP * RQ, sPTQ with the soft IDS; class means over the included classes
  with at least one ground-truth segment (TP + FN > 0). MOTSA = (TP - FP - IDS) / (TP + FN),
  sMOTSA = (IoU sum - FP - IDS) / (TP + FN), MOTSP = IoU sum / TP, over those thing classes.
- PQ (for PAT) averages **every** included class. TQ: for every thing ground-truth track (a
  (class, label) with **more than** ``min_points`` points in a frame), the class-agnostic
  prediction matched in each such frame (IoU > 0.5, float32) or "none" (1); AQ =
  sum_p n_p^2 / (L + FP_p) / L over matched labels p != 1, with FP_p the number of frames where
  p has more than ``min_points`` points minus n_p; IS = 1 - switches / (L - 1) (a switch is a
  change of label or a frame after "none"); TQ = mean of sqrt(AQ * IS); PAT = 2 PQ TQ / (PQ + TQ).
- LSTQ = sqrt(S_assoc * mIoU) with tubes of thing classes (ground truth: more than
  ``min_points`` points in a frame; predicted thing segments likewise; intersections with any
  prediction label), S_assoc normalised by the thing tubes, mIoU over every included class.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from panoptic_bench.metrics.lstq import LSTQMode, LSTQStats, SequenceTubes

EPS = 1e-15
_B = 16  # bits of a shifted label (labels + 1 < 2**16)

__all__ = ["FrameTracking", "SceneTracking", "TrackingStats", "tracking_frame"]


def _uniq(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    u, c = np.unique(keys, return_counts=True)
    return u.astype(np.int64), c.astype(np.int64)


def _lookup(sorted_keys: np.ndarray, values: np.ndarray, keys: np.ndarray) -> np.ndarray:
    return values[np.searchsorted(sorted_keys, keys)]


@dataclass(frozen=True)
class FrameTracking:
    """Counts of one frame (see :func:`tracking_frame`); shapes (C,) unless stated."""

    conf: np.ndarray
    tp: np.ndarray
    fp: np.ndarray
    fn: np.ndarray
    iou32: np.ndarray  # float32 IoU sum per class, as the devkit's np.sum
    match_keys: np.ndarray  # (n,) int64 thing-class matches ``cl << 16 | gt``, sorted
    match_pred: np.ndarray  # (n,) int64 matched predicted label (+1)
    match_iou: np.ndarray  # (n,) float32
    tubes: SequenceTubes
    big_preds: np.ndarray  # class-agnostic predicted labels with > min_points points
    track_keys: np.ndarray  # thing gt tracks of this frame, in the devkit's append order
    track_pred: np.ndarray  # their class-agnostic match (1 = none)


def tracking_frame(
    sem_pred: np.ndarray,
    pred: np.ndarray,
    sem_gt: np.ndarray,
    gt: np.ndarray,
    *,
    num_classes: int,
    n_things: int,
    ignore: Sequence[int] = (0,),
    min_points: int = 15,
) -> FrameTracking:
    """Panoptic tracking counts of one frame.

    Parameters
    ----------
    sem_pred, sem_gt : array of shape (n_points,), integer in [0, num_classes)
        Predicted and ground-truth challenge classes.
    pred, gt : array of shape (n_points,), integer in [0, 65535)
        Full panoptic labels (the instance ids of matching). Each label must have one class
        (as in Panoptic nuScenes, where the class is ``label // 1000`` or its mapping), so a
        segment is its label and counting needs no sort.
    num_classes : int
    n_things : int
        Thing classes are ``1..n_things`` (the devkit's ``min_stuff_cls_id - 1``).
    ignore : sequence of int
    min_points : int

    Returns
    -------
    FrameTracking

    Raises
    ------
    ValueError
        Mismatched lengths, values out of range, or a label with two classes.
    """
    C = int(num_classes)
    sp = np.asarray(sem_pred).astype(np.int64).ravel()
    sg = np.asarray(sem_gt).astype(np.int64).ravel()
    xp = np.asarray(pred).astype(np.int64).ravel() + 1
    yg = np.asarray(gt).astype(np.int64).ravel() + 1
    if not (len(sp) == len(sg) == len(xp) == len(yg)):
        raise ValueError("the four label arrays must have the same length")
    for name, a, hi in (("sem_pred", sp, C), ("sem_gt", sg, C), ("pred", xp, 1 << _B)):
        if a.size and (a.min() < 0 or a.max() >= hi):
            raise ValueError(f"{name} out of range")
    if yg.size and (yg.min() < 1 or yg.max() >= 1 << _B):
        raise ValueError("gt labels out of range")
    conf = np.bincount(sp * C + sg, minlength=C * C).reshape(C, C).astype(np.int64)
    ignored = np.zeros(C, dtype=bool)
    ignored[list(ignore)] = True
    keep = ~ignored[sg]
    sp, sg, xp, yg = sp[keep], sg[keep], xp[keep], yg[keep]
    thing = np.zeros(C, dtype=bool)
    thing[1 : n_things + 1] = True
    size = 1 << _B
    # a label determines its class (pred: label // 1000; gt: the class map), so a segment is
    # its label: segments are counted with dense bincounts, pairs on the distinct labels
    cls_p = np.zeros(size, dtype=np.int64)
    cls_p[xp] = sp
    cls_g = np.zeros(size, dtype=np.int64)
    cls_g[yg] = sg
    if not (np.array_equal(cls_p[xp], sp) and np.array_equal(cls_g[yg], sg)):
        raise ValueError("every label must have one class (class = function of the label)")
    g_count = np.bincount(yg, minlength=size)
    a_count = np.bincount(xp, minlength=size)  # class-agnostic predicted labels
    gk, ak = np.flatnonzero(g_count), np.flatnonzero(a_count)
    gc, ac = g_count[gk], a_count[ak]
    g_index = np.zeros(size, dtype=np.int64)
    g_index[gk] = np.arange(len(gk))
    a_index = np.zeros(size, dtype=np.int64)
    a_index[ak] = np.arange(len(ak))

    def pairs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(gt label, pred label, count) of the points in ``mask``, sorted by gt then pred."""
        code = np.bincount(g_index[yg[mask]] * len(ak) + a_index[xp[mask]],
                           minlength=len(gk) * len(ak))  # fmt: skip
        cells = np.flatnonzero(code)
        return gk[cells // len(ak)], ak[cells % len(ak)], code[cells]

    # class-specific segments and matching
    pin = ~ignored[sp]
    p_count = np.bincount(xp[pin], minlength=size)
    pk = np.flatnonzero(p_count)
    pc = p_count[pk]
    ig, ipk, ic = pairs(pin & (sp == sg))
    iou = ic.astype(np.float32) / (g_count[ig] + p_count[ipk] - ic).astype(np.float32)
    tp = iou > 0.5
    cl_of = cls_g[ig]
    tp_n = np.bincount(cl_of[tp], minlength=C)
    iou32 = np.zeros(C, dtype=np.float32)
    tcl = cl_of[tp]
    tiou = iou[tp]
    for c in np.unique(tcl):
        iou32[c] = np.sum(tiou[tcl == c])  # float32 sum in key order, as the devkit
    g_matched = np.isin(gk, ig[tp])
    p_matched = np.isin(pk, ipk[tp])
    fn = np.bincount(cls_g[gk[(gc >= min_points) & ~g_matched]], minlength=C)
    fp = np.bincount(cls_p[pk[(pc >= min_points) & ~p_matched]], minlength=C)
    mt = tp & thing[cl_of]
    m_key = (cl_of[mt] << _B) | ig[mt]
    m_order = np.argsort(m_key, kind="stable")
    match_keys, match_pred, match_iou = m_key[m_order], ipk[mt][m_order], iou[mt][m_order]

    # tubes of thing classes (LSTQ) and class-agnostic tracks (TQ)
    g_big = thing[cls_g[gk]] & (gc > min_points)
    p_big = thing[cls_p[pk]] & (pc > min_points)
    valid = np.zeros(size, dtype=bool)
    valid[gk[g_big]] = True
    v_g, v_p, vc = pairs(valid[yg])
    v_key = ((cls_g[v_g] << _B) | v_g) << 32 | v_p
    v_order = np.argsort(v_key, kind="stable")
    t_key = (cls_g[gk[g_big]] << _B) | gk[g_big]
    t_order = np.argsort(t_key, kind="stable")
    tubes = SequenceTubes(t_key[t_order], gc[g_big][t_order], pk[p_big], pc[p_big],
                          v_key[v_order], vc[v_order])  # fmt: skip
    a_iou = vc.astype(np.float32) / (g_count[v_g] + a_count[v_p] - vc).astype(np.float32)
    hit = a_iou > 0.5
    tracks = gk[g_big]
    matched_tr = np.isin(tracks, v_g[hit])
    labels = np.concatenate([v_g[hit], tracks[~matched_tr]])
    preds = np.concatenate([v_p[hit], np.ones(int((~matched_tr).sum()), dtype=np.int64)])
    keys = (cls_g[labels] << _B) | labels
    flag = np.r_[np.zeros(int(hit.sum())), np.ones(len(keys) - int(hit.sum()))]
    order = np.lexsort((flag, keys >> _B))
    return FrameTracking(
        conf=conf,
        tp=tp_n.astype(np.int64),
        fp=fp.astype(np.int64),
        fn=fn.astype(np.int64),
        iou32=iou32,
        match_keys=match_keys,
        match_pred=match_pred,
        match_iou=match_iou,
        tubes=tubes,
        big_preds=ak[ac > min_points],
        track_keys=keys[order],
        track_pred=preds[order],
    )


@dataclass
class SceneTracking:
    """Frames of one scene added in order with :meth:`add`; :meth:`finish` gives the counts."""

    num_classes: int
    ids: np.ndarray = field(init=False)
    soft_ids: np.ndarray = field(init=False)
    frames: list[FrameTracking] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.ids = np.zeros(self.num_classes, dtype=np.int64)
        self.soft_ids = np.zeros(self.num_classes)
        self._prev: FrameTracking | None = None
        self._pred_frames: dict[int, int] = {}
        self._tracks: dict[int, list[int]] = {}
        self._tubes = SequenceTubes()

    def add(self, f: FrameTracking) -> None:
        """Add the next frame of the scene."""
        if self._prev is not None:
            _, a, b = np.intersect1d(self._prev.match_keys, f.match_keys, return_indices=True)
            switched = self._prev.match_pred[a] != f.match_pred[b]
            for key, s, v in zip(f.match_keys[b], switched, f.match_iou[b]):
                if s:
                    c = int(key >> _B)
                    self.ids[c] += 1
                    self.soft_ids[c] += float(v)
        self._prev = f
        for p in f.big_preds.tolist():
            self._pred_frames[p] = self._pred_frames.get(p, 0) + 1
        for k, p in zip(f.track_keys.tolist(), f.track_pred.tolist()):
            self._tracks.setdefault(k, []).append(p)
        self._tubes = self._tubes + f.tubes
        self.frames.append(f)

    def tq_terms(self) -> list[float]:
        """sqrt(AQ * IS) of every ground-truth track, in the devkit's order."""
        out = []
        for key in sorted(self._tracks, key=lambda k: k >> _B):  # classes in order, stable
            prs = self._tracks[key]
            u, n = np.unique(prs, return_counts=True)
            length = len(prs)
            n = n[u != 1]
            u = u[u != 1]
            fp = np.array([self._pred_frames[p] - k if p in self._pred_frames else 0
                           for p, k in zip(u.tolist(), n.tolist())], dtype=np.int64)  # fmt: skip
            aq = np.sum(n**2 / (length + fp).astype(np.double)) / np.double(length)
            is_ = 1.0
            if length > 1:
                switches = sum(1 for a, b in zip(prs, prs[1:]) if b != a or a == 1)
                is_ = 1 - switches / np.double(length - 1)
            out.append(float(np.sqrt(aq * is_)))
        return out

    def finish(self, name: str, n_things: int, ignore: Sequence[int]) -> TrackingStats:
        """The scene's counts as :class:`TrackingStats`."""
        C = self.num_classes
        z = np.zeros(C, dtype=np.int64)
        conf, tp, fp, fn = np.zeros((C, C), dtype=np.int64), z.copy(), z.copy(), z.copy()
        iou = np.zeros(C)
        for f in self.frames:
            conf += f.conf
            tp += f.tp
            fp += f.fp
            fn += f.fn
            iou += f.iou32.astype(np.float64)
        tubes = LSTQStats(C, tuple(ignore), tuple(range(1, n_things + 1)), LSTQMode.REFERENCE,
                          conf, {name: self._tubes})  # fmt: skip
        terms = self.tq_terms()
        return TrackingStats(C, n_things, tuple(ignore), tp, fp, fn, iou, self.ids.copy(),
                             self.soft_ids.copy(), tubes, float(np.sum(terms)) if terms else 0.0,
                             len(terms), len(self.frames))  # fmt: skip


@dataclass(frozen=True)
class TrackingStats:
    """Accumulated panoptic tracking counts; add scenes with ``+``, metrics from :meth:`compute`."""

    num_classes: int
    n_things: int
    ignore: tuple[int, ...]
    tp: np.ndarray
    fp: np.ndarray
    fn: np.ndarray
    iou: np.ndarray
    ids: np.ndarray
    soft_ids: np.ndarray
    tubes: LSTQStats
    tq_sum: float
    tq_count: int
    n_frames: int

    def __add__(self, o: TrackingStats) -> TrackingStats:
        return TrackingStats(self.num_classes, self.n_things, self.ignore, self.tp + o.tp,
                             self.fp + o.fp, self.fn + o.fn, self.iou + o.iou, self.ids + o.ids,
                             self.soft_ids + o.soft_ids, self.tubes + o.tubes,
                             self.tq_sum + o.tq_sum, self.tq_count + o.tq_count,
                             self.n_frames + o.n_frames)  # fmt: skip

    def compute(self, dagger_things: Sequence[int] = (), dagger_stuff: Sequence[int] = ()) -> dict:
        """Devkit ``tracking`` results: ``{"all": {...}, "per_class": {metric: array (C,)}}``."""
        C, T = self.num_classes, self.n_things
        include = np.array([c for c in range(C) if c not in self.ignore])
        tp, fp, fn = (a.astype(np.double) for a in (self.tp, self.fp, self.fn))
        iou, ids, sids = self.iou, self.ids.astype(np.double), self.soft_ids
        tp_eps = np.maximum(tp, EPS)
        rq_den = np.maximum(tp + 0.5 * fp + 0.5 * fn, EPS)
        pq_all = (iou / tp_eps) * (tp / rq_den)
        pq = float(pq_all[include].mean())
        tq = self.tq_sum / self.tq_count if self.tq_count else math.nan
        pat = 2 * pq * tq / (pq + tq) if self.tq_count else math.nan
        ptq = ((iou - ids) / tp_eps) * (tp / rq_den)
        sptq = ((iou - sids) / tp_eps) * (tp / rq_den)
        valid = (tp + fn) > 0.5
        valid[list(self.ignore)] = False
        th = np.zeros(C, dtype=bool)
        th[1 : T + 1] = True
        vt = valid & th
        conf = self.tubes.conf.astype(np.double)
        conf[:, list(self.ignore)] = 0
        inter = conf.diagonal()
        union = np.maximum(conf.sum(axis=1) + conf.sum(axis=0) - inter, EPS)
        class_iou = inter / union
        miou = float((inter[include] / union[include]).mean())
        s_assoc = self.tubes.compute().S_assoc
        with np.errstate(invalid="ignore", divide="ignore"):
            motsa = ((tp - fp - ids)[vt] / (tp_eps + fn)[vt]).mean() if vt.any() else math.nan
            smotsa = ((iou - fp - ids)[vt] / (tp_eps + fn)[vt]).mean() if vt.any() else math.nan
            motsp = (iou[vt] / tp_eps[vt]).mean() if vt.any() else math.nan
        dt = list(dagger_things) or list(range(1, T + 1))
        ds = list(dagger_stuff) or [c for c in include if c > T]
        dagger = float(np.mean([float(ptq[c]) for c in dt] + [float(class_iou[c]) for c in ds]))
        return {
            "all": {
                "PAT": pat,
                "PQ": pq,
                "TQ": tq,
                "PTQ": float(ptq[valid].mean()) if valid.any() else math.nan,
                "sPTQ": float(sptq[valid].mean()) if valid.any() else math.nan,
                "LSTQ": float(np.sqrt(s_assoc * miou)),
                "mIoU": miou,
                "S_assoc": float(s_assoc),
                "MOTSA": float(motsa),
                "sMOTSA": float(smotsa),
                "MOTSP": float(motsp),
                "PTQ_dagger": dagger,
            },
            "per_class": {"PTQ": ptq, "sPTQ": sptq, "IoU": class_iou, "IDS": self.ids.copy()},
        }
