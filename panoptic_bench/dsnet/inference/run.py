"""DS-Net inference on a split: load a checkpoint, predict every scan, write the result tree.

Written under ``PRED_ROOT``:

- SemanticKITTI roots: ``sequences/XX/predictions/NNNNNN.label`` (raw semantic id | instance
  id << 16), scorable by ``panoptic-bench eval semantickitti``; nuScenes roots:
  ``panoptic/<split>/<token>_panoptic.npz`` (the Panoptic nuScenes submission format);
- the regressed-centre exchange files of :mod:`panoptic_bench.baselines.centers`
  (``sequences/XX/centers/NNNNNN.npz`` or ``centers/<token>.npz``: ``sem`` uint8 N, ``offset``
  float32 N×3, optional ``features``), so any clusterer can be fed exactly these centres;
- with ``save_probs``: the class probabilities of every point (``sequences/XX/probs/NNNNNN.npy``
  or ``probs/<token>.npy``, float16 N×C), the distillation targets of
  :mod:`panoptic_bench.dsnet.data.soft_labels`;
- for DS-Net checkpoints (unless ``clusterer`` is given): ``sequences/XX/dynamic_shift/
  NNNNNN.npz`` (nuScenes: ``dynamic_shift/<token>.npz``) with ``seed_index`` (M,), per-seed
  ``weights`` (I, M, l), implied ``bandwidth`` (I, M) = sum_j W_j delta_j, ``trajectory``
  (I + 1, M, 3) and the candidate ``bandwidths`` (l,);
- ``run.json`` (method, dataset, data, notes, command) and ``timing.json`` (ms per frame).

Example
-------
>>> run_inference("dsnet_synthetic.pt", "data/synth", "valid", "preds/dsnet")  # doctest: +SKIP
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from panoptic_bench.dsnet.checkpoint import (
    Checkpoint,
    build_backbone,
    build_grid,
    build_shift,
    is_official,
    load_checkpoint,
    load_weights,
)
from panoptic_bench.dsnet.config import BN_STATS, ORPHANS, Clusterer, DatasetFormat, DSNetConfig
from panoptic_bench.dsnet.data.datasets import LidarDataset, NuScenesDataset, SemanticKittiDataset
from panoptic_bench.dsnet.data.density import with_density_policy
from panoptic_bench.dsnet.data.soft_labels import soft_label_path, write_soft_labels
from panoptic_bench.dsnet.inference.clustering import make_clusterer
from panoptic_bench.dsnet.inference.predictor import Predictor, ScanPrediction
from panoptic_bench.errors import InputError
from panoptic_bench.io import ensure_output_dir, write_json, write_npz

__all__ = [
    "InferenceSummary",
    "check_fits",
    "load_predictor",
    "open_split",
    "root_format",
    "run_inference",
]


@dataclass
class InferenceSummary:
    """What :func:`run_inference` did: scans written, mean ms/frame, method label."""

    out: Path
    num_scans: int
    ms_per_frame: float
    method: str


def load_predictor(
    checkpoint: str | Path | Checkpoint,
    *,
    clusterer: Clusterer | None = None,
    bandwidth: float | None = None,
    fusion: bool | None = None,
    device: str = "cpu",
    keep_features: bool = False,
    tta_views: int | None = None,
    bn_stats: str | None = None,
    orphans: str | None = None,
    ensemble: tuple[str | Path, ...] = (),
    keep_probs: bool = False,
) -> tuple[Predictor, Checkpoint]:
    """Build a :class:`Predictor` from a checkpoint.

    Parameters
    ----------
    clusterer : Clusterer, optional
        Heuristic clustering instead of dynamic shifting (or instead of the config's clusterer
        for a backbone checkpoint). ``bandwidth`` defaults to the config's (mean shift 1.2).
    fusion : bool, optional
        Consensus fusion on/off (default: config).
    tta_views : int, optional
        Test-time augmentation views (default: config ``inference.tta_views``).
    bn_stats : {"running", "scan"}, optional
        BatchNorm statistics at test time (default: config ``inference.bn_stats``;
        :mod:`~panoptic_bench.dsnet.inference.scan_norm`).
    orphans : {"keep", "stuff"}, optional
        Fate of thing points left without an instance (default: config ``inference.orphans``).
    ensemble : tuple of paths, optional
        More checkpoints averaged with this one (:mod:`~panoptic_bench.dsnet.inference.ensemble`);
        each must predict the same classes and have a trained offset head.
    keep_probs : bool
        Keep every point's class probabilities (``ScanPrediction.probs``).
    """
    import dataclasses

    import torch

    ckpt = checkpoint if isinstance(checkpoint, Checkpoint) else load_checkpoint(checkpoint)
    cfg = ckpt.config
    if tta_views is not None:
        if not 1 <= tta_views <= 16:
            raise InputError(f"tta_views must be in 1..16, got {tta_views}")
        inf = dataclasses.replace(cfg.inference, tta_views=int(tta_views))
        cfg = dataclasses.replace(cfg, inference=inf)
    for key, value, allowed in (("bn_stats", bn_stats, BN_STATS), ("orphans", orphans, ORPHANS)):
        if value is None:
            continue
        if value not in allowed:
            raise InputError(f"{key} must be one of {', '.join(allowed)}, got {value!r}")
        cfg = dataclasses.replace(cfg, inference=dataclasses.replace(cfg.inference, **{key: value}))
    backbone = build_backbone(cfg, ckpt.class_map.num_classes)
    load_weights(backbone, ckpt.backbone, ckpt.path, "backbone")
    backbone.to(device).eval()
    shift = None
    if ckpt.shift is not None:
        shift = build_shift(cfg, cfg.model.init_size)
        load_weights(shift, ckpt.shift, ckpt.path, "dynamic shifting")
        shift.to(device).eval()
    members = tuple(_load_member(ckpt, path, device) for path in ensemble)
    est = None
    if clusterer is not None or bandwidth is not None:
        kind = clusterer or cfg.inference.clusterer
        est = make_clusterer(kind, cfg.inference.bandwidth if bandwidth is None else bandwidth)
    pred = Predictor(
        backbone,
        shift,
        cfg,
        ckpt.class_map,
        torch.device(device),
        clusterer=est,
        fusion=fusion,
        keep_features=keep_features,
        semantic_only=is_official(cfg) and ckpt.stage == "semantic" and est is None,
        members=members,
        keep_probs=keep_probs,
    )
    return with_density_policy(pred), ckpt


def _load_member(primary: Checkpoint, path: str | Path, device: str):
    """(backbone in eval mode, its grid) of one ensemble member, checked against ``primary``."""
    from panoptic_bench.dsnet.inference.ensemble import check_member

    member = load_checkpoint(path)
    check_member(primary, member, path)
    model = build_backbone(member.config, member.class_map.num_classes)
    load_weights(model, member.backbone, member.path, "backbone")
    return model.to(device).eval(), build_grid(member.config)


def root_format(root: str | Path) -> DatasetFormat | None:
    """SemanticKITTI (``sequences/``) or nuScenes (``v1.0-*/`` or ``samples/``) root, or None."""
    root = Path(root)
    if (root / "sequences").is_dir():
        return DatasetFormat.SEMANTICKITTI
    if (root / "samples").is_dir() or any(root.glob("v1.0-*")):
        return DatasetFormat.NUSCENES
    return None


def check_fits(ckpt: Checkpoint, root: str | Path) -> None:
    """A checkpoint's class map must fit the data root's dataset.

    Raises
    ------
    InputError
        E.g. a nuScenes model on a SemanticKITTI root, naming both.
    """
    kind = root_format(root)
    want = ckpt.config.data.format
    if kind is not None and kind is not want:
        cmap = ckpt.class_map
        raise InputError(
            f"checkpoint {ckpt.path} is a {cmap.dataset} model ({cmap.num_classes} classes) "
            f"but {root} is a {kind.value} root; its class map does not fit: use a "
            f"{kind.value} checkpoint",
            root,
        )


def open_split(
    cfg: DSNetConfig, root: str | Path, split: str, max_samples: int = 0
) -> LidarDataset:
    """The dataset of ``root`` for ``split``: a SemanticKITTI split name or sequence list
    (``08`` or ``00,01``), or a nuScenes split name."""
    if cfg.data.format is DatasetFormat.NUSCENES:
        return NuScenesDataset(root, split, cfg.data.nuscenes_version, max_samples)
    seqs = [s for s in split.split(",") if s] if split[:1].isdigit() else None
    return SemanticKittiDataset(root, None if seqs else split, seqs, max_samples)


def method_label(pred: Predictor, ckpt: Checkpoint, clusterer: Clusterer | None) -> str:
    """Row label: ``DS-Net``, ``Backbone with Fusion``, ``Backbone`` or ``Backbone + <clusterer>``."""
    if pred.shift is not None:
        return "DS-Net" if pred.fusion else "DS-Net (no fusion)"
    if clusterer is None or clusterer is Clusterer.MEANSHIFT:
        base = "Backbone with Fusion" if pred.fusion else "Backbone"
        return base if clusterer is None else f"{base} (mean shift {pred.clusterer.bandwidth})"
    return f"Backbone + {clusterer.value}" + ("" if pred.fusion else " (no fusion)")


def run_inference(
    checkpoint: str | Path,
    data_root: str | Path,
    split: str,
    out: str | Path,
    *,
    clusterer: Clusterer | None = None,
    bandwidth: float | None = None,
    fusion: bool | None = None,
    save_features: bool = False,
    save_probs: bool = False,
    tta_views: int | None = None,
    bn_stats: str | None = None,
    orphans: str | None = None,
    ensemble: tuple[str | Path, ...] = (),
    max_samples: int = 0,
    overwrite: bool = True,
    device: str = "cpu",
    progress: bool = True,
    command: str | None = None,
) -> InferenceSummary:
    """Predict ``split`` of ``data_root`` with a checkpoint and write the prediction tree.

    ``checkpoint`` may be an ensemble file (:mod:`~panoptic_bench.dsnet.inference.ensemble_file`):
    its members and views, with ``ensemble`` appended and ``tta_views`` overriding its views.
    ``command`` (the shell command line, if any) is recorded in ``run.json``.

    Returns
    -------
    InferenceSummary
    """
    from tqdm import tqdm

    from panoptic_bench.dsnet.inference.ensemble_file import expand_ensemble_file

    checkpoint, ensemble, tta_views, spec = expand_ensemble_file(checkpoint, ensemble, tta_views)
    pred, ckpt = load_predictor(
        checkpoint,
        clusterer=clusterer,
        bandwidth=bandwidth,
        fusion=fusion,
        device=device,
        keep_features=save_features,
        tta_views=tta_views,
        bn_stats=bn_stats,
        orphans=orphans,
        ensemble=tuple(ensemble),
        keep_probs=save_probs,
    )
    check_fits(ckpt, data_root)
    dataset = open_split(ckpt.config, data_root, split, max_samples)
    if len(dataset) == 0:
        raise InputError(f"no scans in split {split!r}", data_root)
    out = ensure_output_dir(out, overwrite=overwrite, inputs=(data_root,))
    nus = ckpt.config.data.format is DatasetFormat.NUSCENES
    pred.predict(dataset.load(0))  # warm-up (lazy imports, allocator), not timed
    times = []
    for i in tqdm(range(len(dataset)), desc="infer", disable=not progress):
        sample = dataset.load(i)
        t0 = time.perf_counter()
        p = pred.predict(sample)
        times.append(time.perf_counter() - t0)
        _write_scan(out, sample.key, p, split, nus)
        if save_probs:
            write_soft_labels(soft_label_path(out, sample.key), p.probs)
        if p.shift is not None and not (out / "shift_iterations.npz").exists():
            _write_fig6(out, sample, p)
    ms = 1000.0 * float(np.mean(times))
    method = method_label(pred, ckpt, clusterer)
    if ensemble:
        method += f" (ensemble of {1 + len(ensemble)})"
    write_json(out / "timing.json", {"scans": len(times), "ms_per_frame": ms, "device": device})
    from panoptic_bench.reports.inputs import write_run_meta

    meta = _run_meta(method, pred, ckpt, data_root, split, len(times), ms)
    if ensemble:
        meta["notes"] += f"; averaged with {', '.join(map(str, ensemble))} (ensemble)"
    if spec is not None:
        meta["notes"] += f"; from the ensemble file {spec.path} ({spec.tta_views} views each)"
    if command:
        meta["command"] = command
    write_run_meta(out, meta)
    return InferenceSummary(out, len(times), ms, method)


def _write_scan(out: Path, key: tuple[str, ...], p: ScanPrediction, split: str, nus: bool) -> None:
    from panoptic_bench.baselines import centers as bc
    from panoptic_bench.baselines import panoptic as bp

    if nus:
        token = key[0]
        panoptic = bp.nuscenes_panoptic(p.sem, p.inst)
        write_npz(out / "panoptic" / split / f"{token}_panoptic.npz", data=panoptic)
        centers = bc.centers_path_nuscenes(out, token)
        ds_path = out / "dynamic_shift" / f"{token}.npz"
    else:
        from panoptic_bench.datasets.semantickitti import write_labels

        seq, frame = key
        label = bp.semantickitti_label(p.sem, p.inst)
        write_labels(out / "sequences" / seq / "predictions" / f"{frame}.label", label)
        centers = bc.centers_path_semantickitti(out, seq, frame)
        ds_path = out / "sequences" / seq / "dynamic_shift" / f"{frame}.npz"
    bc.write_centers(centers, p.sem_raw, p.offsets, features=p.features, source="DS-Net backbone")
    if p.shift is not None:
        write_npz(ds_path, **p.shift)


def _write_fig6(out: Path, sample, p: ScanPrediction) -> None:
    """``shift_iterations.npz`` (report Fig. 6) from the first DS-Net scan.

    Panel k shows the seeds after k iterations (panel 0 = regressed centres) coloured by the
    bandwidth they use in the next iteration (the last panel repeats the last iteration's).
    """
    from panoptic_bench.reports.inputs import write_shift_iterations

    bw = p.shift["bandwidths"]
    if bw.size == 0:
        return
    panels = np.concatenate([bw, bw[-1:]], axis=0)
    things = np.isin(p.sem_raw, np.asarray(p.thing_ids))
    write_shift_iterations(out, sample.xyz[things], p.shift["positions"], panels)


CLUSTER_BARS = {
    Clusterer.MEANSHIFT: "Mean Shift",
    Clusterer.BFS: "BFS",
    Clusterer.DBSCAN: "DBSCAN",
    Clusterer.HDBSCAN: "HDBSCAN",
}


def ablation_tags(pred: Predictor, cfg: DSNetConfig) -> dict[str, str]:
    """``run.json`` ablation bars (Fig. 4a/4b/4c) this prediction stands for."""
    from panoptic_bench.dsnet.config import ShiftKernel

    if pred.shift is not None:
        tags = {"clustering": "DS"} if pred.fusion else {}
        tags["framework"] = "+ DS" if pred.fusion else "+ DS (no fusion)"
        flat = cfg.dynamic_shift.kernel is ShiftKernel.FLAT
        tags["bandwidth_learning"] = "weighted candidates" if flat else "direct regression"
        return tags
    kind = next((k for k, v in _kinds().items() if isinstance(pred.clusterer, v)), None)
    if not pred.fusion:
        return {"framework": "backbone"} if kind is Clusterer.MEANSHIFT else {}
    tags = {"clustering": CLUSTER_BARS[kind]} if kind is not None else {}
    if kind is Clusterer.MEANSHIFT and pred.clusterer.bandwidth == cfg.inference.bandwidth:
        tags["framework"] = "+ fusion"
    return tags


def _kinds() -> dict[Clusterer, type]:
    from panoptic_bench.baselines import clustering
    from panoptic_bench.baselines.meanshift import MeanShift

    return {
        Clusterer.MEANSHIFT: MeanShift,
        Clusterer.BFS: clustering.BFS,
        Clusterer.DBSCAN: clustering.DBSCAN,
        Clusterer.HDBSCAN: clustering.HDBSCAN,
    }


def _run_meta(
    method: str,
    pred: Predictor,
    ckpt: Checkpoint,
    data_root: str | Path,
    split: str,
    n: int,
    ms: float,
) -> dict[str, Any]:
    meta: dict[str, Any] = {
        "method": method,
        "dataset": ckpt.class_map.dataset,
        "split": split,
        "data": f"{data_root} split {split} ({n} scans)",
        "notes": f"checkpoint {ckpt.path} (stage {ckpt.stage}, epoch {ckpt.epoch}); {ms:.0f} ms/frame",
        "ablation": ablation_tags(pred, ckpt.config),
    }
    if pred.shift is not None:
        ds = ckpt.config.dynamic_shift
        meta["bandwidths"] = list(ds.bandwidths)
        meta["iterations"] = ds.iterations
    return meta
