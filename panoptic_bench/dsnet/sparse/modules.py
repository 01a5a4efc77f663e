"""Sparse layers as ``nn.Module``: typed constructors, ``extra_repr``, functional ``forward``."""

from __future__ import annotations

import math

import torch
from torch import nn

from panoptic_bench.dsnet.sparse import functional as F
from panoptic_bench.dsnet.sparse.tensor import SparseTensor, _as_triple


class _ConvBase(nn.Module):
    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        kernel_size: int | tuple[int, int, int],
        bias: bool,
    ) -> None:
        super().__init__()
        self.in_channels = in_channels
        self.out_channels = out_channels
        self.kernel_size = _as_triple(kernel_size, "kernel_size")
        n_off = math.prod(self.kernel_size)
        self.weight = nn.Parameter(torch.empty(n_off, in_channels, out_channels))
        self.bias = nn.Parameter(torch.empty(out_channels)) if bias else None
        self.reset_parameters()

    def reset_parameters(self) -> None:
        """Uniform(-1/sqrt(fan_in), 1/sqrt(fan_in)), as ``torch.nn.Conv3d`` by default."""
        bound = 1.0 / math.sqrt(self.in_channels * self.weight.shape[0])
        nn.init.uniform_(self.weight, -bound, bound)
        if self.bias is not None:
            nn.init.uniform_(self.bias, -bound, bound)

    def extra_repr(self) -> str:
        return (
            f"{self.in_channels}, {self.out_channels}, kernel_size={self.kernel_size}, "
            f"bias={self.bias is not None}"
        )


class SubMConv3d(_ConvBase):
    """Submanifold convolution (odd kernel, outputs on the input sites).

    Parameters
    ----------
    in_channels, out_channels : int
    kernel_size : int or tuple of 3 odd ints
        Nominal kernel, e.g. 3, (1, 3, 3), (3, 1, 3), (3, 1, 1); the weight has
        ``prod(kernel_size)`` slices, shape (prod(kernel_size), in_channels, out_channels).
    bias : bool
    effective_kernel : tuple of 3 odd ints, optional
        Kernel the layer actually applies (default: ``kernel_size``). It must have at most
        ``prod(kernel_size)`` offsets; slice ``k`` of the weight then multiplies the ``k``-th
        offset of ``effective_kernel`` in row-major order and the remaining slices are unused.
        This is what spconv 1.x computes when a layer reuses the neighbour pairs of an earlier
        layer with the same ``indice_key`` (the released DS-Net weights were trained so).

    Examples
    --------
    >>> conv = SubMConv3d(4, 8, (3, 3, 3), effective_kernel=(1, 3, 3))
    >>> tuple(conv.weight.shape), conv.effective_kernel
    ((27, 4, 8), (1, 3, 3))
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        kernel_size: int | tuple[int, int, int] = 3,
        bias: bool = False,
        effective_kernel: int | tuple[int, int, int] | None = None,
    ) -> None:
        super().__init__(in_channels, out_channels, kernel_size, bias)
        if any(k % 2 == 0 for k in self.kernel_size):
            raise ValueError(f"submanifold kernels must be odd, got {self.kernel_size}")
        eff = self.kernel_size if effective_kernel is None else effective_kernel
        self.effective_kernel = _as_triple(eff, "effective_kernel")
        if any(k % 2 == 0 for k in self.effective_kernel):
            raise ValueError(f"effective kernels must be odd, got {self.effective_kernel}")
        if math.prod(self.effective_kernel) > self.weight.shape[0]:
            raise ValueError(
                f"effective kernel {self.effective_kernel} has more offsets than the "
                f"{self.kernel_size} weight"
            )

    def extra_repr(self) -> str:
        extra = super().extra_repr()
        if self.effective_kernel != self.kernel_size:
            extra += f", effective_kernel={self.effective_kernel}"
        return extra

    def forward(self, x: SparseTensor) -> SparseTensor:
        if self.effective_kernel == self.kernel_size:
            return F.submanifold_conv3d(x, self.weight, self.kernel_size, self.bias)
        n = math.prod(self.effective_kernel)
        return F.submanifold_conv3d(x, self.weight[:n], self.effective_kernel, self.bias)


class SparseConv3d(_ConvBase):
    """Strided sparse convolution creating new (coarser) sites; spconv output-site rule."""

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        kernel_size: int | tuple[int, int, int] = 3,
        stride: int | tuple[int, int, int] = 2,
        padding: int | tuple[int, int, int] = 1,
        bias: bool = False,
    ) -> None:
        super().__init__(in_channels, out_channels, kernel_size, bias)
        self.stride = _as_triple(stride, "stride")
        self.padding = _as_triple(padding, "padding")

    def extra_repr(self) -> str:
        return f"{super().extra_repr()}, stride={self.stride}, padding={self.padding}"

    def forward(self, x: SparseTensor) -> SparseTensor:
        return F.sparse_conv3d(
            x, self.weight, self.kernel_size, self.stride, self.padding, self.bias
        )


class SparseInverseConv3d(SparseConv3d):
    """Undo an earlier :class:`SparseConv3d` of the same kernel/stride/padding (reuses its map)."""

    def forward(self, x: SparseTensor) -> SparseTensor:
        return F.inverse_conv3d(
            x, self.weight, self.kernel_size, self.stride, self.padding, self.bias
        )


class SparseBatchNorm(nn.BatchNorm1d):
    """``BatchNorm1d`` over the features of all active sites."""

    def forward(self, x: SparseTensor) -> SparseTensor:  # type: ignore[override]
        return x.replace_features(super().forward(x.features))


class SparseActivation(nn.Module):
    """Wrap any elementwise module (``nn.LeakyReLU()``, ``nn.Sigmoid()``) to act on features."""

    def __init__(self, module: nn.Module) -> None:
        super().__init__()
        self.module = module

    def forward(self, x: SparseTensor) -> SparseTensor:
        return x.replace_features(self.module(x.features))
