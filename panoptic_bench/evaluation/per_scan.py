"""Per-scan statistics file of an evaluation (``per_scan.npz``) and the paired comparison of two.

``eval semantickitti`` writes, beside ``scores.json``, the counts of every scan::

    per_scan.npz: scan (S,) str "SEQ/FRAME"; tp, fp, fn (S, C) int64; iou_sum (S, C) float64;
                  confusion (S, C, C) int64; ignore, things, stuff (k,) int64; class_names (C,) str

Summed over the scans they are exactly the dataset's :class:`PanopticStats`, so the file is enough
to bootstrap confidence intervals (:mod:`panoptic_bench.metrics.bootstrap`) and to compare two
prediction sets of the same scans without re-reading any label file (``eval compare``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from panoptic_bench.errors import InputError
from panoptic_bench.io import read_npz, write_npz
from panoptic_bench.metrics.accumulator import PanopticStats
from panoptic_bench.metrics.bootstrap import PairedResult, paired_bootstrap

FILE = "per_scan.npz"
KEYS = (
    "scan",
    "tp",
    "fp",
    "fn",
    "iou_sum",
    "confusion",
    "ignore",
    "things",
    "stuff",
    "class_names",
)

__all__ = ["FILE", "PerScan", "by_sequence", "compare", "read_per_scan", "write_per_scan"]


@dataclass(frozen=True)
class PerScan:
    """The per-scan counts of one evaluation.

    Attributes
    ----------
    scans : tuple of str
        Scan ids, ``SEQ/FRAME``, in evaluation order.
    stats : tuple of PanopticStats
        One per scan.
    things, stuff : tuple of int
        Class ids of the summary (as :meth:`PanopticResult.summary`).
    class_names : tuple of str
    """

    scans: tuple[str, ...]
    stats: tuple[PanopticStats, ...]
    things: tuple[int, ...]
    stuff: tuple[int, ...]
    class_names: tuple[str, ...]


def by_sequence(per: PerScan) -> PerScan:
    """The counts summed per sequence (scan ids ``SEQ/FRAME`` -> ``SEQ``), in first-seen order."""
    groups: dict[str, PanopticStats] = {}
    for scan, st in zip(per.scans, per.stats):
        seq = scan.split("/", 1)[0]
        groups[seq] = groups[seq] + st if seq in groups else st
    return PerScan(tuple(groups), tuple(groups.values()), per.things, per.stuff, per.class_names)


def resample(per: PerScan, unit: str) -> PerScan:
    """``per`` itself (``unit="scan"``) or :func:`by_sequence` (``"sequence"``)."""
    if unit == "scan":
        return per
    if unit == "sequence":
        return by_sequence(per)
    raise ValueError(f"unit must be 'scan' or 'sequence', got {unit!r}")


def write_per_scan(path: str | Path, per: PerScan) -> None:
    """Atomically write ``per`` as ``per_scan.npz`` (layout in the module docstring)."""
    if not per.stats:
        raise ValueError("no scans")
    st = per.stats
    write_npz(
        path,
        scan=np.asarray(per.scans, dtype=str),
        tp=np.stack([s.tp for s in st]).astype(np.int64),
        fp=np.stack([s.fp for s in st]).astype(np.int64),
        fn=np.stack([s.fn for s in st]).astype(np.int64),
        iou_sum=np.stack([s.iou_sum for s in st]).astype(np.float64),
        confusion=np.stack([s.confusion for s in st]).astype(np.int64),
        ignore=np.asarray(st[0].ignore, dtype=np.int64),
        things=np.asarray(per.things, dtype=np.int64),
        stuff=np.asarray(per.stuff, dtype=np.int64),
        class_names=np.asarray(per.class_names, dtype=str),
    )


def read_per_scan(path: str | Path) -> PerScan:
    """Read a ``per_scan.npz`` (a directory means the file inside it).

    Raises
    ------
    InputError
        Missing or corrupt file, missing keys, inconsistent shapes; the message names the file.
    """
    path = Path(path)
    if path.is_dir():
        path = path / FILE
        if not path.is_file():
            raise InputError(
                f"no {FILE} here: re-run `panoptic-bench eval semantickitti` into this "
                "directory (it writes the per-scan counts)",
                path.parent,
            )
    a = read_npz(path, KEYS)
    S = len(a["scan"])
    C = len(a["class_names"])
    want = {"tp": (S, C), "fp": (S, C), "fn": (S, C), "iou_sum": (S, C), "confusion": (S, C, C)}
    for key, shape in want.items():
        if a[key].shape != shape:
            raise InputError(f"{key} has shape {a[key].shape}, expected {shape}", path)
    if S == 0:
        raise InputError("holds no scans", path)
    for key in ("tp", "fp", "fn", "confusion"):
        if a[key].dtype.kind not in "iu" or (a[key] < 0).any():
            raise InputError(f"{key} must hold non-negative integer counts", path)
    iou = a["iou_sum"]
    if iou.dtype.kind != "f" or not np.isfinite(iou).all():
        raise InputError("iou_sum must hold finite floats", path)
    if (iou < 0).any() or (iou > a["tp"] + 1e-9).any():
        raise InputError("iou_sum must lie in [0, tp] (each matched IoU is at most 1)", path)
    bad = [c for key in ("ignore", "things", "stuff") for c in a[key].tolist() if not 0 <= c < C]
    if bad:
        raise InputError(f"class ids {bad[:3]} outside [0, {C})", path)
    try:
        stats = tuple(
            PanopticStats(
                a["tp"][i],
                a["fp"][i],
                a["fn"][i],
                a["iou_sum"][i],
                a["confusion"][i],
                tuple(int(c) for c in a["ignore"]),
            )
            for i in range(S)
        )
    except ValueError as exc:
        raise InputError(f"invalid counts ({exc})", path) from None
    return PerScan(
        tuple(str(s) for s in a["scan"]),
        stats,
        tuple(int(c) for c in a["things"]),
        tuple(int(c) for c in a["stuff"]),
        tuple(str(c) for c in a["class_names"]),
    )


def compare(
    a: PerScan,
    b: PerScan,
    *,
    n_boot: int = 2000,
    level: float = 0.95,
    seed: int = 0,
    names: Sequence[str | Path] = ("A", "B"),
    unit: str = "scan",
) -> PairedResult:
    """Paired bootstrap of ``b - a``; both must hold the same scans and classes.

    ``unit="sequence"`` resamples whole sequences (the per-scan counts summed per sequence).

    Raises
    ------
    InputError
        Different scan sets or class definitions (the message names both inputs).
    """
    na, nb = (str(n) for n in names)
    if a.class_names != b.class_names or (a.things, a.stuff) != (b.things, b.stuff):
        raise InputError(f"{na} and {nb} were scored with different classes")
    if set(a.scans) != set(b.scans) or len(a.scans) != len(b.scans):
        only_a = sorted(set(a.scans) - set(b.scans))[:3]
        only_b = sorted(set(b.scans) - set(a.scans))[:3]
        raise InputError(
            f"{na} ({len(a.scans)} scans) and {nb} ({len(b.scans)} scans) hold different scans "
            f"(only in A: {only_a or '-'}; only in B: {only_b or '-'}): score both on the same "
            "scans to compare them"
        )
    where = {s: i for i, s in enumerate(b.scans)}
    b = PerScan(a.scans, tuple(b.stats[where[s]] for s in a.scans), b.things, b.stuff,
                b.class_names)  # fmt: skip
    a, b = resample(a, unit), resample(b, unit)
    return paired_bootstrap(
        a.stats, b.stats, a.things, a.stuff, n_boot=n_boot, level=level, seed=seed, unit=unit
    )
