"""Box-merge baseline on nuScenes: lidarseg predictions + detection/tracking boxes → Panoptic nuScenes.

Inputs
------
Boxes
    A standard nuScenes **detection** submission JSON (``{"meta": {...}, "results": {sample_token:
    [box, ...]}}``, each box with ``translation``, ``size`` (w, l, h), ``rotation`` (w, x, y, z) in
    the global frame, ``velocity``, ``detection_name``, ``detection_score`` (a float),
    ``attribute_name``) or **tracking** submission JSON (``tracking_name``, ``tracking_score``,
    ``tracking_id`` instead). Read with the devkit's own ``load_prediction`` (at most 1000 boxes
    per sample). Samples outside the eval set are ignored; a sample of the eval set without an
    entry has no boxes.
Semantic prediction
    ``SEG/lidarseg/<version suffix>/<lidar sample_data token>_lidarseg.bin`` (``mini`` for
    ``v1.0-mini``, the layout the devkit script reads), or ``SEG/lidarseg/<eval set>/`` (the
    lidarseg challenge submission layout) when the first folder is absent: uint8, one challenge
    class (0..16) per point of the sweep.

Output: ``OUT/panoptic/<eval set>/<token>_panoptic.npz`` (key ``data``, uint16, class x 1000 +
instance) and ``submission.json``, directly scorable by ``panoptic-bench eval nuscenes``.

Merge rules (:class:`~panoptic_bench.baselines.box_merge.MergeMode`), boxes by descending score
(``np.argsort(scores)[::-1]``):

``devkit``
    nuscenes-devkit 1.2.0 ``eval/panoptic/get_panoptic_from_seg_det_or_track.py`` bit for bit: a box
    takes the points inside it (devkit ``points_in_box`` after ``boxes_to_sensor``) whose class is
    the box class; it is dropped if more than 50 % of them are already taken; its untaken points get
    ``class * 1000 + id``, id = rank + 1 (detection) or the per-scene order of first appearance of
    its ``tracking_id`` (tracking). Untaken stuff points (class >= 11) get ``class * 1000``; every
    other point 0.
``paper``
    DS-Net §4.3: every untaken point inside a box gets the box's class and id; the other points
    keep their class with instance 0.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from panoptic_bench.baselines.box_merge import OVERLAP_THRESHOLD, SIMULATED_DETECTOR, MergeMode
from panoptic_bench.datasets.nuscenes_boxes import BoxFrames, points_in_boxes
from panoptic_bench.errors import InputError, InputErrors
from panoptic_bench.io import write_json, write_npz

__all__ = [
    "BoxTask",
    "SampleBoxes",
    "box_merge_nuscenes",
    "lidarseg_prediction_dir",
    "load_boxes",
    "merge_sample",
    "tracking_names",
]

#: Challenge classes >= this are stuff (devkit ``STUFF_START_COARSE_CLASS_ID``).
STUFF_START = 11
NUM_CLASSES = 17
MAX_BOXES_PER_SAMPLE = 1000


class BoxTask(StrEnum):
    """Kind of box submission: ``detection`` (rank ids) or ``tracking`` (per-scene track ids)."""

    DETECTION = "detection"
    TRACKING = "tracking"


@dataclass(frozen=True, eq=False)
class SampleBoxes:
    """The boxes of one sample, sorted by descending score as the devkit sorts them.

    Attributes
    ----------
    frames : BoxFrames
        Global boxes with the sweep's ego pose and LIDAR_TOP calibration.
    cls : array of shape (n_boxes,), int64
        Challenge class id (1..10) of each box.
    ids : array of shape (n_boxes,), int64
        Instance id of each box (rank + 1, or the per-scene track id).
    """

    frames: BoxFrames
    cls: np.ndarray
    ids: np.ndarray


def tracking_names() -> list[str]:
    """The devkit's tracking classes (``tracking_nips_2019``).

    Building the devkit's ``TrackingConfig`` also sets its module-level ``TRACKING_NAMES``, which
    ``TrackingBox`` checks names against (empty until a config exists).
    """
    from nuscenes.eval.common.config import config_factory

    return list(config_factory("tracking_nips_2019").tracking_names)


def load_boxes(path: str | Path, task: BoxTask, nusc: Any) -> tuple[dict[str, list], dict]:
    """Read a detection/tracking submission JSON with the devkit's ``load_prediction``.

    Returns
    -------
    boxes : dict
        sample token -> list of devkit ``DetectionBox`` / ``TrackingBox`` (file order).
    meta : dict
        The file's ``meta``.

    Raises
    ------
    InputError
        Missing or unreadable file, bad structure or box field, or a sample token that is not a
        sample of the dataset; the message names the file.
    """
    from nuscenes.eval.common.loaders import load_prediction
    from nuscenes.eval.detection.data_classes import DetectionBox
    from nuscenes.eval.tracking.data_classes import TrackingBox

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{task} submission JSON not found", path)
    box_cls = TrackingBox if task is BoxTask.TRACKING else DetectionBox
    if task is BoxTask.TRACKING:
        tracking_names()
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read JSON ({exc})", path) from None
    if not isinstance(data, dict) or not isinstance(data.get("results"), dict):
        raise InputError("expected an object with 'meta' and 'results' {sample_token: [...]}", path)
    if "meta" not in data:
        raise InputError("no 'meta' field (see the nuScenes detection submission format)", path)
    try:
        evalboxes, meta = load_prediction(str(path), MAX_BOXES_PER_SAMPLE, box_cls)
    except AssertionError as exc:
        raise InputError(f"invalid {task} submission: {exc}", path) from None
    except KeyError as exc:
        other = "detection" if task is BoxTask.TRACKING else "tracking"
        raise InputError(
            f"a {task} box lacks the field {exc}; for a {other} submission pass --task {other}",
            path,
        ) from None
    except (TypeError, ValueError) as exc:
        raise InputError(f"invalid {task} box value ({exc})", path) from None
    known = {rec["token"] for rec in nusc.sample}
    unknown = [t for t in evalboxes.sample_tokens if t not in known]
    if unknown:
        raise InputError(
            f"{len(unknown)} sample token(s) are not samples of {nusc.version} "
            f"(first: {unknown[0]}); was the file made for another dataset or version?",
            path,
        )
    boxes = {t: list(evalboxes[t]) for t in evalboxes.sample_tokens}
    for t, bs in boxes.items():
        for b in bs:
            if not np.isfinite([*b.translation, *b.size, *b.rotation]).all():
                raise InputError(f"sample {t}: a box has a non-finite value", path)
            if np.linalg.norm(b.rotation) == 0:
                raise InputError(f"sample {t}: a box has a zero rotation quaternion", path)
            if min(b.size) <= 0:
                raise InputError(
                    f"sample {t}: a box has size {list(b.size)}; sizes must be > 0", path
                )
    return boxes, meta


def sort_boxes(
    boxes: Sequence[Any],
    task: BoxTask,
    coarse2idx: dict[str, int],
    pose: dict,
    calib: dict,
    track_ids: dict[str, int] | None = None,
) -> SampleBoxes:
    """Sort a sample's boxes as the devkit does and attach poses, classes and instance ids.

    ``track_ids`` (tracking only) is the scene's ``tracking_id -> id`` map, updated in place in
    the devkit's order (every sorted box, kept or later dropped).
    """
    tracking = task is BoxTask.TRACKING
    scores = [b.tracking_score if tracking else b.detection_score for b in boxes]
    order = np.argsort(scores)[::-1]
    sorted_boxes = [boxes[i] for i in order]
    names = [b.tracking_name if tracking else b.detection_name for b in sorted_boxes]
    if tracking:
        track_ids = {} if track_ids is None else track_ids
        for b in sorted_boxes:
            track_ids.setdefault(b.tracking_id, len(track_ids) + 1)
        ids = [track_ids[b.tracking_id] for b in sorted_boxes]
    else:
        ids = list(range(1, len(sorted_boxes) + 1))
    frames = BoxFrames(
        translation=np.array([b.translation for b in sorted_boxes], float).reshape(-1, 3),
        size=np.array([b.size for b in sorted_boxes], float).reshape(-1, 3),
        rotation=np.array([b.rotation for b in sorted_boxes], float).reshape(-1, 4),
        ego_translation=np.array(pose["translation"], float),
        ego_rotation=np.array(pose["rotation"], float),
        calib_translation=np.array(calib["translation"], float),
        calib_rotation=np.array(calib["rotation"], float),
    )
    cls = np.array([coarse2idx[n] for n in names], np.int64)
    return SampleBoxes(frames, cls, np.array(ids, np.int64))


def merge_sample(
    points: np.ndarray, seg: np.ndarray, boxes: SampleBoxes, mode: MergeMode
) -> np.ndarray:
    """Panoptic labels of one sweep from its semantic prediction and its sorted boxes.

    Parameters
    ----------
    points : array of shape (n_points, >=3), float32
        The sweep in the LIDAR_TOP frame.
    seg : array of shape (n_points,), uint8
        Challenge class (0..16) of each point.
    boxes : SampleBoxes
        Boxes in descending score order.
    mode : MergeMode

    Returns
    -------
    array of shape (n_points,), uint16
        ``class * 1000 + instance`` (module docstring for both rules).
    """
    mode = MergeMode(mode)
    seg = np.asarray(seg)
    box, point = points_in_boxes(points, boxes.frames)
    starts = np.searchsorted(box, np.arange(len(boxes.cls) + 1))
    labels = np.zeros(len(seg), np.int64)
    taken = np.zeros(len(seg), bool)
    for b, (cls, inst) in enumerate(zip(boxes.cls.tolist(), boxes.ids.tolist())):
        pts = point[starts[b] : starts[b + 1]]
        if mode is MergeMode.DEVKIT:
            pts = pts[seg[pts] == cls]
            inter = taken[pts]
            # the devkit's expression and operand types: sum(bool) / (float32(count) + 1e-32)
            if np.sum(inter) / (np.float32(len(pts)) + 1e-32) > OVERLAP_THRESHOLD:
                continue
            pts = pts[~inter]
        else:
            pts = pts[~taken[pts]]
        labels[pts] = cls * 1000 + inst
        taken[pts] = True
    free = ~taken
    if mode is MergeMode.DEVKIT:
        free &= seg >= STUFF_START
    labels[free] = seg[free].astype(np.int64) * 1000
    return labels.astype(np.uint16)


def lidarseg_prediction_dir(semantic: str | Path, version: str, eval_set: str) -> Path:
    """``SEG/lidarseg/<version suffix>`` if it exists, else ``SEG/lidarseg/<eval_set>``."""
    base = Path(semantic) / "lidarseg"
    first = base / version.split("-")[-1]
    if first.is_dir() or not (base / eval_set).is_dir():
        return first
    return base / eval_set


def _read_seg(path: Path, n_points: int, token: str) -> np.ndarray:
    if not path.is_file():
        raise InputError(f"lidarseg prediction of sample_data {token} is missing", path)
    seg = np.fromfile(path, dtype=np.uint8)
    if len(seg) != n_points:
        raise InputError(
            f"{len(seg)} lidarseg predictions but the sweep of sample_data {token} has "
            f"{n_points} points",
            path,
        )
    if len(seg) and seg.max() >= NUM_CLASSES:
        raise InputError(
            f"lidarseg prediction classes must lie in 0..16 (challenge classes), got {seg.max()}",
            path,
        )
    return seg


def box_merge_nuscenes(
    dataroot: str | Path,
    version: str,
    eval_set: str,
    semantic: str | Path,
    boxes: str | Path,
    output: str | Path,
    mode: MergeMode,
    *,
    task: BoxTask = BoxTask.DETECTION,
) -> int:
    """Merge lidarseg predictions with detection/tracking boxes for every sample of ``eval_set``.

    Parameters
    ----------
    dataroot, version, eval_set
        The nuScenes dataroot, e.g. ``v1.0-mini``, and a devkit split such as ``mini_val``.
    semantic : path
        Root of the lidarseg predictions (module docstring).
    boxes : path
        Detection or tracking submission JSON.
    output : path
        Receives ``panoptic/<eval_set>/<token>_panoptic.npz`` and ``submission.json``.
    mode : MergeMode
    task : BoxTask

    Returns
    -------
    int
        Number of sweeps written. Every input is checked before anything is written.
    """
    from nuscenes.eval.panoptic.utils import PanopticClassMapper

    from panoptic_bench.baselines.run import SUBMISSION_META
    from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar

    mode, task = MergeMode(mode), BoxTask(task)
    reader = NuScenesLidar(dataroot, version)
    nusc = reader.nusc
    tokens = reader.sample_data_tokens(eval_set)
    all_boxes, meta = load_boxes(boxes, task, nusc)
    seg_dir = lidarseg_prediction_dir(semantic, version, eval_set)
    problems = []
    for tok in tokens:
        path = seg_dir / f"{tok}_lidarseg.bin"
        try:
            _read_seg(path, reader.num_points(tok), tok)
        except InputError as exc:
            problems.append(str(exc))
    if problems:
        raise InputErrors(problems[:20], header=f"bad lidarseg predictions under {seg_dir}")
    coarse2idx = PanopticClassMapper(nusc).get_coarse2idx()
    out_dir = Path(output) / "panoptic" / eval_set
    track_ids: dict[str, dict[str, int]] = {}
    for tok in tqdm(tokens, desc=f"box-merge ({mode})", disable=None):
        sd = nusc.get("sample_data", tok)
        sample = nusc.get("sample", sd["sample_token"])
        points = reader.load_points(tok)
        seg = _read_seg(seg_dir / f"{tok}_lidarseg.bin", len(points), tok)
        sorted_boxes = sort_boxes(
            all_boxes.get(sample["token"], []),
            task,
            coarse2idx,
            nusc.get("ego_pose", sd["ego_pose_token"]),
            nusc.get("calibrated_sensor", sd["calibrated_sensor_token"]),
            track_ids.setdefault(sample["scene_token"], {}),
        )
        write_npz(
            out_dir / f"{tok}_panoptic.npz", data=merge_sample(points, seg, sorted_boxes, mode)
        )
    sub_meta = dict(
        SUBMISSION_META, task="tracking" if task is BoxTask.TRACKING else "segmentation"
    )
    sub_meta["method"] = f"box-merge ({mode})"
    if isinstance(meta, dict) and meta.get("source") == SIMULATED_DETECTOR:
        sub_meta["source"] = f"box-merge of {SIMULATED_DETECTOR} boxes"
    write_json(out_dir / "submission.json", {"meta": sub_meta})
    return len(tokens)
