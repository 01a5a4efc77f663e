"""DS-Net prediction of one scan, and scoring a dataset with the metric core.

:class:`Predictor` turns one scan into semantic train ids and instance ids:

1. backbone → per-point logits, offsets, features; predicted class = argmax over the non-ignored
   classes; thing points = points of a predicted thing class;
2. regressed centres ``xyz + offset`` of the thing points are clustered by
   - the dynamic shifting module (DS-Net checkpoint, unless a clusterer is given): FPS seeds are
     shifted, the converged seeds clustered (``inference.ds_clusterer``), every thing point takes
     the instance of its nearest seed;
   - otherwise a heuristic clusterer (``inference.clusterer``, default mean shift 1.2), which
     receives exactly the same regressed centres;
3. consensus fusion (majority vote of the semantic class inside every instance), unless disabled.
   "Backbone with Fusion" = mean shift 1.2 + fusion.

``inference.tta_views`` > 1 replaces step 1's single pass by the test-time augmentation of
:mod:`panoptic_bench.dsnet.inference.tta` (averaged views of the scan); ``members`` (more
backbones) make step 1 the ensemble of :mod:`panoptic_bench.dsnet.inference.ensemble`;
``inference.bn_stats = "scan"`` runs step 1 with each scan's own BatchNorm statistics
(:mod:`panoptic_bench.dsnet.inference.scan_norm`); ``inference.orphans = "stuff"`` gives the thing
points left without an instance after step 3 their most probable stuff class.

With ``model.variant: official`` the rules of the official DS-Net code apply instead
(:mod:`panoptic_bench.dsnet.inference.official`): argmax over all classes, no instance size
filter, DS seeds by FPS on xyz and nearest seed by xyz.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from torch import nn

from panoptic_bench.dsnet import distributed as ddp
from panoptic_bench.dsnet.checkpoint import build_grid, is_official
from panoptic_bench.dsnet.config import DSNetConfig
from panoptic_bench.dsnet.data.datasets import ClassMap, LidarDataset, LidarSample
from panoptic_bench.dsnet.inference.clustering import make_clusterer
from panoptic_bench.dsnet.inference.ensemble import ensemble_forward
from panoptic_bench.dsnet.inference.scan_norm import scan_statistics
from panoptic_bench.dsnet.inference.tta import tta_forward
from panoptic_bench.dsnet.model.forward import backbone_forward
from panoptic_bench.dsnet.model.voxelize import CylinderGrid

__all__ = ["Predictor", "ScanPrediction", "evaluate_dataset"]


@dataclass
class ScanPrediction:
    """Prediction of one scan.

    Attributes
    ----------
    sem : ndarray of shape (n,), int64
        Train ids (after fusion when enabled).
    inst : ndarray of shape (n,), int64
        Instance ids (1..K on thing points, 0 elsewhere).
    sem_raw : ndarray of shape (n,), uint8
        Backbone semantic prediction before fusion.
    offsets : ndarray of shape (n, 3), float32
        Regressed offsets (centre = xyz + offset).
    features : ndarray of shape (n, F), float16 or None
        Backbone point features (kept only when asked for).
    shift : dict of str to ndarray, optional
        DS-Net diagnostics of :func:`panoptic_bench.dsnet.inference.clustering.ds_cluster` (seed indices
        into the predicted thing points, trajectories, weights, implied bandwidths).
    thing_ids : tuple of int
        Thing classes (the thing points are those with ``sem_raw`` in it).
    probs : ndarray of shape (n, C), float16 or None
        Class probabilities of the backbone (softmax over the non-ignored classes; the ignored
        ones get 0; kept only when asked for: the distillation targets of
        :mod:`panoptic_bench.dsnet.data.soft_labels`).
    """

    sem: np.ndarray
    inst: np.ndarray
    sem_raw: np.ndarray
    offsets: np.ndarray
    features: np.ndarray | None = None
    shift: dict[str, np.ndarray] | None = field(default=None)
    thing_ids: tuple[int, ...] = ()
    probs: np.ndarray | None = None


class Predictor:
    """Backbone (+ dynamic shifting) → panoptic prediction of one scan.

    Parameters
    ----------
    backbone : nn.Module
    shift : nn.Module or None
        Dynamic shifting module; used unless ``clusterer`` is given.
    cfg : DSNetConfig
    class_map : ClassMap
    device : torch.device
    clusterer : estimator with ``fit_predict``, optional
        Replaces dynamic shifting / the config's clusterer; receives the same regressed centres.
    fusion : bool, optional
        Consensus fusion (default ``cfg.inference.fusion``).
    semantic_only : bool
        Never predict instances (all 0, no fusion), as the official code does with a step-1
        (semantic) checkpoint, which has no trained offset head.
    keep_features : bool
        Return the point features (for the ``.npz`` exchange file).
    keep_probs : bool
        Return the class probabilities (``ScanPrediction.probs``).
    members : sequence of (nn.Module, CylinderGrid), optional
        More backbones (each with its grid) whose class probabilities and offsets are averaged
        with ``backbone``'s (an ensemble; dynamic shifting and point features stay ``backbone``'s).
    """

    def __init__(
        self,
        backbone: nn.Module,
        shift: nn.Module | None,
        cfg: DSNetConfig,
        class_map: ClassMap,
        device: torch.device | str = "cpu",
        clusterer: Any = None,
        fusion: bool | None = None,
        keep_features: bool = False,
        semantic_only: bool = False,
        members: tuple[tuple[nn.Module, CylinderGrid], ...] = (),
        keep_probs: bool = False,
    ) -> None:
        self.backbone = backbone
        self.members = tuple(members)
        self.shift = shift if clusterer is None else None
        self.cfg = cfg
        self.class_map = class_map
        self.device = torch.device(device)
        inf = cfg.inference
        self.clusterer = clusterer or make_clusterer(inf.clusterer, inf.bandwidth)
        self.fusion = inf.fusion if fusion is None else fusion
        self.keep_features = keep_features
        self.keep_probs = bool(keep_probs)
        self.semantic_only = bool(semantic_only)
        self.grid = build_grid(cfg)
        self._things = class_map.thing_lut()
        self._ignored = list(class_map.ignore_ids)
        self.official = is_official(cfg)

    @torch.no_grad()
    def predict(self, sample: LidarSample, panoptic: bool = True) -> ScanPrediction:
        """Predict one scan; ``panoptic=False`` skips clustering (instances all 0)."""
        from panoptic_bench.baselines.panoptic import assemble_panoptic

        self.backbone.eval()
        views = self.cfg.inference.tta_views
        models = (self.backbone, *(model for model, _ in self.members))
        with scan_statistics(*models, enabled=self.cfg.inference.bn_stats == "scan"):
            if self.members:
                for model, _ in self.members:
                    model.eval()
                members = ((self.backbone, self.grid), *self.members)
                out = ensemble_forward(members, sample, self.device, views)
            elif views > 1:
                out = tta_forward(self.backbone, sample, self.grid, self.device, views)
            else:
                out = backbone_forward(self.backbone, [sample], self.grid, self.device)
        logits = out.sem_logits
        if not self.official:  # the official code's argmax runs over every class
            logits = logits.clone()
            logits[:, self._ignored] = -torch.inf
        sem = logits.argmax(1).cpu().numpy().astype(np.int64)
        offsets = out.offsets.float().cpu().numpy()
        fused, inst, diag = sem, np.zeros(len(sem), dtype=np.int64), None
        panoptic = panoptic and not self.semantic_only
        if panoptic and self.shift is None:
            fused, inst = assemble_panoptic(
                sample.xyz,
                sem,
                offsets,
                self.clusterer,
                thing_ids=self.class_map.thing_ids,
                min_points=0 if self.official else self.cfg.inference.min_points,
                fusion=self.fusion,
                num_classes=self.class_map.num_classes,
            )
        elif panoptic:
            fused, inst, diag = self._dynamic_shift(sample, sem, offsets, out.point_features)
        if panoptic and self.cfg.inference.orphans == "stuff":
            fused = self._orphans_to_stuff(fused, inst, logits)
        feats = out.point_features.half().cpu().numpy() if self.keep_features else None
        probs = None
        if self.keep_probs:
            masked = out.sem_logits.float().clone()
            masked[:, self._ignored] = -torch.inf
            probs = torch.softmax(masked, dim=1).half().cpu().numpy()
        return ScanPrediction(
            np.asarray(fused, dtype=np.int64),
            np.asarray(inst, dtype=np.int64),
            sem.astype(np.uint8),
            offsets,
            feats,
            diag,
            self.class_map.thing_ids,
            probs,
        )

    def _orphans_to_stuff(self, sem, inst, logits):
        """Thing points without an instance take their best stuff class (``inference.orphans``)."""
        from panoptic_bench.baselines.panoptic import orphans_to_stuff

        sem, inst = np.asarray(sem), np.asarray(inst)
        orphans = np.flatnonzero(self._things[sem] & (inst == 0))
        rows = logits[torch.from_numpy(orphans).to(logits.device)].float().cpu().numpy()
        rows[:, self._ignored] = -np.inf
        return orphans_to_stuff(sem, inst, rows, self.class_map.thing_ids)

    def _dynamic_shift(self, sample, sem, offsets, features):
        """DS path: shift FPS seeds, cluster them, nearest seed → instance, then fusion."""
        from panoptic_bench.baselines.panoptic import consensus_fusion, filter_small_instances
        from panoptic_bench.dsnet.inference.clustering import ds_cluster

        inst = np.zeros(len(sem), dtype=np.int64)
        things = np.flatnonzero(self._things[sem])
        if not len(things):
            return sem, inst, None
        self.shift.eval()
        if self.official:
            return self._official_shift(sample, sem, offsets, features, things)
        labels, diag = ds_cluster(
            self.shift,
            points=sample.xyz[things],
            centers=sample.xyz[things] + offsets[things],
            features=features[torch.from_numpy(things).to(features.device)],
            cfg=self.cfg,
        )
        labels = np.asarray(labels, dtype=np.int64)
        valid = labels >= 0  # noise of a DBSCAN-like seed clusterer gets no instance
        _, dense = np.unique(labels[valid], return_inverse=True)
        inst[things[valid]] = filter_small_instances(
            dense.reshape(-1), self.cfg.inference.min_points
        )
        fused = consensus_fusion(sem, inst, self.class_map.num_classes) if self.fusion else sem
        return fused, inst, diag

    def _official_shift(self, sample, sem, offsets, features, things):
        """DS path by the official rules (:mod:`~panoptic_bench.dsnet.inference.official`)."""
        from panoptic_bench.baselines.panoptic import consensus_fusion
        from panoptic_bench.dsnet.inference.clustering import make_clusterer
        from panoptic_bench.dsnet.inference.official import official_shift_instances

        inf = self.cfg.inference
        labels, diag = official_shift_instances(
            self.shift,
            sample.xyz[things],
            sample.xyz[things] + offsets[things],
            features[torch.from_numpy(things).to(features.device)],
            make_clusterer(inf.ds_clusterer, inf.ds_bandwidth),
            self.cfg.dynamic_shift.max_seeds,
        )
        inst = np.zeros(len(sem), dtype=np.int64)
        inst[things] = np.maximum(labels, 0)
        fused = consensus_fusion(sem, inst, self.class_map.num_classes) if self.fusion else sem
        if diag:
            diag["candidates"] = np.asarray(self.cfg.dynamic_shift.bandwidths, dtype=np.float32)
        return fused, inst, diag or None


def evaluate_dataset(
    predictor: Predictor,
    dataset: LidarDataset,
    *,
    indices: list[int] | None = None,
    panoptic: bool = True,
    info: ddp.DistInfo | None = None,
    progress: bool = True,
) -> dict[str, float]:
    """Score ``predictor`` on ``dataset`` (the samples ``indices`` of this rank).

    Returns the headline numbers of :meth:`PanopticResult.summary` (fractions), summed over
    every rank when distributed.
    """
    from tqdm import tqdm

    from panoptic_bench.metrics.panoptic import panoptic_stats

    info = info or ddp.DistInfo()
    cmap = predictor.class_map
    indices = list(range(len(dataset))) if indices is None else indices
    stats = []
    for i in tqdm(indices, desc="validate", disable=not progress, leave=False):
        sample = dataset.load(i)
        pred = predictor.predict(sample, panoptic=panoptic)
        stats.append(
            panoptic_stats(
                pred.sem,
                pred.inst,
                sample.sem,
                sample.inst,
                num_classes=cmap.num_classes,
                ignore=cmap.ignore_ids,
                min_points=predictor.cfg.inference.min_points,
            )
        )
    total = ddp.reduce_sum(stats, info)
    if total is None:
        return {}
    return total.compute().summary(cmap.thing_ids, cmap.stuff_ids)
