"""Training steps: how each training stage turns the backbone output into a loss.

The training loop (:mod:`panoptic_bench.dsnet.training.train`) and the ablations call these;
the batch itself comes from :func:`panoptic_bench.dsnet.model.forward.backbone_forward`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import nn

from panoptic_bench.dsnet.config import DSNetConfig
from panoptic_bench.dsnet.data.datasets import ClassMap, LidarSample
from panoptic_bench.dsnet.model.forward import backbone_forward

if TYPE_CHECKING:
    from panoptic_bench.dsnet.training.train import TrainContext

__all__ = [
    "StageLoss",
    "class_weights_for",
    "ds_stage_loss",
    "stage_loss",
    "step_loss",
]


@dataclass
class StageLoss:
    """Total loss of one step and its named parts (Python floats, for logging)."""

    total: torch.Tensor
    parts: dict[str, float]


def class_weights_for(
    dataset_sem: list[np.ndarray], class_map: ClassMap, power: float
) -> list[float]:
    """CE class weights from the training labels (:func:`losses.class_weights`), as floats."""
    from panoptic_bench.dsnet.training import losses

    counts = losses.label_counts(dataset_sem, class_map.num_classes)
    ignore = class_map.ignore_ids[0] if class_map.ignore_ids else None
    return [float(w) for w in losses.class_weights(counts, power=power, ignore_index=ignore)]


def _cat(samples: list[LidarSample], name: str, device: torch.device) -> torch.Tensor:
    return torch.from_numpy(np.concatenate([getattr(s, name) for s in samples])).to(device)


def _batch_index(samples: list[LidarSample], device: torch.device) -> torch.Tensor:
    sizes = torch.tensor([len(s.xyz) for s in samples], device=device)
    return torch.repeat_interleave(torch.arange(len(samples), device=device), sizes)


def _thing_mask(sem: torch.Tensor, inst: torch.Tensor, class_map: ClassMap) -> torch.Tensor:
    lut = torch.from_numpy(class_map.thing_lut()).to(sem.device)
    return lut[sem] & (inst > 0)


def stage_loss(
    stage: str,
    out,
    samples: list[LidarSample],
    cfg: DSNetConfig,
    class_map: ClassMap,
    class_weights: torch.Tensor,
) -> StageLoss:
    """Backbone loss of the ``semantic`` or ``offset`` stage for a batch.

    ``semantic``: ``ce * weighted CE + lovasz * Lovász-softmax`` (the CE target mixed with the
    samples' teacher probabilities when ``loss.distill`` > 0; every sample must carry them);
    ``offset`` adds
    ``offset * L1`` on ground-truth thing points towards the tight-box centre of their instance.
    """
    from panoptic_bench.dsnet.training import losses

    device = out.sem_logits.device
    sem = _cat(samples, "sem", device)
    w = cfg.loss
    ignore = class_map.ignore_ids[0] if class_map.ignore_ids else -100
    soft = None
    if w.distill > 0:
        if any(s.soft is None for s in samples):
            raise ValueError(
                "loss.distill > 0 but a training sample carries no teacher probabilities"
            )
        soft = _cat(samples, "soft", device)
    total = losses.semantic_loss(
        out.sem_logits,
        sem,
        class_weights,
        ignore,
        ce_weight=w.ce,
        lovasz_weight=w.lovasz,
        soft=soft,
        distill=w.distill,
    )
    parts = {"semantic": float(total.detach())}
    if stage == "offset":
        xyz = _cat(samples, "xyz", device)
        inst = _cat(samples, "inst", device)
        centers = losses.instance_centers(xyz, inst, _batch_index(samples, device))
        off = losses.offset_loss(out.offsets, xyz, centers, _thing_mask(sem, inst, class_map))
        total = total + w.offset * off
        parts["offset"] = float(off.detach())
    else:
        total = total + 0.0 * out.offsets.sum()  # every parameter stays in the graph (DDP)
    parts["total"] = float(total.detach())
    return StageLoss(total, parts)


def ds_stage_loss(
    shift: nn.Module, out, samples: list[LidarSample], cfg: DSNetConfig, class_map: ClassMap
) -> torch.Tensor:
    """Dynamic-shifting loss (paper eq. 4–5), averaged over the scans of the batch.

    Seeds are the FPS sample of the regressed centres of the ground-truth thing points; their
    targets are the tight-box centres of their instances.
    """
    from panoptic_bench.dsnet.model.ds_head import shift_training_loss
    from panoptic_bench.dsnet.training import losses

    device = out.offsets.device
    total, start = out.offsets.new_zeros(()), 0
    for s in samples:
        sl = slice(start, start + len(s.xyz))
        start += len(s.xyz)
        xyz = torch.from_numpy(s.xyz).to(device)
        sem = torch.from_numpy(s.sem).to(device)
        inst = torch.from_numpy(s.inst).to(device)
        idx = torch.nonzero(_thing_mask(sem, inst, class_map)).squeeze(1)
        if len(idx) == 0:
            total = total + 0.0 * sum(p.sum() for p in shift.parameters())
            continue
        gt = losses.instance_centers(xyz[idx], inst[idx])
        total = total + shift_training_loss(
            shift,
            xyz[idx] + out.offsets[sl][idx],
            out.point_features[sl][idx],
            gt,
            max_seeds=cfg.dynamic_shift.max_seeds,
            iteration_weights=cfg.loss.ds_iteration_weights,
        )
    return total / max(len(samples), 1)


def step_loss(
    stage: str,
    model: dict[str, nn.Module | None],
    samples: list[LidarSample],
    ctx: TrainContext,
    weights: torch.Tensor,
    frozen: bool,
) -> torch.Tensor:
    """Loss of one training step of ``stage`` on ``samples`` (``frozen``: a ds stage whose
    backbone runs without gradients and adds no backbone loss)."""
    dev = ctx.info.device
    if stage != "ds":
        out = backbone_forward(model["backbone"], samples, ctx.grid, dev)
        return stage_loss(stage, out, samples, ctx.cfg, ctx.class_map, weights).total
    with torch.set_grad_enabled(not frozen):
        out = backbone_forward(model["backbone"], samples, ctx.grid, dev)
    loss = ds_stage_loss(model["shift"], out, samples, ctx.cfg, ctx.class_map)
    if not frozen:
        loss = loss + stage_loss("offset", out, samples, ctx.cfg, ctx.class_map, weights).total
    return loss
