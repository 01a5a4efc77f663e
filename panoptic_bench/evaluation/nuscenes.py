"""Panoptic nuScenes evaluation: the devkit's numbers from our metric core, with input checks.

Equivalent to ``nuscenes.eval.panoptic.evaluate.NuScenesPanopticEval(..., task='segmentation')``:
predictions are read from ``RES/panoptic/<eval_set>/<sample_data_token>_panoptic.npz`` (key
``data``: challenge class x 1000 + instance), the ground truth from the dataroot's ``panoptic`` table,
mapped from the 32 general classes to the 16 challenge classes + ignore (0) with the devkit's
``PanopticClassMapper``. Matching uses the full panoptic label as instance id for both sides, class 0
is ignored, ``min_inst_points`` (default 15) applies to unmatched segments.

Unlike the devkit, every prediction is checked (present, has ``data``, one label per point of the
sweep, classes in 0..16) and reported as an :class:`~panoptic_bench.errors.InputError`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from panoptic_bench.datasets.nuscenes_reader import (
    POINT_DIMS,
    NuScenesLidar,
    load_panoptic_npz,
)
from panoptic_bench.errors import InputError
from panoptic_bench.evaluation import workers as workers_module
from panoptic_bench.io import ensure_output_dir, write_json
from panoptic_bench.metrics.by_range import RangeStats, panoptic_stats_by_range, point_range
from panoptic_bench.metrics.panoptic import PanopticStats, panoptic_stats

IGNORE = 0


@dataclass(frozen=True)
class ChallengeClasses:
    """The Panoptic nuScenes challenge classes (from the devkit's ``PanopticClassMapper``).

    Attributes
    ----------
    names : tuple of str
        Name of each challenge class id (0 = ``ignore``).
    things, stuff : tuple of int
        Thing (1..10) and stuff (11..16) class ids.
    lut : ndarray of shape (n_general,), int64
        General class index -> challenge class id.
    dagger_things, dagger_stuff : tuple of int
        Thing and stuff ids in the devkit mapper's dict order (built from sets, so it depends on
        the string hash seed): PQ† averages in this order to match the devkit to the last bit.
    """

    names: tuple[str, ...]
    things: tuple[int, ...]
    stuff: tuple[int, ...]
    lut: np.ndarray
    dagger_things: tuple[int, ...] = ()
    dagger_stuff: tuple[int, ...] = ()

    @property
    def num_classes(self) -> int:
        return len(self.names)

    @classmethod
    def from_nusc(cls, nusc: Any) -> ChallengeClasses:
        """The devkit's ``PanopticClassMapper`` facts for a dataroot, without importing it.

        ``nusc`` is a ``nuscenes.NuScenes`` or a
        :class:`~panoptic_bench.datasets.nuscenes_tables.NuScenesTables` (anything with
        ``lidarseg_name2idx_mapping``, the category table's ``index`` per general class).
        """
        from panoptic_bench.datasets.nuscenes_spec import (
            CHALLENGE_CLASSES,
            GENERAL_TO_CHALLENGE,
            N_CHALLENGE_THINGS,
            devkit_set_order,
        )

        ids = {name: i for i, name in enumerate(CHALLENGE_CLASSES)}
        fine = nusc.lidarseg_name2idx_mapping
        lut = np.full(max(fine.values(), default=0) + 1, -1, dtype=np.int64)
        for name, idx in fine.items():
            lut[idx] = ids[GENERAL_TO_CHALLENGE.get(name, CHALLENGE_CLASSES[IGNORE])]
        things = CHALLENGE_CLASSES[1 : N_CHALLENGE_THINGS + 1]
        stuff = CHALLENGE_CLASSES[N_CHALLENGE_THINGS + 1 :]
        return cls(
            CHALLENGE_CLASSES,
            tuple(range(1, N_CHALLENGE_THINGS + 1)),
            tuple(range(N_CHALLENGE_THINGS + 1, len(CHALLENGE_CLASSES))),
            lut,
            tuple(ids[n] for n in devkit_set_order(things)),
            tuple(ids[n] for n in devkit_set_order(stuff)),
        )


@dataclass(frozen=True)
class _Job:
    token: str
    gt_path: str
    pred_path: str
    points_path: str
    n_points: int


def load_checked(
    job: _Job, classes: ChallengeClasses
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Read and check one sample: ``(pred, pred_sem, gt, sem_gt)``, each of shape (n_points,).

    ``pred``/``gt`` are the full panoptic labels (int64), ``pred_sem = pred // 1000`` and
    ``sem_gt`` the ground truth mapped to challenge classes.
    """
    gt = load_panoptic_npz(job.gt_path)
    if len(gt) != job.n_points:
        raise InputError(
            f"{len(gt)} ground-truth labels but the sweep of sample_data {job.token} has "
            f"{job.n_points} points",
            job.gt_path,
        )
    gt_general = gt // 1000
    if gt_general.max(initial=0) >= len(classes.lut) or (classes.lut[gt_general] < 0).any():
        raise InputError("ground truth holds unknown general class ids", job.gt_path)
    pred = load_panoptic_npz(job.pred_path)
    if len(pred) != job.n_points:
        raise InputError(
            f"prediction has {len(pred)} labels but the sweep of sample_data {job.token} has "
            f"{job.n_points} points",
            job.pred_path,
        )
    if pred.dtype != np.uint16:
        raise InputError(
            f"prediction 'data' must be uint16 (class x 1000 + instance), got {pred.dtype}; "
            "save it with data=labels.astype(np.uint16)",
            job.pred_path,
        )
    pred_sem = pred // 1000
    bad = (pred_sem < 0) | (pred_sem >= classes.num_classes)
    if bad.any():
        raise InputError(
            f"prediction class ids must be 0..{classes.num_classes - 1} (label // 1000); "
            f"found {int(pred_sem[bad][0])} (label {int(pred[bad][0])})",
            job.pred_path,
        )
    if (pred < 0).any():
        raise InputError("prediction labels must be non-negative", job.pred_path)
    return pred.astype(np.int64), pred_sem, gt.astype(np.int64), classes.lut[gt_general]


def _score_one(
    job: _Job,
    classes: ChallengeClasses,
    min_points: int,
    edges: tuple[float, ...] | None,
) -> tuple[PanopticStats, RangeStats | None]:
    pred, pred_sem, gt, sem_gt = load_checked(job, classes)
    args = (pred_sem, pred, sem_gt, gt)
    kw = {"num_classes": classes.num_classes, "ignore": (IGNORE,), "min_points": min_points}
    stats = panoptic_stats(*args, **kw)
    ranges = None
    if edges is not None:
        pts = np.fromfile(job.points_path, dtype=np.float32).reshape(-1, POINT_DIMS)
        ranges = panoptic_stats_by_range(*args, point_range(pts), edges, **kw)
    return stats, ranges


def _score_chunk(args: tuple) -> list[tuple[PanopticStats, RangeStats | None]]:
    """Per-sample counts of a chunk (kept apart: summed in sample order, as the devkit does)."""
    jobs, classes, min_points, edges = args
    return [_score_one(j, classes, min_points, edges) for j in jobs]


@dataclass
class NuScenesEvaluation:
    """Accumulated counts of an eval set and the devkit-shaped result.

    Attributes
    ----------
    stats : PanopticStats
    by_range : RangeStats or None
    classes : ChallengeClasses
    n_samples : int
    """

    stats: PanopticStats
    by_range: RangeStats | None
    classes: ChallengeClasses
    n_samples: int

    def devkit_result(self) -> dict[str, dict[str, float]]:
        """``{"all": {PQ, SQ, RQ, mIoU, PQ_dagger}, "<class>": {PQ, SQ, RQ, IoU}, ...}``.

        The ``segmentation`` part of the devkit's ``segmentation-result.json``, same keys and order.
        """
        res = self.stats.compute()
        out: dict[str, dict[str, float]] = {
            "all": {"PQ": res.pq_mean, "SQ": res.sq_mean, "RQ": res.rq_mean, "mIoU": res.miou}
        }
        for idx, name in enumerate(self.classes.names):
            out[name] = {
                "PQ": float(res.pq[idx]),
                "SQ": float(res.sq[idx]),
                "RQ": float(res.rq[idx]),
                "IoU": float(res.iou[idx]),
            }
        dagger = [float(res.pq[c]) for c in self.classes.dagger_things or self.classes.things]
        dagger += [float(res.iou[c]) for c in self.classes.dagger_stuff or self.classes.stuff]
        out["all"]["PQ_dagger"] = float(np.mean(dagger))
        return out


def evaluate_nuscenes(
    dataroot: str | Path,
    version: str,
    result_path: str | Path,
    eval_set: str,
    *,
    min_inst_points: int = 15,
    by_range: Sequence[float] | None = None,
    workers: int = 1,
    progress: bool | None = None,
    reader: NuScenesLidar | None = None,
) -> NuScenesEvaluation:
    """Score Panoptic nuScenes predictions of an eval set.

    Parameters
    ----------
    dataroot, version : str
        nuScenes dataroot holding the ``panoptic`` ground truth, and its version.
    result_path : str or Path
        Holds ``panoptic/<eval_set>/<sample_data_token>_panoptic.npz``.
    eval_set : str
        A devkit split of the version (``mini_val``, ``val``, ...).
    min_inst_points : int
        Unmatched segments smaller than this are not counted (devkit default 15).
    by_range : sequence of float, optional
        Range-bin edges (m) for metrics per distance bin.
    workers : int
        Worker processes.
    progress : bool or None
        tqdm progress bar (None: only on a terminal).
    reader : NuScenesLidar, optional
        An already opened dataroot.

    Returns
    -------
    NuScenesEvaluation
    """
    reader, classes, pred_dir = open_scoring_inputs(
        dataroot, version, result_path, eval_set, workers, min_inst_points, reader
    )
    tokens = reader.sample_data_tokens(eval_set)
    jobs = []
    for tok in tokens:
        pred = pred_dir / f"{tok}_panoptic.npz"
        if not pred.is_file():
            raise InputError(f"prediction for sample_data {tok} is missing", pred)
        jobs.append(
            _Job(
                tok,
                str(reader.label_path(tok, "panoptic")),
                str(pred),
                str(reader.points_path(tok)),
                reader.num_points(tok),
            )
        )
    edges = None if by_range is None else tuple(float(e) for e in by_range)
    stats = PanopticStats.zeros(classes.num_classes, (IGNORE,))
    ranges = None if edges is None else RangeStats.zeros(edges, classes.num_classes, (IGNORE,))
    chunk = 8
    chunks = [
        (jobs[i : i + chunk], classes, min_inst_points, edges) for i in range(0, len(jobs), chunk)
    ]
    bar = workers_module.progress_bar(len(jobs), f"nuScenes {eval_set}", "sweep", progress)
    n_workers = workers_module.pool_size(workers, len(jobs), len(chunks))
    try:
        with workers_module.pool_map(_score_chunk, chunks, n_workers) as results:
            for per_sample in results:
                for s, r in per_sample:
                    stats = stats + s
                    if ranges is not None:
                        ranges = ranges + r
                bar.update(len(per_sample))
    finally:
        bar.close()
    return NuScenesEvaluation(stats, ranges, classes, len(jobs))


def write_nuscenes_result(
    evaluation: NuScenesEvaluation, output: str | Path, *, inputs: Sequence[str | Path] = ()
) -> dict[str, Any]:
    """Write ``segmentation-result.json`` (devkit structure) and the shared score files.

    ``scores.txt``, ``scores.json`` (with ``by_range`` and ``n_samples``) and ``per_class.csv``
    come from :func:`panoptic_bench.evaluation.output.write_scores`.

    Parameters
    ----------
    evaluation : NuScenesEvaluation
    output : str or Path
        Output directory (created; may not lie inside any of ``inputs``).
    inputs : sequence of paths
        Input trees never to write into.

    Returns
    -------
    dict
        The ``scores.json`` content.
    """
    from panoptic_bench.evaluation.output import write_scores

    out = ensure_output_dir(output, inputs=tuple(inputs))
    classes = evaluation.classes
    write_json(out / "segmentation-result.json", {"segmentation": evaluation.devkit_result()})
    return write_scores(
        out,
        evaluation.stats.compute(),
        class_names=classes.names,
        things=classes.things,
        stuff=classes.stuff,
        by_range=evaluation.by_range,
        extra={"n_samples": evaluation.n_samples},
    )


def open_scoring_inputs(
    dataroot: str | Path,
    version: str,
    result_path: str | Path,
    eval_set: str,
    workers: int,
    min_inst_points: int,
    reader: NuScenesLidar | None = None,
) -> tuple[NuScenesLidar, ChallengeClasses, Path]:
    """Check the options and open what every nuScenes scoring task reads.

    Returns the table reader, the challenge classes and ``RESULT_PATH/panoptic/<eval_set>``.

    Raises
    ------
    InputError
        Bad ``workers`` / ``min_inst_points``, no panoptic ground truth, or no prediction folder.
    """
    if workers < 1:
        raise InputError(f"--workers must be >= 1, got {workers}")
    if min_inst_points < 0:
        raise InputError(f"--min-inst-points must be >= 0, got {min_inst_points}")
    reader = reader or NuScenesLidar.tables_only(dataroot, version)
    if not hasattr(reader.nusc, "panoptic") or len(reader.nusc.panoptic) == 0:
        raise InputError(
            "no panoptic ground truth in this dataroot; generate it with "
            f"'panoptic-bench nuscenes make-labels --dataroot {dataroot} --version {version} "
            f"--out-dir {dataroot}'",
            reader.table_root / "panoptic.json",
        )
    classes = ChallengeClasses.from_nusc(reader.nusc)
    pred_dir = Path(result_path) / "panoptic" / eval_set
    if not pred_dir.is_dir():
        raise InputError("prediction folder panoptic/<eval_set> not found", pred_dir)
    return reader, classes, pred_dir
