"""Glue between the data, the backbone, the losses and the dynamic shifting module.

One place that knows how a list of :class:`~panoptic_bench.dsnet.data.LidarSample` becomes the
backbone's batch, and how each training stage turns the backbone output into a loss. The
training loop (:mod:`.train`) and inference (:mod:`.infer`) only call these functions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from panoptic_bench.dsnet.config import DSNetConfig
from panoptic_bench.dsnet.data import ClassMap, LidarSample

__all__ = [
    "StageLoss",
    "backbone_forward",
    "class_weights_from_counts",
    "count_classes",
    "ds_seed_inputs",
    "stage_loss",
]


@dataclass
class StageLoss:
    """Total loss of one step and its named parts (Python floats, for logging)."""

    total: torch.Tensor
    parts: dict[str, float]


def backbone_forward(model: nn.Module, samples: list[LidarSample], grid, device: torch.device):
    """Voxelize ``samples`` on ``grid`` (a ``CylinderGrid``) into one batch and run the backbone.

    Returns
    -------
    BackboneOutput
        ``sem_logits`` (P, C), ``offsets`` (P, 3), ``point_features`` (P, F) over the
        concatenated points of the samples, in sample order.
    """
    from panoptic_bench.dsnet.voxelize import collate

    scans = [np.concatenate([s.xyz, s.remission[:, None]], axis=1) for s in samples]
    return model(collate(scans, grid, device=device))


def count_classes(samples_sem: list[np.ndarray], num_classes: int) -> np.ndarray:
    """Point count per train id over label arrays: int64 array of shape (num_classes,)."""
    counts = np.zeros(num_classes, dtype=np.int64)
    for sem in samples_sem:
        counts += np.bincount(sem, minlength=num_classes)[:num_classes]
    return counts


def class_weights_from_counts(
    counts: np.ndarray, ignore: tuple[int, ...], power: float
) -> list[float]:
    """CE class weights ``1 / frequency ** power``, mean 1 over non-ignored classes present.

    Ignored classes get 0; classes absent from the training set get the largest weight.
    """
    counts = np.asarray(counts, dtype=np.float64)
    freq = counts / max(counts.sum(), 1.0)
    w = np.zeros_like(freq)
    present = freq > 0
    w[present] = 1.0 / freq[present] ** power
    keep = np.ones(len(w), dtype=bool)
    keep[list(ignore)] = False
    if (present & keep).any():
        w[keep & ~present] = w[present & keep].max()
        w[keep] /= w[keep].mean()
    w[~keep] = 0.0
    return [float(x) for x in w]


def _cat(samples: list[LidarSample], name: str, device: torch.device) -> torch.Tensor:
    return torch.from_numpy(np.concatenate([getattr(s, name) for s in samples])).to(device)


def stage_loss(
    stage: str,
    out,
    samples: list[LidarSample],
    cfg: DSNetConfig,
    class_map: ClassMap,
    class_weights: torch.Tensor,
) -> StageLoss:
    """Backbone loss of the ``semantic`` or ``offset`` stage for a batch.

    ``semantic``: ``ce * CE + lovasz * Lovász``; ``offset`` adds ``offset * L1`` on thing points
    towards the tight-box centre of their instance.
    """
    from panoptic_bench.dsnet import losses

    device = out.sem_logits.device
    sem = _cat(samples, "sem", device)
    w = cfg.loss
    ce = losses.weighted_cross_entropy(
        out.sem_logits, sem, class_weights, ignore_index=class_map.ignore_ids[0]
    )
    lov = losses.lovasz_softmax(out.sem_logits, sem, ignore_index=class_map.ignore_ids[0])
    total = w.ce * ce + w.lovasz * lov
    parts = {"ce": float(ce.detach()), "lovasz": float(lov.detach())}
    if stage == "offset":
        xyz = _cat(samples, "xyz", device)
        inst = _cat(samples, "inst", device) + _batch_offsets(samples, device)
        off = losses.offset_loss(out.offsets, xyz, inst)
        total = total + w.offset * off
        parts["offset"] = float(off.detach())
    elif w.offset > 0:
        total = total + 0.0 * out.offsets.sum()  # keep every parameter in the graph (DDP)
    parts["total"] = float(total.detach())
    return StageLoss(total, parts)


def _batch_offsets(samples: list[LidarSample], device: torch.device) -> torch.Tensor:
    """Shift instance ids of each sample so that ids of different samples never collide."""
    shifts, base = [], 0
    for s in samples:
        shifts.append(np.where(s.inst > 0, base, 0))
        base += int(s.inst.max(initial=0))
    return torch.from_numpy(np.concatenate(shifts)).to(device)


def ds_seed_inputs(
    out, samples: list[LidarSample], class_map: ClassMap, use_gt_things: bool
) -> list[dict[str, torch.Tensor]]:
    """Per sample: thing points, their regressed centres, features and instance ids.

    Parameters
    ----------
    use_gt_things : bool
        Select thing points from the ground truth (training) or the prediction (inference).

    Returns
    -------
    list of dict
        ``index`` (M,) int64 point indices in the sample, ``points`` (M, 3), ``centers`` (M, 3),
        ``features`` (M, F), ``inst`` (M,) int64.
    """
    things = torch.zeros(class_map.num_classes, dtype=torch.bool, device=out.offsets.device)
    things[list(class_map.thing_ids)] = True
    res, start = [], 0
    pred = out.sem_logits.argmax(1)
    for s in samples:
        n = len(s.xyz)
        sl = slice(start, start + n)
        start += n
        xyz = torch.from_numpy(s.xyz).to(out.offsets.device)
        if use_gt_things:
            sem = torch.from_numpy(s.sem).to(out.offsets.device)
            mask = things[sem] & (torch.from_numpy(s.inst).to(sem.device) > 0)
        else:
            mask = things[pred[sl]]
        idx = torch.nonzero(mask).squeeze(1)
        res.append(
            {
                "index": idx,
                "points": xyz[idx],
                "centers": xyz[idx] + out.offsets[sl][idx],
                "features": out.point_features[sl][idx],
                "inst": torch.from_numpy(s.inst).to(idx.device)[idx],
            }
        )
    return res
