"""Re-estimate a network's held BatchNorm statistics on a dataset, weights unchanged.

A checkpoint's BatchNorms normalise, in eval mode, with the running averages collected while it
was trained (and fine-tunes with ``optim.freeze_bn`` keep their start's averages). To ask whether
a network's statistics or its features carry a result, :func:`recalibrate_batchnorm` replaces the
averages by those of another dataset (e.g. another synthetic world) without training: every
BatchNorm's running mean and variance are reset and recomputed as the plain average over the
given scans of each scan's batch mean and (unbiased) batch variance (PyTorch's ``momentum=None``
cumulative average; "precise BN", Wu & Johnson 2021; AdaBN, Li et al. 2016). Every other tensor,
convolution and affine BatchNorm weights included, stays bit-identical.

Scans are seen as inference sees them: thinned to ``augment.max_points`` by the inference
subset (:func:`panoptic_bench.dsnet.data.density.thin`, seeded by the scan) when the config sets
``inference.match_training_density``, otherwise whole. A BatchNorm call with a single row (a
scan so small that one level of the U-Net holds one site) has no batch variance: that call
normalises with the averages so far and adds nothing to them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

import numpy as np
import torch
from torch import nn
from torch.nn.modules.batchnorm import _BatchNorm

from panoptic_bench.dsnet.checkpoint import Checkpoint, build_backbone, build_grid
from panoptic_bench.dsnet.data.datasets import LidarSample
from panoptic_bench.dsnet.data.density import density_seed, thin
from panoptic_bench.dsnet.model.forward import backbone_forward
from panoptic_bench.errors import InputError

__all__ = ["inference_view", "recalibrate_batchnorm", "recalibrate_checkpoint"]


def recalibrate_batchnorm(
    backbone: nn.Module,
    samples: Iterable[LidarSample],
    grid,
    device: torch.device | str = "cpu",
) -> int:
    """Replace every BatchNorm's running statistics of ``backbone`` by their average over
    ``samples`` (one forward pass each, no gradients); returns how many scans were seen.

    Parameters
    ----------
    backbone : nn.Module
        Changed in place: only the BatchNorms' ``running_mean``, ``running_var`` and
        ``num_batches_tracked``. Left in eval mode, BatchNorm momenta restored.
    samples : iterable of LidarSample
        A batch of one scan each, already in the view the network should see.
    grid : CylinderGrid
        The checkpoint's voxel grid.

    Raises
    ------
    InputError
        No sample, or a BatchNorm that never received two rows (nothing to average).
    """
    norms = {
        name: m
        for name, m in backbone.named_modules()
        if isinstance(m, _BatchNorm) and m.track_running_stats
    }
    momenta = {name: m.momentum for name, m in norms.items()}
    backbone.eval()
    for m in norms.values():
        m.reset_running_stats()
        m.momentum = None  # cumulative average over the calls
        m.train()
    handles = [m.register_forward_pre_hook(_rows_guard) for m in norms.values()]
    seen = 0
    try:
        with torch.no_grad():
            for sample in samples:
                backbone_forward(backbone, [sample], grid, torch.device(device))
                seen += 1
    finally:
        for h in handles:
            h.remove()
        for name, m in norms.items():
            m.momentum = momenta[name]
        backbone.eval()
    if seen == 0:
        raise InputError("no scans to re-estimate the BatchNorm statistics on")
    empty = [name for name, m in norms.items() if int(m.num_batches_tracked) == 0]
    if empty:
        raise InputError(
            f"BatchNorm {empty[0]} (and {len(empty) - 1} more) saw no scan with two or more "
            "rows; re-estimate on larger scans"
        )
    return seen


def _rows_guard(norm: _BatchNorm, args: tuple) -> None:
    """Pre-hook: a single-row call runs in eval mode (no batch statistics, nothing recorded)."""
    norm.train(args[0].shape[0] >= 2)


def inference_view(ck: Checkpoint, sample: LidarSample) -> LidarSample:
    """``sample`` as ``infer`` feeds it to ``ck``'s network: thinned to ``augment.max_points``
    (the inference subset, seeded by the scan key) under ``inference.match_training_density``,
    else unchanged."""
    cfg = ck.config
    if cfg.inference.match_training_density and cfg.augment.max_points > 0:
        rng = np.random.default_rng(density_seed(sample.key))
        return thin(sample, cfg.augment.max_points, rng)[0]
    return sample


def recalibrate_checkpoint(
    ck: Checkpoint, samples: Iterable[LidarSample], note: str = "", device: str = "cpu"
) -> tuple[Checkpoint, int]:
    """A copy of ``ck`` whose backbone BatchNorm statistics are re-estimated on ``samples``
    (each seen through :func:`inference_view`); ``ck`` itself is not changed.

    Returns
    -------
    (Checkpoint, int)
        The new checkpoint (no optimizer, RNG or weight-average state; one ``metrics`` row
        recording the re-estimation and ``note``) and the number of scans seen.
    """
    net = build_backbone(ck.config, ck.class_map.num_classes)
    net.load_state_dict(ck.backbone)
    views = (inference_view(ck, s) for s in samples)
    seen = recalibrate_batchnorm(net, views, build_grid(ck.config), device)
    state = {k: v.detach().clone() for k, v in net.state_dict().items()}
    row = {"bn_recalibrated_on": note, "scans": seen}
    out = dataclasses.replace(
        ck,
        backbone=state,
        shift=None if ck.shift is None else dict(ck.shift),
        optimizer=None,
        rng=None,
        average=None,
        metrics=[*ck.metrics, row],
        path=None,
    )
    return out, seen
