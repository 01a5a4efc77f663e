"""Ensembles of checkpoints (``infer --ensemble``): one prediction from several networks.

Every member's backbone runs on the scan (on its own grid, and on the test-time augmentation
views of :mod:`panoptic_bench.dsnet.inference.tta` when those are asked for); the class
probabilities (softmax of the logits) and the regressed offsets are averaged with equal
weight. The point features (the dynamic-shifting input) and the dynamic-shifting module are the
first member's (the ``--checkpoint``), and so are the density policy and the inference settings.
An ensemble of one is exactly that member's pass.

Unlike a weight average (``checkpoint average``, :mod:`panoptic_bench.dsnet.soup`), which gives
one network, an ensemble runs every member (cost: one backbone pass per member and view) and its
members may differ in width or grid, as long as they predict the same classes.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import torch
from torch import nn

from panoptic_bench.dsnet.checkpoint import Checkpoint
from panoptic_bench.dsnet.inference.tta import tta_forward
from panoptic_bench.dsnet.model.voxelize import CylinderGrid
from panoptic_bench.errors import InputError

__all__ = ["check_member", "ensemble_forward"]


def ensemble_forward(
    members: Sequence[tuple[nn.Module, CylinderGrid]],
    sample,
    device: torch.device,
    n_views: int = 1,
):
    """Backbone outputs of ``sample`` averaged over ``members`` (see the module doc).

    Parameters
    ----------
    members : sequence of (nn.Module, CylinderGrid)
        Backbones in eval mode with the grid each was trained on; the first is the primary.
    sample : LidarSample
    device : torch.device
    n_views : int
        Test-time augmentation views per member (1 = the plain pass).

    Returns
    -------
    BackboneOutput
        ``sem_logits`` (n, C) = log of the mean class probabilities; ``offsets`` (n, 3) the mean
        offset; ``point_features`` and ``voxel_logits`` of the first member.
    """
    if not members:
        raise ValueError("an ensemble needs at least one member")
    outs = [tta_forward(model, sample, grid, device, n_views) for model, grid in members]
    first = outs[0]
    if len(outs) == 1:
        return first
    probs = sum(torch.softmax(o.sem_logits.float(), dim=1) for o in outs)
    offsets = sum(o.offsets.float() for o in outs)
    n = len(outs)
    return dataclasses.replace(first, sem_logits=torch.log(probs / n), offsets=offsets / n)


def check_member(primary: Checkpoint, member: Checkpoint, member_path: str | Path) -> None:
    """Raise one clear error when ``member`` cannot join ``primary``'s ensemble.

    Members must predict the same classes (same class map) and have a trained offset head
    (not a stage-1 ``semantic`` checkpoint).

    Raises
    ------
    InputError
        Naming the member file and what differs.
    """
    a, b = primary.class_map, member.class_map
    if b.to_dict() != a.to_dict():
        raise InputError(
            f"ensemble member predicts other classes ({b.dataset}, {b.num_classes} train ids) "
            f"than {primary.path} ({a.dataset}, {a.num_classes} train ids)",
            member_path,
        )
    if member.stage == "semantic":
        raise InputError(
            "ensemble member is a stage-1 (semantic) checkpoint: its offset head is not "
            "trained; use an offset or ds checkpoint",
            member_path,
        )
