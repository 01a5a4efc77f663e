"""Dynamic shifting (paper §3.2, Algorithm 1, appendix §2–4): functional ops and the module.

Seeds are the farthest-point sample of the things points' regressed centres (at most
``max_seeds``). In iteration i the seeds' features give weights ``W_i = softmax(MLP_i(F))`` over
the l bandwidth candidates; each candidate δ_j is a flat kernel (mean of the seeds within δ_j,
self included) and the seeds move to ``X ← Σ_j W_i[:, j] · mean_j(X)``. The kernel targets are
constants (appendix eq. 13–17): the gradient reaches the MLPs through the weights only. The
neighbour sums are exact and never build an M × M matrix (:mod:`.shift_ops`).

The "direct regression" ablation (Fig. 4c, appendix eq. 19) is the same module with
``kernel=ShiftKernel.GAUSSIAN``: each MLP_i regresses one bandwidth per seed in
``[min(bandwidths), max(bandwidths)]`` for a Gaussian kernel truncated at ``gaussian_cutoff · δ``.

Example
-------
>>> module = DynamicShift(feature_dim=16)
>>> out = module(torch.randn(100, 3), torch.randn(100, 16))
>>> len(out.positions), out.weights[0].shape, out.bandwidths[0].shape
(5, torch.Size([100, 3]), torch.Size([100]))
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import fpsample
import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import nn

from panoptic_bench.dsnet.config import ShiftKernel
from panoptic_bench.dsnet.model.shift_ops import flat_kernel_means, gaussian_kernel_means

PAPER_BANDWIDTHS: tuple[float, ...] = (0.2, 1.7, 3.2)


class Clusterer(Protocol):
    """Anything with scikit-learn's ``fit_predict(X) -> labels`` (MeanShift, BFS, DBSCAN...)."""

    def fit_predict(self, X: np.ndarray) -> np.ndarray: ...


@dataclass
class DynamicShiftOutput:
    """Per-iteration trace of dynamic shifting (for the loss and for Figs. 5–7).

    Attributes
    ----------
    positions : list of torch.Tensor of shape (M', 3)
        ``I + 1`` entries: the initial seeds, then the seeds after every iteration.
    weights : list of torch.Tensor of shape (M', l)
        Softmax weights of every iteration (``I`` entries); empty for the Gaussian kernel.
    bandwidths : list of torch.Tensor of shape (M',)
        Implied bandwidth ``Σ_j W_j δ_j`` (flat) or the regressed bandwidth (Gaussian).
    """

    positions: list[torch.Tensor]
    weights: list[torch.Tensor]
    bandwidths: list[torch.Tensor]

    @property
    def final(self) -> torch.Tensor:
        """Converged seeds, shape (M', 3)."""
        return self.positions[-1]


def select_seeds(centers: np.ndarray, max_seeds: int = 10000) -> np.ndarray:
    """Farthest point sampling of regressed centres (Algorithm 1, line 1), deterministic.

    Parameters
    ----------
    centers : np.ndarray of shape (M, 3), float
    max_seeds : int
        Every point is a seed when ``M <= max_seeds``; otherwise the FPS starts at index 0.

    Returns
    -------
    np.ndarray of shape (min(M, max_seeds),), int64
        Distinct sorted indices into ``centers`` (duplicate positions fill up the count when
        there are fewer distinct positions than seeds).
    """
    m = len(centers)
    if m <= max_seeds:
        return np.arange(m, dtype=np.int64)
    pts = np.ascontiguousarray(centers, dtype=np.float32)
    height = max(1, min(7, int(np.log2(m))))  # bucket size 2**h must not exceed M
    idx = fpsample.bucket_fps_kdline_sampling(pts, max_seeds, h=height, start_idx=0)
    idx = np.unique(idx.astype(np.int64))
    if len(idx) < max_seeds:  # fewer distinct positions than seeds: FPS repeats an index
        rest = np.setdiff1d(np.arange(m, dtype=np.int64), idx)[: max_seeds - len(idx)]
        idx = np.sort(np.concatenate([idx, rest]))
    return idx


def flat_shift_step(
    positions: torch.Tensor, weights: torch.Tensor, bandwidths: Sequence[float]
) -> torch.Tensor:
    """One dynamic-shifting iteration with flat kernels (paper eq. 3).

    Parameters
    ----------
    positions : torch.Tensor of shape (M, 3), float
        Seeds X (treated as constants: the kernel targets carry no gradient).
    weights : torch.Tensor of shape (M, l), float
        Candidate weights (rows sum to 1); the gradient flows into them (eq. 16).
    bandwidths : sequence of float, length l

    Returns
    -------
    torch.Tensor of shape (M, 3)
        ``Σ_j weights[:, j] · mean_j(X)``.
    """
    targets = flat_kernel_means(positions.detach().cpu().numpy(), tuple(bandwidths))
    targets_t = torch.from_numpy(targets).to(device=weights.device, dtype=weights.dtype)
    return (weights.unsqueeze(-1) * targets_t).sum(dim=1)


def dynamic_shift_loss(
    positions: Sequence[torch.Tensor],
    gt_centers: torch.Tensor,
    iteration_weights: Sequence[float] | None = None,
) -> torch.Tensor:
    """Dynamic-shifting loss ``Σ_i w_i (1/M') Σ_x ‖X_i[x] − C'_gt[x]‖₁`` (paper eq. 4–5).

    Parameters
    ----------
    positions : sequence of torch.Tensor of shape (M', 3)
        Seeds after each iteration, ``X_1 ... X_I`` (not the initial seeds).
    gt_centers : torch.Tensor of shape (M', 3)
        Ground-truth centre of each seed's instance.
    iteration_weights : sequence of float, optional
        ``w_i``; all 1 by default (paper).

    Returns
    -------
    torch.Tensor, scalar
        0 (still differentiable) when there are no seeds.
    """
    weights = [1.0] * len(positions) if iteration_weights is None else list(iteration_weights)
    if len(weights) != len(positions):
        raise ValueError(f"{len(weights)} iteration weights for {len(positions)} iterations")
    denom = max(len(gt_centers), 1)
    total = gt_centers.new_zeros(())
    for w, x in zip(weights, positions):
        total = total + w * (x - gt_centers).abs().sum() / denom
    return total


def cluster_seeds(positions: np.ndarray, clusterer: Clusterer) -> np.ndarray:
    """Instance label of every converged seed (Algorithm 1, line 13).

    Returns
    -------
    np.ndarray of shape (M',), int64
        The clusterer's labels (−1 = noise for DBSCAN-like clusterers).
    """
    if len(positions) == 0:
        return np.zeros(0, dtype=np.int64)
    if len(positions) == 1:
        return np.zeros(1, dtype=np.int64)
    return np.asarray(clusterer.fit_predict(np.asarray(positions, dtype=np.float64)), np.int64)


def assign_to_seeds(
    points: np.ndarray, seed_points: np.ndarray, seed_labels: np.ndarray
) -> np.ndarray:
    """Every point takes the label of its nearest seed (Algorithm 1, lines 14–15).

    Parameters
    ----------
    points : np.ndarray of shape (M, 3)
    seed_points : np.ndarray of shape (M', 3)
        In the same space as ``points``.
    seed_labels : np.ndarray of shape (M',), int

    Returns
    -------
    np.ndarray of shape (M,), int64
    """
    if len(points) == 0 or len(seed_points) == 0:
        return np.full(len(points), -1, dtype=np.int64)
    _, nearest = cKDTree(np.asarray(seed_points, np.float64)).query(np.asarray(points, np.float64))
    return np.asarray(seed_labels, dtype=np.int64)[nearest]


def _mlp(feature_dim: int, hidden: int, out: int, batch_norm: bool) -> nn.Sequential:
    if batch_norm:  # official: Linear -> BatchNorm1d -> ReLU -> Linear (keys 0, 1, 3)
        return nn.Sequential(
            nn.Linear(feature_dim, hidden),
            nn.BatchNorm1d(hidden),
            nn.ReLU(),
            nn.Linear(hidden, out),
        )
    return nn.Sequential(nn.Linear(feature_dim, hidden), nn.ReLU(), nn.Linear(hidden, out))


class DynamicShift(nn.Module):
    """Learnable dynamic shifting of seeds (paper §3.2).

    Parameters
    ----------
    feature_dim : int
        Width of the backbone features of the seeds.
    bandwidths : tuple of float
        Bandwidth candidates δ_j in metres (Table 4).
    iterations : int
        Number of shifting iterations I (Table 5).
    hidden : int
        Hidden width of each per-iteration MLP.
    kernel : ShiftKernel or str
        ``FLAT``: weighting of flat-kernel candidates (paper); ``GAUSSIAN``: direct regression of
        one bandwidth per seed in ``[min(bandwidths), max(bandwidths)]`` (ablation, eq. 19).
    gaussian_cutoff : float
        Gaussian kernel truncation radius in units of each seed's bandwidth.
    batch_norm : bool
        BatchNorm1d after the hidden Linear of each MLP (the official DS-Net, with
        ``hidden = feature_dim = 32``); False: Linear -> ReLU -> Linear.
    """

    def __init__(
        self,
        feature_dim: int,
        bandwidths: tuple[float, ...] = PAPER_BANDWIDTHS,
        iterations: int = 4,
        hidden: int = 64,
        kernel: ShiftKernel | str = ShiftKernel.FLAT,
        gaussian_cutoff: float = 3.0,
        batch_norm: bool = False,
    ) -> None:
        super().__init__()
        if not bandwidths or min(bandwidths) <= 0:
            raise ValueError(f"bandwidths must be positive, got {bandwidths}")
        if iterations < 1:
            raise ValueError(f"iterations must be >= 1, got {iterations}")
        self.feature_dim = int(feature_dim)
        self.bandwidths = tuple(float(b) for b in bandwidths)
        self.iterations = int(iterations)
        self.hidden = int(hidden)
        self.kernel = ShiftKernel(kernel)
        self.gaussian_cutoff = float(gaussian_cutoff)
        n_out = len(self.bandwidths) if self.kernel is ShiftKernel.FLAT else 1
        self.batch_norm = bool(batch_norm)
        self.mlps = nn.ModuleList(
            _mlp(feature_dim, hidden, n_out, self.batch_norm) for _ in range(iterations)
        )
        self.register_buffer("delta", torch.tensor(self.bandwidths), persistent=False)

    def extra_repr(self) -> str:
        return (
            f"feature_dim={self.feature_dim}, bandwidths={self.bandwidths}, "
            f"iterations={self.iterations}, hidden={self.hidden}, kernel={self.kernel.value}, "
            f"batch_norm={self.batch_norm}"
        )

    def regressed_bandwidth(self, logits: torch.Tensor) -> torch.Tensor:
        """Gaussian ablation: map MLP outputs (M', 1) into ``[min δ, max δ]``; shape (M',)."""
        lo, hi = min(self.bandwidths), max(self.bandwidths)
        return lo + (hi - lo) * torch.sigmoid(logits[:, 0])

    def forward(self, positions: torch.Tensor, features: torch.Tensor) -> DynamicShiftOutput:
        """Shift the seeds ``iterations`` times.

        Parameters
        ----------
        positions : torch.Tensor of shape (M', 3), float
            Seeds' regressed centres.
        features : torch.Tensor of shape (M', feature_dim), float
            Seeds' backbone features.

        Returns
        -------
        DynamicShiftOutput
        """
        if positions.ndim != 2 or positions.shape[1] != 3 or len(features) != len(positions):
            raise ValueError(
                f"need positions (M, 3) and features (M, F), got {tuple(positions.shape)} "
                f"and {tuple(features.shape)}"
            )
        x = positions.to(features.dtype)
        out = DynamicShiftOutput(positions=[x], weights=[], bandwidths=[])
        delta = self.delta.to(features.dtype)
        for mlp in self.mlps:
            logits = mlp(features)
            if self.kernel is ShiftKernel.FLAT:
                w = torch.softmax(logits, dim=1)
                x = flat_shift_step(x, w, self.bandwidths)
                out.weights.append(w)
                out.bandwidths.append(w @ delta)
            else:
                bw = self.regressed_bandwidth(logits)
                x = gaussian_kernel_means(x, bw, self.gaussian_cutoff)
                out.bandwidths.append(bw)
            out.positions.append(x)
        return out
