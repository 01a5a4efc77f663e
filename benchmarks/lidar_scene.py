"""A LiDAR-like synthetic scan for benchmarks: ray-cast ground, two building walls, boxes."""

from __future__ import annotations

import numpy as np


def lidar_scan(
    n_beams: int = 64, n_azimuth: int = 1875, seed: int = 0, max_range: float = 60.0
) -> np.ndarray:
    """Points of shape (n, 4), float32: x, y, z, remission of one 360-degree sweep.

    Sensor at 1.73 m; ground at z = -1.73; walls at y = +-9 m; 12 random 4 x 2 x 1.6 m boxes.
    """
    rng = np.random.default_rng(seed)
    elev = np.deg2rad(np.linspace(-24.9, 2.0, n_beams))
    azim = np.linspace(-np.pi, np.pi, n_azimuth, endpoint=False)
    e, a = np.meshgrid(elev, azim, indexing="ij")
    d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)
    t = np.full(d.shape[0], np.inf)
    down = d[:, 2] < 0
    t[down] = -1.73 / d[down, 2]
    side = np.abs(d[:, 1]) > 1e-6
    t[side] = np.minimum(t[side], 9.0 / np.abs(d[side, 1]))
    lo_all, hi_all = [], []
    for _ in range(12):
        c = np.array([rng.uniform(-40, 40), rng.uniform(-7, 7), -0.93])
        lo_all.append(c - [2.0, 1.0, 0.8])
        hi_all.append(c + [2.0, 1.0, 0.8])
    with np.errstate(divide="ignore", invalid="ignore"):
        for lo, hi in zip(lo_all, hi_all):
            t1, t2 = lo / d, hi / d
            tmin = np.nanmax(np.minimum(t1, t2), axis=1)
            tmax = np.nanmin(np.maximum(t1, t2), axis=1)
            hit = (tmax >= tmin) & (tmin > 0)
            t[hit] = np.minimum(t[hit], tmin[hit])
    keep = t < max_range
    pts = d[keep] * t[keep, None] + rng.normal(0, 0.02, (int(keep.sum()), 3))
    rem = rng.uniform(0, 1, (pts.shape[0], 1))
    return np.concatenate([pts, rem], 1).astype(np.float32)
