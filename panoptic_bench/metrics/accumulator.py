"""The addable accumulator of panoptic and semantic counts and the metrics computed from it.

:class:`PanopticStats` holds the per-class counts of :func:`panoptic_bench.metrics.panoptic.panoptic_stats`
(add them with ``+`` across scans or worker processes); ``.compute()`` turns them into a
:class:`PanopticResult` with the formulas of the official evaluator (see the module docstring of
:mod:`panoptic_bench.metrics.panoptic` for the rules).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

EPS = 1e-15

__all__ = ["EPS", "PanopticResult", "PanopticStats"]


@dataclass(eq=False)
class PanopticStats:
    """Accumulated panoptic and semantic counts; add with ``+`` (e.g. across worker processes).

    Attributes
    ----------
    tp, fp, fn : ndarray of shape (C,), int64
        Matched segments, unmatched predicted and unmatched gt segments (>= min_points), per class.
    iou_sum : ndarray of shape (C,), float64
        Sum of the IoU of the matched pairs, per class.
    confusion : ndarray of shape (C, C), int64
        Point confusion matrix, rows = prediction, columns = ground truth.
    ignore : tuple of int
        Ignored class ids.
    """

    tp: np.ndarray
    fp: np.ndarray
    fn: np.ndarray
    iou_sum: np.ndarray
    confusion: np.ndarray
    ignore: tuple[int, ...] = (0,)

    def __post_init__(self) -> None:
        self.ignore = tuple(sorted({int(c) for c in self.ignore}))
        C = len(self.tp)
        if any(c < 0 or c >= C for c in self.ignore):
            raise ValueError(f"ignore ids {self.ignore} outside [0, {C})")
        for name in ("fp", "fn", "iou_sum"):
            if np.shape(getattr(self, name)) != (C,):
                raise ValueError(f"{name} must have shape ({C},)")
        if np.shape(self.confusion) != (C, C):
            raise ValueError(f"confusion must have shape ({C}, {C})")

    @property
    def num_classes(self) -> int:
        """Number of classes C."""
        return len(self.tp)

    @classmethod
    def zeros(cls, num_classes: int, ignore: Sequence[int] = (0,)) -> PanopticStats:
        """An empty accumulator for ``num_classes`` classes."""
        C = int(num_classes)
        z = np.zeros(C, dtype=np.int64)
        return cls(
            z.copy(), z.copy(), z.copy(), np.zeros(C), np.zeros((C, C), np.int64), tuple(ignore)
        )

    def __add__(self, other: PanopticStats) -> PanopticStats:
        if not isinstance(other, PanopticStats):
            return NotImplemented
        if other.num_classes != self.num_classes or other.ignore != self.ignore:
            raise ValueError("cannot add PanopticStats with different classes or ignore ids")
        return PanopticStats(
            self.tp + other.tp,
            self.fp + other.fp,
            self.fn + other.fn,
            self.iou_sum + other.iou_sum,
            self.confusion + other.confusion,
            self.ignore,
        )

    def __radd__(self, other: object) -> PanopticStats:
        if other == 0:  # allows sum(list_of_stats)
            return self
        return NotImplemented

    def to_dict(self) -> dict:
        """Plain-Python form (lists), e.g. for JSON or sending between processes."""
        return {
            "tp": self.tp.tolist(),
            "fp": self.fp.tolist(),
            "fn": self.fn.tolist(),
            "iou_sum": self.iou_sum.tolist(),
            "confusion": self.confusion.tolist(),
            "ignore": list(self.ignore),
        }

    @classmethod
    def from_dict(cls, data: dict) -> PanopticStats:
        """Inverse of :meth:`to_dict`; unknown keys are rejected."""
        keys = {"tp", "fp", "fn", "iou_sum", "confusion", "ignore"}
        if set(data) != keys:
            raise ValueError(f"PanopticStats keys must be {sorted(keys)}, got {sorted(data)}")
        i64 = np.int64
        return cls(
            np.asarray(data["tp"], i64),
            np.asarray(data["fp"], i64),
            np.asarray(data["fn"], i64),
            np.asarray(data["iou_sum"], np.float64),
            np.asarray(data["confusion"], i64),
            tuple(data["ignore"]),
        )

    def compute(self) -> PanopticResult:
        """Per-class PQ/SQ/RQ/IoU and their means, from the accumulated counts only."""
        tp = self.tp.astype(np.float64)
        sq = self.iou_sum / np.maximum(tp, EPS)
        rq = tp / np.maximum(tp + 0.5 * self.fp + 0.5 * self.fn, EPS)
        pq = sq * rq

        conf = self.confusion.astype(np.float64)
        conf[:, list(self.ignore)] = 0
        ctp = conf.diagonal().copy()
        cfp = conf.sum(axis=1) - ctp
        cfn = conf.sum(axis=0) - ctp
        union = np.maximum(ctp + cfp + cfn, EPS)
        iou = ctp / union
        include = tuple(c for c in range(self.num_classes) if c not in self.ignore)
        inc = list(include)
        accuracy = ctp.sum() / np.maximum(ctp[inc].sum() + cfp[inc].sum(), EPS)
        present = tuple(c for c in include if ctp[c] + cfn[c] > 0)
        return PanopticResult(
            pq=pq,
            sq=sq,
            rq=rq,
            iou=iou,
            include=include,
            accuracy=float(accuracy),
            pq_mean=float(pq[inc].mean()),
            sq_mean=float(sq[inc].mean()),
            rq_mean=float(rq[inc].mean()),
            miou=float(iou[inc].mean()),
            present=present,
            miou_present=float(iou[list(present)].mean()) if present else float("nan"),
        )


@dataclass(frozen=True, eq=False)
class PanopticResult:
    """Metrics computed from a :class:`PanopticStats` (all fractions in [0, 1]).

    Attributes
    ----------
    pq, sq, rq, iou : ndarray of shape (C,), float64
        Per-class values (ignored classes included as computed, never averaged).
    include : tuple of int
        Class ids averaged in the means.
    pq_mean, sq_mean, rq_mean, miou, accuracy : float
        Means over ``include`` and the point accuracy.
    present : tuple of int
        The included classes with at least one ground-truth point.
    miou_present : float
        Mean IoU over ``present`` only (NaN when no class is present). Not an official key: the
        official ``miou`` averages all included classes, an absent class counting 0.
    """

    pq: np.ndarray
    sq: np.ndarray
    rq: np.ndarray
    iou: np.ndarray
    include: tuple[int, ...]
    accuracy: float
    pq_mean: float
    sq_mean: float
    rq_mean: float
    miou: float
    present: tuple[int, ...] = ()
    miou_present: float = float("nan")

    def summary(self, things: Sequence[int], stuff: Sequence[int]) -> dict[str, float]:
        """The headline numbers, as the official ``evaluate_panoptic.py`` computes them.

        Parameters
        ----------
        things, stuff : sequence of int
            Class ids of thing and stuff classes; together exactly the included classes.

        Returns
        -------
        dict of str to float
            ``PQ, PQ_dagger, SQ, RQ, PQ_th, SQ_th, RQ_th, PQ_st, SQ_st, RQ_st, mIoU, accuracy,
            mIoU_present``. ``PQ_dagger`` averages thing PQ and stuff IoU; ``mIoU_present`` is
            the mean IoU over the classes with ground truth (not an official key).
        """
        th, st = [int(c) for c in things], [int(c) for c in stuff]
        if set(th) & set(st) or sorted(th + st) != sorted(self.include):
            raise ValueError(
                f"things {th} and stuff {st} must partition the included classes {self.include}"
            )

        def mean(arr: np.ndarray, ids: list[int]) -> float:
            return float(np.mean(arr[ids])) if ids else float("nan")

        allc = th + st
        return {
            "PQ": mean(self.pq, allc),
            "PQ_dagger": float(np.mean(np.concatenate([self.pq[th], self.iou[st]]))),
            "SQ": mean(self.sq, allc),
            "RQ": mean(self.rq, allc),
            "PQ_th": mean(self.pq, th),
            "SQ_th": mean(self.sq, th),
            "RQ_th": mean(self.rq, th),
            "PQ_st": mean(self.pq, st),
            "SQ_st": mean(self.sq, st),
            "RQ_st": mean(self.rq, st),
            "mIoU": self.miou,
            "accuracy": self.accuracy,
            "mIoU_present": self.miou_present,
        }

    def per_class(self, class_names: Sequence[str]) -> dict[str, dict[str, float]]:
        """``{name: {"PQ", "SQ", "RQ", "IoU"}}`` for the included classes, as Python floats."""
        return {
            class_names[c]: {
                "PQ": float(self.pq[c]),
                "SQ": float(self.sq[c]),
                "RQ": float(self.rq[c]),
                "IoU": float(self.iou[c]),
            }
            for c in self.include
        }
