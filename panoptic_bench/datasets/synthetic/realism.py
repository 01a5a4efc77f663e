"""Sensor and world realism measures of one labelled scan (remission, ground, pose, layout, rings).

:func:`scan_measures` is a pure array function of one scan in the sensor frame; it returns the
scalar measures named in :data:`MEASURES` (``nan`` where a scan has too few points to define one)
and a few histograms (:data:`HISTOGRAMS`). :func:`aggregate` combines scans: fractions are
averaged over scans, medians and geometry take the median over scans, histograms are summed.

Conventions (the same estimator runs on real and synthetic scans, so only the comparison matters):

- **rings** are recovered from the point order: the unwrapped azimuth grows by one turn per ring
  in both the KITTI files and the synthetic writer; rings are then ranked by median elevation
  (0 = lowest beam);
- **road plane**: least squares ``z = a x + b y + c`` over road points 3-20 m away, refitted
  without residuals above 0.15 m; ``c`` is the road height under the sensor, ``atan(a)`` the
  ground slope along x (reported as sensor pitch, positive when the road rises ahead, i.e. the
  sensor looks down) and ``atan(b)`` along y (sensor roll, positive when the road rises to the
  left); roughness is the standard deviation of the refit residuals (it includes camber and
  undulation, so it says nothing about point-to-point smoothness);
- **jitter** (point-to-point roughness) of road, sidewalk and terrain: the second difference of
  z along the ring, ``z[i] - (z[i-1] + z[i+1]) / 2``, over consecutive triples of the class
  3-15 m away whose neighbours lie within 0.5 m, as a robust std (1.4826 x median absolute
  deviation, mm): what a voxel sees of a surface's local texture;
- **beside the road**: the ground points (parking, sidewalk, other-ground, terrain) 3-20 m away
  whose 0.5 m cell (x, y) or one of its 8 neighbours holds a road point; the share of terrain
  among them says whether grass verges border the road;
- **road edges**: in 1 m slabs across the street 4-12 m ahead and behind, the lateral distance from
  the sensor to the first ground point (of the ground classes) that is neither road nor parking,
  to the right and to the left; the median over the slabs (cars and people on the road are not
  ground, so they do not end it);
- **road far to the side**: the share of road among the ground points 6-12 m to the right and
  to the left, 5-15 m ahead and behind (side streets, inner lanes, wide roads);
- **fence see-through**: the share of fence points under 30 m whose previous or next point in
  recording order (the neighbouring column of the same ring) is more than 1 m farther (the laser
  passing through a lattice or mesh to what stands behind), each neighbour counted once;
- heights of sidewalk, terrain, fence, traffic-sign and trunk are median residuals of their points 3-20 m away from that
  plane; the ego hole is the minimum horizontal range of ground points (road, parking, sidewalk, other-ground,
  terrain) in each of 8 azimuth sectors (45 degrees,
  sector 0 centred on +x, counter-clockwise).
"""

from __future__ import annotations

import numpy as np

from panoptic_bench.datasets.synthetic.raw_ids import (
    BUILDING,
    CAR,
    FENCE,
    MOVING_CAR,
    OTHER_GROUND,
    OTHER_OBJECT,
    OTHER_STRUCTURE,
    OTHER_VEHICLES,
    PEOPLE,
    POLE,
    ROAD,
    SIDEWALK,
    SIGN,
    TERRAIN,
    TRUNK,
    VEGETATION,
)
from panoptic_bench.datasets.synthetic.realism_labels import MEASURES
from panoptic_bench.datasets.synthetic.realism_layout import (
    GROUND,
    NEAR_CLASSES,
    beside_road_terrain,
    median,
    near_field,
    pct,
    road_edges,
    road_far,
    terrain_step,
)
from panoptic_bench.datasets.synthetic.realism_materials import material_measures

__all__ = ["HISTOGRAMS", "MEASURES", "aggregate", "recover_rings", "scan_measures"]

#: Histograms summed over scans: key -> bin edges (``ring_points`` and ``hole`` have fixed length).
HISTOGRAMS = {
    "remission": np.linspace(0.0, 1.0, 51),
    "height": np.linspace(-0.6, 0.6, 61),
    "range": np.arange(0.0, 122.0, 2.0),
}
RANGE_BINS = np.arange(0.0, 85.0, 5.0)
N_RINGS = 64
N_SECTORS = 8
CLUTTER = (OTHER_STRUCTURE, OTHER_OBJECT)


def recover_rings(xyz: np.ndarray) -> np.ndarray:
    """Ring index of every point of a ring-ordered scan, ranked by elevation.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float
        Points in the order the sensor recorded them (ring by ring).

    Returns
    -------
    ndarray of shape (N,), int64
        0 = lowest ring; ``max + 1`` is the number of rings found.
    """
    if xyz.shape[0] == 0:
        return np.zeros(0, np.int64)
    turn = np.unwrap(np.arctan2(xyz[:, 1], xyz[:, 0]).astype(np.float64))
    turn = np.abs(turn - turn[0])
    elev = np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1]))
    # rings may start before the first recorded point (hidden azimuths): choose the phase
    # whose segments have the least elevation spread
    best, seg = np.inf, None
    for shift in np.linspace(0.0, 2 * np.pi, 16, endpoint=False):
        cand = np.floor((turn + shift) / (2 * np.pi) + 1e-3).astype(np.int64)
        n = np.bincount(cand).astype(np.float64)
        mean = np.bincount(cand, elev) / np.maximum(n, 1)
        spread = float(np.sum((elev - mean[cand]) ** 2))
        if spread < best - 1e-12:
            best, seg = spread, cand
    seg = seg - seg.min()
    n = seg.max() + 1
    med = np.array([np.median(elev[seg == k]) if np.any(seg == k) else np.inf for k in range(n)])
    rank = np.empty(n, np.int64)
    rank[np.argsort(med, kind="stable")] = np.arange(n)
    return rank[seg]


def _plane(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray | None:
    """Robust least-squares plane ``z = a x + b y + c``: ``(a, b, c)`` or None."""
    keep = np.ones(x.size, bool)
    coef = None
    for _ in range(3):
        if keep.sum() < 100:
            return None
        a = np.column_stack([x[keep], y[keep], np.ones(keep.sum())])
        coef = np.linalg.lstsq(a, z[keep], rcond=None)[0]
        keep = np.abs(z - (coef[0] * x + coef[1] * y + coef[2])) < 0.15
    return coef


def _see_through(r: np.ndarray, fence: np.ndarray) -> float:
    """% of fence points' recording-order neighbours (under 30 m) that lie > 1 m farther."""
    if r.size < 2:
        return float("nan")
    near = fence & (r < 30.0)
    behind = []
    for a, b in ((slice(1, None), slice(None, -1)), (slice(None, -1), slice(1, None))):
        sel = near[a]
        behind.append(r[b][sel] - r[a][sel] > 1.0)
    both = np.concatenate(behind)
    return pct(both) if both.size else float("nan")


def _jitter(x, y, z, r, mask: np.ndarray) -> float:
    """Robust std (mm) of the second z difference over consecutive in-class triples, 3-15 m."""
    if mask.size < 3:
        return float("nan")
    step = np.hypot(np.diff(x), np.diff(y)) < 0.5
    ok = mask[1:-1] & mask[:-2] & mask[2:] & step[:-1] & step[1:] & (r[1:-1] >= 3) & (r[1:-1] < 15)
    if ok.sum() < 50:
        return float("nan")
    d = (z[1:-1] - (z[:-2] + z[2:]) / 2)[ok]
    return 1000.0 * 1.4826 * float(np.median(np.abs(d - np.median(d))))


def _range_texture(x, y, r, mask: np.ndarray) -> float:
    """Robust std (mm) of the second range difference over in-class ring neighbours, 3-20 m.

    Neighbours are consecutive points in recording order less than 0.01 rad apart in azimuth
    (the same ring, at most a few columns apart), so depth jumps inside a porous surface such as
    a bush count, where :func:`_jitter`'s 0.5 m step would drop them.
    """
    if mask.size < 3:
        return float("nan")
    near = np.abs(np.diff(np.arctan2(y, x))) < 0.01
    ok = mask[1:-1] & mask[:-2] & mask[2:] & near[:-1] & near[1:] & (r[1:-1] >= 3) & (r[1:-1] < 20)
    if ok.sum() < 50:
        return float("nan")
    d = (r[1:-1] - (r[:-2] + r[2:]) / 2)[ok]
    return 1000.0 * 1.4826 * float(np.median(np.abs(d - np.median(d))))


def scan_measures(
    points: np.ndarray, labels: np.ndarray
) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """Realism measures of one scan.

    Parameters
    ----------
    points : ndarray of shape (N, 4), float32
        ``x, y, z, remission`` in the sensor frame, in recording order.
    labels : ndarray of shape (N,), uint32
        SemanticKITTI labels (raw id in the low 16 bits).

    Returns
    -------
    measures : dict of str to float
        One value per key of :data:`MEASURES`.
    hists : dict of str to ndarray
        Counts per key of :data:`HISTOGRAMS`, plus ``road_rem_sum`` / ``road_rem_n`` (road
        remission sums and counts per 5 m range bin), ``ring_points`` (64,), ``ring_elev`` (64,)
        median elevation per ring, degrees) and ``hole`` (8,).
    """
    x, y, z = (points[:, k].astype(np.float64) for k in range(3))
    rem = points[:, 3].astype(np.float64)
    raw = (labels & 0xFFFF).astype(np.int64)
    r = np.hypot(x, y)
    road, car = raw == ROAD, (raw == CAR) | (raw == MOVING_CAR)
    dark = rem < 0.1
    near = (r >= 3) & (r < 20)
    other_vehicle = np.isin(raw, OTHER_VEHICLES)
    m: dict[str, float] = {
        "rem_zero_pct": pct(rem == 0),
        "rem_dark_pct": pct(dark),
        "rem_dark_road_pct": pct(road[dark]),
        "rem_dark_car_pct": pct(car[dark]),
        "rem_std": float(rem.std()) if rem.size else float("nan"),
        "rem_car_median": median(rem[car]),
        "rem_car_zero_pct": pct(rem[car] == 0),
        "rem_other_vehicle_median": median(rem[other_vehicle & near]),
        "rem_other_vehicle_zero_pct": pct(rem[other_vehicle] == 0),
        "rem_people_median": median(rem[np.isin(raw, PEOPLE) & near]),
        "rem_pole_median": median(rem[(raw == POLE) & near]),
        "rem_sign_median": median(rem[(raw == SIGN) & near]),
        "rem_sign_bright_pct": pct(rem[(raw == SIGN) & near] > 0.8),
        "rem_pole_zero_pct": pct(rem[(raw == POLE) & near] == 0),
        "rem_road_lt5": median(rem[road & (r < 5)]),
        "rem_road_20_40": median(rem[road & (r >= 20) & (r < 40)]),
        "rem_road_gt40": median(rem[road & (r >= 40)]),
        "rem_sidewalk_20_40": median(rem[(raw == SIDEWALK) & (r >= 20) & (r < 40)]),
        "rem_terrain_20_40": median(rem[(raw == TERRAIN) & (r >= 20) & (r < 40)]),
        "rem_terrain_gt40": median(rem[(raw == TERRAIN) & (r >= 40)]),
        "below_185_pct": pct(z < -1.85),
        "building_y": median(np.abs(y[raw == BUILDING])),
        "car_y": median(np.abs(y[car])),
        "car_range": median(r[car]),
        "near5_pct": pct(r < 5),
        "far_max": float(r.max()) if r.size else float("nan"),
        "clutter_pct": pct(np.isin(raw, CLUTTER)),
    }
    from panoptic_bench.datasets.semantickitti import to_train

    m["unlabeled_pct"] = pct(to_train(raw.astype(np.uint16)) == 0)
    sel = road & (r >= 3) & (r <= 20)
    coef = _plane(x[sel], y[sel], z[sel])
    resid = np.zeros(0)
    nan = float("nan")
    m.update(road_z=nan, pitch_deg=nan, roll_deg=nan, road_rough_cm=nan)
    m.update(sidewalk_h=nan, terrain_h=nan, fence_h=nan, other_ground_h=nan, veg_low_pct=nan)
    m["veg_overhang"] = nan
    m.update({f"near_{key}_pct": nan for key, _ in NEAR_CLASSES})
    m["sign_h"] = m["trunk_h"] = nan
    if coef is not None:
        a, b, c = coef
        m.update(
            road_z=float(c),
            pitch_deg=float(np.degrees(np.arctan(a))),
            roll_deg=float(np.degrees(np.arctan(b))),
        )
        resid = z - (a * x + b * y + c)
        fit = sel & (np.abs(resid) < 0.15)
        m["road_rough_cm"] = 100.0 * float(resid[fit].std())
        near = (r >= 3) & (r <= 20)
        m["sidewalk_h"] = median(resid[near & (raw == SIDEWALK)])
        m["terrain_h"] = median(resid[near & (raw == TERRAIN)])
        m["fence_h"] = median(resid[near & (raw == FENCE)])
        m["sign_h"] = median(resid[near & (raw == SIGN)])
        m["trunk_h"] = median(resid[near & (raw == TRUNK)])
        m["other_ground_h"] = median(resid[near & (raw == OTHER_GROUND)])
        m["veg_low_pct"] = pct(resid[near & (raw == VEGETATION)] < 0.5)
        beside = (r >= 3) & (r < 8) & (np.abs(y) < 3.5) & (resid >= 1.0) & (resid < 2.5)
        m["veg_overhang"] = float(np.sum(beside & (raw == VEGETATION)))
        m.update(near_field(r, resid, raw))
    m["fence_through_pct"] = _see_through(r, raw == FENCE)
    m.update(material_measures(rem, raw, r, z))
    m["verge_terrain_pct"] = beside_road_terrain(x, y, r, raw)
    m["road_right"], m["road_left"] = road_edges(x, y, raw)
    m["road_far_right_pct"], m["road_far_left_pct"] = road_far(x, y, raw)
    m["terrain_step"], m["terrain_flush_pct"] = terrain_step(x, y, z, r, raw)
    m["kerb_step"], m["kerb_flush_pct"] = terrain_step(x, y, z, r, raw, raw_id=SIDEWALK)
    for key, raw_id in (("road", ROAD), ("sidewalk", SIDEWALK), ("terrain", TERRAIN)):
        m[f"{key}_jitter_mm"] = _jitter(x, y, z, r, raw == raw_id)
    rho = np.sqrt(r**2 + z**2)
    m["vegetation_texture_mm"] = _range_texture(x, y, rho, raw == VEGETATION)
    m["building_texture_mm"] = _range_texture(x, y, rho, raw == BUILDING)
    ring = recover_rings(points[:, :3])
    ring_points = np.bincount(ring, minlength=N_RINGS)[:N_RINGS]
    elev = np.degrees(np.arctan2(z, r))
    ring_elev = np.array([median(elev[ring == k]) for k in range(N_RINGS)])
    m["n_rings"] = float(ring.max() + 1) if ring.size else 0.0
    others = ring_points[12:]
    m["low_ring_ratio"] = (
        float(ring_points[:12].mean() / others.mean()) if others.sum() > 0 else nan
    )
    sector = np.floor((np.arctan2(y, x) + np.pi / N_SECTORS) / (2 * np.pi / N_SECTORS))
    sector = sector.astype(np.int64) % N_SECTORS
    ground = np.isin(raw, GROUND)
    hole = np.full(N_SECTORS, np.nan)
    for k in range(N_SECTORS):
        if np.any(ground & (sector == k)):
            hole[k] = r[ground & (sector == k)].min()
    m["hole_min"], m["hole_max"] = float(np.nanmin(hole)), float(np.nanmax(hole))
    rbin = np.digitize(r, RANGE_BINS) - 1
    ok = road & (rbin >= 0) & (rbin < RANGE_BINS.size - 1)
    nb = RANGE_BINS.size - 1
    h = {
        "remission": np.histogram(rem, HISTOGRAMS["remission"])[0],
        "height": np.histogram(resid, HISTOGRAMS["height"])[0],
        "range": np.histogram(r, HISTOGRAMS["range"])[0],
        "road_rem_sum": np.bincount(rbin[ok], weights=rem[ok], minlength=nb)[:nb],
        "road_rem_n": np.bincount(rbin[ok], minlength=nb)[:nb].astype(np.float64),
        "ring_points": ring_points.astype(np.float64),
        "ring_elev": ring_elev,
        "hole": hole,
    }
    return m, h


def aggregate(
    scans: list[tuple[dict[str, float], dict[str, np.ndarray]]],
) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """Combine per-scan measures: mean, median or std / mean ("cv") over scans (``nan`` ignored);
    histograms summed.

    ``ring_points`` becomes the mean per scan; ``hole`` and ``ring_elev`` the median per entry.
    """
    out: dict[str, float] = {}
    for key, (_, how) in MEASURES.items():
        v = np.array([s[0][key] for s in scans], float)
        v = v[np.isfinite(v)]
        if how == "cv":
            ok = v.size >= 2 and np.mean(v) > 0
            out[key] = float(np.std(v) / np.mean(v)) if ok else float("nan")
        else:
            out[key] = (
                float("nan")
                if v.size == 0
                else float(np.mean(v) if how == "mean" else np.median(v))
            )
    medians = ("hole", "ring_elev")
    hists = {k: np.sum([s[1][k] for s in scans], axis=0) for k in scans[0][1] if k not in medians}
    hists["ring_points"] = hists["ring_points"] / len(scans)
    for key in medians:
        v = np.array([s[1][key] for s in scans])
        hists[key] = np.array([np.nanmedian(c) if np.isfinite(c).any() else np.nan for c in v.T])
    return out, hists
