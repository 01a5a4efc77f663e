"""The DS-Net strong backbone: point encoder + cylinder U-Net + semantic and offset heads.

Example
-------
>>> import torch
>>> from panoptic_bench.dsnet.model.network import PanopticBackbone
>>> from panoptic_bench.dsnet.model.voxelize import CylinderGrid, collate
>>> grid = CylinderGrid(size=(32, 32, 8))
>>> model = PanopticBackbone(num_classes=5, init_size=4, grid=grid, point_hidden=(16,),
...                          point_feature_dim=16, voxel_feature_dim=8, offset_hidden=8)
>>> batch = collate([torch.rand(200, 4) * 20], grid)
>>> out = model(batch)
>>> out.sem_logits.shape, out.offsets.shape
(torch.Size([200, 5]), torch.Size([200, 3]))
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch
from torch import nn

from panoptic_bench.dsnet.data.shape import N_SHAPE_FEATURES
from panoptic_bench.dsnet.model.backbone import AsymmetricUNet
from panoptic_bench.dsnet.model.heads import InstanceHead, SemanticHead
from panoptic_bench.dsnet.model.renorm import NORMS, renormalise_batchnorms
from panoptic_bench.dsnet.model.voxelize import (
    N_POINT_FEATURES,
    CylinderGrid,
    PointVoxelEncoder,
    VoxelBatch,
)
from panoptic_bench.dsnet.sparse import fused
from panoptic_bench.dsnet.sparse.gemm import FAST_KEY


@dataclass
class BackboneOutput:
    """Network outputs for a :class:`VoxelBatch` (points in batch order).

    Attributes
    ----------
    sem_logits : torch.Tensor
        Array of shape (n_points, num_classes), float: each point's voxel logits.
    offsets : torch.Tensor
        Array of shape (n_points, 3), float: predicted ``centre - xyz`` (metres, Cartesian).
    point_features : torch.Tensor
        Array of shape (n_points, init_size), float: instance-head features of each point.
    voxel_logits : torch.Tensor
        Array of shape (n_voxels, num_classes), float.
    """

    sem_logits: torch.Tensor
    offsets: torch.Tensor
    point_features: torch.Tensor
    voxel_logits: torch.Tensor


@dataclass
class BackbonePrediction:
    """Hard predictions: labels, regressed centres (``xyz + offsets``), per-point scan index."""

    sem_labels: torch.Tensor
    centers: torch.Tensor
    point_batch: torch.Tensor


class PanopticBackbone(nn.Module):
    """DS-Net "strong backbone" (paper §3.1), assembled from explicit arguments.

    Parameters
    ----------
    num_classes : int
        Semantic logits per point (including an ignored class 0 if the label map has one).
    init_size : int
        U-Net base width (paper 32; a CPU configuration uses 8-16).
    grid : CylinderGrid
        The voxel grid (only its size is used by the network; voxelization is in ``collate``).
    point_hidden : tuple of ints
        Hidden widths of the per-point MLP (DS-Net: 64, 128, 256).
    point_feature_dim : int
        Per-point width before max-pooling into voxels (DS-Net: 64).
    voxel_feature_dim : int
        Voxel feature width after compression (16).
    offset_hidden : int or None
        Hidden width of the offset MLP (DS-Net: ``init_size``; None means that).
    spconv1_rulebooks : bool
        U-Net convs act with the effective kernels of the official spconv 1.x network
        (:mod:`panoptic_bench.dsnet.model.backbone`).
    offset_norm_first : bool
        Offset-head convs in the official order conv -> BatchNorm -> LeakyReLU.
    fast_inference : bool
        Without gradients, the sparse convs take the im2col GEMM path of
        :mod:`panoptic_bench.dsnet.sparse.gemm` (same outputs up to float round-off; training
        and calls with gradients are unchanged). True for the official network only, so the
        nominal network's pinned outputs stay bit for bit.
    remission_input : bool
        False: the remission channel (last of the 9 point features) is replaced by zeros before
        the point MLP, so predictions do not depend on remission (the batch is not modified).
    level_ground : bool
        True: :func:`panoptic_bench.dsnet.model.forward.backbone_forward` levels every scan
        (:mod:`panoptic_bench.dsnet.data.level`) before voxelizing it and rotates the offsets
        back. The flag changes no weight; it is read by that function, not by ``forward``.
    shape_features : bool
        True: the point MLP takes 4 more inputs, the local shape features of
        :mod:`panoptic_bench.dsnet.data.shape`, which
        :func:`~panoptic_bench.dsnet.model.forward.backbone_forward` computes and appends.
    shape_points : int
        ``max_points`` of those features (the training scans' point count; 0: every point).
    norm : {"batch", "renorm"}
        ``renorm``: every BatchNorm trains with Batch Renormalization
        (:mod:`panoptic_bench.dsnet.model.renorm`); the same parameters and buffers, the same
        eval-mode outputs.

    Both flags are False for the nominal network and True for the official one
    (``model.variant`` of the config, see :func:`panoptic_bench.dsnet.checkpoint.build_backbone`).
    """

    def __init__(
        self,
        num_classes: int,
        init_size: int = 32,
        grid: CylinderGrid | None = None,
        point_hidden: tuple[int, ...] = (64, 128, 256),
        point_feature_dim: int = 64,
        voxel_feature_dim: int = 16,
        offset_hidden: int | None = None,
        spconv1_rulebooks: bool = False,
        offset_norm_first: bool = False,
        fast_inference: bool = False,
        remission_input: bool = True,
        level_ground: bool = False,
        shape_features: bool = False,
        shape_points: int = 0,
        norm: str = "batch",
    ) -> None:
        super().__init__()
        if norm not in NORMS:
            raise ValueError(f"norm must be one of {', '.join(NORMS)}, got {norm!r}")
        self.norm = norm
        self.shape_features = bool(shape_features)
        self.shape_points = int(shape_points)
        self.fast_inference = bool(fast_inference)
        self.remission_input = bool(remission_input)
        self.level_ground = bool(level_ground)
        self.grid = CylinderGrid() if grid is None else grid
        self.num_classes = num_classes
        n_in = N_POINT_FEATURES + (N_SHAPE_FEATURES if self.shape_features else 0)
        self.encoder = PointVoxelEncoder(
            n_in, tuple(point_hidden), point_feature_dim, voxel_feature_dim
        )
        self.unet = AsymmetricUNet(voxel_feature_dim, init_size, spconv1_rulebooks)
        self.semantic_head = SemanticHead(self.unet.out_channels, num_classes)
        self.instance_head = InstanceHead(
            self.unet.out_channels,
            init_size,
            init_size if offset_hidden is None else offset_hidden,
            norm_before_act=offset_norm_first,
        )
        if norm == "renorm":
            renormalise_batchnorms(self)

    def extra_repr(self) -> str:
        extra = "" if self.remission_input else ", remission_input=False"
        extra += ", level_ground=True" if self.level_ground else ""
        extra += ", shape_features=True" if self.shape_features else ""
        extra += f", norm={self.norm}" if self.norm != "batch" else ""
        return f"num_classes={self.num_classes}, grid_size={self.grid.size}{extra}"

    def forward(self, batch: VoxelBatch) -> BackboneOutput:
        """Run on a batch from :func:`panoptic_bench.dsnet.model.voxelize.collate` (same device)."""
        if tuple(batch.spatial_shape) != tuple(self.grid.size):
            raise ValueError(
                f"batch voxelized on a {batch.spatial_shape} grid, model built for "
                f"{self.grid.size}; collate with the model's grid"
            )
        if not self.remission_input:
            feats = batch.point_features.clone()
            feats[:, N_POINT_FEATURES - 1] = 0.0  # remission (shape features follow it)
            batch = dataclasses.replace(batch, point_features=feats)
        fold = self.fast_inference and fused.inference_enabled(self.encoder)
        x = self.encoder(batch, fold_norms=fold)
        if self.fast_inference:
            x.cache[FAST_KEY] = True
        voxels = self.unet(x)
        logits, first = self.semantic_head.logits, self.instance_head.convs[0]
        heads = (self.semantic_head, self.instance_head)
        if fused.inference_path(voxels, *heads) and fused.can_merge([logits, first.conv]):
            # both heads' first convs read the U-Net output through the same map: one conv
            h = fused.merged_conv(voxels, [logits, first.conv])
            voxel_logits = h.features[:, : self.num_classes].contiguous()
            sem_logits = voxel_logits.index_select(0, batch.point_voxel)
            rest = h.replace_features(h.features[:, self.num_classes :])
            offsets, point_features = self.instance_head.from_first_conv(
                rest, batch.point_voxel, batch.xyz
            )
            return BackboneOutput(sem_logits, offsets, point_features, voxel_logits)
        voxel_logits, sem_logits = self.semantic_head(voxels, batch.point_voxel)
        offsets, point_features = self.instance_head(voxels, batch.point_voxel, batch.xyz)
        return BackboneOutput(sem_logits, offsets, point_features, voxel_logits)

    @torch.no_grad()
    def predict(self, batch: VoxelBatch, ignore_index: int | None = 0) -> BackbonePrediction:
        """Labels and regressed centres without gradients (call ``eval()`` first).

        ``ignore_index`` (the unlabelled class) is never predicted; None allows every class.
        """
        out = self.forward(batch)
        logits = out.sem_logits
        if ignore_index is not None:
            logits = logits.clone()
            logits[:, ignore_index] = float("-inf")
        return BackbonePrediction(logits.argmax(1), batch.xyz + out.offsets, batch.point_batch)
