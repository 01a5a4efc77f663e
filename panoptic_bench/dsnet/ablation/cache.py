"""Frozen-backbone cache for the dynamic-shifting ablations (issue 7; paper §4.1, appendix §3).

In stage ``ds`` the backbone is frozen (paper default), so everything dynamic shifting sees is
a fixed function of the scan. :func:`build_cache` runs the backbone once per scan and keeps

- for training scans (:class:`TrainScan`): the FPS seeds of the regressed centres of the
  ground-truth things points, their point features and the tight-box centre of their
  ground-truth instance — exactly the inputs of :func:`~panoptic_bench.dsnet.model.ds_head.
  shift_training_loss` (FPS is deterministic, so the seeds are the ones it would pick);
- for validation scans (:class:`EvalScan`): xyz, the semantic prediction, the offsets, the
  features of the predicted things points and the raw ground-truth labels (for the evaluator).

Training DS variants on the cache is therefore the stage-``ds`` optimisation without the
per-step backbone pass (no augmentation: the cached scans are the un-augmented ones).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from panoptic_bench.dsnet.checkpoint import Checkpoint
from panoptic_bench.dsnet.model.dynamic_shift import select_seeds

__all__ = ["EvalScan", "TrainScan", "build_cache", "scan_refs"]


@dataclass
class TrainScan:
    """Cached DS training input of one scan (M' seeds).

    Attributes
    ----------
    key : (sequence, frame)
    centers : (M', 3) float32, regressed centres of the seeds.
    features : (M', F) float32, their backbone point features.
    gt_centers : (M', 3) float32, tight-box centre of each seed's ground-truth instance.
    """

    key: tuple[str, ...]
    centers: np.ndarray
    features: np.ndarray
    gt_centers: np.ndarray


@dataclass
class EvalScan:
    """Cached backbone output of one validation scan (n points, k predicted things points).

    Attributes
    ----------
    key : (sequence, frame)
    xyz : (n, 3) float32
    sem : (n,) int64, semantic prediction (argmax over the non-ignored classes).
    offsets : (n, 3) float32, regressed offsets (centre = xyz + offset).
    things : (k,) int64, indices of the predicted things points.
    features : (k, F) float32, backbone features of the predicted things points.
    gt_label : (n,) uint32, raw SemanticKITTI ground-truth labels (sem | inst << 16).
    gt_sem, gt_inst : (n,) int64, train ids and scan-unique instance ids of the ground truth.
    """

    key: tuple[str, ...]
    xyz: np.ndarray
    sem: np.ndarray
    offsets: np.ndarray
    things: np.ndarray
    features: np.ndarray
    gt_label: np.ndarray
    gt_sem: np.ndarray
    gt_inst: np.ndarray

    @property
    def centers(self) -> np.ndarray:
        """(k, 3) float64 regressed centres of the predicted things points."""
        return self.xyz[self.things].astype(np.float64) + self.offsets[self.things]


def scan_refs(root: str | Path, sequences: Sequence[str], max_scans: int = 0) -> list:
    """Scans of ``sequences`` under ``root``; with ``max_scans`` an evenly spaced subset.

    Returns
    -------
    list of ScanRef
        Sorted by (sequence, frame); evenly strided over all sequences when limited.
    """
    from panoptic_bench.datasets.semantickitti import list_scans

    refs = list_scans(root, split=None, sequences=list(sequences))
    if 0 < max_scans < len(refs):
        pick = np.unique(np.linspace(0, len(refs) - 1, max_scans).round().astype(np.int64))
        refs = [refs[i] for i in pick]
    return refs


def _load(ref, things_lut: np.ndarray):
    from panoptic_bench.datasets import semantickitti as sk
    from panoptic_bench.dsnet.data.datasets import LidarSample, _unique_instances

    points = sk.read_scan(ref.scan)
    labels = sk.read_labels(ref.label)
    sem = sk.to_train(labels).astype(np.int64)
    inst = _unique_instances(sem, (labels >> 16).astype(np.int64), things_lut)
    sample = LidarSample(
        np.ascontiguousarray(points[:, :3]),
        np.ascontiguousarray(points[:, 3]),
        sem,
        inst,
        (ref.sequence, ref.frame),
    )
    return sample, labels


@torch.no_grad()
def build_cache(
    ckpt: Checkpoint,
    train_refs: Sequence,
    val_refs: Sequence,
    *,
    max_seeds: int | None = None,
    progress: bool = True,
) -> tuple[list[TrainScan], list[EvalScan]]:
    """Run the frozen backbone of ``ckpt`` once over every scan and cache what DS needs.

    Parameters
    ----------
    ckpt : Checkpoint
        Stage-2 (``offset``) or later checkpoint; only its backbone is used.
    train_refs, val_refs : sequence of ScanRef
        Labelled scans (see :func:`scan_refs`).
    max_seeds : int, optional
        FPS budget of the training seeds (default: the config's ``dynamic_shift.max_seeds``).

    Returns
    -------
    (list of TrainScan, list of EvalScan)
        Training scans without ground-truth things points are skipped.
    """
    from tqdm import tqdm

    from panoptic_bench.dsnet.checkpoint import build_backbone, build_grid
    from panoptic_bench.dsnet.model.forward import backbone_forward
    from panoptic_bench.dsnet.training import losses

    cfg, cmap = ckpt.config, ckpt.class_map
    backbone = build_backbone(cfg, cmap.num_classes)
    backbone.load_state_dict(ckpt.backbone)
    backbone.eval()
    grid, dev = build_grid(cfg), torch.device("cpu")
    lut = cmap.thing_lut()
    budget = cfg.dynamic_shift.max_seeds if max_seeds is None else max_seeds
    train, val = [], []
    jobs = [(r, True) for r in train_refs] + [(r, False) for r in val_refs]
    for ref, is_train in tqdm(jobs, desc="backbone cache", unit="scan", disable=not progress):
        sample, labels = _load(ref, lut)
        out = backbone_forward(backbone, [sample], grid, dev)
        offsets = out.offsets.float().numpy()
        feats = out.point_features.float()
        if is_train:
            idx = np.flatnonzero(lut[sample.sem] & (sample.inst > 0))
            if len(idx) == 0:
                continue
            xyz = torch.from_numpy(sample.xyz[idx])
            gt = losses.instance_centers(xyz, torch.from_numpy(sample.inst[idx])).numpy()
            centers = sample.xyz[idx] + offsets[idx]
            seeds = select_seeds(centers, budget)
            train.append(
                TrainScan(
                    sample.key,
                    np.ascontiguousarray(centers[seeds], dtype=np.float32),
                    feats[torch.from_numpy(idx[seeds])].numpy(),
                    np.ascontiguousarray(gt[seeds], dtype=np.float32),
                )
            )
            continue
        logits = out.sem_logits.clone()
        logits[:, list(cmap.ignore_ids)] = -torch.inf
        sem = logits.argmax(1).numpy().astype(np.int64)
        things = np.flatnonzero(lut[sem])
        val.append(
            EvalScan(
                sample.key,
                sample.xyz,
                sem,
                offsets,
                things,
                feats[torch.from_numpy(things)].numpy(),
                labels,
                sample.sem,
                sample.inst,
            )
        )
    return train, val
