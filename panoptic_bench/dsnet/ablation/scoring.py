"""Scoring the ablation variants on the validation cache, one run directory each.

Every prediction is assembled exactly as :class:`~panoptic_bench.dsnet.inference.predictor.Predictor`
does (DS: FPS seeds → shift → final clustering ``inference.ds_clusterer`` → nearest seed →
small-instance filter → consensus fusion; heuristics: :func:`~panoptic_bench.baselines.panoptic.
assemble_panoptic` on the same regressed centres), encoded as official SemanticKITTI labels
(:func:`~panoptic_bench.baselines.panoptic.semantickitti_label`) and scored with the
SemanticKITTI evaluator's kernel (:func:`~panoptic_bench.evaluation.semantickitti.label_stats`,
minimum 50 points, per-range bins) into ``scores.json`` by
:meth:`~panoptic_bench.evaluation.semantickitti.SemanticKittiEvaluation.write`.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from panoptic_bench.dsnet.ablation.cache import EvalScan
from panoptic_bench.dsnet.checkpoint import Checkpoint

__all__ = ["RANGE_EDGES", "EvalContext", "score_baselines", "score_variant"]

#: Range bins (m) of the per-range scores, as the demo's SemanticKITTI runs.
RANGE_EDGES = (0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 80.0)


@dataclass
class EvalContext:
    """Shared inputs of every scored run (see :func:`~panoptic_bench.dsnet.ablation.run.run_ablation`)."""

    ckpt: Checkpoint
    scans: Sequence[EvalScan]
    runs_dir: Path
    data: str
    training: str
    checkpoint: str
    command: str | None = None
    progress: bool = True


class _Scorer:
    """Accumulates evaluator statistics over the validation scans of one run."""

    def __init__(self) -> None:
        from panoptic_bench.metrics.by_range import parse_edges

        self.edges = parse_edges(RANGE_EDGES)
        self.stats = None
        self.ranges = None
        self.seqs: set[str] = set()
        self.n = 0

    def add(self, scan: EvalScan, sem: np.ndarray, inst: np.ndarray) -> None:
        from panoptic_bench.baselines.panoptic import semantickitti_label
        from panoptic_bench.evaluation.semantickitti import label_stats
        from panoptic_bench.metrics.by_range import point_range

        pred = semantickitti_label(sem, inst)
        s, r = label_stats(pred, scan.gt_label, ranges=point_range(scan.xyz), edges=self.edges)
        self.stats = s if self.stats is None else self.stats + s
        self.ranges = r if self.ranges is None else self.ranges + r
        self.seqs.add(scan.key[0])
        self.n += 1

    def write(self, run_dir: Path) -> dict:
        from panoptic_bench.evaluation.semantickitti import SemanticKittiEvaluation

        ev = SemanticKittiEvaluation(self.stats, self.ranges, self.n, tuple(sorted(self.seqs)))
        return ev.write(run_dir)


def _meta(ctx: EvalContext, method: str, notes: str, **extra: Any) -> dict:
    meta = {
        "method": method,
        "dataset": "semantickitti",
        "split": "val",
        "data": ctx.data,
        "notes": f"{notes}; frozen backbone of {ctx.checkpoint}",
        **{k: v for k, v in extra.items() if v},
    }
    if ctx.command:
        meta["command"] = ctx.command
    return meta


def _row(name: str, method: str, scores: dict) -> dict:
    keys = ("PQ", "PQ_dagger", "RQ", "SQ", "PQ_th", "PQ_st", "mIoU")
    return {"run": name, "method": method, **{k: scores["all"][k] for k in keys}}


def ds_predict(ctx: EvalContext, module, scan: EvalScan):
    """DS-Net prediction of one cached scan (as ``Predictor._dynamic_shift``).

    Returns
    -------
    sem : (n,) int64 after fusion; inst : (n,) int64; diagnostics : ShiftDiagnostics or None
    """
    from panoptic_bench.baselines.panoptic import consensus_fusion, filter_small_instances
    from panoptic_bench.dsnet.inference.clustering import make_clusterer
    from panoptic_bench.dsnet.model.ds_head import shift_instances

    cfg, cmap = ctx.ckpt.config, ctx.ckpt.class_map
    inst = np.zeros(len(scan.sem), dtype=np.int64)
    if len(scan.things) == 0:
        return scan.sem, inst, None
    labels, diag = shift_instances(
        module,
        scan.centers,
        torch.from_numpy(scan.features),
        points=scan.xyz[scan.things],
        clusterer=make_clusterer(cfg.inference.ds_clusterer, cfg.inference.ds_bandwidth),
        max_seeds=cfg.dynamic_shift.max_seeds,
    )
    valid = labels >= 0
    _, dense = np.unique(labels[valid], return_inverse=True)
    inst[scan.things[valid]] = filter_small_instances(dense.reshape(-1), cfg.inference.min_points)
    fused = consensus_fusion(scan.sem, inst, cmap.num_classes) if cfg.inference.fusion else scan.sem
    return fused, inst, diag


def score_variant(ctx: EvalContext, variant, module, losses: Sequence[float]) -> tuple[Path, dict]:
    """Score one trained DS variant into ``runs_dir/<variant.name>``; returns (dir, summary row).

    The default variant also writes ``analysis.json`` (Figs. 5 and 7), ``shift_iterations.npz``
    (Fig. 6, first validation scan) and ``dynamic_shift/<seq>_<frame>.npz`` (per-seed weights,
    implied bandwidths, trajectories) via :mod:`.diagnostics`.
    """
    from tqdm import tqdm

    from panoptic_bench.dsnet.ablation.diagnostics import Diagnostics
    from panoptic_bench.reports.inputs import write_run_meta
    from panoptic_bench.reports.tables import format_bandwidths

    run_dir = ctx.runs_dir / variant.name
    scorer = _Scorer()
    diags = Diagnostics(variant.bandwidths) if variant.is_default else None
    bar = tqdm(ctx.scans, desc=f"score {variant.name}", leave=False, disable=not ctx.progress)
    for scan in bar:
        sem, inst, diag = ds_predict(ctx, module, scan)
        scorer.add(scan, sem, inst)
        if diags is not None and diag is not None:
            diags.add(run_dir, scan, diag)
    scores = scorer.write(run_dir)
    if diags is not None:
        diags.write(run_dir)
    inf = ctx.ckpt.config.inference
    k = max(1, len(losses) // 10)
    head, tail = (np.mean(losses[:k]), np.mean(losses[-k:])) if losses else (np.nan, np.nan)
    notes = (
        f"{variant.kernel.value} kernel, bandwidth candidates {format_bandwidths(variant.bandwidths)}"
        f" m, {variant.iterations} iterations; {ctx.training}; DS loss (mean of first / last 10% "
        f"of the steps) {head:.3f} -> {tail:.3f}; final clustering {inf.ds_clusterer.value} {inf.ds_bandwidth:g} m, "
        f"nearest seed, min {inf.min_points} points, consensus fusion"
    )
    meta = _meta(
        ctx,
        variant.method,
        notes,
        bandwidths=list(variant.bandwidths) if variant.table4 else None,
        iterations=variant.iterations if variant.table5 else None,
        ablation=dict(variant.ablation),
    )
    write_run_meta(run_dir, meta)
    return run_dir, _row(variant.name, variant.method, scores)


def _baselines() -> list[tuple[str, str, Any, bool, dict[str, str], str]]:
    """(run name, method, clustering spec, fusion, Fig. 4 tags, description) of each baseline."""
    from panoptic_bench.demo.config import CLUSTERINGS

    spec = {c.key: c for c in CLUSTERINGS}
    ms = spec["meanshift"]
    out = [
        ("backbone", "Backbone", ms, False, {"framework": "backbone"}, ms.describe()),
        (
            "backbone-fusion",
            "Backbone with Fusion",
            ms,
            True,
            {"framework": "+ fusion", "clustering": "Mean Shift"},
            ms.describe(),
        ),
    ]
    for key in ("bfs", "dbscan", "hdbscan"):
        c = spec[key]
        out.append((key, f"Backbone + {c.label}", c, True, {"clustering": c.label}, c.describe()))
    return out


def score_baselines(ctx: EvalContext) -> Iterator[tuple[Path, dict]]:
    """Backbone, Backbone with Fusion, BFS, DBSCAN, HDBSCAN on the cached regressed centres.

    Yields
    ------
    (run directory, summary row) per baseline.
    """
    from tqdm import tqdm

    from panoptic_bench.baselines.panoptic import assemble_panoptic
    from panoptic_bench.reports.inputs import write_run_meta

    cfg, cmap = ctx.ckpt.config, ctx.ckpt.class_map
    for name, method, spec, fusion, tags, desc in _baselines():
        scorer = _Scorer()
        for scan in tqdm(ctx.scans, desc=f"score {name}", leave=False, disable=not ctx.progress):
            sem, inst = assemble_panoptic(
                scan.xyz,
                scan.sem,
                scan.offsets,
                spec.make(),
                thing_ids=cmap.thing_ids,
                min_points=cfg.inference.min_points,
                fusion=fusion,
                num_classes=cmap.num_classes,
            )
            scorer.add(scan, sem, inst)
        run_dir = ctx.runs_dir / name
        scores = scorer.write(run_dir)
        notes = (
            f"clustering {desc} of the regressed centres of every predicted things point, "
            f"min {cfg.inference.min_points} points, "
            + ("consensus fusion" if fusion else "no fusion")
        )
        write_run_meta(run_dir, _meta(ctx, method, notes, ablation=tags))
        yield run_dir, _row(name, method, scores)
