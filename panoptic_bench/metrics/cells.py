"""Points to *cells*: the distinct (pred class, pred id, gt class, gt id) tuples and their sizes.

Every panoptic and semantic count of a scan is a sum over these cells (a scan of ~120k points
has a few hundred), so the per-point work of :func:`~panoptic_bench.metrics.panoptic.panoptic_stats`
is this reduction alone. It is numpy only (``bincount`` and table look-ups, no sort of the
points, no pandas: importing pandas costs more CPU than scoring a hundred scans):

- :func:`factorize` maps ids of any range below 2**32 to dense codes: one ``bincount`` when the
  range is small, else each 16-bit half separately and then their (few) combinations (a sort
  only when there are more than :data:`DENSE_LIMIT` of these);
- :func:`point_cells` factorizes both id arrays, counts the id pairs with one ``bincount`` and
  attaches the classes, checking that they are a function of the pair (true whenever the id
  encodes the class, as full SemanticKITTI labels and nuScenes ``class * 1000 + id`` do);
  otherwise (arbitrary ids) a second factorization over (pair, class pair) cells.

The result does not depend on which path ran (``tests/test_metrics_devkit.py``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["Cells", "factorize", "point_cells"]

#: largest value range counted with a dense ``bincount`` (8 bytes a slot)
DENSE_LIMIT = 1 << 17
#: largest number of possible cells counted with a dense ``bincount`` (tests lower it)
_DENSE_CELL_LIMIT = 1 << 21


def factorize(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Dense codes of non-negative integers below 2**32.

    Parameters
    ----------
    x : array of shape (n,), integer, values in [0, 2**32)

    Returns
    -------
    codes : ndarray of shape (n,), intp
        ``uniques[codes] == x``.
    uniques : ndarray of shape (k,), int64
        The distinct values, sorted.
    """
    x = np.asarray(x).ravel()
    if x.dtype == np.uint64:  # bincount takes no uint64; the values are < 2**32
        x = x.astype(np.int64)
    if x.size == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.int64)
    top = int(x.max())
    if top < DENSE_LIMIT:
        uniq = np.flatnonzero(np.bincount(x, minlength=top + 1))
        lut = np.empty(top + 1, np.intp)
        lut[uniq] = np.arange(len(uniq))
        return lut[x], uniq.astype(np.int64)
    if top < 1 << 16:  # only with DENSE_LIMIT lowered
        uniq, codes = np.unique(x, return_inverse=True)
        return codes, uniq.astype(np.int64)
    x32 = x.astype(np.uint32, copy=False)
    lo, lo_u = factorize(x32 & 0xFFFF)
    hi, hi_u = factorize(x32 >> 16)
    n_lo = len(lo_u)
    both = hi * n_lo + lo  # < 2**32: the halves' combinations present
    if len(hi_u) * n_lo < DENSE_LIMIT:
        codes, combo = factorize(both)
    else:
        combo, codes = np.unique(both, return_inverse=True)
    uniq = (hi_u[combo // n_lo] << 16) | lo_u[combo % n_lo]
    return codes, uniq


class Cells:
    """The distinct cells of a set of points.

    Attributes
    ----------
    sem_pred, inst_pred, sem_gt, inst_gt : ndarray of shape (k,), int64
        Class and id of each cell's prediction and ground truth.
    count : ndarray of shape (k,), int64
        Points per cell (> 0).
    """

    __slots__ = ("count", "inst_gt", "inst_pred", "sem_gt", "sem_pred")

    def __init__(self, sem_pred, inst_pred, sem_gt, inst_gt, count) -> None:
        self.sem_pred = np.asarray(sem_pred, np.int64)
        self.inst_pred = np.asarray(inst_pred, np.int64)
        self.sem_gt = np.asarray(sem_gt, np.int64)
        self.inst_gt = np.asarray(inst_gt, np.int64)
        self.count = np.asarray(count, np.int64)


def _count_pairs(codes: np.ndarray, n_codes: int) -> tuple[np.ndarray, np.ndarray]:
    """Distinct codes in [0, n_codes) and their counts; dense codes of the points."""
    if n_codes <= _DENSE_CELL_LIMIT:
        counts = np.bincount(codes, minlength=n_codes)
        present = np.flatnonzero(counts)
        lut = np.empty(n_codes, np.intp)
        lut[present] = np.arange(len(present))
        return present, counts[present], lut[codes]
    present, inverse = np.unique(codes, return_inverse=True)
    return present, np.bincount(inverse, minlength=len(present)), inverse


def point_cells(
    sem_pred: np.ndarray,
    inst_pred: np.ndarray,
    sem_gt: np.ndarray,
    inst_gt: np.ndarray,
    num_classes: int,
) -> Cells:
    """Reduce points to their cells.

    Parameters
    ----------
    sem_pred, sem_gt : array of shape (n,), integer in [0, num_classes)
    inst_pred, inst_gt : array of shape (n,), integer in [0, 2**32)
    num_classes : int

    Returns
    -------
    Cells
    """
    g, g_u = factorize(inst_gt)
    p, p_u = factorize(inst_pred)
    n_p = max(len(p_u), 1)
    pairs, cnt, pair_of = _count_pairs(g * n_p + p, len(g_u) * n_p)
    C = int(num_classes)
    sub = sem_pred.astype(np.int64) * C + sem_gt
    first = np.empty(len(pairs), np.int64)
    first[pair_of] = sub
    if not np.array_equal(first[pair_of], sub):  # classes not a function of the ids
        cc = C * C
        pairs2, cnt, _ = _count_pairs(pair_of * cc + sub, len(pairs) * cc)
        pairs, first = pairs[pairs2 // cc], pairs2 % cc
    c_sp, c_sg = np.divmod(first, C)
    return Cells(c_sp, p_u[pairs % n_p], c_sg, g_u[pairs // n_p], cnt)
