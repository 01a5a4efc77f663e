"""Panoptic nuScenes ground truth from lidarseg + boxes, byte-identical to the devkit's.

Same rules as ``nuscenes/panoptic/generate_panoptic_labels.py``: panoptic = 1000 x general class
index + instance id; instance ids are numbered 1, 2, ... per scene in order of first appearance of
each instance token (samples in table order, annotations in table order); a point takes a box's id
only if its lidarseg class is the box's category; points counted by more than one such box -> 0;
thing points (classes 1..23) in no box -> 0. Output: ``panoptic/<version>/<token>_panoptic.npz``
(key ``data``, uint16), ``<version>/panoptic.json`` and a copy of ``category.json``.

Differences from the devkit are only in speed: the boxes of a sweep are tested at once
(:func:`~panoptic_bench.datasets.nuscenes_boxes.points_in_boxes`), samples run in parallel, all
inputs are checked before anything is written, and the output appears atomically.
"""

from __future__ import annotations

import json
import os
import shutil
import uuid
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from panoptic_bench.datasets.nuscenes_boxes import BoxFrames, points_in_boxes
from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar, open_nuscenes
from panoptic_bench.errors import InputError

STUFF_START_CLASS_ID = 24  # devkit panoptic_utils: general classes >= 24 are stuff


@dataclass(frozen=True)
class SampleJob:
    """Everything one worker needs for one sweep (no devkit object crosses processes)."""

    points_path: str
    lidarseg_path: str
    out_path: str
    frames: BoxFrames
    category: np.ndarray  # (n_boxes,) general class index of each box
    instance_id: np.ndarray  # (n_boxes,) per-scene instance id


def panoptic_labels(
    points: np.ndarray,
    lidarseg: np.ndarray,
    frames: BoxFrames,
    category: np.ndarray,
    instance_id: np.ndarray,
) -> np.ndarray:
    """Panoptic labels of one sweep.

    Parameters
    ----------
    points : array of shape (n_points, >=3), float32
        Sweep in the LIDAR_TOP frame.
    lidarseg : array of shape (n_points,), uint8
        General class index of each point.
    frames : BoxFrames
        The sweep's annotation boxes and poses.
    category, instance_id : arrays of shape (n_boxes,), int
        General class index and per-scene instance id of each box.

    Returns
    -------
    array of shape (n_points,), uint16
        ``1000 * class + instance`` exactly as the devkit computes it.
    """
    box, point = points_in_boxes(points, frames)
    match = lidarseg[point] == category[box]
    box, point = box[match], point[match]
    panoptic = lidarseg.astype(np.int32) * 1000
    ids = np.asarray(instance_id, np.float64)[box]  # small integers: exact in float64
    panoptic += np.bincount(point, weights=ids, minlength=len(lidarseg)).astype(np.int32)
    overlap = np.bincount(point, minlength=len(lidarseg))
    panoptic[overlap > 1] = 0
    semantic = panoptic // 1000
    thing = np.logical_and(semantic > 0, semantic < STUFF_START_CLASS_ID)
    panoptic[np.logical_and(thing, panoptic % 1000 == 0)] = 0
    return panoptic.astype(np.uint16)


def run_job(job: SampleJob) -> None:
    """Read one sweep and its lidarseg, write its panoptic ``.npz``."""
    points = np.fromfile(job.points_path, dtype=np.float32).reshape(-1, 5)[:, :4]
    lidarseg = np.fromfile(job.lidarseg_path, dtype=np.uint8)
    if len(points) != len(lidarseg):  # checked before, unless the file changed meanwhile
        raise InputError(
            f"{len(lidarseg)} labels for {len(points)} points of {job.points_path}",
            job.lidarseg_path,
        )
    from panoptic_bench.datasets.nuscenes_spec import GENERAL_CLASSES

    if len(lidarseg) and int(lidarseg.max()) >= len(GENERAL_CLASSES):  # 1000 x 200 wraps uint16
        raise InputError(
            f"lidarseg class {int(lidarseg.max())} is not a general class 0-"
            f"{len(GENERAL_CLASSES) - 1}",
            job.lidarseg_path,
        )
    labels = panoptic_labels(points, lidarseg, job.frames, job.category, job.instance_id)
    # Written straight into the private staging directory, which make_panoptic_labels renames
    # into place once every file is complete: the whole output appears atomically, so the
    # per-file temp file + fsync of io.write_npz (3-4 ms a file) would only cost time.
    import io

    buffer = io.BytesIO()  # built in memory: a full disk fails in one plain write
    np.savez_compressed(buffer, data=labels)
    with open(job.out_path, "wb") as fh:
        fh.write(buffer.getvalue())


def _jobs(reader: NuScenesLidar, stage_dir: Path) -> tuple[list[SampleJob], list[dict]]:
    """Instance ids in devkit order, one job and one panoptic.json row per sample; all checked."""
    nusc = reader.nusc
    if not hasattr(nusc, "lidarseg") or len(nusc.lidarseg) == 0:
        raise InputError(
            f"no nuScenes-lidarseg annotations in {reader.version}: panoptic labels need "
            "lidarseg.json and lidarseg/<version>/*.bin",
            reader.table_root / "lidarseg.json",
        )
    name2idx = nusc.lidarseg_name2idx_mapping
    subdir = os.path.join("panoptic", nusc.version)
    inst_ids: dict[str, dict[str, int]] = {}
    jobs, rows = [], []
    for sample in nusc.sample:
        ids = inst_ids.setdefault(sample["scene_token"], {})
        sd_token = reader.lidar_token(sample)
        sd = nusc.get("sample_data", sd_token)
        lidarseg_path = reader.label_path(sd_token, "lidarseg")
        n_points = reader.num_points(sd_token)
        n_labels = lidarseg_path.stat().st_size if lidarseg_path.is_file() else None
        if n_labels is None:
            raise InputError(f"lidarseg file of sample_data {sd_token} is missing", lidarseg_path)
        if n_labels != n_points:
            raise InputError(
                f"{n_labels} lidarseg labels but the sweep of sample_data {sd_token} has "
                f"{n_points} points",
                lidarseg_path,
            )
        anns = [nusc.get("sample_annotation", t) for t in sample["anns"]]
        for ann in anns:
            ids.setdefault(ann["instance_token"], len(ids) + 1)
        unknown = [a["category_name"] for a in anns if a["category_name"] not in name2idx]
        if unknown:
            raise InputError(
                f"category {unknown[0]!r} of sample {sample['token']} is not a lidarseg class",
                reader.table_root / "category.json",
            )
        pose = nusc.get("ego_pose", sd["ego_pose_token"])
        calib = nusc.get("calibrated_sensor", sd["calibrated_sensor_token"])
        frames = BoxFrames(
            translation=np.array([a["translation"] for a in anns], float).reshape(-1, 3),
            size=np.array([a["size"] for a in anns], float).reshape(-1, 3),
            rotation=np.array([a["rotation"] for a in anns], float).reshape(-1, 4),
            ego_translation=np.array(pose["translation"], float),
            ego_rotation=np.array(pose["rotation"], float),
            calib_translation=np.array(calib["translation"], float),
            calib_rotation=np.array(calib["rotation"], float),
        )
        name = nusc.get("lidarseg", sd_token)["filename"].split("/")[-1]
        name = name.replace("lidarseg", "panoptic").replace(".bin", ".npz")
        jobs.append(
            SampleJob(
                points_path=str(reader.points_path(sd_token)),
                lidarseg_path=str(lidarseg_path),
                out_path=str(stage_dir / name),
                frames=frames,
                category=np.array([name2idx[a["category_name"]] for a in anns], np.int64),
                instance_id=np.array([ids[a["instance_token"]] for a in anns], np.int64),
            )
        )
        rows.append(
            {
                "token": sd_token,
                "sample_data_token": sd_token,
                "filename": os.path.join(subdir, name),
            }
        )
    return jobs, rows


def make_panoptic_labels(
    dataroot: str | Path,
    version: str,
    out_dir: str | Path,
    *,
    workers: int = 1,
    progress: bool | None = None,
    nusc: Any | None = None,
) -> list[dict]:
    """Generate Panoptic nuScenes labels for every sample of a dataroot.

    Parameters
    ----------
    dataroot : str or Path
        nuScenes dataroot with lidarseg (read only).
    version : str
        E.g. ``"v1.0-mini"``.
    out_dir : str or Path
        Receives ``panoptic/<version>/*.npz``, ``<version>/panoptic.json`` and
        ``<version>/category.json`` (copied unless present). May be the dataroot itself.
    workers : int
        Worker processes (1: in this process).
    progress : bool or None
        tqdm progress bar (None: only on a terminal).
    nusc : nuscenes.NuScenes, optional
        The caller's already loaded devkit object for this dataroot and version (saves loading
        the tables again); only read.

    Returns
    -------
    list of dict
        The ``panoptic.json`` rows, as written.
    """
    if workers < 1:
        raise InputError(f"--workers must be >= 1, got {workers}")
    reader = NuScenesLidar(
        dataroot, version, nusc=nusc if nusc is not None else open_nuscenes(dataroot, version)
    )
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError("output exists and is not a directory", out)
    stage = out / f".staging-{uuid.uuid4().hex}"
    jobs, rows = _jobs(reader, stage / "panoptic")
    created = not out.exists()
    done = False
    try:
        (stage / "panoptic").mkdir(parents=True)
        disable = None if progress is None else not progress
        bar = tqdm(total=len(jobs), desc="panoptic labels", unit="sweep", disable=disable)
        if workers == 1 or len(jobs) < 2:
            for job in jobs:
                run_job(job)
                bar.update()
        else:
            import multiprocessing as mp

            chunk = max(1, min(16, len(jobs) // (4 * workers)))
            with ProcessPoolExecutor(workers, mp_context=mp.get_context("fork")) as pool:
                for _ in pool.map(run_job, jobs, chunksize=chunk):
                    bar.update()
        bar.close()
        meta = out / version
        # like the .npz files: complete in the private staging directory, then renamed in place
        (stage / "panoptic.json").write_text(json.dumps(rows, indent=2))
        if not (meta / "category.json").is_file():
            shutil.copyfile(reader.table_root / "category.json", stage / "category.json")
        final = out / "panoptic" / version
        final.parent.mkdir(parents=True, exist_ok=True)
        if final.exists():
            os.replace(final, stage / "old")
        os.replace(stage / "panoptic", final)
        meta.mkdir(parents=True, exist_ok=True)
        os.replace(stage / "panoptic.json", meta / "panoptic.json")
        if (stage / "category.json").is_file():
            os.replace(stage / "category.json", meta / "category.json")
        done = True
    finally:
        shutil.rmtree(stage, ignore_errors=True)
        if created and not done:
            shutil.rmtree(out, ignore_errors=True)
    return rows
