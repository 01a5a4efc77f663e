"""Realism measures of the street layout: where the carriageway ends and what borders it.

Helpers of :func:`panoptic_bench.datasets.synthetic.realism.scan_measures` (conventions in its
module docstring): points are in the sensor frame, ``x`` ahead, ``y`` to the left.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from panoptic_bench.datasets.synthetic.raw_ids import (
    BUILDING,
    CAR,
    FENCE,
    MOVING_CAR,
    OTHER_GROUND,
    PARKING,
    ROAD,
    SIDEWALK,
    TERRAIN,
    TRUNK,
    VEGETATION,
)

__all__ = [
    "GROUND",
    "NEAR_CLASSES",
    "beside_road_terrain",
    "median",
    "near_field",
    "pct",
    "road_edges",
    "road_far",
    "terrain_step",
]

#: Raw ids of the ground classes.
GROUND = (ROAD, PARKING, SIDEWALK, OTHER_GROUND, TERRAIN)


#: Classes whose share of the upright returns 3-6 m away is a ``synth stats`` row (session 43).
NEAR_CLASSES = (
    ("veg", (VEGETATION,)),
    ("fence", (FENCE,)),
    ("building", (BUILDING,)),
    ("car", (CAR, MOVING_CAR)),
    ("trunk", (TRUNK,)),
)


def median(v: np.ndarray) -> float:
    """Median, ``nan`` for an empty array."""
    return float(np.median(v)) if v.size else float("nan")


def pct(mask: np.ndarray) -> float:
    """Share of ``True`` in %, ``nan`` for an empty array."""
    return 100.0 * float(mask.mean()) if mask.size else float("nan")


def beside_road_terrain(x, y, r, raw: np.ndarray, cell: float = 0.5) -> float:
    """% terrain among the non-road ground points 3-20 m away next to a road cell."""
    road = raw == ROAD
    ground = np.isin(raw, (PARKING, SIDEWALK, OTHER_GROUND, TERRAIN)) & (r >= 3) & (r <= 20)
    if not road.any() or not ground.any():
        return float("nan")
    n = int(np.ceil(2 * 80.0 / cell)) + 3
    i = np.clip(np.floor((x + 80.0) / cell).astype(np.int64) + 1, 1, n - 2)
    j = np.clip(np.floor((y + 80.0) / cell).astype(np.int64) + 1, 1, n - 2)
    occ = np.zeros((n, n), bool)
    occ[i[road], j[road]] = True
    near = np.zeros_like(occ)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            near |= np.roll(np.roll(occ, di, 0), dj, 1)
    beside = ground & near[i, j]
    return pct(raw[beside] == TERRAIN) if beside.any() else float("nan")


def road_edges(x, y, raw: np.ndarray) -> tuple[float, float]:
    """Median lateral distance (m) to the first non-carriageway ground point: right, left."""
    ground = np.isin(raw, GROUND)
    slab = np.floor(x).astype(np.int64)
    ahead = ground & (np.abs(x) >= 4) & (np.abs(x) < 12)
    edges = []
    for side in (-1, 1):
        found = []
        for k in np.unique(slab[ahead]):
            sel = ahead & (slab == k) & (side * y > 0)
            if sel.sum() < 20:
                continue
            order = np.argsort(side * y[sel], kind="stable")
            off = ~np.isin(raw[sel][order], (ROAD, PARKING))
            if off.any():
                found.append(float(side * y[sel][order][np.argmax(off)]))
        edges.append(median(np.array(found)))
    return edges[0], edges[1]


def road_far(x, y, raw: np.ndarray) -> tuple[float, float]:
    """% road among the ground points 6-12 m to the right / left, 5-15 m ahead and behind."""
    ground = np.isin(raw, GROUND) & (np.abs(x) >= 5) & (np.abs(x) < 15)
    out = []
    for side in (-1, 1):
        sel = ground & (side * y >= 6) & (side * y < 12)
        out.append(pct(raw[sel] == ROAD) if sel.any() else float("nan"))
    return out[0], out[1]


def terrain_step(
    x, y, z, r, raw: np.ndarray, reach: float = 1.0, flush: float = 0.05, raw_id: int = TERRAIN
) -> tuple[float, float]:
    """Step from the road up to the terrain (or class ``raw_id``) beside it: median (m), % flush.

    Every point of ``raw_id`` 3-25 m away whose nearest road point (in ``x, y``) is closer than
    ``reach`` m gives ``z - z_road``; returns the median step and the % of steps with
    ``|step| < flush`` (``nan`` for both when fewer than 20 such points). With the sidewalk's
    raw id it is the kerb step.
    """
    road = (raw == ROAD) & (r < 25)
    ter = (raw == raw_id) & (r >= 3) & (r < 25)
    if road.sum() < 20 or ter.sum() < 20:
        return float("nan"), float("nan")
    dist, idx = cKDTree(np.column_stack([x[road], y[road]])).query(
        np.column_stack([x[ter], y[ter]])
    )
    near = dist < reach
    if near.sum() < 20:
        return float("nan"), float("nan")
    step = z[ter][near] - z[road][idx[near]]
    return median(step), pct(np.abs(step) < flush)


def near_field(r: np.ndarray, height: np.ndarray, raw: np.ndarray) -> dict[str, float]:
    """What stands beside the sensor: ``near_<key>_pct`` for each of :data:`NEAR_CLASSES`.

    The % of each class among the points 3-6 m away (``r``, horizontal range, m) more than
    0.45 m above the road plane (``height``, m); ``nan`` where there are no such points.
    """
    sel = raw[(r >= 3) & (r < 6) & (height > 0.45)]
    return {f"near_{key}_pct": pct(np.isin(sel, ids)) for key, ids in NEAR_CLASSES}
