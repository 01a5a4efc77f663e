"""The sparse voxel tensor: features on active sites plus their integer coordinates.

A :class:`SparseTensor` carries a ``cache`` dict that is *shared* by every tensor derived from
it (through convolutions, batch norm, activations), so a kernel map computed once at a given
resolution is reused by every later layer at that resolution, and the inverse convolution finds
the map of the strided convolution it undoes.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

Shape3 = tuple[int, int, int]


def _as_triple(value: int | tuple[int, ...], name: str) -> Shape3:
    if isinstance(value, int):
        return (value, value, value)
    triple = tuple(int(v) for v in value)
    if len(triple) != 3:
        raise ValueError(f"{name} must be an int or 3 ints, got {value!r}")
    return triple  # type: ignore[return-value]


class SparseTensor:
    """Features on the active sites of a batch of 3-D grids.

    Parameters
    ----------
    features : torch.Tensor
        Array of shape (n_sites, channels), float.
    coords : torch.Tensor
        Array of shape (n_sites, 4), int32: ``(batch, x, y, z)`` of each site, in cells of this
        tensor's resolution, each row unique, ``0 <= x < spatial_shape[0]`` etc.
    spatial_shape : tuple of 3 ints
        Grid size at this resolution.
    stride : tuple of 3 ints
        Cumulative stride relative to the input grid (``(1, 1, 1)`` for the input).
    cache : dict, optional
        Kernel-map cache shared with related tensors; a new one when omitted.

    Examples
    --------
    >>> x = SparseTensor(torch.ones(2, 3), torch.tensor([[0, 0, 0, 0], [0, 1, 0, 0]],
    ...                  dtype=torch.int32), (4, 4, 4))
    >>> x.features.shape
    torch.Size([2, 3])
    """

    __slots__ = ("features", "coords", "spatial_shape", "stride", "cache")

    def __init__(
        self,
        features: torch.Tensor,
        coords: torch.Tensor,
        spatial_shape: int | tuple[int, ...],
        stride: int | tuple[int, ...] = 1,
        cache: dict | None = None,
    ) -> None:
        if coords.ndim != 2 or coords.shape[1] != 4:
            raise ValueError(f"coords must have shape (n, 4), got {tuple(coords.shape)}")
        if features.ndim != 2 or features.shape[0] != coords.shape[0]:
            raise ValueError(
                f"features must have shape ({coords.shape[0]}, C), got {tuple(features.shape)}"
            )
        self.features = features
        self.coords = coords.to(torch.int32)
        self.spatial_shape = _as_triple(spatial_shape, "spatial_shape")
        self.stride = _as_triple(stride, "stride")
        self.cache = {} if cache is None else cache

    @property
    def F(self) -> torch.Tensor:  # noqa: N802 - torchsparse-style short alias
        """Alias of :attr:`features`."""
        return self.features

    @property
    def C(self) -> torch.Tensor:  # noqa: N802
        """Alias of :attr:`coords`."""
        return self.coords

    @property
    def device(self) -> torch.device:
        return self.features.device

    def __len__(self) -> int:
        return int(self.coords.shape[0])

    def replace_features(self, features: torch.Tensor) -> SparseTensor:
        """Same sites, shared cache, new features of shape (n_sites, any)."""
        return SparseTensor(features, self.coords, self.spatial_shape, self.stride, self.cache)

    def apply(self, fn: Callable[[torch.Tensor], torch.Tensor]) -> SparseTensor:
        """Apply a per-site function (BatchNorm, activation, Linear) to the features."""
        return self.replace_features(fn(self.features))

    def batch_size(self) -> int:
        """Number of scans (largest batch index + 1; 0 when empty)."""
        return int(self.coords[:, 0].max().item()) + 1 if len(self) else 0

    def dense(self) -> torch.Tensor:
        """Dense array of shape (batch, channels, *spatial_shape), zeros at inactive sites."""
        b = self.batch_size()
        out = self.features.new_zeros((b, *self.spatial_shape, self.features.shape[1]))
        c = self.coords.long()
        out[c[:, 0], c[:, 1], c[:, 2], c[:, 3]] = self.features
        return out.permute(0, 4, 1, 2, 3).contiguous()

    def __repr__(self) -> str:
        return (
            f"SparseTensor(n_sites={len(self)}, channels={self.features.shape[1]}, "
            f"spatial_shape={self.spatial_shape}, stride={self.stride})"
        )


def encode_keys(coords: torch.Tensor, spatial_shape: Shape3) -> torch.Tensor:
    """Integer keys ``((b * X + x) * Y + y) * Z + z`` of shape (n,), int64, order-preserving."""
    c = coords.long()
    x, y, z = spatial_shape
    return ((c[:, 0] * x + c[:, 1]) * y + c[:, 2]) * z + c[:, 3]


def decode_keys(keys: torch.Tensor, spatial_shape: Shape3) -> torch.Tensor:
    """Inverse of :func:`encode_keys`: coords of shape (n, 4), int32."""
    x, y, z = spatial_shape
    zc = keys % z
    rest = keys // z
    yc = rest % y
    rest = rest // y
    xc = rest % x
    b = rest // x
    return torch.stack([b, xc, yc, zc], dim=1).to(torch.int32)
