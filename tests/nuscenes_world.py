"""Small nuScenes-format worlds for the nuScenes tests, written with our writer.

Boxes are built in the LIDAR_TOP frame (axis-aligned there, sizes and centres on a 1/8 m grid)
and moved to the global frame through non-identity calibration and ego poses, so the devkit has
to undo real transforms. Points are put exactly on box faces and corners, inside two touching or
overlapping boxes, and with thing classes outside every box.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pyquaternion import Quaternion

from panoptic_bench.datasets.nuscenes import (
    GENERAL_CLASSES,
    BoxSpec,
    SampleSpec,
    SceneSpec,
    scene_names,
    write_dataset,
)

CAR = GENERAL_CLASSES.index("vehicle.car")
PED = GENERAL_CLASSES.index("human.pedestrian.adult")
BARRIER = GENERAL_CLASSES.index("movable_object.barrier")
ROAD = GENERAL_CLASSES.index("flat.driveable_surface")
BUILDING = GENERAL_CLASSES.index("static.manmade")
POLICE = GENERAL_CLASSES.index("vehicle.emergency.police")


def _to_global(center, yaw, calib, ego):
    """Sensor-frame box (center, yaw) -> global translation and rotation."""
    (ct, cq), (et, eq) = calib, ego
    q_local = Quaternion(axis=[0, 0, 1], angle=yaw)
    c_ego = cq.rotate(np.asarray(center, float)) + np.asarray(ct)
    c_glob = eq.rotate(c_ego) + np.asarray(et)
    q = eq * cq * q_local
    return tuple(float(v) for v in c_glob), tuple(float(v) for v in q.elements)


def _face_points(center, size, rng, n=12):
    """Points exactly on faces/corners of an axis-aligned (sensor frame) box."""
    width, length, height = size
    half = np.array([length, width, height]) / 2
    pts = []
    for k in range(n):
        p = rng.uniform(-1, 1, 3).round(3) * half
        axis = k % 3
        p[axis] = half[axis] * (1 if k % 2 else -1)
        pts.append(p)
    pts.append(half.copy())
    pts.append(-half)
    return np.asarray(pts) + np.asarray(center)


def make_scene(name, seed, n_samples=3, base_points=None, yaw_boxes=True):
    rng = np.random.default_rng(seed)
    calib = ((0.94, 0.01, 1.84), Quaternion(axis=[0.05, 0.02, 1], angle=-1.57 + 0.01 * seed))
    # instances: key -> (category, class idx, size, base centre)
    objs = [
        ("car-a", "vehicle.car", CAR, (1.875, 4.5, 1.625), (8.0, 3.0, -0.75)),
        ("car-b", "vehicle.car", CAR, (1.875, 4.5, 1.625), (8.0, 7.5, -0.75)),  # touches car-a
        ("car-c", "vehicle.car", CAR, (2.0, 4.0, 1.5), (9.0, 5.0, -0.75)),  # overlaps both
        ("ped-a", "human.pedestrian.adult", PED, (0.625, 0.75, 1.75), (-5.0, 2.0, -0.5)),
        ("bar-a", "movable_object.barrier", BARRIER, (0.5, 2.0, 1.0), (3.0, -6.0, -1.0)),
        ("pol-a", "vehicle.emergency.police", POLICE, (2.0, 5.0, 1.75), (-12.0, -8.0, -0.5)),
    ]
    samples = []
    for i in range(n_samples):
        ego = (
            (600.0 + 3.7 * i + seed, 1600.0 - 1.3 * i, 0.1 * seed),
            Quaternion(axis=[0.01, -0.02, 1], angle=0.3 + 0.4 * seed + 0.05 * i),
        )
        shift = np.array([0.5 * i, 0.0, 0.0])
        present = [o for j, o in enumerate(objs) if (i + j) % 4 != 3 or j < 2]
        boxes, pts, labels = [], [], []
        for key, cat, cls, size, c in present:
            center = np.asarray(c) + shift
            yaw = 0.0 if (not yaw_boxes or key.startswith("car")) else 0.3 * (seed + 1)
            t, q = _to_global(center, yaw, calib, ego)
            boxes.append(
                BoxSpec(f"{name}/{key}", cat, t, size, q, ("vehicle.parked",) if cls == CAR else ())
            )
            half = np.array([size[1], size[0], size[2]]) / 2
            inside = rng.uniform(-1, 1, (40, 3)) * half
            if yaw:
                cz, sz = np.cos(yaw), np.sin(yaw)
                inside = inside @ np.array([[cz, sz, 0], [-sz, cz, 0], [0, 0, 1]])
            pts.append(inside + center)
            labels.append(np.full(40, cls))
            if yaw == 0.0:
                pts.append(_face_points(center, size, rng))
                labels.append(np.full(len(pts[-1]), cls))
        # thing points outside every box, stuff points inside boxes, stuff everywhere
        pts.append(rng.uniform(-30, 30, (25, 3)) + np.array([0, 40, 0]))
        labels.append(np.full(25, CAR))
        pts.append(np.array([[8.0, 3.0, -0.75], [-5.0, 2.0, -0.5]]) + shift)
        labels.append(np.array([ROAD, BUILDING]))
        if base_points is not None:
            pts.append(base_points[:, :3].astype(np.float64))
            labels.append(rng.choice([ROAD, BUILDING, CAR, PED], len(base_points)))
        else:
            pts.append(rng.uniform(-40, 40, (300, 3)) * np.array([1, 1, 0.05]))
            labels.append(rng.choice([ROAD, BUILDING, 0], 300))
        xyz = np.concatenate(pts)
        lab = np.concatenate(labels).astype(np.uint8)
        points = np.zeros((len(xyz), 5), np.float32)
        points[:, :3] = xyz
        points[:, 3] = rng.integers(0, 256, len(xyz))
        points[:, 4] = rng.integers(0, 32, len(xyz))
        samples.append(
            SampleSpec(
                timestamp=1_532_402_927_000_000 + 500_000 * i + seed,
                ego_translation=tuple(float(v) for v in ego[0]),
                ego_rotation=tuple(float(v) for v in ego[1].elements),
                points=points,
                lidarseg=lab,
                boxes=boxes,
            )
        )
    return SceneSpec(
        name=name,
        samples=samples,
        lidar_translation=calib[0],
        lidar_rotation=tuple(float(v) for v in calib[1].elements),
    )


def write_mini(root: Path, real_sweep: Path | None = None) -> Path:
    """A v1.0-mini dataroot: both mini_val scenes and two mini_train scenes."""
    base = None
    if real_sweep is not None:
        base = np.fromfile(real_sweep, dtype=np.float32).reshape(-1, 5)
    names = scene_names("v1.0-mini", "mini_val") + scene_names("v1.0-mini", "mini_train")[:2]
    scenes = [
        make_scene(n, seed=k, n_samples=3 if k else 2, base_points=base if k == 0 else None)
        for k, n in enumerate(names)
    ]
    write_dataset(root, "v1.0-mini", scenes)
    return root


def real_sweep(shared_data: Path) -> Path:
    """The real nuScenes LIDAR_TOP sweep in ../shared/data (34,688 points)."""
    files = sorted((shared_data / "nuscenes-unlabeled").glob("*.pcd.bin"))
    assert files, f"no .pcd.bin in {shared_data / 'nuscenes-unlabeled'}"
    return files[0]


def tree_snapshot(root: Path) -> dict[str, tuple[int, int]]:
    """Relative path -> (size, mtime_ns) of every file under ``root``."""
    return {
        str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns)
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def tree_bytes(root: Path) -> dict[str, bytes]:
    """Relative path -> content of every file under ``root``."""
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }
