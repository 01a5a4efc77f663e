"""A "simulated detector" for nuScenes: ground-truth boxes with jitter, misses and false positives.

Writes a standard nuScenes detection (or tracking) submission JSON for the samples of an eval set,
readable by the devkit's ``load_prediction`` and by ``panoptic-bench box-merge nuscenes``. Its
``meta`` carries ``"source": "simulated detector"``, the noise parameters and the seed, so that
every result built from it is labelled simulated; it is never a detector result.

Per sample (samples in the devkit's eval-set order, one random generator seeded with ``seed``):
every annotation whose category maps to a Panoptic nuScenes things class (the devkit's
``PanopticClassMapper``: e.g. ``vehicle.emergency.police`` -> ``car``; for tracking only the 7
tracking classes) becomes a box with the centre moved by N(0, ``position_sigma``) per axis, each
size multiplied by exp(N(0, ``size_sigma``)), the heading turned about the global z axis by
N(0, ``yaw_sigma``), score U(0.5, 1); it is missed with probability ``miss_rate``. Then
Poisson(``fp_rate`` x #boxes) false positives of random classes, with the size of a random
ground-truth box, a uniform heading, score U(0, 0.6), centred uniformly within the horizontal
extent of the sample's ground-truth boxes grown by 5 m, at the height of a random one.
Tracking ids are the annotation's instance token (stable across samples) or ``fp-<n>``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from panoptic_bench.baselines.box_merge import SIMULATED_DETECTOR, DetectorNoise
from panoptic_bench.baselines.box_merge_nuscenes import BoxTask
from panoptic_bench.io import write_json

__all__ = ["simulate_submission_nuscenes", "write_simulated_submission_nuscenes"]

#: ``meta`` of a lidar-only detection submission.
DETECTION_META = {
    "use_camera": False,
    "use_lidar": True,
    "use_radar": False,
    "use_map": False,
    "use_external": False,
}


def _thing_names(nusc: Any, task: BoxTask) -> tuple[dict[str, str], list[str]]:
    """Category name -> box class name, and the allowed class names (sorted)."""
    from nuscenes.eval.panoptic.utils import PanopticClassMapper

    from panoptic_bench.baselines.box_merge_nuscenes import tracking_names

    mapper = PanopticClassMapper(nusc)
    things = mapper.get_things()
    allowed = sorted(things if task is BoxTask.DETECTION else set(things) & set(tracking_names()))
    coarse_name = {idx: name for name, idx in mapper.get_coarse2idx().items()}
    fine2coarse = mapper.get_fine_idx_2_coarse_idx()
    by_category = {}
    for fine_name, fine_idx in nusc.lidarseg_name2idx_mapping.items():
        name = coarse_name.get(fine2coarse.get(fine_idx))
        if name in allowed:
            by_category[fine_name] = name
    return by_category, allowed


def _box(sample: str, t, s, q, name: str, score: float, task: BoxTask, track: str) -> dict:
    box = {
        "sample_token": sample,
        "translation": [float(v) for v in t],
        "size": [float(v) for v in s],
        "rotation": [float(v) for v in q],
        "velocity": [0.0, 0.0],
    }
    if task is BoxTask.TRACKING:
        box.update(tracking_id=track, tracking_name=name, tracking_score=float(score))
    else:
        box.update(detection_name=name, detection_score=float(score), attribute_name="")
    return box


def simulate_submission_nuscenes(
    dataroot: str | Path,
    version: str,
    eval_set: str,
    *,
    noise: DetectorNoise | None = None,
    seed: int = 0,
    task: BoxTask = BoxTask.DETECTION,
) -> dict:
    """Simulated-detector submission (``{"meta": ..., "results": ...}``) for ``eval_set``.

    Parameters
    ----------
    dataroot, version, eval_set
        nuScenes dataroot, e.g. ``v1.0-mini``, and a devkit split such as ``mini_val``.
    noise : DetectorNoise, optional
        Jitter, miss and false-positive rates (``DetectorNoise(0, 0, 0, 0, 0)``: exact GT boxes).
    seed : int
    task : BoxTask
        Detection or tracking submission.

    Returns
    -------
    dict
        JSON-ready submission; deterministic given the arguments.
    """
    from pyquaternion import Quaternion

    from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar

    noise = DetectorNoise() if noise is None else noise
    task = BoxTask(task)
    reader = NuScenesLidar(dataroot, version)
    nusc = reader.nusc
    by_category, allowed = _thing_names(nusc, task)
    rng = np.random.default_rng(seed)
    results: dict[str, list[dict]] = {}
    n_fp_total = 0
    for sd_token in tqdm(reader.sample_data_tokens(eval_set), desc="simulate boxes", disable=None):
        sample = nusc.get("sample_data", sd_token)["sample_token"]
        anns = [nusc.get("sample_annotation", t) for t in nusc.get("sample", sample)["anns"]]
        anns = [a for a in anns if a["category_name"] in by_category]
        n = len(anns)
        trans = np.array([a["translation"] for a in anns], float).reshape(-1, 3)
        size = np.array([a["size"] for a in anns], float).reshape(-1, 3)
        trans_j = trans + rng.normal(0, noise.position_sigma, (n, 3))
        size_j = size * np.exp(rng.normal(0, noise.size_sigma, (n, 3)))
        turn = rng.normal(0, noise.yaw_sigma, n)
        keep = rng.random(n) >= noise.miss_rate
        score = rng.uniform(0.5, 1.0, n)
        boxes = []
        for k, a in enumerate(anns):
            if keep[k]:
                q = Quaternion(axis=[0, 0, 1], angle=turn[k]) * Quaternion(a["rotation"])
                boxes.append(
                    _box(sample, trans_j[k], size_j[k], q.elements, by_category[a["category_name"]],
                         score[k], task, a["instance_token"])
                )  # fmt: skip
        n_fp = int(rng.poisson(noise.fp_rate * n)) if n else 0
        if n_fp:
            lo, hi = trans[:, :2].min(0) - 5, trans[:, :2].max(0) + 5
            xy = rng.uniform(lo, hi, (n_fp, 2))
            z = trans[rng.integers(0, n, n_fp), 2]
            sizes = size[rng.integers(0, n, n_fp)]
            yaw = rng.uniform(-np.pi, np.pi, n_fp)
            names = rng.choice(allowed, n_fp)
            fp_score = rng.uniform(0, 0.6, n_fp)
            for j in range(n_fp):
                q = Quaternion(axis=[0, 0, 1], angle=yaw[j])
                boxes.append(
                    _box(sample, [*xy[j], z[j]], sizes[j], q.elements, str(names[j]),
                         fp_score[j], task, f"fp-{n_fp_total + j}")
                )  # fmt: skip
            n_fp_total += n_fp
        results[sample] = boxes
    meta = dict(DETECTION_META, source=SIMULATED_DETECTOR, seed=seed, task=str(task))
    meta["noise"] = {
        "position_sigma": noise.position_sigma,
        "size_sigma": noise.size_sigma,
        "yaw_sigma": noise.yaw_sigma,
        "miss_rate": noise.miss_rate,
        "fp_rate": noise.fp_rate,
    }
    return {"meta": meta, "results": results}


def write_simulated_submission_nuscenes(
    dataroot: str | Path,
    version: str,
    eval_set: str,
    output: str | Path,
    *,
    noise: DetectorNoise | None = None,
    seed: int = 0,
    task: BoxTask = BoxTask.DETECTION,
) -> int:
    """Write :func:`simulate_submission_nuscenes` atomically to ``output``; returns #boxes."""
    sub = simulate_submission_nuscenes(
        dataroot, version, eval_set, noise=noise, seed=seed, task=task
    )
    write_json(output, sub, indent=None)
    return sum(len(b) for b in sub["results"].values())
