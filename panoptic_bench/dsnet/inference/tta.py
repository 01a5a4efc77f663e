"""Test-time augmentation (``inference.tta_views``): the backbone on several views of one scan.

View ``k`` of ``K`` rotates the scan about the sensor's vertical axis by
``k * 360 / K`` degrees plus ``k / K`` of one azimuth cell of the grid, and mirrors it
(``y -> -y``) when ``k`` is odd. The rotations spread the views over the circle, the sub-cell
part makes every view cut the scan into different voxels, and view 0 is the scan itself.
The views' class probabilities (softmax of the logits) are averaged, the regressed offsets are
turned back into the scan's frame and averaged; the point features (the dynamic-shifting
input) are those of view 0. ``K = 1`` is exactly the plain forward pass.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch

from panoptic_bench.dsnet.model.forward import backbone_forward

__all__ = ["tta_forward", "view_matrices"]


def view_matrices(n_views: int, phi_cell_rad: float) -> list[np.ndarray]:
    """The linear maps of the ``n_views`` views (``xyz_view = xyz @ A.T``).

    Returns
    -------
    list of ndarray of shape (3, 3), float64
        Orthogonal matrices; the first is the identity.
    """
    if n_views < 1:
        raise ValueError(f"n_views must be >= 1, got {n_views}")
    out = []
    for k in range(n_views):
        angle = 2 * math.pi * k / n_views + phi_cell_rad * k / n_views
        c, s = math.cos(angle), math.sin(angle)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        mirror = np.diag([1.0, -1.0 if k % 2 else 1.0, 1.0])
        out.append(rot @ mirror)
    return out


def tta_forward(model, sample, grid, device: torch.device, n_views: int):
    """Backbone outputs of ``sample`` averaged over ``n_views`` views (see the module doc).

    Parameters
    ----------
    model : PanopticBackbone
    sample : LidarSample
    grid : CylinderGrid
    device : torch.device
    n_views : int

    Returns
    -------
    BackboneOutput
        ``sem_logits`` (n, C) = log of the mean class probabilities; ``offsets`` (n, 3) in the
        scan's frame; ``point_features`` and ``voxel_logits`` of view 0.
    """
    first = backbone_forward(model, [sample], grid, device)
    if n_views == 1:
        return first
    phi_cell = math.radians(grid.phi_range_deg[1] - grid.phi_range_deg[0]) / grid.size[1]
    probs = torch.softmax(first.sem_logits.float(), dim=1)
    offsets = first.offsets.float().clone()
    for a in view_matrices(n_views, phi_cell)[1:]:
        view = dataclasses.replace(sample, xyz=(sample.xyz @ a.T).astype(np.float32))
        out = backbone_forward(model, [view], grid, device)
        probs += torch.softmax(out.sem_logits.float(), dim=1)
        back = torch.as_tensor(a, dtype=torch.float32, device=out.offsets.device)
        offsets += out.offsets.float() @ back  # o = A^T o_view: row vectors times A
    return dataclasses.replace(
        first, sem_logits=torch.log(probs / n_views), offsets=offsets / n_views
    )
