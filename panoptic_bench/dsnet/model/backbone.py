"""Cylinder3D asymmetric residual U-Net, as used by DS-Net (paper §3.1).

Context block -> 4 down blocks (strided conv; stride 2 in all axes for the first two, "height
pooling", then (2, 2, 1)) -> 4 up blocks (submanifold conv, inverse conv reusing the matching
down-sampling map, skip addition, asymmetric convs) -> reconstruction block (three 1-D convs,
sigmoid gates multiplied onto the input). The output concatenates the reconstruction with its
input: ``4 * init_size`` features at the input sites.

Layer order follows the reference: convolution, LeakyReLU, then BatchNorm (sigmoid after
BatchNorm in the reconstruction block).

``spconv1_rulebooks=True`` builds the network the released DS-Net weights were trained with:
spconv 1.x lets every conv with an ``indice_key`` already present in the tensor reuse the
neighbour pairs of the first conv with that key, whatever its own kernel, and multiply only the
first slices of its weight. So in the context block all four convs act as 1x3x3, in each down
block all four as 3x1x3, in each up block the three refine convs as 1x3x3 (the nominal 3x3x3
one uses its first kernel plane) and in the reconstruction block all three as 3x1x1. Each layer
gets that *effective kernel* as a constructor argument (:class:`~..sparse.SubMConv3d`); the
weights keep their nominal shapes, so the official state dicts load unchanged.
"""

from __future__ import annotations

import torch
from torch import nn

from panoptic_bench.dsnet.sparse import (
    SparseConv3d,
    SparseInverseConv3d,
    SparseTensor,
    SubMConv3d,
    fused,
)

K_1x3x3 = (1, 3, 3)
K_3x1x3 = (3, 1, 3)
K_3x3x3 = (3, 3, 3)
K_3x1x1 = (3, 1, 1)

Kernel = tuple[int, int, int]


class ConvActNorm(nn.Module):
    """Submanifold conv -> LeakyReLU -> BatchNorm on the features.

    ``effective_kernel``: see :class:`~panoptic_bench.dsnet.sparse.SubMConv3d`.
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        kernel_size: Kernel,
        effective_kernel: Kernel | None = None,
    ):
        super().__init__()
        self.conv = SubMConv3d(
            in_channels, out_channels, kernel_size, effective_kernel=effective_kernel
        )
        self.act = nn.LeakyReLU()
        self.norm = nn.BatchNorm1d(out_channels)

    def forward(self, x: SparseTensor) -> SparseTensor:
        y = self.conv(x)
        return y.replace_features(self.post(y.features, fused.inference_path(y, self.norm)))

    def post(self, features: torch.Tensor, in_place: bool = False) -> torch.Tensor:
        """LeakyReLU then BatchNorm of the conv output (n_sites, out_channels).

        ``in_place``: overwrite ``features`` (the inference path, :mod:`..sparse.fused`).
        """
        if in_place:
            return fused.act_norm_(features, self.act, [self.norm])
        return self.norm(self.act(features))


class ConvNormAct(ConvActNorm):
    """Submanifold conv -> BatchNorm -> LeakyReLU (the official offset head's order)."""

    def post(self, features: torch.Tensor, in_place: bool = False) -> torch.Tensor:
        """BatchNorm then LeakyReLU (in place on the inference path)."""
        if in_place:
            return fused.norm_act_(features, self.norm, self.act)
        return self.act(self.norm(features))


class ResContextBlock(nn.Module):
    """Two asymmetric branches (1x3x3 then 3x1x3, and 3x1x3 then 1x3x3), summed.

    ``effective_kernel``: the kernel all four convs act as (None: their nominal kernels).
    """

    def __init__(
        self, in_channels: int, out_channels: int, effective_kernel: Kernel | None = None
    ) -> None:
        super().__init__()
        e = effective_kernel
        self.branch_a = nn.Sequential(
            ConvActNorm(in_channels, out_channels, K_1x3x3, e),
            ConvActNorm(out_channels, out_channels, K_3x1x3, e),
        )
        self.branch_b = nn.Sequential(
            ConvActNorm(in_channels, out_channels, K_3x1x3, e),
            ConvActNorm(out_channels, out_channels, K_1x3x3, e),
        )

    def forward(self, x: SparseTensor) -> SparseTensor:
        a0, b0 = self.branch_a[0], self.branch_b[0]
        if (
            fused.inference_path(x, a0.norm, b0.norm)
            and fused.can_merge([a0.conv, b0.conv])
            and a0.act.negative_slope == b0.act.negative_slope
        ):  # both first convs read x through the same map: one conv, twice as wide
            h = fused.merged_conv(x, [a0.conv, b0.conv])
            f = fused.act_norm_(h.features, a0.act, [a0.norm, b0.norm])
            c = a0.conv.out_channels
            a = self.branch_a[1](h.replace_features(f[:, :c]))
            b = self.branch_b[1](h.replace_features(f[:, c:]))
        else:
            a, b = self.branch_a(x), self.branch_b(x)
        return b.replace_features(a.features + b.features)


class DownBlock(nn.Module):
    """Residual asymmetric block, then a strided 3x3x3 conv (padding 1).

    The residual block has the context block's two branches (1x3x3 then 3x1x3, 3x1x3 then
    1x3x3; the reference names them the other way round, the sum is the same).

    ``forward`` returns ``(pooled, before_pooling)``; the second is the skip connection.
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        height_pooling: bool,
        effective_kernel: Kernel | None = None,
    ) -> None:
        super().__init__()
        self.residual = ResContextBlock(in_channels, out_channels, effective_kernel)
        self.stride = (2, 2, 2) if height_pooling else (2, 2, 1)
        self.pool = SparseConv3d(out_channels, out_channels, 3, self.stride, 1)

    def forward(self, x: SparseTensor) -> tuple[SparseTensor, SparseTensor]:
        skip = self.residual(x)
        return self.pool(skip), skip


class UpBlock(nn.Module):
    """3x3x3 conv, inverse conv back to the skip's sites, add skip, 1x3x3 / 3x1x3 / 3x3x3 convs."""

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        stride: tuple[int, int, int],
        effective_kernel: Kernel | None = None,
    ):
        super().__init__()
        e = effective_kernel
        self.reduce = ConvActNorm(in_channels, out_channels, K_3x3x3)
        self.up = SparseInverseConv3d(out_channels, out_channels, 3, stride, 1)
        self.refine = nn.Sequential(
            ConvActNorm(out_channels, out_channels, K_1x3x3, e),
            ConvActNorm(out_channels, out_channels, K_3x1x3, e),
            ConvActNorm(out_channels, out_channels, K_3x3x3, e),
        )

    def forward(self, x: SparseTensor, skip: SparseTensor) -> SparseTensor:
        up = self.up(self.reduce(x))
        return self.refine(up.replace_features(up.features + skip.features))


class ReconBlock(nn.Module):
    """Three 1-D convs (3x1x1, 1x3x1, 1x1x3), each BatchNorm -> sigmoid, summed, times input."""

    def __init__(self, channels: int, effective_kernel: Kernel | None = None) -> None:
        super().__init__()
        kernels = ((3, 1, 1), (1, 3, 1), (1, 1, 3))
        self.convs = nn.ModuleList(
            SubMConv3d(channels, channels, k, effective_kernel=effective_kernel) for k in kernels
        )
        self.norms = nn.ModuleList(nn.BatchNorm1d(channels) for _ in kernels)

    def forward(self, x: SparseTensor) -> SparseTensor:
        convs = list(self.convs)
        if fused.inference_path(x, *self.norms) and fused.can_merge(convs):
            h = fused.merged_conv(x, convs).features  # the three gates side by side
            torch.sigmoid_(fused.affine_(h, *fused.norms_scale_shift(list(self.norms))))
            c = convs[0].out_channels
            gate = h[:, :c] + h[:, c : 2 * c] + h[:, 2 * c :]
            return x.replace_features(gate.mul_(x.features))
        gate = sum(
            torch.sigmoid(norm(conv(x).features)) for conv, norm in zip(self.convs, self.norms)
        )
        return x.replace_features(gate * x.features)


class AsymmetricUNet(nn.Module):
    """Cylinder3D backbone.

    Parameters
    ----------
    in_channels : int
        Voxel feature width from the point encoder (16).
    init_size : int
        Base width (paper 32); widths are ``init_size * (1, 2, 4, 8, 16)`` down the U.
    spconv1_rulebooks : bool
        Effective kernels of the official (spconv 1.x) network (module docstring); False: every
        conv acts with its nominal kernel.

    Forward
    -------
    ``SparseTensor`` with ``in_channels`` features -> ``SparseTensor`` with
    ``out_channels == 4 * init_size`` features on the same sites.
    """

    def __init__(
        self, in_channels: int = 16, init_size: int = 32, spconv1_rulebooks: bool = False
    ) -> None:
        super().__init__()
        w = init_size
        self.init_size = init_size
        self.spconv1_rulebooks = bool(spconv1_rulebooks)
        self.out_channels = 4 * w
        ctx, down, up, recon = (
            (K_1x3x3, K_3x1x3, K_1x3x3, K_3x1x1) if spconv1_rulebooks else (None,) * 4
        )
        self.context = ResContextBlock(in_channels, w, ctx)
        self.down = nn.ModuleList(
            [
                DownBlock(w, 2 * w, True, down),
                DownBlock(2 * w, 4 * w, True, down),
                DownBlock(4 * w, 8 * w, False, down),
                DownBlock(8 * w, 16 * w, False, down),
            ]
        )
        strides = [d.stride for d in self.down]
        self.up = nn.ModuleList(
            [
                UpBlock(16 * w, 16 * w, strides[3], up),
                UpBlock(16 * w, 8 * w, strides[2], up),
                UpBlock(8 * w, 4 * w, strides[1], up),
                UpBlock(4 * w, 2 * w, strides[0], up),
            ]
        )
        self.recon = ReconBlock(2 * w, recon)

    def extra_repr(self) -> str:
        return f"init_size={self.init_size}, spconv1_rulebooks={self.spconv1_rulebooks}"

    def forward(self, x: SparseTensor) -> SparseTensor:
        h = self.context(x)
        skips = []
        for block in self.down:
            h, skip = block(h)
            skips.append(skip)
        for block, skip in zip(self.up, reversed(skips)):
            h = block(h, skip)
        r = self.recon(h)
        return r.replace_features(torch.cat([r.features, h.features], dim=1))
