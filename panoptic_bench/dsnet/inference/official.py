"""Inference rules of the official DS-Net code (``model.variant: official``).

Read from ``network/model_zoo.py``, ``network/modules/pytorch_meanshift.py``,
``utils/clustering.py`` and ``utils/common_utils.py`` of hongfz16/DS-Net:

- semantic class = argmax over *all* logits (class 0 included); thing points are those whose
  class is a thing class;
- backbone (steps 1-2): the regressed centres ``xyz + offset`` of the thing points are clustered
  by mean shift (bandwidth 1.2, bin seeding), instance id = cluster label + 1, no size filter;
- DS-Net (step 3): when there are more than ``max_seeds`` thing points, seeds are the farthest
  point sample of the points' *xyz* (``torch_cluster.fps`` without random start, so from index 0,
  ``ceil(n * max_seeds / n)`` seeds in float32), otherwise every thing point is a seed; the seeds'
  centres are shifted, the converged seeds clustered by mean shift 0.65 (bin seeding), and every
  thing point takes the label of its nearest seed by xyz (each point its own seed's label when
  there is no sampling); one seed or none gives no instance; instance id = label + 1, no size
  filter;
- fusion (``merge_ins_sem``): every instance takes the most frequent class of its points, the
  smallest class on a tie.

The official voxelizer also keeps at most 256 random points per voxel before max-pooling; the
real scans in ../shared/data have at most 25 points per voxel, so that cap is not applied here.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from panoptic_bench.dsnet.model.dynamic_shift import Clusterer, cluster_seeds

__all__ = ["official_seed_count", "official_seeds", "official_shift_instances"]


def official_seed_count(n: int, max_seeds: int) -> int:
    """Seeds ``torch_cluster.fps`` returns for ``n`` points at ratio ``max_seeds / n``.

    ``n`` when ``n <= max_seeds`` (no sampling), else ``ceil(float32(n) * float32(ratio))``.
    """
    if n <= max_seeds:
        return n
    return int(math.ceil(np.float32(n) * np.float32(max_seeds / n)))


def official_seeds(points: np.ndarray, max_seeds: int) -> np.ndarray | None:
    """Seed indices into ``points`` (FPS on xyz from index 0), or None when all are seeds.

    Parameters
    ----------
    points : np.ndarray of shape (M, 3), float
        Thing points' coordinates.

    Returns
    -------
    np.ndarray of shape (K,), int64, in FPS order; None when ``M <= max_seeds``.
    """
    import fpsample

    m = len(points)
    if m <= max_seeds:
        return None
    k = official_seed_count(m, max_seeds)
    pts = np.ascontiguousarray(points, dtype=np.float32)
    return np.asarray(fpsample.fps_sampling(pts, k, start_idx=0), dtype=np.int64)


@torch.no_grad()
def official_shift_instances(
    module: nn.Module,
    points: np.ndarray,
    centers: np.ndarray,
    features: torch.Tensor,
    clusterer: Clusterer,
    max_seeds: int = 10000,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Instance ids of the thing points by the official DS-Net rules (module docstring).

    Parameters
    ----------
    module : DynamicShift
    points, centers : np.ndarray of shape (M, 3)
        Thing points and their regressed centres.
    features : torch.Tensor of shape (M, F)
    clusterer : estimator with ``fit_predict``
        Mean shift 0.65 with bin seeding in the official config.

    Returns
    -------
    inst : np.ndarray of shape (M,), int64
        1..K (clusterer label + 1); all 0 with fewer than two seeds.
    diagnostics : dict of str to ndarray
        ``seed_index``, ``positions`` (I + 1, K, 3), ``weights`` (I, K, l), ``bandwidths``
        (I, K), ``seed_labels`` (K,).
    """
    from scipy.spatial import cKDTree

    m = len(points)
    idx = official_seeds(points, max_seeds)
    seed_idx = np.arange(m, dtype=np.int64) if idx is None else idx
    if len(seed_idx) <= 1:
        return np.zeros(m, dtype=np.int64), {}
    dev = next(module.parameters()).device
    module.eval()
    x = torch.from_numpy(np.asarray(centers, np.float32)[seed_idx]).to(dev)
    f = features[torch.from_numpy(seed_idx).to(features.device)].to(dev, torch.float32)
    out = module(x, f)
    seed_labels = cluster_seeds(out.final.cpu().double().numpy(), clusterer) + 1
    if idx is None:
        inst = seed_labels.astype(np.int64)
    else:
        seeds_xyz = np.asarray(points, np.float64)[idx]
        _, nearest = cKDTree(seeds_xyz).query(np.asarray(points, np.float64))
        inst = seed_labels[nearest].astype(np.int64)
    diag = {
        "seed_index": seed_idx,
        "positions": torch.stack(out.positions).cpu().numpy(),
        "weights": torch.stack(out.weights).cpu().numpy() if out.weights else np.zeros((0,)),
        "bandwidths": torch.stack(out.bandwidths).cpu().numpy(),
        "seed_labels": seed_labels - 1,
    }
    return inst, diag
