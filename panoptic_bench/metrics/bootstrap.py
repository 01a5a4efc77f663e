"""Scan-level bootstrap of panoptic metrics: confidence intervals and paired comparisons.

A dataset score is computed from the *sum* of per-scan :class:`PanopticStats` (PQ, mIoU are
not means over scans). A bootstrap replicate draws ``n_scans`` scans with replacement and sums
their counts with the drawn multiplicities: ``W @ X`` with ``W`` of shape (n_boot, n_scans)
(multinomial counts) and ``X`` the stacked per-scan counts. Every replicate is then scored by
:meth:`PanopticStats.compute` / :meth:`~PanopticResult.summary`, the same formulas as the point
estimate, so replicate ``b`` with ``W[b] = 1`` reproduces the dataset score (counts exactly,
IoU sums to float round-off: the matrix product adds them in another order).

A *paired* comparison of two prediction sets of the same scans uses the same ``W`` for both
and reports the distribution of the difference ``B - A`` (the scan-to-scan variation that both
share cancels out).

The resampling unit is whatever one accumulator stands for: a scan, or (with the per-scan counts
summed per sequence first, ``unit="sequence"``) a whole sequence. Caveat written into every
output: consecutive scans of one sequence are correlated, so scan-level intervals are narrower
than the uncertainty about new places (a lower bound on the noise); sequence-level intervals
answer "another set of places like these", but are coarse with few sequences.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from panoptic_bench.metrics.accumulator import PanopticStats

__all__ = [
    "BootstrapResult",
    "Resampling",
    "PairedResult",
    "bootstrap",
    "paired_bootstrap",
    "resample_counts",
]

CAVEATS = {
    "scan": (
        "scan-level bootstrap: scans of one sequence are correlated, so the interval is a lower "
        "bound on the uncertainty about unseen places"
    ),
    "sequence": (
        "sequence-level bootstrap: whole sequences (places) are resampled; with few sequences "
        "the interval is coarse"
    ),
}


def resample_counts(n_scans: int, n_boot: int, seed: int = 0) -> np.ndarray:
    """Multiplicity of every scan in every replicate.

    Returns
    -------
    ndarray of shape (n_boot, n_scans), int64
        Row ``b`` sums to ``n_scans`` (a draw of ``n_scans`` scans with replacement).
    """
    if n_scans < 1 or n_boot < 1:
        raise ValueError(f"need at least one scan and one replicate, got {n_scans}, {n_boot}")
    rng = np.random.default_rng(seed)
    return rng.multinomial(n_scans, np.full(n_scans, 1.0 / n_scans), size=n_boot).astype(np.int64)


def _stack(per_scan: Sequence[PanopticStats]) -> tuple[np.ndarray, ...]:
    if not per_scan:
        raise ValueError("no scans to resample")
    first = per_scan[0]
    if any(s.num_classes != first.num_classes or s.ignore != first.ignore for s in per_scan):
        raise ValueError("per-scan stats differ in classes or ignore ids")
    C = first.num_classes
    tp = np.stack([s.tp for s in per_scan]).astype(np.int64)
    fp = np.stack([s.fp for s in per_scan]).astype(np.int64)
    fn = np.stack([s.fn for s in per_scan]).astype(np.int64)
    iou = np.stack([s.iou_sum for s in per_scan]).astype(np.float64)
    conf = np.stack([s.confusion.reshape(C * C) for s in per_scan]).astype(np.int64)
    return tp, fp, fn, iou, conf


def _replicates(
    per_scan: Sequence[PanopticStats], counts: np.ndarray, things, stuff
) -> dict[str, np.ndarray]:
    tp, fp, fn, iou, conf = _stack(per_scan)
    if counts.shape[1] != len(per_scan):
        raise ValueError(f"counts have {counts.shape[1]} scans, stats {len(per_scan)}")
    C, ignore = per_scan[0].num_classes, per_scan[0].ignore
    sums = (counts @ tp, counts @ fp, counts @ fn, counts.astype(np.float64) @ iou, counts @ conf)
    out: dict[str, list[float]] = {}
    for b in range(counts.shape[0]):
        st = PanopticStats(
            sums[0][b], sums[1][b], sums[2][b], sums[3][b], sums[4][b].reshape(C, C), ignore
        )
        for key, value in st.compute().summary(things, stuff).items():
            out.setdefault(key, []).append(value)
    return {k: np.asarray(v, dtype=np.float64) for k, v in out.items()}


def _interval(samples: np.ndarray, level: float) -> tuple[float, float]:
    alpha = (1.0 - level) / 2.0
    lo, hi = np.nanquantile(samples, [alpha, 1.0 - alpha])
    return float(lo), float(hi)


@dataclass(frozen=True)
class Resampling:
    """How the replicates were drawn: coverage, replicate count, units, seed and unit kind."""

    level: float
    n_boot: int
    n_units: int
    seed: int
    unit: str = "scan"

    def __post_init__(self) -> None:
        if self.unit not in CAVEATS:
            raise ValueError(f"unit must be one of {sorted(CAVEATS)}, got {self.unit!r}")

    def to_dict(self) -> dict:
        return {
            "level": self.level,
            "n_boot": self.n_boot,
            "n_units": self.n_units,
            "seed": self.seed,
            "unit": self.unit,
            "caveat": CAVEATS[self.unit],
        }


@dataclass(frozen=True)
class BootstrapResult:
    """Point estimates and percentile intervals of the headline metrics.

    Attributes
    ----------
    estimate : dict of str to float
        The metrics of all scans (as :meth:`PanopticResult.summary`).
    low, high : dict of str to float
        Percentile interval bounds at ``resampling.level``.
    resampling : Resampling
    """

    estimate: dict[str, float]
    low: dict[str, float]
    high: dict[str, float]
    resampling: Resampling

    def to_dict(self) -> dict:
        return {
            **self.resampling.to_dict(),
            "metrics": {
                k: {"estimate": v, "low": self.low[k], "high": self.high[k]}
                for k, v in self.estimate.items()
            },
        }


def bootstrap(
    per_scan: Sequence[PanopticStats],
    things: Sequence[int],
    stuff: Sequence[int],
    n_boot: int = 1000,
    level: float = 0.95,
    seed: int = 0,
    unit: str = "scan",
) -> BootstrapResult:
    """Percentile bootstrap intervals of PQ, mIoU, ... over scans.

    Parameters
    ----------
    per_scan : sequence of PanopticStats
        One accumulator per scan (same classes).
    things, stuff : sequence of int
        As :meth:`PanopticResult.summary`.
    n_boot : int
        Replicates.
    level : float
        Interval coverage in (0, 1).
    seed : int
        Seed of the resampling (results are deterministic per seed).
    unit : {"scan", "sequence"}
        What one accumulator of ``per_scan`` stands for (recorded in the result).
    """
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    estimate = sum(per_scan, PanopticStats.zeros(per_scan[0].num_classes, per_scan[0].ignore))
    point = estimate.compute().summary(things, stuff)
    reps = _replicates(per_scan, resample_counts(len(per_scan), n_boot, seed), things, stuff)
    bounds = {k: _interval(v, level) for k, v in reps.items()}
    return BootstrapResult(
        point,
        {k: b[0] for k, b in bounds.items()},
        {k: b[1] for k, b in bounds.items()},
        Resampling(level, n_boot, len(per_scan), seed, unit),
    )


@dataclass(frozen=True)
class PairedResult:
    """Paired bootstrap of ``B - A`` on the same scans.

    Attributes
    ----------
    a, b : dict of str to float
        Metrics of the two prediction sets on all scans.
    low, high : dict of str to float
        Percentile interval of the difference ``B - A``.
    p_b_greater : dict of str to float
        Fraction of replicates where B scores strictly higher than A.
    resampling : Resampling
    """

    a: dict[str, float]
    b: dict[str, float]
    low: dict[str, float]
    high: dict[str, float]
    p_b_greater: dict[str, float]
    resampling: Resampling

    def to_dict(self) -> dict:
        return {
            **self.resampling.to_dict(),
            "metrics": {
                k: {
                    "a": self.a[k],
                    "b": self.b[k],
                    "diff": self.b[k] - self.a[k],
                    "low": self.low[k],
                    "high": self.high[k],
                    "p_b_greater": self.p_b_greater[k],
                }
                for k in self.a
            },
        }


def paired_bootstrap(
    per_scan_a: Sequence[PanopticStats],
    per_scan_b: Sequence[PanopticStats],
    things: Sequence[int],
    stuff: Sequence[int],
    n_boot: int = 1000,
    level: float = 0.95,
    seed: int = 0,
    unit: str = "scan",
) -> PairedResult:
    """Paired bootstrap of two prediction sets scored on the same scans (same order).

    ``unit`` as in :func:`bootstrap`.
    """
    if len(per_scan_a) != len(per_scan_b):
        raise ValueError(f"A has {len(per_scan_a)} scans, B {len(per_scan_b)}")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    counts = resample_counts(len(per_scan_a), n_boot, seed)
    ra = _replicates(per_scan_a, counts, things, stuff)
    rb = _replicates(per_scan_b, counts, things, stuff)
    zero = PanopticStats.zeros(per_scan_a[0].num_classes, per_scan_a[0].ignore)
    a = sum(per_scan_a, zero).compute().summary(things, stuff)
    b = sum(per_scan_b, zero).compute().summary(things, stuff)
    low, high, p = {}, {}, {}
    for k in a:
        d = rb[k] - ra[k]
        low[k], high[k] = _interval(d, level)
        p[k] = float(np.mean(d > 0))
    return PairedResult(a, b, low, high, p, Resampling(level, n_boot, len(per_scan_a), seed, unit))
