"""Cylindrical voxelization, 9-D point features, batching, and the point-to-voxel encoder.

A point ``(x, y, z)`` goes to cylindrical ``(rho, phi, z)``; the grid splits
``[rho_min, rho_max] x [phi_min, phi_max) x [z_min, z_max]`` into ``size`` equal cells, and
points outside the ranges are clipped into the border cells (as Cylinder3D / DS-Net do, so
every point gets a voxel and a prediction).

Point features (9 per point, Cylinder3D order): offset of the point to its voxel centre in
cylindrical coordinates ``(d_rho, d_phi, d_z)``, then ``rho, phi, z, x, y, remission``.

Two cell rules (``CylinderGrid.official_cells``):

- nominal: cell = range / size, computed in the points' dtype (torch);
- official (DS-Net ``dataloader/dataset.py``): cell = range / (size - 1), i.e. the upper bound
  is the *start* of the last cell; polar coordinates in float32, then clipping, cell indices,
  voxel centres and relative features in float64 (numpy), cast to float32 at the end.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from panoptic_bench.dsnet.sparse import SparseTensor, fused
from panoptic_bench.dsnet.sparse.tensor import decode_keys

N_POINT_FEATURES = 9


@dataclass(frozen=True)
class CylinderGrid:
    """Cylindrical voxel grid: cell counts along (rho, phi, z) and the clipped ranges.

    Defaults are the paper's 480 x 360 x 32 cells over rho in [3, 50] m, phi in [-180, 180)
    degrees, z in [-3, 1.5] m. Field names match ``panoptic_bench.dsnet.config.GridConfig``.
    """

    size: tuple[int, int, int] = (480, 360, 32)
    rho_range: tuple[float, float] = (3.0, 50.0)
    phi_range_deg: tuple[float, float] = (-180.0, 180.0)
    z_range: tuple[float, float] = (-3.0, 1.5)
    official_cells: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "size", tuple(int(s) for s in self.size))
        object.__setattr__(self, "official_cells", bool(self.official_cells))
        for name in ("rho_range", "phi_range_deg", "z_range"):
            object.__setattr__(self, name, tuple(float(v) for v in getattr(self, name)))
        if len(self.size) != 3 or min(self.size) < 1:
            raise ValueError(f"grid size must be 3 positive ints, got {self.size}")
        for name in ("rho_range", "phi_range_deg", "z_range"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise ValueError(f"grid {name} must be increasing, got {[lo, hi]}")

    @property
    def min_bound(self) -> tuple[float, float, float]:
        """Lower corner (rho m, phi rad, z m)."""
        return (self.rho_range[0], math.radians(self.phi_range_deg[0]), self.z_range[0])

    @property
    def max_bound(self) -> tuple[float, float, float]:
        """Upper corner (rho m, phi rad, z m)."""
        return (self.rho_range[1], math.radians(self.phi_range_deg[1]), self.z_range[1])

    @property
    def cell_size(self) -> tuple[float, float, float]:
        """Cell extent (rho m, phi rad, z m): range / size, or range / (size - 1) (official)."""
        d = 1 if self.official_cells else 0
        return tuple(  # type: ignore[return-value]
            (hi - lo) / max(n - d, 1)
            for lo, hi, n in zip(self.min_bound, self.max_bound, self.size)
        )

    @classmethod
    def from_dict(cls, mapping: dict[str, Any]) -> CylinderGrid:
        """Build from a plain mapping; unknown keys are an error."""
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(mapping) - known)
        if unknown:
            raise ValueError(f"unknown grid keys {unknown}; known: {sorted(known)}")
        return cls(**{k: v if isinstance(v, bool) else tuple(v) for k, v in mapping.items()})

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping (lists, not tuples) that :meth:`from_dict` reads back."""
        return {
            f.name: v if isinstance(v := getattr(self, f.name), bool) else list(v)
            for f in dataclasses.fields(self)
        }


def cylindrical(xyz: torch.Tensor) -> torch.Tensor:
    """(x, y, z) -> (rho, phi, z); arrays of shape (n, 3), phi in [-pi, pi] radians."""
    rho = torch.sqrt(xyz[:, 0] ** 2 + xyz[:, 1] ** 2)
    phi = torch.atan2(xyz[:, 1], xyz[:, 0])
    return torch.stack([rho, phi, xyz[:, 2]], dim=1)


def voxel_indices(xyz: torch.Tensor, grid: CylinderGrid) -> torch.Tensor:
    """Cell (i_rho, i_phi, i_z) of each point, shape (n, 3), int64; outside points clipped."""
    if grid.official_cells:
        pts = xyz.detach().cpu().numpy()
        _, idx = official_point_features(pts, np.zeros(len(pts), np.float32), grid)
        return torch.from_numpy(idx).to(xyz.device)
    pol = cylindrical(xyz)
    lo = pol.new_tensor(grid.min_bound)
    hi = pol.new_tensor(grid.max_bound)
    cell = pol.new_tensor(grid.cell_size)
    idx = torch.floor((torch.minimum(torch.maximum(pol, lo), hi) - lo) / cell).long()
    upper = torch.tensor(grid.size, device=xyz.device) - 1
    return torch.minimum(idx.clamp_(min=0), upper)


def point_features(
    xyz: torch.Tensor, remission: torch.Tensor, grid: CylinderGrid
) -> tuple[torch.Tensor, torch.Tensor]:
    """9-D point features and voxel indices.

    Parameters
    ----------
    xyz : torch.Tensor
        Array of shape (n, 3), float, metres.
    remission : torch.Tensor
        Array of shape (n,), float.
    grid : CylinderGrid

    Returns
    -------
    features : torch.Tensor
        Array of shape (n, 9), same dtype: ``d_rho, d_phi, d_z`` (point minus its voxel centre,
        cylindrical, unclipped point), ``rho, phi, z, x, y, remission``.
    indices : torch.Tensor
        Array of shape (n, 3), int64, from :func:`voxel_indices`.
    """
    if grid.official_cells:
        feats_np, idx_np = official_point_features(
            xyz.detach().cpu().numpy(), remission.detach().cpu().numpy(), grid
        )
        return (
            torch.from_numpy(feats_np).to(device=xyz.device, dtype=xyz.dtype),
            torch.from_numpy(idx_np).to(xyz.device),
        )
    pol = cylindrical(xyz)
    idx = voxel_indices(xyz, grid)
    centre = (idx.to(pol.dtype) + 0.5) * pol.new_tensor(grid.cell_size) + pol.new_tensor(
        grid.min_bound
    )
    feats = torch.cat([pol - centre, pol, xyz[:, :2], remission[:, None].to(pol.dtype)], dim=1)
    return feats, idx


def official_point_features(
    xyz: np.ndarray, remission: np.ndarray, grid: CylinderGrid
) -> tuple[np.ndarray, np.ndarray]:
    """9-D point features and cell indices by the official DS-Net rule (module docstring).

    Parameters
    ----------
    xyz : np.ndarray of shape (n, 3), float32
    remission : np.ndarray of shape (n,), float32
    grid : CylinderGrid
        Its ranges and size; the cell is ``range / (size - 1)`` whatever ``official_cells``.

    Returns
    -------
    features : np.ndarray of shape (n, 9), float32
    indices : np.ndarray of shape (n, 3), int64, in ``0 .. size - 1``
    """
    xyz = np.asarray(xyz, dtype=np.float32)
    rho = np.sqrt(xyz[:, 0] ** 2 + xyz[:, 1] ** 2)
    phi = np.arctan2(xyz[:, 1], xyz[:, 0])
    pol = np.stack([rho, phi, xyz[:, 2]], axis=1)  # float32, as the official dataloader
    lo = np.asarray(grid.min_bound, dtype=np.float64)
    hi = np.asarray(grid.max_bound, dtype=np.float64)
    cell = (hi - lo) / (np.asarray(grid.size, dtype=np.int64) - 1)
    idx = np.floor((np.clip(pol, lo, hi) - lo) / cell).astype(np.int64)
    centre = (idx.astype(np.float32) + 0.5) * cell + lo
    feats = np.concatenate(
        [pol - centre, pol, xyz[:, :2], np.asarray(remission, np.float32)[:, None]], axis=1
    )
    return feats.astype(np.float32), idx


@dataclass
class VoxelBatch:
    """Several scans voxelized together.

    Attributes
    ----------
    point_features : torch.Tensor
        Array of shape (n_points, 9), float32.
    xyz : torch.Tensor
        Array of shape (n_points, 3), float32, Cartesian (input to the offset head).
    point_voxel : torch.Tensor
        Array of shape (n_points,), int64: row of ``voxel_coords`` holding each point.
    point_batch : torch.Tensor
        Array of shape (n_points,), int64: scan index of each point (scans concatenated in order).
    voxel_coords : torch.Tensor
        Array of shape (n_voxels, 4), int32, ``(scan, i_rho, i_phi, i_z)``, sorted, unique.
    spatial_shape : tuple of 3 ints
    batch_size : int
    """

    point_features: torch.Tensor
    xyz: torch.Tensor
    point_voxel: torch.Tensor
    point_batch: torch.Tensor
    voxel_coords: torch.Tensor
    spatial_shape: tuple[int, int, int]
    batch_size: int

    def to(self, device: torch.device | str) -> VoxelBatch:
        """Copy every tensor to ``device``."""
        moved = {
            f.name: getattr(self, f.name).to(device)
            for f in dataclasses.fields(self)
            if isinstance(getattr(self, f.name), torch.Tensor)
        }
        return dataclasses.replace(self, **moved)

    @property
    def num_points(self) -> int:
        return int(self.xyz.shape[0])


def collate(
    scans: Sequence[torch.Tensor | np.ndarray], grid: CylinderGrid, device: Any = None
) -> VoxelBatch:
    """Voxelize scans of shape (n_i, 4 + e) ``x, y, z, remission`` into one :class:`VoxelBatch`.

    Points keep their order (scan 0 first); ``device`` defaults to that of the first tensor.
    Columns after the fourth (``e`` extra per-point features, the same count in every scan, e.g.
    :mod:`panoptic_bench.dsnet.data.shape`) are appended to the 9 point features.
    """
    if not scans:
        raise ValueError("collate needs at least one scan")
    tensors = [torch.as_tensor(s) for s in scans]
    device = tensors[0].device if device is None else torch.device(device)
    feats, xyzs, idxs, batch = [], [], [], []
    for b, pts in enumerate(tensors):
        if pts.ndim != 2 or pts.shape[1] < 4:
            raise ValueError(f"scan {b} must have shape (n, 4 + e), got {tuple(pts.shape)}")
        pts = pts.to(device=device, dtype=torch.float32)
        if pts.shape[1] != tensors[0].shape[1]:
            raise ValueError(f"scan {b} has {pts.shape[1]} columns, scan 0 {tensors[0].shape[1]}")
        f, idx = point_features(pts[:, :3], pts[:, 3], grid)
        feats.append(torch.cat([f, pts[:, 4:]], dim=1) if pts.shape[1] > 4 else f)
        xyzs.append(pts[:, :3])
        idxs.append(idx)
        batch.append(torch.full((pts.shape[0],), b, dtype=torch.long, device=device))
    idx = torch.cat(idxs)
    point_batch = torch.cat(batch)
    x, y, z = grid.size
    keys = ((point_batch * x + idx[:, 0]) * y + idx[:, 1]) * z + idx[:, 2]
    uniq, inverse = torch.unique(keys, sorted=True, return_inverse=True)
    return VoxelBatch(
        point_features=torch.cat(feats),
        xyz=torch.cat(xyzs),
        point_voxel=inverse,
        point_batch=point_batch,
        voxel_coords=decode_keys(uniq, grid.size),
        spatial_shape=grid.size,
        batch_size=len(tensors),
    )


class PointVoxelEncoder(nn.Module):
    """Per-point MLP (PointNet-style) max-pooled into voxels, then compressed.

    ``BN -> [Linear -> BN -> ReLU] * len(hidden) -> Linear(point_feature_dim)``, max over the
    points of each voxel (``scatter_reduce``), then ``Linear(voxel_feature_dim) -> ReLU``.

    Parameters
    ----------
    in_channels : int
        Point feature size (9).
    hidden : tuple of ints
        Hidden widths of the point MLP (DS-Net: 64, 128, 256).
    point_feature_dim : int
        Width before pooling (DS-Net: 64; Cylinder3D: 256).
    voxel_feature_dim : int
        Width after compression, input of the backbone (16).
    """

    def __init__(
        self,
        in_channels: int = N_POINT_FEATURES,
        hidden: tuple[int, ...] = (64, 128, 256),
        point_feature_dim: int = 64,
        voxel_feature_dim: int = 16,
    ) -> None:
        super().__init__()
        layers: list[nn.Module] = [nn.BatchNorm1d(in_channels)]
        width = in_channels
        for h in hidden:
            layers += [nn.Linear(width, h), nn.BatchNorm1d(h), nn.ReLU()]
            width = h
        layers.append(nn.Linear(width, point_feature_dim))
        self.point_mlp = nn.Sequential(*layers)
        self.compress = nn.Sequential(nn.Linear(point_feature_dim, voxel_feature_dim), nn.ReLU())
        self.out_channels = voxel_feature_dim

    def forward(self, batch: VoxelBatch, fold_norms: bool = False) -> SparseTensor:
        """Voxel features as a :class:`SparseTensor` on ``batch.voxel_coords``.

        ``fold_norms``: run the point MLP with its (eval-mode) BatchNorms folded into the
        Linears (:func:`~panoptic_bench.dsnet.sparse.fused.folded_mlp`; the inference path of
        the official network, same outputs up to float round-off).
        """
        if fold_norms:
            pf = fused.folded_mlp(self.point_mlp, batch.point_features)
        else:
            pf = self.point_mlp(batch.point_features)
        n_vox = batch.voxel_coords.shape[0]
        index = batch.point_voxel[:, None].expand(-1, pf.shape[1])
        pooled = pf.new_zeros((n_vox, pf.shape[1])).scatter_reduce(
            0, index, pf, reduce="amax", include_self=False
        )
        return SparseTensor(self.compress(pooled), batch.voxel_coords, batch.spatial_shape)
