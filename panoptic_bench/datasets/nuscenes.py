"""Write a nuScenes-format dataset (tables, LIDAR_TOP sweeps, lidarseg) that the devkit loads.

No nuScenes download is possible in our tests, so fixtures and the synthetic world are written with
:func:`write_dataset`. The result is a dataroot that ``nuscenes.NuScenes(version, dataroot)`` loads
unchanged: every JSON table the devkit reads, ``samples/LIDAR_TOP/*.pcd.bin`` (float32 x, y, z,
intensity, ring) and ``lidarseg/<version>/<token>_lidarseg.bin`` (uint8, the 32 general classes).
Boxes are given in the global frame, as the real dataset stores them; points in the LIDAR_TOP
sensor frame. Tokens are deterministic (md5 of a readable key), so writing twice gives the same bytes.

Example
-------
>>> spec = SceneSpec(name="scene-0103", samples=[...], lidar_translation=(0.9, 0.0, 1.8),
...                  lidar_rotation=(0.707, 0.0, 0.0, 0.707))  # doctest: +SKIP
>>> write_dataset("/tmp/nus", "v1.0-mini", [spec])  # doctest: +SKIP
"""

from __future__ import annotations

import io as _io
import os
import shutil
import uuid
from pathlib import Path

import numpy as np

from panoptic_bench.datasets.nuscenes_spec import (  # noqa: F401 (public API re-exported here)
    ATTRIBUTES,
    GENERAL_CLASSES,
    LIDAR_CHANNEL,
    VISIBILITY_LEVELS,
    BoxSpec,
    SampleSpec,
    SceneSpec,
    _valid_scene_names,
    scene_names,
    token,
    version_kind,
)
from panoptic_bench.errors import InputError
from panoptic_bench.io import write_array, write_bytes, write_json


def _check(scenes: list[SceneSpec], version: str) -> None:
    valid = _valid_scene_names(version)
    classes = set(GENERAL_CLASSES)
    seen_scenes: set[str] = set()
    instance_owner: dict[str, tuple[str, str]] = {}
    for scene in scenes:
        where = f"scene {scene.name}"
        if scene.name not in valid:
            raise InputError(
                f"{where}: not a scene name of {version} in nuscenes.utils.splits; "
                "use scene_names(version, split)"
            )
        if scene.name in seen_scenes:
            raise InputError(f"{where}: written twice")
        seen_scenes.add(scene.name)
        if not scene.samples:
            raise InputError(f"{where}: has no samples")
        last_ts = None
        for i, s in enumerate(scene.samples):
            w = f"{where} sample {i}"
            if s.points.ndim != 2 or s.points.shape[1] != 5 or s.points.dtype != np.float32:
                raise InputError(
                    f"{w}: points must be float32 (N, 5), got {s.points.dtype} {s.points.shape}"
                )
            if s.lidarseg.shape != (len(s.points),) or s.lidarseg.dtype != np.uint8:
                raise InputError(f"{w}: lidarseg must be uint8 ({len(s.points)},)")
            if len(s.points) == 0:
                raise InputError(f"{w}: has no points")
            if s.lidarseg.max() >= len(GENERAL_CLASSES):
                raise InputError(f"{w}: lidarseg class ids must be 0..{len(GENERAL_CLASSES) - 1}")
            if last_ts is not None and s.timestamp <= last_ts:
                raise InputError(f"{w}: timestamps must increase within a scene")
            last_ts = s.timestamp
            keys = set()
            for b in s.boxes:
                if b.category not in classes:
                    raise InputError(f"{w}: unknown category {b.category!r} of {b.instance}")
                if b.instance in keys:
                    raise InputError(f"{w}: instance {b.instance} annotated twice")
                keys.add(b.instance)
                owner = instance_owner.setdefault(b.instance, (scene.name, b.category))
                if owner != (scene.name, b.category):
                    raise InputError(
                        f"{w}: instance {b.instance} changes scene or category ({owner} -> "
                        f"{(scene.name, b.category)})"
                    )
                bad = [a for a in b.attributes if a not in ATTRIBUTES]
                if bad:
                    raise InputError(f"{w}: unknown attributes {bad} of {b.instance}")
                if b.visibility not in VISIBILITY_LEVELS:
                    raise InputError(f"{w}: visibility must be one of {list(VISIBILITY_LEVELS)}")


def _num_lidar_pts(sample: SampleSpec, scene: SceneSpec) -> list[int]:
    """Points of the sweep inside each box (devkit ``points_in_box`` in the sensor frame)."""
    from nuscenes.utils.data_classes import Box
    from nuscenes.utils.geometry_utils import points_in_box
    from pyquaternion import Quaternion

    pts = sample.points[:, :3].T
    counts = []
    for b in sample.boxes:
        box = Box(list(b.translation), list(b.size), Quaternion(list(b.rotation)))
        box.translate(-np.array(sample.ego_translation))
        box.rotate(Quaternion(list(sample.ego_rotation)).inverse)
        box.translate(-np.array(scene.lidar_translation))
        box.rotate(Quaternion(list(scene.lidar_rotation)).inverse)
        counts.append(int(points_in_box(box, pts).sum()))
    return counts


def _tiny_png() -> bytes:
    from PIL import Image

    buf = _io.BytesIO()
    Image.new("L", (1, 1), 0).save(buf, format="PNG")
    return buf.getvalue()


def _build(stage: Path, version: str, scenes: list[SceneSpec]) -> None:
    """Write the whole dataset under ``stage`` (a fresh directory)."""
    tables: dict[str, list[dict]] = {
        "category": [
            {"token": token("category", n), "name": n, "description": n, "index": i}
            for i, n in enumerate(GENERAL_CLASSES)
        ],
        "attribute": [
            {"token": token("attribute", n), "name": n, "description": n} for n in ATTRIBUTES
        ],
        "visibility": [
            {"token": k, "level": v, "description": f"visibility of whole object is {v}"}
            for k, v in VISIBILITY_LEVELS.items()
        ],
        "sensor": [
            {"token": token("sensor", LIDAR_CHANNEL), "channel": LIDAR_CHANNEL, "modality": "lidar"}
        ],
    }
    for name in (
        "calibrated_sensor ego_pose log scene sample sample_data sample_annotation instance "
        "map lidarseg"
    ).split():
        tables[name] = []
    maps: dict[str, list[str]] = {}
    ann_of_instance: dict[str, list[dict]] = {}
    category_of: dict[str, str] = {}
    for scene in scenes:
        log_tok = token("log", scene.name)
        cs_tok = token("calibrated_sensor", scene.name)
        logfile = f"synthetic-{scene.name}"
        tables["log"].append(
            {
                "token": log_tok,
                "logfile": logfile,
                "vehicle": "synthetic",
                "date_captured": "2018-08-01",
                "location": scene.location,
            }
        )
        maps.setdefault(scene.location, []).append(log_tok)
        tables["calibrated_sensor"].append(
            {
                "token": cs_tok,
                "sensor_token": token("sensor", LIDAR_CHANNEL),
                "translation": [float(v) for v in scene.lidar_translation],
                "rotation": [float(v) for v in scene.lidar_rotation],
                "camera_intrinsic": [],
            }
        )
        n = len(scene.samples)
        s_toks = [token("sample", scene.name, i) for i in range(n)]
        sd_toks = [token("sample_data", scene.name, i) for i in range(n)]
        tables["scene"].append(
            {
                "token": token("scene", scene.name),
                "log_token": log_tok,
                "nbr_samples": n,
                "first_sample_token": s_toks[0],
                "last_sample_token": s_toks[-1],
                "name": scene.name,
                "description": scene.description,
            }
        )
        for i, s in enumerate(scene.samples):
            prev_s, next_s = (s_toks[i - 1] if i else ""), (s_toks[i + 1] if i + 1 < n else "")
            prev_d, next_d = (sd_toks[i - 1] if i else ""), (sd_toks[i + 1] if i + 1 < n else "")
            ep_tok = token("ego_pose", scene.name, i)
            filename = f"samples/{LIDAR_CHANNEL}/{logfile}__{LIDAR_CHANNEL}__{s.timestamp}.pcd.bin"
            tables["sample"].append(
                {
                    "token": s_toks[i],
                    "timestamp": int(s.timestamp),
                    "prev": prev_s,
                    "next": next_s,
                    "scene_token": token("scene", scene.name),
                }
            )
            tables["ego_pose"].append(
                {
                    "token": ep_tok,
                    "timestamp": int(s.timestamp),
                    "rotation": [float(v) for v in s.ego_rotation],
                    "translation": [float(v) for v in s.ego_translation],
                }
            )
            tables["sample_data"].append(
                {
                    "token": sd_toks[i],
                    "sample_token": s_toks[i],
                    "ego_pose_token": ep_tok,
                    "calibrated_sensor_token": cs_tok,
                    "timestamp": int(s.timestamp),
                    "fileformat": "pcd",
                    "is_key_frame": True,
                    "height": 0,
                    "width": 0,
                    "filename": filename,
                    "prev": prev_d,
                    "next": next_d,
                }
            )
            seg_name = f"lidarseg/{version}/{sd_toks[i]}_lidarseg.bin"
            tables["lidarseg"].append(
                {"token": sd_toks[i], "sample_data_token": sd_toks[i], "filename": seg_name}
            )
            write_array(stage / filename, s.points.astype(np.float32))
            write_array(stage / seg_name, s.lidarseg.astype(np.uint8))
            for b, npts in zip(s.boxes, _num_lidar_pts(s, scene)):
                rec = {
                    "token": token("sample_annotation", b.instance, scene.name, i),
                    "sample_token": s_toks[i],
                    "instance_token": token("instance", b.instance),
                    "visibility_token": b.visibility,
                    "attribute_tokens": [token("attribute", a) for a in b.attributes],
                    "translation": [float(v) for v in b.translation],
                    "size": [float(v) for v in b.size],
                    "rotation": [float(v) for v in b.rotation],
                    "prev": "",
                    "next": "",
                    "num_lidar_pts": npts,
                    "num_radar_pts": 0,
                }
                tables["sample_annotation"].append(rec)
                anns = ann_of_instance.setdefault(b.instance, [])
                if anns:
                    anns[-1]["next"] = rec["token"]
                    rec["prev"] = anns[-1]["token"]
                anns.append(rec)
                category_of[b.instance] = b.category
    for key, anns in ann_of_instance.items():
        tables["instance"].append(
            {
                "token": anns[0]["instance_token"],
                "category_token": token("category", category_of[key]),
                "nbr_annotations": len(anns),
                "first_annotation_token": anns[0]["token"],
                "last_annotation_token": anns[-1]["token"],
            }
        )
    png = _tiny_png()
    for location, log_tokens in maps.items():
        map_tok = token("map", location)
        tables["map"].append(
            {
                "category": "semantic_prior",
                "token": map_tok,
                "filename": f"maps/{map_tok}.png",
                "log_tokens": log_tokens,
            }
        )
        write_bytes(stage / "maps" / f"{map_tok}.png", png)
    for name, rows in tables.items():
        write_json(stage / version / f"{name}.json", rows)


def write_dataset(root: str | Path, version: str, scenes: list[SceneSpec]) -> None:
    """Write ``scenes`` as a nuScenes dataroot that ``NuScenes(version, root)`` loads.

    Parameters
    ----------
    root : str or Path
        Dataroot; created if missing. Other versions already in it are kept; an existing
        ``root/<version>`` and ``root/lidarseg/<version>`` are replaced.
    version : str
        E.g. ``"v1.0-mini"``; scene names must come from its splits (see :func:`scene_names`).
    scenes : list of SceneSpec
        The scenes, written in this order (table order = scene order, then sample order).

    Notes
    -----
    Everything is written to a staging directory inside ``root`` first and moved into place at
    the end (the version table folder last), so an interrupted run leaves no partial dataset.
    """
    _check(scenes, version)
    root = Path(root)
    if root.exists() and not root.is_dir():
        raise InputError("dataset root exists and is not a directory", root)
    root.mkdir(parents=True, exist_ok=True)
    stage = root / f".staging-{uuid.uuid4().hex}"
    trash = root / f".trash-{uuid.uuid4().hex}"
    try:
        _build(stage, version, scenes)
        for sub in ("samples/" + LIDAR_CHANNEL, "maps"):
            (root / sub).mkdir(parents=True, exist_ok=True)
            for f in (stage / sub).iterdir():
                os.replace(f, root / sub / f.name)
        trash.mkdir()
        for sub in (f"lidarseg/{version}", "panoptic/" + version, version):
            if (root / sub).exists():
                os.replace(root / sub, trash / sub.replace("/", "_"))
        (root / "lidarseg").mkdir(exist_ok=True)
        os.replace(stage / "lidarseg" / version, root / "lidarseg" / version)
        os.replace(stage / version, root / version)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
        shutil.rmtree(trash, ignore_errors=True)
