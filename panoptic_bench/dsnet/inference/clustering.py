"""Clusterers of the regressed centres: the heuristic baselines and Algorithm 1 (dynamic shifting)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import nn

from panoptic_bench.dsnet.config import Clusterer, DSNetConfig

__all__ = ["ds_cluster", "make_clusterer"]


def make_clusterer(kind: Clusterer, bandwidth: float) -> Any:
    """A heuristic clusterer of ``panoptic_bench.baselines`` with its scale parameter set.

    ``bandwidth`` is the mean-shift bandwidth (bin seeding, as DS-Net's code), the BFS radius,
    or DBSCAN's ``eps`` (metres); HDBSCAN has no scale parameter and ignores it.
    """
    from panoptic_bench.baselines.clustering import make_clusterer as make

    scale = {
        Clusterer.MEANSHIFT: {"bandwidth": bandwidth, "bin_seeding": True},
        Clusterer.BFS: {"radius": bandwidth},
        Clusterer.DBSCAN: {"eps": bandwidth},
        Clusterer.HDBSCAN: {},
    }[kind]
    return make(kind.value, **scale)


def ds_cluster(
    shift: nn.Module,
    points: np.ndarray,
    centers: np.ndarray,
    features: torch.Tensor,
    cfg: DSNetConfig,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Algorithm 1 on the predicted thing points of one scan.

    Parameters
    ----------
    points, centers : ndarray of shape (M, 3)
        Thing points and their regressed centres.
    features : torch.Tensor of shape (M, F)

    Returns
    -------
    labels : ndarray of shape (M,), int64
        Cluster of each point's nearest seed.
    diagnostics : dict of str to ndarray
        ``seed_index`` (M',), ``positions`` (I + 1, M', 3) (the seed trajectories),
        ``weights`` (I, M', l), ``bandwidths`` (I, M') implied Σ_j W_j δ_j, ``seed_labels``
        (M',), ``candidates`` (l,) the bandwidth candidates δ_j.
    """
    from panoptic_bench.dsnet.model.ds_head import shift_instances

    inf = cfg.inference
    labels, diag = shift_instances(
        shift,
        centers,
        features,
        points=points,
        clusterer=make_clusterer(inf.ds_clusterer, inf.ds_bandwidth),
        max_seeds=cfg.dynamic_shift.max_seeds,
    )
    arrays = diag.as_arrays()
    arrays["candidates"] = np.asarray(cfg.dynamic_shift.bandwidths, dtype=np.float32)
    return labels, arrays
