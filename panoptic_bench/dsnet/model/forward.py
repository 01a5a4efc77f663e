"""One forward pass of the backbone on a list of scans (shared by training and inference)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import nn

if TYPE_CHECKING:
    from panoptic_bench.dsnet.data.datasets import LidarSample

__all__ = ["backbone_forward"]


def backbone_forward(model: nn.Module, samples: list[LidarSample], grid, device: torch.device):
    """Voxelize ``samples`` on ``grid`` (a ``CylinderGrid``) into one batch and run the backbone.

    Returns
    -------
    BackboneOutput
        ``sem_logits`` (P, C), ``offsets`` (P, 3), ``point_features`` (P, F) over the
        concatenated points of the samples, in sample order.
    """
    from panoptic_bench.dsnet.model.voxelize import collate

    scans = [np.concatenate([s.xyz, s.remission[:, None]], axis=1) for s in samples]
    return model(collate(scans, grid, device=device))
