"""One SemanticKITTI scan from its two label files to panoptic counts, in a few passes.

A full label (high 16 bits instance, low 16 bits raw class) is both the segment id and, through
``learning_map``, the class. So the per-point work of a scan is only:

1. per file: one look-up of the low halves in a 65536-entry table giving the raw id's index
   among the defined raw ids (255 = undefined: the checked error of
   :func:`~panoptic_bench.evaluation.semantickitti.check_label_ids`), one ``bincount`` of the
   high halves (instance ids present) and one look-up turning them into dense codes;
2. one ``bincount`` of the (gt code, prediction code) pairs: the scan's *cells*.

Classes, full labels and segment sizes then come from the few hundred cells, and
:func:`~panoptic_bench.metrics.panoptic.stats_from_cells` turns them into exactly the counts of
:func:`~panoptic_bench.metrics.panoptic.panoptic_stats` (tested equal in
``tests/test_eval_semantickitti_cells.py``).
"""

from __future__ import annotations

import sys

import numpy as np

from panoptic_bench.datasets import semantickitti as sk
from panoptic_bench.metrics.panoptic import PanopticStats, stats_from_cells

__all__ = [
    "RAW_IDS",
    "RAW_TRAIN",
    "label_codes",
    "label_halves",
    "scan_cells",
    "scan_stats",
    "train_ids",
]

#: the defined raw semantic ids, sorted; a raw id's position here is its *raw index*
RAW_IDS = np.flatnonzero(sk.LABELS.valid_raw).astype(np.int64)
_N_RAW = len(RAW_IDS)
_UNDEFINED = 255
assert _N_RAW < _UNDEFINED
_RAW_INDEX = np.full(sk.LUT_SIZE, _UNDEFINED, np.uint8)
_RAW_INDEX[RAW_IDS] = np.arange(_N_RAW)
#: train id of each raw index
RAW_TRAIN = sk.LABELS.train_lut[RAW_IDS].astype(np.int64)
#: label code ranges up to this size skip the search for the instance ids present
_DIRECT_CODES = 1 << 16
#: pair spaces up to this size are counted with a dense ``bincount`` (tests lower both)
_DENSE_PAIRS = 1 << 16


def label_halves(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) 16-bit halves of uint32 labels, as views where the byte order allows."""
    if sys.byteorder == "little" and labels.dtype == np.uint32:
        v = labels.view(np.uint16)
        return v[0::2], v[1::2]
    return (labels & 0xFFFF).astype(np.uint16), (labels >> 16).astype(np.uint16)


def label_codes(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Dense codes of full labels.

    Parameters
    ----------
    labels : array of shape (n,), uint32

    Returns
    -------
    (codes, instances) or None
        ``codes`` of shape (n,), int32: ``instance index * len(RAW_IDS) + raw index``, where
        ``instances`` (shape (k,), int64, sorted) holds the instance id of each index (all ids
        up to the largest one when they are few, else only those present). None when a label
        has an undefined raw id.
    """
    lo, hi = label_halves(labels)
    raw = np.take(_RAW_INDEX, lo)
    if raw.size and raw.max() == _UNDEFINED:
        return None
    top = int(hi.max(initial=0))
    if (top + 1) * _N_RAW <= _DIRECT_CODES:  # small ids: the id itself is the index
        codes = np.multiply(hi, _N_RAW, dtype=np.int32)
        inst = np.arange(top + 1, dtype=np.int64)
    else:
        inst = np.flatnonzero(np.bincount(hi, minlength=top + 1))
        lut = np.empty(top + 1, np.int32)
        lut[inst] = np.arange(len(inst), dtype=np.int32) * _N_RAW
        codes = np.take(lut, hi)
        inst = inst.astype(np.int64)
    codes += raw
    return codes, inst


def _compress(codes: np.ndarray, n_codes: int) -> tuple[np.ndarray, np.ndarray]:
    """Codes in [0, n_codes) to dense ones: (new codes, old code of each new one)."""
    present = np.flatnonzero(np.bincount(codes, minlength=n_codes))
    lut = np.empty(n_codes, np.int32)
    lut[present] = np.arange(len(present), dtype=np.int32)
    return np.take(lut, codes), present


def _decode(code: np.ndarray, inst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(train id, full label) of label codes, both int64."""
    i, r = np.divmod(code, _N_RAW)
    return RAW_TRAIN[r], (inst[i] << 16) | RAW_IDS[r]


def scan_cells(
    gt: tuple[np.ndarray, np.ndarray], pred: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, ...]:
    """The cells of a scan from the :func:`label_codes` of its two files.

    Returns
    -------
    (sem_pred, label_pred, sem_gt, label_gt, count)
        Arrays of shape (k,), int64: train ids, full labels and points of each distinct
        (gt label, predicted label) pair.
    """
    (g, g_inst), (p, p_inst) = gt, pred
    n_g, n_p = len(g_inst) * _N_RAW, len(p_inst) * _N_RAW
    g, g_of = _compress(g, n_g)  # ground truth: a few dozen labels a scan
    n_g = len(g_of)
    p_of = None
    if n_g * n_p > _DENSE_PAIRS:
        p, p_of = _compress(p, n_p)
        n_p = len(p_of)
    if n_g * n_p > _DENSE_PAIRS:  # only with thousands of labels in both files
        pairs, inverse = np.unique(g.astype(np.int64) * n_p + p, return_inverse=True)
        count = np.bincount(inverse, minlength=len(pairs))
    else:
        pair = g * np.int32(n_p)  # < 2**16: int32 arithmetic is exact
        pair += p
        count = np.bincount(pair, minlength=n_g * n_p)
        pairs = np.flatnonzero(count)
        count = count[pairs]
    gc, pc = np.divmod(pairs, n_p)
    gc = g_of[gc]
    if p_of is not None:
        pc = p_of[pc]
    sg, lg = _decode(gc, g_inst)
    sp, lp = _decode(pc, p_inst)
    return sp, lp, sg, lg, count.astype(np.int64)


def scan_stats(
    gt: tuple[np.ndarray, np.ndarray], pred: tuple[np.ndarray, np.ndarray], min_points: int
) -> PanopticStats:
    """:func:`~panoptic_bench.metrics.panoptic.panoptic_stats` of a scan from its label codes."""
    kw = {"num_classes": sk.LABELS.num_classes, "ignore": sk.LABELS.ignore_ids}
    return stats_from_cells(*scan_cells(gt, pred), min_points=min_points, **kw)


def train_ids(codes: np.ndarray) -> np.ndarray:
    """Per-point train ids (uint8) from :func:`label_codes` codes (for per-range statistics)."""
    return RAW_TRAIN.astype(np.uint8)[codes % _N_RAW]
