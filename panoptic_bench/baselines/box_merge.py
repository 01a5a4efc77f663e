"""Box-merge baseline: semantic prediction + 3D boxes of any detector → panoptic prediction.

Two merge rules (:class:`MergeMode`):

``DEVKIT``
    The rule of nuscenes-devkit ``eval/panoptic/get_panoptic_from_seg_det_or_track.py``: boxes by
    descending score (``np.argsort(scores)[::-1]``); a box takes the points inside it whose
    semantic class equals the box class; it is dropped if more than 50 % of those points are
    already taken; otherwise its untaken points get instance id ``rank + 1`` (rank in the sorted
    order, so dropped boxes leave gaps). Things points in no box end with class 0 and instance 0,
    stuff points keep their class with instance 0.
``PAPER``
    DS-Net §4.3: every point inside a box (higher scores first; a point already taken stays
    with the earlier box) gets the box's instance id and the box's class. Other points keep their
    semantic class with instance 0.

SemanticKITTI boxes file (one per scan, ``BOXES/sequences/XX/boxes/NNNNNN.txt``): one box per line,
``x y z l w h yaw class score``, LiDAR frame, metres and radians: ``(x, y, z)`` the box centre, ``l``
along the heading, ``w`` across it, ``h`` vertical, ``yaw`` the heading angle about +z from +x,
``class`` a SemanticKITTI train id (1..8) or class name (``car``), ``score`` the confidence.
Lines starting with ``#`` are comments (the simulated detector writes ``# simulated detector``).
Points on a face count as inside.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import numpy as np

from panoptic_bench.errors import InputError

__all__ = [
    "Boxes",
    "DetectorNoise",
    "MergeMode",
    "merge_boxes",
    "points_in_boxes",
    "read_boxes",
    "simulate_detections",
    "write_boxes",
]

OVERLAP_THRESHOLD = 0.5
SIMULATED_DETECTOR = "simulated detector"


class MergeMode(StrEnum):
    """Merge rule (see module docstring)."""

    DEVKIT = "devkit"
    PAPER = "paper"


@dataclass(frozen=True, eq=False)
class Boxes:
    """K boxes: ``params`` float64 (K, 7) = x y z l w h yaw; ``cls`` int64 (K,); ``score`` (K,)."""

    params: np.ndarray
    cls: np.ndarray
    score: np.ndarray

    def __len__(self) -> int:
        return len(self.cls)


def points_in_boxes(xyz: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Inside test (faces inclusive) of every point against every box.

    Parameters
    ----------
    xyz : array of shape (n, 3), float
    params : array of shape (k, 7), float: x y z l w h yaw

    Returns
    -------
    ndarray of shape (k, n), bool
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    out = np.zeros((len(params), len(xyz)), dtype=bool)
    for b, (x, y, z, ln, w, h, yaw) in enumerate(np.asarray(params, dtype=np.float64)):
        reach = np.hypot(ln, w) / 2
        near = np.flatnonzero((np.abs(xyz[:, 0] - x) <= reach) & (np.abs(xyz[:, 1] - y) <= reach))
        d = xyz[near] - (x, y, z)
        c, s = np.cos(yaw), np.sin(yaw)
        along = c * d[:, 0] + s * d[:, 1]
        across = -s * d[:, 0] + c * d[:, 1]
        inside = (np.abs(along) <= ln / 2) & (np.abs(across) <= w / 2) & (np.abs(d[:, 2]) <= h / 2)
        out[b, near[inside]] = True
    return out


def merge_boxes(
    xyz: np.ndarray, sem: np.ndarray, boxes: Boxes, mode: MergeMode, *, thing_ids: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """Merge a semantic prediction with boxes.

    Parameters
    ----------
    xyz : array of shape (n, 3), float
        Points in the boxes' frame.
    sem : array of shape (n,), integer
        Semantic prediction (train ids).
    boxes : Boxes
        Detections; classes in the same id space as ``sem``.
    mode : MergeMode
    thing_ids : tuple of int
        Things class ids.

    Returns
    -------
    sem : ndarray of shape (n,), same dtype as input
    inst : ndarray of shape (n,), uint32 (0 = no instance)
    """
    sem = np.asarray(sem)
    mode = MergeMode(mode)
    order = np.argsort(np.asarray(boxes.score))[::-1]
    inside = (
        points_in_boxes(xyz, boxes.params[order]) if len(order) else np.zeros((0, len(sem)), bool)
    )
    inst = np.zeros(len(sem), dtype=np.uint32)
    out_sem = sem.copy()
    taken = np.zeros(len(sem), dtype=bool)
    for rank, b in enumerate(order):
        cls = boxes.cls[b]
        if mode is MergeMode.DEVKIT:
            msk = inside[rank] & (sem == cls)
            inter = taken & msk
            if inter.sum() / (np.float32(msk.sum()) + 1e-32) > OVERLAP_THRESHOLD:
                continue
            msk &= ~inter
        else:
            msk = inside[rank] & ~taken
            out_sem[msk] = cls
        inst[msk] = rank + 1
        taken |= msk
    if mode is MergeMode.DEVKIT:
        orphan = np.isin(sem, thing_ids) & ~taken
        out_sem[orphan] = 0
    return out_sem, inst


def _class_id(token: str, path: Path, line: int) -> int:
    from panoptic_bench.datasets.semantickitti import LABELS

    if token.isascii() and token.isdigit():  # "²" is isdigit() but no number
        cid = int(token)
        if not 0 < cid < LABELS.num_classes:
            raise InputError(
                f"line {line}: class id {cid} is not a train id 1-{LABELS.num_classes - 1}", path
            )
        return cid
    try:
        return LABELS.class_names.index(token)
    except ValueError:
        raise InputError(
            f"line {line}: unknown class {token!r}; use a train id or one of {LABELS.class_names[1:9]}",
            path,
        ) from None


def read_boxes(path: str | Path) -> Boxes:
    """Read a SemanticKITTI boxes file (format in the module docstring); missing file = error."""
    path = Path(path)
    if not path.is_file():
        raise InputError("boxes file not found (one .txt per scan; may be empty)", path)
    params, cls, score = [], [], []
    for i, raw in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        text = raw.strip()
        if not text or text.startswith("#"):
            continue
        parts = text.split()
        if len(parts) != 9:
            raise InputError(
                f"line {i}: expected 'x y z l w h yaw class score', got {len(parts)} fields", path
            )
        try:
            values = [float(v) for v in parts[:7]] + [float(parts[8])]
        except ValueError:
            raise InputError(f"line {i}: non-numeric box value", path) from None
        if not np.isfinite(values).all() or min(values[3:6]) <= 0:
            raise InputError(f"line {i}: box values must be finite with positive l, w, h", path)
        params.append(values[:7])
        cls.append(_class_id(parts[7], path, i))
        score.append(values[7])
    return Boxes(
        np.array(params, float).reshape(-1, 7), np.array(cls, np.int64), np.array(score, float)
    )


def write_boxes(path: str | Path, boxes: Boxes, comment: str | None = None) -> None:
    """Atomically write a SemanticKITTI boxes file (``# comment`` first if given)."""
    from panoptic_bench.io import write_text

    lines = [f"# {comment}"] if comment else []
    lines += [
        " ".join(f"{v:.6f}" for v in p) + f" {int(c)} {s:.6f}"
        for p, c, s in zip(boxes.params, boxes.cls, boxes.score)
    ]
    write_text(path, "\n".join(lines) + "\n")


@dataclass(frozen=True)
class DetectorNoise:
    """Simulated detector: GT tight boxes with jitter, misses and false positives.

    ``position_sigma`` (m), ``size_sigma`` (relative), ``yaw_sigma`` (rad), ``miss_rate`` (probability
    a GT box is missed), ``fp_rate`` (false positives per GT box, Poisson mean).
    """

    position_sigma: float = 0.2
    size_sigma: float = 0.1
    yaw_sigma: float = 0.05
    miss_rate: float = 0.1
    fp_rate: float = 0.2


def simulate_detections(
    xyz: np.ndarray,
    sem: np.ndarray,
    instance: np.ndarray,
    thing_ids: tuple[int, ...],
    *,
    noise: DetectorNoise | None = None,
    seed: int = 0,
) -> Boxes:
    """A "simulated detector": boxes from the ground truth of one scan.

    GT box = axis-aligned tight box of each things instance (yaw 0), then jittered; missed with
    ``miss_rate``; plus Poisson(``fp_rate`` × #GT) false positives of random things classes placed
    at random GT-box-sized positions within the scan's extent. Scores: detections U(0.5, 1),
    false positives U(0, 0.6). Deterministic given ``seed``.
    """
    noise = DetectorNoise() if noise is None else noise
    rng = np.random.default_rng(seed)
    xyz = np.asarray(xyz, dtype=np.float64)[:, :3]
    sem = np.asarray(sem).astype(np.int64)
    instance = np.asarray(instance).astype(np.int64)
    sel = np.flatnonzero(np.isin(sem, thing_ids) & (instance > 0))
    params, cls = [], []
    for key in np.unique(sem[sel] * (1 << 32) + instance[sel]):
        pts = xyz[sel][(sem[sel] * (1 << 32) + instance[sel]) == key]
        lo, hi = pts.min(0), pts.max(0)
        params.append([*(lo + hi) / 2, *np.maximum(hi - lo, 0.05), 0.0])
        cls.append(int(key >> 32))
    params = np.array(params, float).reshape(-1, 7)
    cls = np.array(cls, np.int64)
    n = len(params)
    params[:, :3] += rng.normal(0, noise.position_sigma, (n, 3))
    params[:, 3:6] *= np.exp(rng.normal(0, noise.size_sigma, (n, 3)))
    params[:, 6] += rng.normal(0, noise.yaw_sigma, n)
    keep = rng.random(n) >= noise.miss_rate
    score = rng.uniform(0.5, 1.0, n)
    n_fp = rng.poisson(noise.fp_rate * n) if n else 0
    fp = np.zeros((n_fp, 7))
    if n_fp:
        lo, hi = xyz.min(0), xyz.max(0)
        fp[:, :3] = rng.uniform(lo, hi, (n_fp, 3))
        fp[:, 3:6] = params[rng.integers(0, n, n_fp), 3:6]
        fp[:, 6] = rng.uniform(-np.pi, np.pi, n_fp)
    return Boxes(
        np.concatenate([params[keep], fp]),
        np.concatenate([cls[keep], rng.choice(np.asarray(thing_ids), n_fp)]),
        np.concatenate([score[keep], rng.uniform(0, 0.6, n_fp)]),
    )


# --------------------------------------------------------------------------- SemanticKITTI drivers


def boxes_path(root: str | Path, sequence: str, frame: str) -> Path:
    """``root/sequences/<sequence>/boxes/<frame>.txt``."""
    return Path(root) / "sequences" / sequence / "boxes" / f"{frame}.txt"


def box_merge_semantickitti(
    dataset: str | Path,
    semantic: str | Path,
    boxes: str | Path,
    output: str | Path,
    mode: MergeMode,
    *,
    sequences: list | None = None,
) -> int:
    """Merge semantic predictions (``semantic/sequences/XX/predictions/*.label``, raw ids; only the
    semantic part is used) with boxes files into ``output/sequences/XX/predictions/*.label``.
    Returns the number of scans written."""
    from tqdm import tqdm

    from panoptic_bench.baselines.panoptic import semantickitti_label
    from panoptic_bench.datasets.semantickitti import (
        LABELS,
        list_scans,
        prediction_path,
        read_labels,
        read_scan,
        to_train,
        write_labels,
    )
    from panoptic_bench.evaluation.semantickitti import check_label_ids

    refs = list_scans(dataset, sequences=sequences)
    for ref in tqdm(refs, desc="box-merge", disable=None):
        points = read_scan(ref.scan)
        sem_path = prediction_path(semantic, ref)
        raw = read_labels(sem_path)
        check_label_ids(raw, len(points), sem_path, "semantic prediction")  # as eval does
        sem = to_train(raw)
        b = read_boxes(boxes_path(boxes, ref.sequence, ref.frame))
        s, i = merge_boxes(points[:, :3], sem, b, mode, thing_ids=LABELS.thing_ids)
        write_labels(prediction_path(output, ref), semantickitti_label(s, i))
    return len(refs)


def simulate_boxes_semantickitti(
    dataset: str | Path,
    output: str | Path,
    *,
    noise: DetectorNoise | None = None,
    seed: int = 0,
    sequences: list | None = None,
) -> int:
    """Write "simulated detector" boxes files from the ground truth of a labelled tree."""
    from panoptic_bench.datasets.semantickitti import (
        LABELS,
        list_scans,
        read_labels,
        read_scan,
        to_train,
    )

    refs = list_scans(dataset, sequences=sequences)
    for k, ref in enumerate(refs):
        points, labels = read_scan(ref.scan), read_labels(ref.label)
        b = simulate_detections(
            points, to_train(labels), labels >> 16, LABELS.thing_ids, noise=noise, seed=seed + k
        )
        write_boxes(boxes_path(output, ref.sequence, ref.frame), b, comment=SIMULATED_DETECTOR)
    return len(refs)
