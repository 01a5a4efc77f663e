"""Evaluation steps of the demo: score a prediction tree into a run directory.

A run directory holds what ``panoptic-bench eval`` writes (``scores.json``, ``scores.txt``,
``per_class.csv``) plus ``run.json`` saying which method and data the numbers belong to;
:func:`panoptic_bench.reports.index.build_report` reads exactly these.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from panoptic_bench.io import ensure_output_dir

__all__ = [
    "KITTI_RANGE_EDGES",
    "NUS_RANGE_EDGES",
    "evaluate_nuscenes_run",
    "evaluate_semantickitti_run",
]

#: Range bins (m) of the per-distance scores.
KITTI_RANGE_EDGES = (0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 80.0)
NUS_RANGE_EDGES = (0.0, 10.0, 20.0, 30.0, 50.0)


def _edges_text(edges: Sequence[float]) -> str:
    return ",".join(f"{e:g}" for e in edges)


def _write_meta(run_dir: Path, meta: Mapping[str, Any]) -> None:
    from panoptic_bench.reports.inputs import write_run_meta

    write_run_meta(run_dir, dict(meta))


def evaluate_semantickitti_run(
    dataset: Path,
    predictions: Path,
    sequences: Sequence[str],
    run_dir: Path,
    meta: Mapping[str, Any],
    *,
    workers: int = 1,
    show: Callable[[Path], str] = str,
) -> dict[str, Any]:
    """Score SemanticKITTI predictions into ``run_dir`` and write its ``run.json``.

    Same as ``panoptic-bench eval semantickitti --dataset D --predictions P --sequences 08
    --by-range 0,10,20,30,40,50,80 --output RUN_DIR``.

    Parameters
    ----------
    dataset, predictions : Path
        Dataset root and prediction root.
    sequences : sequence of str
        Sequences to score.
    run_dir : Path
        Output run directory.
    meta : mapping
        ``run.json`` content (method, dataset, split, data, notes, ablation, ...); ``command``
        (the equivalent ``eval`` command line) is added here.
    workers : int
        Worker processes.
    show : callable
        How a path appears in the recorded command (e.g. ``$WORK/...`` for temporary data).

    Returns
    -------
    dict
        The ``scores.json`` content.
    """
    from panoptic_bench.evaluation.semantickitti import evaluate_semantickitti

    ev = evaluate_semantickitti(
        dataset,
        predictions,
        split=None,
        sequences=list(sequences),
        workers=workers,
        by_range=KITTI_RANGE_EDGES,
    )
    out = ensure_output_dir(run_dir, inputs=(dataset, predictions))
    scores = ev.write(out)
    command = (
        f"panoptic-bench eval semantickitti --dataset {show(dataset)} "
        f"--predictions {show(predictions)} --sequences {','.join(sequences)} "
        f"--by-range {_edges_text(KITTI_RANGE_EDGES)} --output {show(run_dir)}"
    )
    _write_meta(out, {**meta, "command": command})
    return scores


def evaluate_nuscenes_run(
    dataroot: Path,
    version: str,
    eval_set: str,
    predictions: Path,
    run_dir: Path,
    meta: Mapping[str, Any],
    *,
    workers: int = 1,
    show: Callable[[Path], str] = str,
) -> dict[str, Any]:
    """Score Panoptic nuScenes predictions into ``run_dir`` and write its ``run.json``.

    Same as ``panoptic-bench eval nuscenes --dataroot D --version v1.0-mini --result-path P
    --eval-set mini_val --by-range 0,10,20,30,50 --output RUN_DIR``. Returns ``scores.json``.
    """
    from panoptic_bench.evaluation.nuscenes import evaluate_nuscenes, write_nuscenes_result

    ev = evaluate_nuscenes(
        dataroot, version, predictions, eval_set, by_range=NUS_RANGE_EDGES, workers=workers
    )
    scores = write_nuscenes_result(ev, run_dir, inputs=(dataroot, predictions))
    command = (
        f"panoptic-bench eval nuscenes --dataroot {show(dataroot)} --version {version} "
        f"--result-path {show(predictions)} --eval-set {eval_set} "
        f"--by-range {_edges_text(NUS_RANGE_EDGES)} --output {show(run_dir)}"
    )
    _write_meta(run_dir, {**meta, "command": command})
    return scores
