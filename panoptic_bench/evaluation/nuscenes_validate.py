"""Panoptic nuScenes submission validator: every problem of a result folder, listed at once.

A submission (the layout the devkit evaluator and the challenge server read) is::

    RES/<eval_set>/submission.json               {"meta": {"task", "use_camera", "use_lidar",
                                                           "use_radar", "use_map", "use_external"}}
    RES/panoptic/<eval_set>/<sd_token>_panoptic.npz   key "data": uint16, class * 1000 + instance

Checks: ``submission.json`` exists, is JSON with exactly those ``meta`` keys, ``task`` is
``segmentation`` or ``tracking`` and the ``use_*`` values are booleans; one ``.npz`` per keyframe
LIDAR_TOP sample_data of the split and no other file; each holds ``data``, a 1-D uint16 array
with one label per point of the sweep (from the ``.pcd.bin`` size, so the test split validates
without ground truth), class ids ``label // 1000`` in 0..16 (so instance ids ``label % 1000``
are <= 999) and non-zero instance ids only on thing classes (1..10).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from tqdm import tqdm

from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar
from panoptic_bench.errors import InputError

__all__ = ["META_KEYS", "N_CLASSES", "N_THINGS", "check_prediction", "validate_nuscenes"]

META_KEYS = ("task", "use_camera", "use_lidar", "use_radar", "use_map", "use_external")
TASKS = ("segmentation", "tracking")
N_CLASSES = 17  # challenge classes 0 (ignore) .. 16
N_THINGS = 10  # thing classes 1 .. 10
SUFFIX = "_panoptic.npz"


def check_submission_json(path: Path) -> list[str]:
    """Problems of ``submission.json`` (``"path: message"`` strings)."""
    if not path.is_file():
        return [f"{path}: submission.json missing (it holds the meta fields {list(META_KEYS)})"]
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        return [f"{path}: not valid JSON ({exc})"]
    meta = data.get("meta") if isinstance(data, dict) else None
    if not isinstance(meta, dict):
        return [f"{path}: no 'meta' object"]
    out = []
    missing = [k for k in META_KEYS if k not in meta]
    extra = sorted(set(meta) - set(META_KEYS))
    if missing:
        out.append(f"{path}: meta lacks {', '.join(missing)}")
    if extra:
        out.append(f"{path}: meta has unknown keys {', '.join(extra)}")
    if "task" in meta and meta["task"] not in TASKS:
        out.append(f"{path}: meta.task must be 'segmentation' or 'tracking', got {meta['task']!r}")
    for k in META_KEYS[1:]:
        if k in meta and not isinstance(meta[k], bool):
            out.append(f"{path}: meta.{k} must be true or false, got {meta[k]!r}")
    return out


def check_prediction(path: Path, n_points: int) -> list[str]:
    """Problems of one prediction ``.npz`` for a sweep of ``n_points`` points."""
    from panoptic_bench.errors import InputError
    from panoptic_bench.io import read_npz

    try:  # raw .npy, truncated, CRC / zlib errors, no 'data': one problem, never a traceback
        data = read_npz(path, keys=("data",))["data"]
    except InputError as exc:
        return [str(exc)]
    out = []
    if data.dtype != np.uint16:
        out.append(f"{path}: 'data' must be uint16, got {data.dtype}")
    if data.ndim != 1:
        return [*out, f"{path}: 'data' must be 1-D, got shape {data.shape}"]
    if not np.issubdtype(data.dtype, np.integer):
        return out
    if len(data) != n_points:
        out.append(f"{path}: {len(data)} labels but the sweep has {n_points} points")
    lab = data.astype(np.int64)
    sem, inst = lab // 1000, lab % 1000
    bad = (lab < 0) | (sem >= N_CLASSES)
    if bad.any():
        shown = ", ".join(str(int(v)) for v in np.unique(lab[bad])[:5])
        out.append(
            f"{path}: {int(bad.sum())} labels with class ids outside 0..16 "
            f"(label // 1000; labels {shown})"
        )
    stuff_inst = ~bad & (inst > 0) & ((sem == 0) | (sem > N_THINGS))
    if stuff_inst.any():
        classes = ", ".join(str(int(c)) for c in np.unique(sem[stuff_inst]))
        out.append(
            f"{path}: {int(stuff_inst.sum())} points of non-thing classes ({classes}) carry an "
            "instance id; only thing classes 1..10 may (stuff: class * 1000)"
        )
    return out


def validate_nuscenes(
    dataroot: str | Path,
    version: str,
    result_path: str | Path,
    eval_set: str,
    *,
    progress: bool | None = None,
    reader: NuScenesLidar | None = None,
) -> tuple[int, list[str]]:
    """Check a Panoptic nuScenes submission folder.

    Parameters
    ----------
    dataroot, version : str
        nuScenes dataroot (tables and sweeps; ground truth not needed) and its version.
    result_path : str or Path
        The submission folder ``RES``.
    eval_set : str
        Devkit split (``mini_val``, ``val``, ``test`` ...).
    progress : bool or None
    reader : NuScenesLidar, optional

    Returns
    -------
    (int, list of str)
        Number of samples of the split and every problem found (empty: valid).

    Raises
    ------
    InputError
        If the dataroot or the split itself cannot be used.
    """
    reader = reader or NuScenesLidar.tables_only(dataroot, version)
    res = Path(result_path)
    problems = check_submission_json(res / eval_set / "submission.json")
    tokens = reader.sample_data_tokens(eval_set)
    folder = res / "panoptic" / eval_set
    if not folder.is_dir():
        return len(tokens), [*problems, f"{folder}: prediction folder missing"]
    wanted = {f"{t}{SUFFIX}": t for t in tokens}
    present = {p.name for p in folder.iterdir()}
    for name in sorted(present - set(wanted)):
        problems.append(f"{folder / name}: extra file, not a sample of {eval_set}")
    disable = None if progress is None else not progress
    for tok in tqdm(tokens, desc=f"validate {eval_set}", unit="sweep", disable=disable):
        path = folder / f"{tok}{SUFFIX}"
        if path.name not in present:
            problems.append(f"{path}: prediction for sample_data {tok} missing")
            continue
        try:
            n = reader.num_points(tok)
        except InputError as exc:
            problems.append(str(exc))
            continue
        problems.extend(check_prediction(path, n))
    return len(tokens), problems
