"""Writers for the optional report inputs of a run directory, and the two statistics they hold.

Upstream code (``train``, ``infer``, ``cluster``) calls these to leave figure inputs next to
``scores.json`` in exactly the format :func:`panoptic_bench.reports.index.build_report` reads:
``run.json`` (:func:`write_run_meta`), ``analysis.json`` (:func:`write_analysis`),
``shift_iterations.npz`` (:func:`write_shift_iterations`) and ``bev.npz`` (:func:`write_bev`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from panoptic_bench.io import write_json, write_npz
from panoptic_bench.reports.index import ANALYSIS_FILE, ANALYSIS_KEYS, BEV_FILE, SHIFT_FILE
from panoptic_bench.reports.runs import RUN_FILE, RunMeta


def write_run_meta(run_dir: str | Path, meta: RunMeta | Mapping) -> Path:
    """Validate ``meta`` (a RunMeta or its dict form) and write ``run_dir/run.json``."""
    meta = meta if isinstance(meta, RunMeta) else RunMeta.from_dict(meta)
    path = Path(run_dir) / RUN_FILE
    write_json(path, meta.to_dict())
    return path


def _jsonable(obj):
    if isinstance(obj, Mapping):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, np.ndarray | list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def write_analysis(run_dir: str | Path, **sections: Mapping) -> Path:
    """Write ``run_dir/analysis.json`` from the sections named in ``index`` (arrays allowed).

    Parameters
    ----------
    **sections
        Any of ``centres_per_voxel={"distance_m", "counts"}``,
        ``bandwidth_rq={"bandwidth_m", "rq"}``, ``learned_bandwidth={"size_m", "bandwidth_m"}``,
        ``bandwidth_per_iteration={"bandwidth_m", "lower_limit"}``; numpy arrays become lists.
    """
    unknown = sorted(set(sections) - set(ANALYSIS_KEYS))
    if unknown:
        raise ValueError(f"unknown analysis section(s) {unknown}; allowed: {list(ANALYSIS_KEYS)}")
    path = Path(run_dir) / ANALYSIS_FILE
    write_json(path, _jsonable(sections))
    return path


def write_shift_iterations(
    run_dir: str | Path,
    points: np.ndarray,
    seeds: np.ndarray | Sequence[np.ndarray],
    bandwidths: np.ndarray | Sequence[np.ndarray],
) -> Path:
    """Write ``run_dir/shift_iterations.npz`` for Fig. 6.

    Parameters
    ----------
    points : array of shape (n_points, >=2), float
    seeds : array of shape (n_panels, n_seeds, >=2), float
    bandwidths : array of shape (n_panels, n_seeds), float (m)
    """
    seeds = np.asarray(seeds, dtype=np.float32)
    bandwidths = np.asarray(bandwidths, dtype=np.float32)
    if seeds.ndim != 3 or bandwidths.shape != seeds.shape[:2]:
        raise ValueError(f"seeds {seeds.shape} and bandwidths {bandwidths.shape} do not match")
    path = Path(run_dir) / SHIFT_FILE
    write_npz(path, points=np.asarray(points, np.float32), seeds=seeds, bandwidths=bandwidths)
    return path


def write_bev(
    run_dir: str | Path,
    xyz: np.ndarray,
    pred_sem: np.ndarray,
    pred_inst: np.ndarray,
    gt_sem: np.ndarray,
    gt_inst: np.ndarray,
    thing_classes: Sequence[int],
) -> Path:
    """Write ``run_dir/bev.npz`` (one scan) for the bird's-eye panoptic figure.

    Parameters
    ----------
    xyz : array of shape (n_points, >=2), float
    pred_sem, pred_inst, gt_sem, gt_inst : arrays of shape (n_points,), integer
        Learning ids and instance ids (0 = none).
    thing_classes : sequence of int
        Learning ids of the things classes.
    """
    n = len(xyz)
    arrays = {"pred_sem": pred_sem, "pred_inst": pred_inst, "gt_sem": gt_sem, "gt_inst": gt_inst}
    arrays = {k: np.asarray(v).astype(np.int32) for k, v in arrays.items()}
    bad = {k: v.shape for k, v in arrays.items() if v.shape != (n,)}
    if bad:
        raise ValueError(f"label arrays must have shape ({n},), got {bad}")
    path = Path(run_dir) / BEV_FILE
    write_npz(
        path,
        xyz=np.asarray(xyz, dtype=np.float32)[:, :3],
        thing_classes=np.asarray(list(thing_classes), dtype=np.int32),
        **arrays,
    )
    return path


def learned_bandwidth(weights: np.ndarray, candidates: Sequence[float]) -> np.ndarray:
    """Per-seed learned bandwidth: candidates averaged with the learned weights (paper Sec. 4.4).

    Parameters
    ----------
    weights : array of shape (..., n_candidates), float
        Softmax weights of the dynamic shifting module (rows sum to 1).
    candidates : sequence of float, length n_candidates
        Bandwidth candidates in metres.

    Returns
    -------
    numpy.ndarray of shape (...,), float64
    """
    w = np.asarray(weights, dtype=np.float64)
    c = np.asarray(candidates, dtype=np.float64)
    if w.shape[-1] != c.size:
        raise ValueError(f"{w.shape[-1]} weights per seed for {c.size} candidates")
    return w @ c


def centres_per_voxel_by_distance(
    centres: np.ndarray,
    instance: np.ndarray,
    distance: np.ndarray,
    edges: Sequence[float],
    *,
    voxel_size: float = 0.2,
) -> np.ndarray:
    """Fig. 3a statistic: mean number of regressed centres per valid voxel, per distance bin.

    Each instance's regressed centres are binned into a Cartesian grid of ``voxel_size``; a
    voxel is valid when it holds at least one centre. For each distance bin the result is
    (centres of instances in the bin) / (valid voxels of instances in the bin). Low values mean
    sparse, spread-out centres (far instances in the paper).

    Parameters
    ----------
    centres : array of shape (n_points, 3), float
        Regressed centres (point + predicted offset) of things points.
    instance : array of shape (n_points,), integer
        Ground-truth instance id per point (instances must be unique across classes; 0 ignored).
    distance : array of shape (n_points,), float
        Distance of each point's instance to the sensor (m); an instance's distance is taken as
        the mean over its points.
    edges : sequence of float, length n_bins + 1
        Distance bin edges in metres, increasing.
    voxel_size : float
        Voxel edge length in metres.

    Returns
    -------
    numpy.ndarray of shape (n_bins,), float64
        NaN where a bin holds no instance.
    """
    centres = np.asarray(centres, dtype=np.float64)
    inst = np.asarray(instance).astype(np.int64)
    dist = np.asarray(distance, dtype=np.float64)
    edges = np.asarray(edges, dtype=np.float64)
    keep = inst != 0
    centres, inst, dist = centres[keep], inst[keep], dist[keep]
    ids, inverse, counts = np.unique(inst, return_inverse=True, return_counts=True)
    inst_dist = np.bincount(inverse, weights=dist, minlength=ids.size) / np.maximum(counts, 1)
    cells = np.floor(centres / voxel_size).astype(np.int64)
    keys = np.concatenate([inverse[:, None], cells], axis=1)
    voxel_inst = np.unique(keys, axis=0)[:, 0]
    voxels = np.bincount(voxel_inst, minlength=ids.size)
    bins = np.digitize(inst_dist, edges) - 1
    n_bins = edges.size - 1
    ok = (bins >= 0) & (bins < n_bins)
    pts = np.bincount(bins[ok], weights=counts[ok], minlength=n_bins)
    vox = np.bincount(bins[ok], weights=voxels[ok], minlength=n_bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(vox > 0, pts / vox, np.nan)
