"""A tiny hand-made SemanticKITTI-format world for DS-Net training tests (no generator needed).

Each scan: a road disc, a building wall, and 2-3 box-shaped cars at random places, ~1500 points.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from panoptic_bench.datasets.semantickitti import make_label, write_labels, write_scan
from panoptic_bench.dsnet.model.network import PanopticBackbone
from panoptic_bench.dsnet.model.voxelize import CylinderGrid

ROAD, CAR, BUILDING = 40, 10, 50


def tiny_model(num_classes: int, grid: CylinderGrid, **flags: bool) -> PanopticBackbone:
    """The tiny test network (init_size 4, 16-wide point MLP) on ``grid``; ``flags``: variant switches."""
    return PanopticBackbone(
        num_classes,
        init_size=4,
        grid=grid,
        point_hidden=(16,),
        point_feature_dim=16,
        voxel_feature_dim=8,
        offset_hidden=8,
        **flags,
    )


def _box(rng: np.random.Generator, centre: np.ndarray, size: np.ndarray, n: int) -> np.ndarray:
    """Points on the surface of an axis-aligned box."""
    pts = rng.uniform(-0.5, 0.5, (n, 3)) * size
    face = rng.integers(0, 3, n)
    sign = rng.choice([-0.5, 0.5], n)
    pts[np.arange(n), face] = sign * size[face]
    return pts + centre


def make_scan(rng: np.random.Generator, n_cars: int) -> tuple[np.ndarray, np.ndarray]:
    """One scan: points (n, 4) float32 and uint32 labels (raw sem | inst << 16)."""
    r = np.sqrt(rng.uniform(3.0**2, 25.0**2, 700))
    a = rng.uniform(-np.pi, np.pi, 700)
    road = np.stack([r * np.cos(a), r * np.sin(a), np.full(700, -1.7)], 1)
    wall = np.stack([rng.uniform(-20, 20, 300), np.full(300, 12.0), rng.uniform(-1.7, 3.0, 300)], 1)
    parts, sem = [road, wall], [np.full(700, ROAD), np.full(300, BUILDING)]
    inst = [np.zeros(700), np.zeros(300)]
    for k in range(n_cars):
        centre = np.array([rng.uniform(-15, 15), rng.uniform(-9, 8), -0.9])
        n = 150
        parts.append(_box(rng, centre, np.array([4.0, 1.8, 1.5]), n))
        sem.append(np.full(n, CAR))
        inst.append(np.full(n, k + 1))
    xyz = np.concatenate(parts).astype(np.float32)
    rem = rng.uniform(0, 1, (len(xyz), 1)).astype(np.float32)
    labels = make_label(np.concatenate(sem).astype(np.int64), np.concatenate(inst).astype(np.int64))
    return np.concatenate([xyz, rem], 1), labels


def write_tiny_world(root: Path, sequences: dict[str, int], seed: int = 0) -> Path:
    """Write ``sequences`` (name -> scan count) under ``root/sequences``; returns ``root``."""
    rng = np.random.default_rng(seed)
    for seq, count in sequences.items():
        for i in range(count):
            pts, labels = make_scan(rng, int(rng.integers(2, 4)))
            base = root / "sequences" / seq
            write_scan(base / "velodyne" / f"{i:06d}.bin", pts)
            write_labels(base / "labels" / f"{i:06d}.label", labels)
    return root
