"""Semantic and instance (centre-offset) heads of the DS-Net backbone (paper §3.1)."""

from __future__ import annotations

import torch
from torch import nn

from panoptic_bench.dsnet.model.backbone import ConvActNorm, ConvNormAct
from panoptic_bench.dsnet.sparse import SparseTensor, SubMConv3d, fused


class SemanticHead(nn.Module):
    """3x3x3 submanifold conv with bias to per-voxel logits; points copy their voxel's logits.

    Parameters
    ----------
    in_channels : int
        Backbone output width (``4 * init_size``).
    num_classes : int
        Number of logits (including the ignored class 0 when the dataset has one).
    """

    def __init__(self, in_channels: int, num_classes: int) -> None:
        super().__init__()
        self.logits = SubMConv3d(in_channels, num_classes, 3, bias=True)

    def forward(
        self, x: SparseTensor, point_voxel: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Return ``(voxel_logits (n_voxels, C), point_logits (n_points, C))``."""
        voxel_logits = self.logits(x).features
        return voxel_logits, voxel_logits.index_select(0, point_voxel)


class InstanceHead(nn.Module):
    """Per-point offsets to the instance centre.

    Three 3x3x3 submanifold conv layers (``4w -> 4w -> 2w -> w``, each LeakyReLU +
    BatchNorm) give per-voxel features; each point takes its voxel's features, concatenated with
    its Cartesian ``(x, y, z)``, through ``Linear(w + 3, hidden) -> BN -> ReLU -> Linear(3)``.

    Parameters
    ----------
    in_channels : int
        Backbone output width (``4 * init_size``).
    feature_dim : int
        Width ``w`` of the per-point features (``init_size`` in DS-Net).
    hidden : int
        Hidden width of the point MLP.
    norm_before_act : bool
        Conv -> BatchNorm -> LeakyReLU, the order of the official DS-Net code; False (the
        nominal network): conv -> LeakyReLU -> BatchNorm.
    """

    def __init__(
        self, in_channels: int, feature_dim: int, hidden: int, norm_before_act: bool = False
    ) -> None:
        super().__init__()
        layer = ConvNormAct if norm_before_act else ConvActNorm
        self.convs = nn.Sequential(
            layer(in_channels, in_channels, (3, 3, 3)),
            layer(in_channels, 2 * feature_dim, (3, 3, 3)),
            layer(2 * feature_dim, feature_dim, (3, 3, 3)),
        )
        self.mlp = nn.Sequential(
            nn.Linear(feature_dim + 3, hidden),
            nn.BatchNorm1d(hidden),
            nn.ReLU(),
            nn.Linear(hidden, 3),
        )
        self.out_channels = feature_dim

    def forward(
        self, x: SparseTensor, point_voxel: torch.Tensor, xyz: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Return ``(offsets (n_points, 3), point_features (n_points, feature_dim))``."""
        return self.from_voxels(self.convs(x).features, point_voxel, xyz)

    def from_first_conv(
        self, first: SparseTensor, point_voxel: torch.Tensor, xyz: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`forward` given the raw output of ``convs[0].conv`` (inference path).

        ``first`` holds the first conv's output features (n_voxels, in_channels), overwritten:
        its BatchNorm and activation run in place.
        """
        layer = self.convs[0]
        h = first.replace_features(layer.post(first.features, in_place=True))
        for layer in self.convs[1:]:
            h = layer(h)
        return self.from_voxels(h.features, point_voxel, xyz, fold_norms=True)

    def from_voxels(
        self,
        voxel_features: torch.Tensor,
        point_voxel: torch.Tensor,
        xyz: torch.Tensor,
        fold_norms: bool = False,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Point MLP on each point's voxel features (n_voxels, feature_dim); see :meth:`forward`.

        ``fold_norms``: the MLP's eval BatchNorm folded into its Linear (inference path).
        """
        point_features = voxel_features.index_select(0, point_voxel)
        inputs = torch.cat([point_features, xyz.to(point_features.dtype)], dim=1)
        offsets = fused.folded_mlp(self.mlp, inputs) if fold_norms else self.mlp(inputs)
        return offsets, point_features
