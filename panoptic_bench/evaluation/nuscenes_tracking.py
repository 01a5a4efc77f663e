"""Panoptic nuScenes panoptic tracking: the devkit's ``task='tracking'`` numbers, with input checks.

Equivalent to ``NuScenesPanopticEval(..., task='tracking')``: every scene of the eval set is
scored frame by frame in scene order (the ``first_sample_token`` -> ``next`` chain) with the rules
of :mod:`panoptic_bench.metrics.tracking`, and the single-frame segmentation metrics of the same
samples are computed from the same reads (:mod:`panoptic_bench.evaluation.nuscenes`). Predictions
are checked as for segmentation (present, key ``data``, uint16, one label per point, classes
0..16); a scene of the split absent from the dataroot is an error (the devkit raises KeyError).
Scenes are scored in worker processes and summed in scene order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar
from panoptic_bench.errors import InputError
from panoptic_bench.evaluation import workers as workers_module
from panoptic_bench.evaluation.nuscenes import (
    IGNORE,
    ChallengeClasses,
    NuScenesEvaluation,
    _Job,
    load_checked,
    open_scoring_inputs,
)
from panoptic_bench.metrics.panoptic import PanopticStats, panoptic_stats
from panoptic_bench.metrics.tracking import SceneTracking, TrackingStats, tracking_frame

__all__ = ["NuScenesTrackingEvaluation", "evaluate_nuscenes_tracking", "scene_jobs"]


def scene_jobs(
    reader: NuScenesLidar, eval_set: str, pred_dir: Path
) -> list[tuple[str, list[_Job]]]:
    """``(scene name, jobs in frame order)`` for every scene of ``eval_set``, in split order."""
    from panoptic_bench.datasets.nuscenes import scene_names

    tokens = reader.sample_data_tokens(eval_set)  # checks scenes and links
    by_name = {rec["name"]: rec for rec in reader.nusc.scene}
    out, start = [], 0
    for name in scene_names(reader.version, eval_set):
        n = by_name[name]["nbr_samples"]
        jobs = []
        for tok in tokens[start : start + n]:
            pred = pred_dir / f"{tok}_panoptic.npz"
            if not pred.is_file():
                raise InputError(
                    f"prediction for sample_data {tok} of scene {name} is missing", pred
                )
            jobs.append(
                _Job(
                    tok,
                    str(reader.label_path(tok, "panoptic")),
                    str(pred),
                    str(reader.points_path(tok)),
                    reader.num_points(tok),
                )  # fmt: skip
            )
        out.append((name, jobs))
        start += n
    return out


def _score_scene(args: tuple) -> tuple[TrackingStats, list[PanopticStats]]:
    name, jobs, classes, min_points = args
    n_things = len(classes.things)
    scene = SceneTracking(classes.num_classes)
    seg = []
    kw = {"num_classes": classes.num_classes, "ignore": (IGNORE,), "min_points": min_points}
    for job in jobs:
        pred, pred_sem, gt, sem_gt = load_checked(job, classes)
        seg.append(panoptic_stats(pred_sem, pred, sem_gt, gt, **kw))
        scene.add(tracking_frame(pred_sem, pred, sem_gt, gt, n_things=n_things, **kw))
    return scene.finish(name, n_things, (IGNORE,)), seg


def _num(v: Any) -> Any:
    return float(v)


@dataclass
class NuScenesTrackingEvaluation:
    """Segmentation and tracking counts of an eval set."""

    segmentation: NuScenesEvaluation
    tracking: TrackingStats
    classes: ChallengeClasses
    n_scenes: int

    def devkit_tracking(self) -> dict[str, dict[str, float]]:
        """The ``tracking`` part of the devkit's ``tracking-result.json`` (same keys, order)."""
        res = self.tracking.compute(self.classes.dagger_things, self.classes.dagger_stuff)
        a = res["all"]
        keys = ("PAT", "PQ", "TQ", "PTQ", "sPTQ", "LSTQ", "mIoU", "S_assoc", "MOTSA", "sMOTSA",
                "MOTSP")  # fmt: skip
        out: dict[str, dict[str, float]] = {"all": {k: _num(a[k]) for k in keys}}
        per = res["per_class"]
        for idx, name in enumerate(self.classes.names):
            out[name] = {k: float(per[k][idx]) for k in ("PTQ", "sPTQ", "IoU")}
        out["all"]["PTQ_dagger"] = _num(a["PTQ_dagger"])
        return out

    def write(self, output: str | Path, *, inputs: tuple = ()) -> dict[str, Any]:
        """Write ``tracking-result.json`` (devkit structure), ``scores.json`` (with a
        ``tracking`` section), ``scores.txt`` and ``per_class.csv``; returns ``scores.json``."""
        from panoptic_bench.evaluation.output import write_scores
        from panoptic_bench.io import ensure_output_dir, write_json

        out = ensure_output_dir(output, inputs=tuple(inputs))
        seg = self.segmentation
        trk = self.devkit_tracking()
        ids = self.tracking.ids
        classes = {
            name: {**trk[name], "IDS": int(ids[i])}
            for i, name in enumerate(self.classes.names)
            if i != IGNORE
        }
        tracking = {"all": {k: (None if math.isnan(v) else v) for k, v in trk["all"].items()},
                    "classes": classes}  # fmt: skip
        write_json(
            out / "tracking-result.json",
            {"segmentation": seg.devkit_result(), "tracking": trk},
        )
        return write_scores(
            out,
            seg.stats.compute(),
            class_names=self.classes.names,
            things=self.classes.things,
            stuff=self.classes.stuff,
            extra={
                "task": "tracking",
                "n_samples": seg.n_samples,
                "n_scenes": self.n_scenes,
                "tracking": tracking,
            },
        )


def evaluate_nuscenes_tracking(
    dataroot: str | Path,
    version: str,
    result_path: str | Path,
    eval_set: str,
    *,
    min_inst_points: int = 15,
    workers: int = 1,
    progress: bool | None = None,
    reader: NuScenesLidar | None = None,
) -> NuScenesTrackingEvaluation:
    """Score Panoptic nuScenes tracking predictions of an eval set.

    Parameters
    ----------
    dataroot, version : str
        nuScenes dataroot with panoptic ground truth, and its version.
    result_path : str or Path
        Holds ``panoptic/<eval_set>/<sample_data_token>_panoptic.npz`` (instance ids consistent
        along each scene).
    eval_set : str
        A devkit split.
    min_inst_points : int
        The devkit's ``min_inst_points`` (default 15).
    workers : int
        Worker processes (scenes are distributed).
    progress : bool or None
    reader : NuScenesLidar, optional

    Returns
    -------
    NuScenesTrackingEvaluation
    """
    reader, classes, pred_dir = open_scoring_inputs(
        dataroot, version, result_path, eval_set, workers, min_inst_points, reader
    )
    scenes = scene_jobs(reader, eval_set, pred_dir)
    tasks = [(name, jobs, classes, min_inst_points) for name, jobs in scenes]
    n_samples = sum(len(j) for _, j in scenes)
    bar = workers_module.progress_bar(n_samples, f"nuScenes tracking {eval_set}", "sweep", progress)
    n_workers = workers_module.pool_size(workers, n_samples, len(tasks))
    seg = PanopticStats.zeros(classes.num_classes, (IGNORE,))
    trk = None
    try:
        with workers_module.pool_map(_score_scene, tasks, n_workers) as results:
            for t, per_frame in results:  # scene order, frames in order: as the devkit sums
                trk = t if trk is None else trk + t
                for s in per_frame:
                    seg = seg + s
                bar.update(len(per_frame))
    finally:
        bar.close()
    if trk is None:
        raise InputError(f"eval set {eval_set!r} has no scenes", reader.table_root / "scene.json")
    return NuScenesTrackingEvaluation(
        NuScenesEvaluation(seg, None, classes, n_samples), trk, classes, len(scenes)
    )
