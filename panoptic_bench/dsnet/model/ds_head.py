"""Dynamic shifting applied to a scan: backbone outputs in, instance ids and diagnostics out.

:func:`shift_instances` is Algorithm 1 on the things points of one scan (FPS seeds, I shifting
iterations, clustering of the converged seeds, nearest seed → instance);
:func:`shift_training_loss` is the stage-3 loss on one scan; :class:`DSNetHead` wraps both
behind the backbone's outputs (semantic logits, offsets, point features, xyz).

Nearest-seed assignment is done in regressed-centre space (the space the seeds were sampled
and shifted in) unless ``assign_by_xyz=True``, which follows Algorithm 1 line 14 literally
(nearest seed by the points' own coordinates).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from panoptic_bench.baselines.meanshift import MeanShift
from panoptic_bench.dsnet.model.dynamic_shift import (
    Clusterer,
    DynamicShift,
    assign_to_seeds,
    cluster_seeds,
    dynamic_shift_loss,
    select_seeds,
)


def default_clusterer() -> Clusterer:
    """SemanticKITTI preset of the paper: flat mean shift with bandwidth 0.65 (appendix §4)."""
    return MeanShift(bandwidth=0.65, bin_seeding=True)


@dataclass
class ShiftDiagnostics:
    """Per-seed record of one scan (for Figs. 5–7), numpy arrays.

    Attributes
    ----------
    seed_index : (M',) int64, index of each seed among the things points.
    positions : (I + 1, M', 3) float32, seeds before and after each iteration.
    weights : (I, M', l) float32, candidate weights (l = 0 for the Gaussian kernel).
    bandwidths : (I, M') float32, implied bandwidth Σ_j W_j δ_j (or the regressed one).
    seed_labels : (M',) int64, cluster of each converged seed.
    """

    seed_index: np.ndarray
    positions: np.ndarray
    weights: np.ndarray
    bandwidths: np.ndarray
    seed_labels: np.ndarray

    def as_arrays(self) -> dict[str, np.ndarray]:
        """Name → array, e.g. for ``panoptic_bench.io.write_npz(path, **diag.as_arrays())``."""
        return dict(vars(self))


def _stack(tensors: list[torch.Tensor], m: int, tail: tuple[int, ...]) -> np.ndarray:
    if not tensors:
        return np.zeros((0, m, *tail), dtype=np.float32)
    return torch.stack([t.detach().float().cpu() for t in tensors]).numpy()


@torch.no_grad()
def shift_instances(
    module: DynamicShift,
    centers: np.ndarray,
    features: torch.Tensor,
    *,
    points: np.ndarray | None = None,
    clusterer: Clusterer | None = None,
    max_seeds: int = 10000,
    assign_by_xyz: bool = False,
) -> tuple[np.ndarray, ShiftDiagnostics]:
    """Instance label of every things point of one scan (Algorithm 1).

    Parameters
    ----------
    module : DynamicShift
    centers : np.ndarray of shape (M, 3), float
        Regressed centres (xyz + offsets) of the things points.
    features : torch.Tensor of shape (M, F)
        Their backbone features (any device; the module's device is used).
    points : np.ndarray of shape (M, 3), optional
        The things points' coordinates; required with ``assign_by_xyz``.
    clusterer : object with ``fit_predict``, optional
        Clustering of the converged seeds; default :func:`default_clusterer`.
    max_seeds : int
        FPS budget (10,000 in the paper).
    assign_by_xyz : bool
        Nearest seed by xyz (Algorithm 1 line 14) instead of by regressed centre.

    Returns
    -------
    labels : np.ndarray of shape (M,), int64
        The clusterer's label of each point's nearest seed (−1 only for noise labels).
    diagnostics : ShiftDiagnostics
    """
    centers = np.asarray(centers, dtype=np.float64)
    if assign_by_xyz and points is None:
        raise ValueError("assign_by_xyz=True needs the things points' coordinates")
    idx = select_seeds(centers, max_seeds)
    dev = next(module.parameters()).device
    idx_t = torch.from_numpy(idx).to(features.device)
    seeds = torch.from_numpy(centers[idx]).to(dev, torch.float32)
    out = module(seeds, features[idx_t].to(dev, torch.float32))
    final = out.final.cpu().double().numpy()
    seed_labels = cluster_seeds(final, clusterer or default_clusterer())
    space = np.asarray(points if assign_by_xyz else centers, dtype=np.float64)
    labels = assign_to_seeds(space, space[idx], seed_labels)
    m = len(idx)
    diag = ShiftDiagnostics(
        seed_index=idx,
        positions=_stack(out.positions, m, (3,)),
        weights=_stack(out.weights, m, (len(module.bandwidths),)),
        bandwidths=_stack(out.bandwidths, m, ()),
        seed_labels=seed_labels,
    )
    return labels, diag


def shift_training_loss(
    module: DynamicShift,
    centers: torch.Tensor,
    features: torch.Tensor,
    gt_centers: torch.Tensor,
    *,
    max_seeds: int = 10000,
    iteration_weights: Sequence[float] | None = None,
) -> torch.Tensor:
    """Stage-3 loss of one scan: FPS seeds of the things points, shift, eq. 4–5.

    Parameters
    ----------
    centers : torch.Tensor of shape (M, 3)
        Regressed centres of the ground-truth things points.
    features : torch.Tensor of shape (M, F)
    gt_centers : torch.Tensor of shape (M, 3)
        Ground-truth centre of each point's instance.

    Returns
    -------
    torch.Tensor, scalar (0 when the scan has no things points)
    """
    idx = select_seeds(centers.detach().cpu().numpy(), max_seeds)
    idx_t = torch.from_numpy(idx).to(centers.device)
    out = module(centers[idx_t], features[idx_t])
    return dynamic_shift_loss(out.positions[1:], gt_centers[idx_t], iteration_weights)


class DSNetHead:
    """Dynamic-shifting instance head over the backbone's per-point outputs.

    Parameters
    ----------
    module : DynamicShift
    thing_ids : sequence of int
        Semantic class ids that are things.
    clusterer : object with ``fit_predict``, optional
        Default :func:`default_clusterer` (SemanticKITTI); BFS(1.2) for nuScenes.
    max_seeds : int
    assign_by_xyz : bool
        See :func:`shift_instances`.
    """

    def __init__(
        self,
        module: DynamicShift,
        thing_ids: Sequence[int],
        *,
        clusterer: Clusterer | None = None,
        max_seeds: int = 10000,
        assign_by_xyz: bool = False,
    ) -> None:
        self.module = module
        self.thing_ids = tuple(int(t) for t in thing_ids)
        self.clusterer = clusterer
        self.max_seeds = max_seeds
        self.assign_by_xyz = assign_by_xyz

    def __call__(
        self,
        sem_logits: torch.Tensor,
        offsets: torch.Tensor,
        point_features: torch.Tensor,
        xyz: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, ShiftDiagnostics | None]:
        """Semantic prediction and instance ids of one scan.

        Parameters
        ----------
        sem_logits : (P, C) tensor; offsets : (P, 3) tensor; point_features : (P, F) tensor;
        xyz : (P, 3) array.

        Returns
        -------
        sem : np.ndarray of shape (P,), int64
            argmax of the logits.
        inst : np.ndarray of shape (P,), int64
            0 for stuff points (and noise), ``1..K`` for the instances of things points.
        diagnostics : ShiftDiagnostics or None
            None when the scan has no things point.
        """
        sem = sem_logits.argmax(1).cpu().numpy().astype(np.int64)
        inst = np.zeros(len(sem), dtype=np.int64)
        things = np.flatnonzero(np.isin(sem, self.thing_ids))
        if len(things) == 0:
            return sem, inst, None
        xyz = np.asarray(xyz, dtype=np.float64)
        centers = xyz[things] + offsets.detach().cpu().double().numpy()[things]
        labels, diag = shift_instances(
            self.module,
            centers,
            point_features[torch.from_numpy(things).to(point_features.device)],
            points=xyz[things],
            clusterer=self.clusterer,
            max_seeds=self.max_seeds,
            assign_by_xyz=self.assign_by_xyz,
        )
        valid = labels >= 0
        _, dense = np.unique(labels[valid], return_inverse=True)
        inst[things[valid]] = dense.reshape(-1) + 1
        return sem, inst, diag
