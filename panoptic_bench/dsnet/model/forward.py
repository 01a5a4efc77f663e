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

    A backbone built with ``shape_features=True`` also gets the local shape features of
    :mod:`panoptic_bench.dsnet.data.shape`, computed in the frame it voxelizes.
    A backbone built with ``level_ground=True`` sees each scan levelled by
    :func:`panoptic_bench.dsnet.data.level.level_points` (training, validation and inference all
    come through here); its offsets are rotated back, so they are in each scan's own frame.
    The samples are not modified.

    Returns
    -------
    BackboneOutput
        ``sem_logits`` (P, C), ``offsets`` (P, 3), ``point_features`` (P, F) over the
        concatenated points of the samples, in sample order.
    """
    from panoptic_bench.dsnet.model.voxelize import collate

    net = getattr(model, "module", model)  # DistributedDataParallel keeps the flags on .module
    if not getattr(net, "level_ground", False):
        scans = [_columns(net, s.xyz, s.remission) for s in samples]
        return model(collate(scans, grid, device=device))
    from panoptic_bench.dsnet.data.level import level_points

    levelled = [level_points(s.xyz) for s in samples]
    scans = [_columns(net, xyz, s.remission) for (xyz, _), s in zip(levelled, samples)]
    out = model(collate(scans, grid, device=device))
    parts, start = [], 0
    for (_, rot), s in zip(levelled, samples):  # a levelled-frame vector v is v @ R in the scan
        stop = start + len(s.xyz)
        parts.append(out.offsets[start:stop] @ out.offsets.new_tensor(rot))
        start = stop
    out.offsets = torch.cat(parts)
    return out


def _columns(net: nn.Module, xyz: np.ndarray, remission: np.ndarray) -> np.ndarray:
    """``x, y, z, remission`` (n, 4), then the shape features (n, 4) if the network takes them."""
    cols = [xyz, remission[:, None]]
    if getattr(net, "shape_features", False):
        from panoptic_bench.dsnet.data.shape import shape_features

        cols.append(shape_features(xyz, max_points=net.shape_points))
    return np.concatenate(cols, axis=1).astype(np.float32, copy=False)
