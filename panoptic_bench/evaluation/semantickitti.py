"""SemanticKITTI panoptic evaluation over a dataset tree (the official ``evaluate_panoptic.py``).

Ground truth ``DATASET/sequences/XX/labels/NNNNNN.label`` is scored against
``PREDICTIONS/sequences/XX/predictions/NNNNNN.label``. As in the official tool, both are mapped to
train ids with ``learning_map`` and the **full uint32 label** is the instance id used for matching;
class 0 is ignored. Unlike the official tool, every input is checked first: missing or extra
prediction files, point counts, file sizes and unknown raw ids raise
:class:`~panoptic_bench.errors.InputError` naming the file.

Scans are scored in worker processes; the per-scan accumulators are summed in scan order, so the
result does not depend on ``workers``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from panoptic_bench.datasets import semantickitti as sk
from panoptic_bench.errors import InputError
from panoptic_bench.evaluation import semantickitti_cells as cells
from panoptic_bench.evaluation import workers as workers_module
from panoptic_bench.metrics.by_range import (
    RangeStats,
    panoptic_stats_by_range,
    parse_edges,
    point_range,
)
from panoptic_bench.metrics.panoptic import (
    PanopticResult,
    PanopticStats,
    panoptic_stats,
)

__all__ = [
    "SemanticKittiEvaluation",
    "check_label_ids",
    "checked_train_ids",
    "evaluate_semantickitti",
    "label_stats",
    "prediction_problems",
    "require_predictions",
    "scan_point_count",
]

OFFICIAL_MIN_POINTS = 50


def label_stats(
    pred: np.ndarray,
    gt: np.ndarray,
    *,
    min_points: int = OFFICIAL_MIN_POINTS,
    ranges: np.ndarray | None = None,
    edges: Sequence[float] | None = None,
) -> tuple[PanopticStats, RangeStats | None]:
    """Score one scan given as raw SemanticKITTI labels.

    Parameters
    ----------
    pred, gt : array of shape (n_points,), uint32
        Full labels (low 16 bits raw semantic id, high 16 bits instance id).
    min_points : int
        Minimum size of an unmatched segment to count as FP / FN (official CLI: 50).
    ranges : array of shape (n_points,), float, optional
        Point ranges, needed with ``edges``.
    edges : sequence of float, optional
        Range-bin edges for per-bin statistics.

    Returns
    -------
    (PanopticStats, RangeStats or None)
    """
    sp, sg = sk.to_train(pred), sk.to_train(gt)
    kw = {"num_classes": sk.LABELS.num_classes, "ignore": sk.LABELS.ignore_ids}
    stats = panoptic_stats(sp, pred, sg, gt, min_points=min_points, **kw)
    if edges is None:
        return stats, None
    if ranges is None:
        raise ValueError("ranges are needed for per-range statistics")
    return stats, panoptic_stats_by_range(
        sp, pred, sg, gt, ranges, edges, min_points=min_points, **kw
    )


def scan_point_count(path: Path) -> int:
    """Number of points of a ``.bin`` scan from its size (checked to be a multiple of 16)."""
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise InputError("scan file not found", path) from None
    except OSError as exc:
        raise InputError(f"cannot read scan file ({exc.strerror})", path) from None
    if size % 16:
        raise InputError(
            f"scan file size {size} is not a multiple of 16 bytes (float32 x, y, z, remission); "
            "the file is truncated or not a SemanticKITTI scan",
            path,
        )
    return size // 16


def check_label_ids(labels: np.ndarray, n_points: int, path: Path, what: str) -> None:
    """Raise :class:`InputError` unless ``labels`` has ``n_points`` entries of known raw ids."""
    if len(labels) != n_points:
        raise InputError(
            f"{what} has {len(labels)} labels but the scan has {n_points} points", path
        )
    bad = ~sk.LABELS.valid_raw[labels & 0xFFFF]
    if bad.any():
        ids = np.unique(labels[bad] & 0xFFFF)
        shown = ", ".join(str(i) for i in ids[:8]) + (" ..." if len(ids) > 8 else "")
        raise InputError(
            f"{what} holds {int(bad.sum())} points with unknown raw label ids ({shown}); "
            "write raw SemanticKITTI ids (e.g. 10 car, 40 road), not train ids 0-19 "
            "('panoptic-bench semantickitti remap --inverse' converts them)",
            path,
        )


def prediction_problems(
    refs: Sequence[sk.ScanRef], predictions: str | Path
) -> tuple[list[str], list[str]]:
    """Missing and extra prediction files of ``refs`` (as ``"path: message"`` strings)."""
    missing, extra = [], []
    wanted = {sk.prediction_path(predictions, r) for r in refs}
    for pred in sorted(wanted):
        if not pred.is_file():
            missing.append(f"{pred}: prediction file missing")
    for pred_dir in sorted({p.parent for p in wanted}):
        if not pred_dir.is_dir():
            continue
        try:
            names = sorted(p.name for p in pred_dir.iterdir())
        except OSError as exc:
            missing.append(f"{pred_dir}: cannot read directory ({exc.strerror or exc})")
            continue
        for name in names:
            if pred_dir / name not in wanted:
                extra.append(
                    f"{pred_dir / name}: extra file, no scan velodyne/{Path(name).stem}.bin "
                    "in the dataset"
                )
    return missing, extra


def require_predictions(refs: Sequence[sk.ScanRef], predictions: str | Path) -> None:
    """Raise :class:`InputError` naming the first missing, then the first extra, prediction."""
    missing, extra = prediction_problems(refs, predictions)
    for problems in (missing, extra):
        if problems:
            more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
            hint = "; 'panoptic-bench validate semantickitti' lists every problem"
            raise InputError(problems[0] + more + hint)


@dataclass(frozen=True)
class _Job:
    ref: sk.ScanRef
    pred: Path
    min_points: int
    edges: tuple[float, ...] | None


_INVALID = 255
#: raw semantic id -> train id, 255 for a raw id that SemanticKITTI does not define
_CHECKED_LUT = np.where(sk.LABELS.valid_raw, sk.LABELS.train_lut, _INVALID).astype(np.uint8)


def checked_train_ids(labels: np.ndarray, n_points: int, path: Path, what: str) -> np.ndarray:
    """Train ids of uint32 labels, checked like :func:`check_label_ids` in one table lookup.

    Parameters
    ----------
    labels : array of shape (n,), uint32
    n_points : int
        Point count of the scan.
    path : Path
        File named in the error.
    what : str
        ``"prediction"`` or ``"ground truth"``.

    Returns
    -------
    ndarray of shape (n_points,), uint8

    Raises
    ------
    InputError
        Wrong length or an unknown raw id (the message of :func:`check_label_ids`).
    """
    if len(labels) != n_points:
        check_label_ids(labels, n_points, path, what)
    raw, _ = cells.label_halves(labels)  # a strided view where the byte order allows
    sem = np.take(_CHECKED_LUT, raw)  # faster than fancy indexing on a strided view
    if sem.max(initial=0) == _INVALID:
        check_label_ids(labels, n_points, path, what)
    return sem


def _codes(labels: np.ndarray, n_points: int, path: Path, what: str) -> tuple:
    """:func:`semantickitti_cells.label_codes`, checked like :func:`check_label_ids`."""
    if len(labels) != n_points:
        check_label_ids(labels, n_points, path, what)
    codes = cells.label_codes(labels)
    if codes is None:
        check_label_ids(labels, n_points, path, what)
    return codes


def _score(job: _Job) -> tuple[PanopticStats, RangeStats | None]:
    n = scan_point_count(job.ref.scan)
    gt = sk.read_labels(job.ref.label)
    g = _codes(gt, n, job.ref.label, "ground truth")
    pred = sk.read_labels(job.pred)
    p = _codes(pred, n, job.pred, "prediction")
    stats = cells.scan_stats(g, p, job.min_points)
    if job.edges is None:
        return stats, None
    kw = {"num_classes": sk.LABELS.num_classes, "ignore": sk.LABELS.ignore_ids}
    sp, sg = cells.train_ids(p[0]), cells.train_ids(g[0])
    ranges = point_range(sk.read_scan(job.ref.scan))
    return stats, panoptic_stats_by_range(
        sp, pred, sg, gt, ranges, job.edges, min_points=job.min_points, **kw
    )


@dataclass(frozen=True)
class SemanticKittiEvaluation:
    """Accumulated statistics of a SemanticKITTI evaluation."""

    stats: PanopticStats
    by_range: RangeStats | None
    n_scans: int
    sequences: tuple[str, ...]
    min_points: int = OFFICIAL_MIN_POINTS
    per_scan: tuple[PanopticStats, ...] = ()
    scan_ids: tuple[str, ...] = ()

    def result(self) -> PanopticResult:
        """Per-class and mean metrics."""
        return self.stats.compute()

    def per_scan_counts(self):
        """The per-scan counts as :class:`~panoptic_bench.evaluation.per_scan.PerScan`."""
        from panoptic_bench.evaluation.per_scan import PerScan

        labels = sk.LABELS
        return PerScan(
            self.scan_ids, self.per_scan, labels.thing_ids, labels.stuff_ids, labels.class_names
        )

    def write(self, out_dir: str | Path, bootstrap: int = 0, unit: str = "scan") -> dict:
        """Write ``scores.txt``, ``scores.json``, ``per_class.csv`` and ``per_scan.npz``.

        ``bootstrap`` > 0 adds 95 % bootstrap intervals of the headline metrics to ``scores.json``
        (key ``bootstrap``; :mod:`panoptic_bench.metrics.bootstrap`, seed 0), resampling scans or
        whole sequences (``unit``).
        Returns the ``scores.json`` content.
        """
        from panoptic_bench.evaluation.output import write_scores
        from panoptic_bench.evaluation.per_scan import FILE, resample, write_per_scan

        extra: dict = {}
        if self.per_scan:
            write_per_scan(Path(out_dir) / FILE, self.per_scan_counts())
            if bootstrap:
                from panoptic_bench.metrics.bootstrap import bootstrap as run_bootstrap

                units = resample(self.per_scan_counts(), unit).stats
                labels = sk.LABELS
                got = run_bootstrap(
                    units, labels.thing_ids, labels.stuff_ids, n_boot=bootstrap, unit=unit
                )
                extra["bootstrap"] = got.to_dict()
        return write_scores(
            out_dir,
            self.result(),
            class_names=sk.LABELS.class_names,
            things=sk.LABELS.thing_ids,
            stuff=sk.LABELS.stuff_ids,
            by_range=self.by_range,
            extra={
                "dataset": "semantickitti",
                "sequences": list(self.sequences),
                "n_scans": self.n_scans,
                "min_inst_points": self.min_points,
                **extra,
            },
        )


def evaluate_semantickitti(
    dataset: str | Path,
    predictions: str | Path,
    *,
    split: str | None = "valid",
    sequences: Sequence[int | str] | None = None,
    min_points: int = OFFICIAL_MIN_POINTS,
    workers: int = 1,
    by_range: Sequence[float] | None = None,
    progress: bool | None = None,
) -> SemanticKittiEvaluation:
    """Score a prediction tree against a SemanticKITTI dataset tree.

    Parameters
    ----------
    dataset : path
        Root with ``sequences/XX/{velodyne,labels}``.
    predictions : path
        Root with ``sequences/XX/predictions/NNNNNN.label`` (raw ids, full labels).
    split : {"train", "valid", "test"}, optional
        Sequences of the split (ignored when ``sequences`` is given).
    sequences : sequence of int or str, optional
        Explicit sequence numbers.
    min_points : int
        Minimum size of an unmatched segment to count (official CLI default 50).
    workers : int
        Worker processes (1 = in this process).
    by_range : sequence of float, optional
        Range-bin edges in metres for per-bin metrics.
    progress : bool or None
        Progress bar (None: only on a terminal).

    Returns
    -------
    SemanticKittiEvaluation

    Raises
    ------
    InputError
        Any missing, extra or malformed file; the message names it.
    """
    if workers < 1:
        raise InputError(f"--workers must be >= 1, got {workers}")
    if min_points < 0:
        raise InputError(f"--min-inst-points must be >= 0, got {min_points}")
    edges = None
    if by_range is not None:
        try:
            edges = parse_edges(by_range)
        except ValueError as exc:
            raise InputError(f"--by-range: {exc}") from None
    refs = sk.list_scans(dataset, split=split, sequences=sequences)
    require_predictions(refs, predictions)

    jobs = [_Job(r, sk.prediction_path(predictions, r), min_points, edges) for r in refs]
    C, ignore = sk.LABELS.num_classes, sk.LABELS.ignore_ids
    stats = PanopticStats.zeros(C, ignore)
    ranges = None if edges is None else RangeStats.zeros(edges, C, ignore)
    per_scan: list[PanopticStats] = []
    bar = workers_module.progress_bar(len(jobs), "SemanticKITTI", "scan", progress)
    n_workers = workers_module.pool_size(workers, len(jobs))
    chunksize = max(1, len(jobs) // (8 * n_workers))
    try:
        with workers_module.pool_map(_score, jobs, n_workers, chunksize) as results:
            for s, r in results:  # scan order: identical sums for any number of workers
                stats = stats + s
                per_scan.append(s)
                if ranges is not None:
                    ranges = ranges + r
                bar.update()
    finally:
        bar.close()
    seqs = tuple(sorted({r.sequence for r in refs}))
    ids = tuple(f"{r.sequence}/{r.frame}" for r in refs)
    return SemanticKittiEvaluation(stats, ranges, len(jobs), seqs, min_points, tuple(per_scan), ids)
