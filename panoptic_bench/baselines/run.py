"""Dataset-level drivers: regressed centres of every scan → official-format panoptic predictions.

SemanticKITTI: centres ``CENTERS/sequences/XX/centers/NNNNNN.npz`` → predictions
``OUT/sequences/XX/predictions/NNNNNN.label`` (scorable by ``panoptic-bench eval semantickitti``).
nuScenes: centres ``CENTERS/centers/<lidar token>.npz`` → ``OUT/panoptic/<eval set>/<token>_panoptic.npz``
(key ``data``, uint16; scorable by ``panoptic-bench eval nuscenes``). Also: simulated centres for a
labelled SemanticKITTI tree or nuScenes dataroot with panoptic labels (``centers simulate``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from panoptic_bench.baselines.centers import (
    centers_path_nuscenes,
    centers_path_semantickitti,
    read_centers,
    write_centers,
)
from panoptic_bench.baselines.clustering import Clusterer
from panoptic_bench.baselines.panoptic import (
    SmallInstance,
    assemble_panoptic,
    nuscenes_panoptic,
    semantickitti_label,
)
from panoptic_bench.baselines.regression import SIMULATED, RegressionNoise, simulate_offsets
from panoptic_bench.io import write_json, write_npz

__all__ = [
    "NUSCENES_NUM_CLASSES",
    "NUSCENES_THING_IDS",
    "AssemblyOptions",
    "cluster_nuscenes",
    "cluster_semantickitti",
    "simulate_centers_nuscenes",
    "simulate_centers_semantickitti",
]

#: Panoptic nuScenes evaluation classes: 0 = ignore, 1..10 things, 11..16 stuff.
NUSCENES_THING_IDS = tuple(range(1, 11))
NUSCENES_NUM_CLASSES = 17
#: ``submission.json`` meta of a lidar-only panoptic segmentation submission.
SUBMISSION_META = {
    "task": "segmentation",
    "use_camera": False,
    "use_lidar": True,
    "use_radar": False,
    "use_map": False,
    "use_external": False,
}


@dataclass(frozen=True)
class AssemblyOptions:
    """Everything :func:`assemble_panoptic` needs besides the scan (picklable for workers)."""

    clusterer: Clusterer
    min_points: int
    fusion: bool = True
    small: SmallInstance = SmallInstance.NO_INSTANCE


def _map(fn: Callable, jobs: list, workers: int, desc: str) -> list:
    if workers <= 1 or len(jobs) <= 1:
        return [fn(j) for j in tqdm(jobs, desc=desc, disable=None)]
    with ProcessPoolExecutor(max_workers=workers) as pool:
        return list(tqdm(pool.map(fn, jobs), total=len(jobs), desc=desc, disable=None))


# --------------------------------------------------------------------------- SemanticKITTI


def _kitti_job(job: tuple[Path, Path, Path, AssemblyOptions]) -> int:
    from panoptic_bench.datasets.semantickitti import LABELS, read_scan, write_labels

    scan_path, centers_path, out_path, opts = job
    points = read_scan(scan_path)
    c = read_centers(centers_path, n_points=len(points), num_classes=LABELS.num_classes)
    sem, inst = assemble_panoptic(
        points, c.sem, c.offset, opts.clusterer, thing_ids=LABELS.thing_ids,
        min_points=opts.min_points, fusion=opts.fusion, small=opts.small,
        num_classes=LABELS.num_classes,
    )  # fmt: skip
    write_labels(out_path, semantickitti_label(sem, inst))
    return int(inst.max())


def cluster_semantickitti(
    dataset: str | Path,
    centers: str | Path,
    output: str | Path,
    options: AssemblyOptions,
    *,
    split: str | None = None,
    sequences: Iterable | None = None,
    workers: int = 1,
) -> int:
    """Cluster the regressed centres of every scan and write SemanticKITTI predictions.

    Parameters
    ----------
    dataset : path
        SemanticKITTI root (``sequences/XX/velodyne``).
    centers : path
        Root of the centre files (``sequences/XX/centers/NNNNNN.npz``).
    output : path
        Prediction root; ``sequences/XX/predictions/NNNNNN.label`` are written.
    options : AssemblyOptions
    split, sequences : optional
        Scan selection, as :func:`panoptic_bench.datasets.semantickitti.list_scans`.
    workers : int
        Worker processes.

    Returns
    -------
    int
        Number of scans written.
    """
    from panoptic_bench.datasets.semantickitti import list_scans, prediction_path
    from panoptic_bench.errors import InputErrors

    refs = list_scans(
        dataset, split=split, sequences=None if sequences is None else list(sequences)
    )
    jobs = [
        (
            r.scan,
            centers_path_semantickitti(centers, r.sequence, r.frame),
            prediction_path(output, r),
            options,
        )
        for r in refs
    ]
    missing = [str(j[1]) for j in jobs if not j[1].is_file()]
    if missing:
        raise InputErrors(missing[:20], header="regressed-centre files missing (one .npz per scan)")
    _map(_kitti_job, jobs, workers, "cluster")
    return len(jobs)


def _simulate_job(job: tuple[Path, Path, Path, RegressionNoise, int]) -> None:
    from panoptic_bench.datasets.semantickitti import LABELS, read_labels, read_scan, to_train

    scan_path, label_path, out_path, noise, seed = job
    points = read_scan(scan_path)
    labels = read_labels(label_path)
    if len(labels) != len(points):
        from panoptic_bench.errors import InputError

        raise InputError(f"{len(labels)} labels for {len(points)} points", label_path)
    sem = to_train(labels)
    offset = simulate_offsets(points, sem, labels >> 16, LABELS.thing_ids, noise=noise, seed=seed)
    write_centers(out_path, sem, offset, source=SIMULATED)


def simulate_centers_semantickitti(
    dataset: str | Path,
    output: str | Path,
    *,
    noise: RegressionNoise | None = None,
    seed: int = 0,
    split: str | None = None,
    sequences: Iterable | None = None,
    workers: int = 1,
) -> int:
    """Write "simulated regression" centre files from the ground truth of a labelled tree.

    The semantic prediction is the ground truth; offsets follow
    :func:`~panoptic_bench.baselines.regression.simulate_offsets` with seed ``seed + scan index``.
    ``output/simulated.json`` records the source label, the noise parameters and the seed.

    Returns
    -------
    int
        Number of scans written.
    """
    from panoptic_bench.datasets.semantickitti import list_scans

    noise = RegressionNoise() if noise is None else noise
    refs = list_scans(
        dataset, split=split, sequences=None if sequences is None else list(sequences)
    )
    jobs = [
        (r.scan, r.label, centers_path_semantickitti(output, r.sequence, r.frame), noise, seed + k)
        for k, r in enumerate(refs)
    ]
    _map(_simulate_job, jobs, workers, "simulate centres")
    meta: dict[str, Any] = {"source": SIMULATED, "seed": seed, "noise": noise.to_dict()}
    write_json(Path(output) / "simulated.json", meta)
    return len(jobs)


# --------------------------------------------------------------------------- nuScenes


def _nuscenes_job(job: tuple[Path, Path, Path, AssemblyOptions]) -> int:
    points_path, centers_path, out_path, opts = job
    points = np.fromfile(points_path, dtype=np.float32).reshape(-1, 5)
    c = read_centers(centers_path, n_points=len(points), num_classes=NUSCENES_NUM_CLASSES)
    sem, inst = assemble_panoptic(
        points, c.sem, c.offset, opts.clusterer, thing_ids=NUSCENES_THING_IDS,
        min_points=opts.min_points, fusion=opts.fusion, small=opts.small,
        num_classes=NUSCENES_NUM_CLASSES,
    )  # fmt: skip
    write_npz(out_path, data=nuscenes_panoptic(sem, inst))
    return int(inst.max())


def cluster_nuscenes(
    dataroot: str | Path,
    version: str,
    eval_set: str,
    centers: str | Path,
    output: str | Path,
    options: AssemblyOptions,
    *,
    workers: int = 1,
) -> int:
    """Cluster the regressed centres of every keyframe of ``eval_set`` into Panoptic nuScenes files.

    Centre ``sem`` values are the 17 evaluation classes (0 ignore, 1..10 things, 11..16 stuff).
    Writes ``output/panoptic/<eval_set>/<lidar token>_panoptic.npz``; returns the number written.
    """
    from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar
    from panoptic_bench.errors import InputErrors

    reader = NuScenesLidar(dataroot, version)
    tokens = reader.sample_data_tokens(eval_set)
    missing = [str(centers_path_nuscenes(centers, t)) for t in tokens]
    missing = [m for m in missing if not Path(m).is_file()]
    if missing:
        raise InputErrors(
            missing[:20], header="regressed-centre files missing (one .npz per sweep)"
        )
    out_dir = Path(output) / "panoptic" / eval_set
    jobs = [
        (
            reader.points_path(t),
            centers_path_nuscenes(centers, t),
            out_dir / f"{t}_panoptic.npz",
            options,
        )
        for t in tokens
    ]
    _map(_nuscenes_job, jobs, workers, "cluster")
    write_json(out_dir / "submission.json", {"meta": SUBMISSION_META})
    return len(jobs)


def _simulate_nuscenes_job(job: tuple[Path, np.ndarray, Path, RegressionNoise, int]) -> None:
    points_path, panoptic, out_path, noise, seed = job
    points = np.fromfile(points_path, dtype=np.float32).reshape(-1, 5)
    sem, inst = panoptic // 1000, panoptic % 1000
    offset = simulate_offsets(points, sem, inst, NUSCENES_THING_IDS, noise=noise, seed=seed)
    write_centers(out_path, sem, offset, source=SIMULATED)


def simulate_centers_nuscenes(
    dataroot: str | Path,
    version: str,
    eval_set: str,
    output: str | Path,
    *,
    noise: RegressionNoise | None = None,
    seed: int = 0,
    workers: int = 1,
) -> int:
    """Write "simulated regression" centre files for the keyframes of a nuScenes eval set.

    Needs the dataroot's Panoptic nuScenes labels (``panoptic-bench nuscenes make-labels``). The
    semantic prediction is the ground truth mapped to the 17 challenge classes; instances are the
    panoptic instance ids; offsets as :func:`simulate_centers_semantickitti` (seed ``seed + sweep
    index``). Writes ``output/centers/<lidar token>.npz`` and ``output/simulated.json``.

    Returns
    -------
    int
        Number of sweeps written.
    """
    from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar
    from panoptic_bench.evaluation.nuscenes import ChallengeClasses

    noise = RegressionNoise() if noise is None else noise
    reader = NuScenesLidar(dataroot, version)
    lut = ChallengeClasses.from_nusc(reader.nusc).lut
    jobs = []
    for k, tok in enumerate(reader.sample_data_tokens(eval_set)):
        gt = reader.load_panoptic(tok).astype(np.int64)
        panoptic = np.maximum(lut[gt // 1000], 0) * 1000 + gt % 1000
        jobs.append(
            (reader.points_path(tok), panoptic, centers_path_nuscenes(output, tok), noise, seed + k)
        )
    _map(_simulate_nuscenes_job, jobs, workers, "simulate centres")
    meta: dict[str, Any] = {"source": SIMULATED, "seed": seed, "noise": noise.to_dict()}
    write_json(Path(output) / "simulated.json", meta)
    return len(jobs)
