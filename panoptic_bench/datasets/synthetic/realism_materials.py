"""Realism measures of the surface materials: stuff remission per class and its scan-to-scan spread.

Real SemanticKITTI scans come from one sensor in one city: the median remission of a stuff class
moves little from scan to scan (3-15 m: sidewalk 0.31, terrain 0.36, vegetation 0.36, each with a
scan-to-scan spread, std / mean of the per-scan medians, of 3-7 %), and stuff surfaces rarely return
exactly 0 (1-2 % of their points). Session 24 found the realistic world's stuff 3-6 times as spread
and 3-4 times as often 0 (per-primitive material draws), which teaches a model that remission says
little about sidewalk against terrain; these rows measure it (``synth stats``). Session 31 adds the
road (0.29, spread 7 %) and the order of the three ground classes at 3-15 m: in 98 % of the real
scans that hold all three, road is darker than sidewalk and sidewalk darker than terrain; row 30's
worlds kept that order in 50 % of their scans. Session 42 adds the upper block's near returns:
real stuff points 4-8 m away seen by the beams above -8.1 degrees are dim (median 0.24-0.29,
10-22 % exactly 0) where the lower block's are not.
"""

from __future__ import annotations

import numpy as np

from panoptic_bench.datasets.synthetic.raw_ids import (
    BUILDING,
    FENCE,
    OTHER_GROUND,
    OTHER_OBJECT,
    OTHER_STRUCTURE,
    POLE,
    ROAD,
    SIDEWALK,
    SIGN,
    TERRAIN,
    TRUNK,
    VEGETATION,
)

__all__ = ["MATERIAL_MEASURES", "material_measures"]

#: Classes with a per-scan median row and a scan-to-scan spread row: (key, name, raw id).
MATERIAL_CLASSES = (
    ("road", "road", ROAD),
    ("sidewalk", "sidewalk", SIDEWALK),
    ("terrain", "terrain", TERRAIN),
    ("vegetation", "vegetation", VEGETATION),
    ("building", "building", BUILDING),
    ("other_ground", "other-ground", OTHER_GROUND),
)
#: Stuff surfaces whose exact-zero share is measured.
STUFF = (SIDEWALK, OTHER_GROUND, BUILDING, FENCE, VEGETATION, TRUNK, TERRAIN)
#: Upright stuff of the upper block's near rows.
UPRIGHT = (BUILDING, FENCE, VEGETATION, TRUNK, POLE, SIGN, OTHER_STRUCTURE, OTHER_OBJECT)
#: Elevation (degrees, from the sensor) above which a point counts as an upper-block return.
UPPER_DEG = -8.1
#: Fewest points of a class in 3-15 m for a scan's median to count.
MIN_POINTS = 200

#: Scalar measures (``realism.MEASURES`` format); "cv" = std / mean over scans of the per-scan value.
MATERIAL_MEASURES: dict[str, tuple[str, str]] = {
    **{
        f"rem_{key}_median": (f"remission: {name} median (3-15 m)", "median")
        for key, name, _ in MATERIAL_CLASSES
    },
    **{
        f"rem_{key}_cv": (
            f"remission: scan-to-scan spread of the {name} median (std / mean)",
            "cv",
        )
        for key, name, _ in MATERIAL_CLASSES
    },
    "rem_ground_order_pct": (
        "remission: % of scans whose road, sidewalk and terrain medians (3-15 m) rise in that order "
        "(scans holding all three)",
        "mean",
    ),
    "rem_stuff_zero_pct": (
        "remission: % of stuff points exactly 0 (3-15 m: sidewalk, other-ground, building, fence, "
        "vegetation, trunk, terrain)",
        "mean",
    ),
    "rem_upper_near_median": (
        "remission: upright stuff 4-8 m away above -8.1 degrees (upper block) median (session 42)",
        "median",
    ),
    "rem_upper_near_zero_pct": (
        "remission: % of upright stuff points 4-8 m away above -8.1 degrees exactly 0 (session 42)",
        "mean",
    ),
}


def material_measures(
    rem: np.ndarray, raw: np.ndarray, r: np.ndarray, z: np.ndarray | None = None
) -> dict[str, float]:
    """Per-scan values of :data:`MATERIAL_MEASURES`.

    Parameters
    ----------
    rem : ndarray of shape (N,), float64
        Remission.
    raw : ndarray of shape (N,), int64
        Raw SemanticKITTI label ids.
    r : ndarray of shape (N,), float64
        Horizontal range from the sensor (m).
    z : ndarray of shape (N,), float64, optional
        Height above the sensor (m); without it the upper-block rows are ``nan``.

    Returns
    -------
    dict of str to float
        ``rem_<class>_median`` and ``rem_<class>_cv`` (both the scan's median; the spread is taken
        over scans by :func:`realism.aggregate`), ``rem_ground_order_pct`` (100 where the road,
        sidewalk and terrain medians rise strictly in that order, 0 where they do not, ``nan``
        where one of them is missing), ``rem_stuff_zero_pct``, ``rem_upper_near_median`` /
        ``rem_upper_near_zero_pct`` (:data:`UPRIGHT` points 4-8 m away whose elevation is above
        :data:`UPPER_DEG`); ``nan`` where a class (or those points) has fewer than
        :data:`MIN_POINTS` points.
    """
    near = (r >= 3) & (r < 15)
    m: dict[str, float] = {}
    for key, _, raw_id in MATERIAL_CLASSES:
        sel = near & (raw == raw_id)
        v = float(np.median(rem[sel])) if sel.sum() >= MIN_POINTS else float("nan")
        m[f"rem_{key}_median"] = m[f"rem_{key}_cv"] = v
    ground = [m[f"rem_{key}_median"] for key in ("road", "sidewalk", "terrain")]
    m["rem_ground_order_pct"] = (
        100.0 * float(ground[0] < ground[1] < ground[2])
        if np.all(np.isfinite(ground))
        else float("nan")
    )
    stuff = near & np.isin(raw, STUFF)
    m["rem_stuff_zero_pct"] = (
        100.0 * float(np.mean(rem[stuff] == 0)) if stuff.sum() >= MIN_POINTS else float("nan")
    )
    upper = np.zeros(rem.size, bool)
    if z is not None:
        upper = (r >= 4) & (r < 8) & (np.degrees(np.arctan2(z, r)) > UPPER_DEG)
    sel = upper & np.isin(raw, UPRIGHT)
    enough = sel.sum() >= MIN_POINTS
    m["rem_upper_near_median"] = float(np.median(rem[sel])) if enough else float("nan")
    m["rem_upper_near_zero_pct"] = 100.0 * float(np.mean(rem[sel] == 0)) if enough else float("nan")
    return m
