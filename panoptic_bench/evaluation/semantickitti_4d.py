"""SemanticKITTI 4D panoptic evaluation (LSTQ) over a dataset tree.

Ground truth ``DATASET/sequences/XX/labels/NNNNNN.label`` is scored against
``PREDICTIONS/sequences/XX/predictions/NNNNNN.label`` with the rules of
:mod:`panoptic_bench.metrics.lstq` (``--mode reference`` = the 4D-PLS benchmark code,
``--mode corrected``). Both files are mapped to train ids with ``learning_map``; the instance id
is ``label >> 16`` and must be consistent along a sequence. Every input is checked first: a
missing or extra prediction frame, a wrong point count (a 64-bit label file shows up as twice the
points) or an unknown raw id raises :class:`~panoptic_bench.errors.InputError` naming the file.

Frames are scored in chunks (consecutive frames of one sequence) in worker processes; tube
statistics add up, and chunks are summed in frame order, so the result does not depend on
``workers``. With ``by_range`` every range bin is scored as its own point set (a tube crossing a
bin edge is split), as :mod:`panoptic_bench.metrics.by_range` does for single scans.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from panoptic_bench.datasets import semantickitti as sk
from panoptic_bench.errors import InputError
from panoptic_bench.evaluation import workers as workers_module
from panoptic_bench.evaluation.semantickitti import (
    checked_train_ids,
    require_predictions,
    scan_point_count,
)
from panoptic_bench.metrics.by_range import parse_edges, point_range
from panoptic_bench.metrics.lstq import (
    LSTQMode,
    LSTQResult,
    LSTQStats,
    SequenceTubes,
    lstq_frame_stats,
)

__all__ = ["SemanticKitti4DEvaluation", "evaluate_semantickitti_4d", "lstq_scores"]

OFFICIAL_MIN_POINTS = 50
_CHUNK = 16  # frames per job


@dataclass(frozen=True)
class _Job:
    refs: tuple[sk.ScanRef, ...]
    preds: tuple[Path, ...]
    min_points: int
    mode: LSTQMode
    edges: tuple[float, ...] | None


def _split(labels: np.ndarray, n: int, path: Path, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Checked ``(train ids uint8, instance ids uint16)`` of a label file of a scan of ``n`` points.

    On a little-endian machine the halves of each uint32 are read as strided uint16 views.
    """
    if len(labels) == 2 * n and n:
        raise InputError(
            f"{what} has {len(labels)} uint32 values for {n} points: 64-bit labels? write one "
            "uint32 per point (raw class in the low 16 bits, instance id < 2**16 in the high 16)",
            path,
        )
    sem = checked_train_ids(labels, n, path, what)
    inst = labels.view(np.uint16)[1::2] if sys.byteorder == "little" else labels >> 16
    return sem, inst


def _zeros(mode: LSTQMode) -> LSTQStats:
    L = sk.LABELS
    return LSTQStats.zeros(L.num_classes, L.ignore_ids, L.thing_ids, mode)


def _score(job: _Job) -> tuple[LSTQStats, list[LSTQStats] | None]:
    L = sk.LABELS
    kw = {
        "num_classes": L.num_classes,
        "ignore": L.ignore_ids,
        "things": L.thing_ids,
        "min_points": job.min_points,
        "mode": job.mode,
    }
    conf = np.zeros((L.num_classes, L.num_classes), dtype=np.int64)
    tubes: dict[str, list[SequenceTubes]] = {}
    bins = None if job.edges is None else [_zeros(job.mode) for _ in job.edges[1:]]
    for ref, pred_path in zip(job.refs, job.preds):
        n = scan_point_count(ref.scan)
        sg, ig = _split(sk.read_labels(ref.label), n, ref.label, "ground truth")
        sp, ip = _split(sk.read_labels(pred_path), n, pred_path, "prediction")
        c, t = lstq_frame_stats(sp, ip, sg, ig, **kw)
        conf += c
        tubes.setdefault(ref.sequence, []).append(t)
        if bins is not None:
            rng = point_range(sk.read_scan(ref.scan))
            which = np.searchsorted(np.asarray(job.edges), rng, side="right") - 1
            for b in range(len(bins)):
                m = which == b
                frame = lstq_frame_stats(sp[m], ip[m], sg[m], ig[m], **kw)
                bins[b] = bins[b].add_frame(ref.sequence, *frame)
    seqs = {name: SequenceTubes.concat(parts) for name, parts in tubes.items()}
    total = LSTQStats(L.num_classes, L.ignore_ids, L.thing_ids, job.mode, conf, seqs)
    return total, bins


def _float(v: float) -> float | None:
    return None if math.isnan(v) else float(v)


def lstq_scores(result: LSTQResult) -> dict[str, Any]:
    """``{"all": {...}, "classes": {name: {"IoU", "AQ"}}}`` of one result (NaN -> None)."""
    L = sk.LABELS
    th = list(L.thing_ids)
    st = list(L.stuff_ids)
    return {
        "all": {
            "LSTQ": _float(result.LSTQ),
            "S_assoc": _float(result.S_assoc),
            "S_cls": _float(result.S_cls),
            "IoU_th": float(result.iou[th].mean()),
            "IoU_st": float(result.iou[st].mean()),
            "AQ_precision": _float(result.AQ_precision),
            "AQ_recall": _float(result.AQ_recall),
            "phantom_class_0": result.phantom_class_0,
        },
        "classes": {
            L.class_names[c]: {
                "kind": "thing" if c in L.thing_ids else "stuff",
                "IoU": float(result.iou[c]),
                "AQ": float(result.aq[c]),
                "tubes": int(result.n_tubes[c]),
            }
            for c in (*L.thing_ids, *L.stuff_ids)
        },
    }


@dataclass(frozen=True)
class SemanticKitti4DEvaluation:
    """Accumulated statistics of a 4D evaluation."""

    stats: LSTQStats
    by_range: tuple[tuple[float, float, LSTQStats], ...] | None
    n_scans: int
    sequences: tuple[str, ...]
    min_points: int
    mode: LSTQMode

    def scores(self) -> dict[str, Any]:
        """The ``scores.json`` content (fractions)."""
        out = lstq_scores(self.stats.compute())
        out["by_range"] = [
            {"range": [lo, hi], **lstq_scores(s.compute())} for lo, hi, s in self.by_range or ()
        ]
        out.update(
            dataset="semantickitti",
            task="4d-panoptic",
            mode=self.mode.value,
            sequences=list(self.sequences),
            n_scans=self.n_scans,
            min_inst_points=self.min_points,
        )
        return out

    def write(self, out_dir: str | Path) -> dict[str, Any]:
        """Write ``scores.json``, ``scores.txt`` (YAML headline) and ``per_class.csv``."""
        import yaml

        from panoptic_bench.io import write_json, write_text

        out = Path(out_dir)
        scores = self.scores()
        head = {k: scores["all"][k] for k in ("LSTQ", "S_assoc", "S_cls", "IoU_th", "IoU_st")}
        lines = ["class,kind,IoU,AQ,tubes"]
        for name, m in scores["classes"].items():
            lines.append(f"{name},{m['kind']},{m['IoU']!r},{m['AQ']!r},{m['tubes']}")
        write_json(out / "scores.json", scores)
        write_text(out / "scores.txt", yaml.safe_dump(head, default_flow_style=False))
        write_text(out / "per_class.csv", "\n".join(lines) + "\n")
        return scores


def evaluate_semantickitti_4d(
    dataset: str | Path,
    predictions: str | Path,
    *,
    split: str | None = "valid",
    sequences: Sequence[int | str] | None = None,
    min_points: int = OFFICIAL_MIN_POINTS,
    mode: LSTQMode | str = LSTQMode.REFERENCE,
    workers: int = 1,
    by_range: Sequence[float] | str | None = None,
    progress: bool | None = None,
) -> SemanticKitti4DEvaluation:
    """Score a 4D prediction tree (consistent ids along each sequence) against SemanticKITTI.

    Parameters
    ----------
    dataset, predictions : path
        Roots with ``sequences/XX/{velodyne,labels}`` and ``sequences/XX/predictions``.
    split : {"train", "valid", "test"}, optional
        Sequences of the split (ignored when ``sequences`` is given).
    sequences : sequence of int or str, optional
        Explicit sequence numbers.
    min_points : int
        Ground-truth segment size threshold (benchmark default 50).
    mode : LSTQMode or {"reference", "corrected"}
    workers : int
        Worker processes (1 = in this process).
    by_range : sequence of float or str, optional
        Range-bin edges in metres.
    progress : bool or None
        Progress bar (None: only on a terminal).

    Returns
    -------
    SemanticKitti4DEvaluation

    Raises
    ------
    InputError
        Any missing, extra or malformed file or a bad option; the message names it.
    """
    if workers < 1:
        raise InputError(f"--workers must be >= 1, got {workers}")
    if min_points < 0:
        raise InputError(f"--min-inst-points must be >= 0, got {min_points}")
    try:
        mode = LSTQMode(mode)
    except ValueError:
        raise InputError(f"--mode must be reference or corrected, got {mode!r}") from None
    edges = None
    if by_range is not None:
        try:
            edges = parse_edges(by_range)
        except ValueError as exc:
            raise InputError(f"--by-range: {exc}") from None
    refs = sk.list_scans(dataset, split=split, sequences=sequences)
    require_predictions(refs, predictions)
    seqs = tuple(dict.fromkeys(r.sequence for r in refs))
    size = _CHUNK
    n_workers = workers_module.pool_size(workers, len(refs))
    if n_workers > 1:  # enough chunks to keep every worker busy
        size = max(1, min(_CHUNK, math.ceil(len(refs) / (4 * n_workers))))
    jobs = []
    for seq in seqs:
        s_refs = [r for r in refs if r.sequence == seq]
        for i in range(0, len(s_refs), size):
            part = tuple(s_refs[i : i + size])
            preds = tuple(sk.prediction_path(predictions, r) for r in part)
            jobs.append(_Job(part, preds, min_points, mode, edges))
    total = _zeros(mode)
    bins = None if edges is None else [_zeros(mode) for _ in edges[1:]]
    bar = workers_module.progress_bar(len(refs), "SemanticKITTI 4D", "scan", progress)
    try:
        with workers_module.pool_map(_score, jobs, n_workers) as results:
            for job, (s, b) in zip(jobs, results):  # job order: same sums for any worker count
                total = total + s
                if bins is not None:
                    bins = [x + y for x, y in zip(bins, b)]
                bar.update(len(job.refs))
    finally:
        bar.close()
    ranges = None
    if edges is not None:
        ranges = tuple((lo, hi, s) for lo, hi, s in zip(edges, edges[1:], bins))
    return SemanticKitti4DEvaluation(total, ranges, len(refs), seqs, min_points, mode)
