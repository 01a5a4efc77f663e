"""Road paint of the synthetic street: asphalt texture, lane markings and dark patches.

Painted into the ground raster (:class:`GroundMap`) of :func:`street.build_street`; ``plan`` is
its :class:`street.StreetPlan` (lane width, lanes per side, carriageway half width, profile).
"""

from __future__ import annotations

import numpy as np

from panoptic_bench.datasets.synthetic.ground import GroundMap
from panoptic_bench.datasets.synthetic.raw_ids import ROAD

__all__ = ["ROAD_TEXTURE", "dark_patches", "markings"]

ROAD_TEXTURE = 0.025  # std of the road paint's reflectivity per 0.2 m cell


def markings(gm: GroundMap, rng, plan, x0: float, x1: float) -> None:
    """The road's paint and texture, dashed lane lines and the edge lines of the carriageway."""
    gm.paint(x0, x1, -plan.road_half, plan.road_half, ROAD, plan.profile.road_reflect)
    noise = rng.normal(0.0, ROAD_TEXTURE, size=gm.reflect.shape).astype(np.float32)
    gm.reflect += np.where(gm.label == ROAD, noise, 0.0).astype(np.float32)
    lines = [0.0] + [
        k * plan.lane_width * s for k in range(1, plan.lanes_per_side) for s in (-1, 1)
    ]
    for y in lines:
        for xd in np.arange(x0, x1, 9.0):
            gm.paint(xd, xd + 3.0, y - 0.075, y + 0.075, None, 0.75)
    for s in (-1, 1):
        y = s * (plan.lanes_per_side * plan.lane_width + 0.1)
        gm.paint(x0, x1, y - 0.06, y + 0.06, None, 0.7)


def dark_patches(gm: GroundMap, rng, plan, x0: float, x1: float, y_max: float) -> None:
    """Dark asphalt (repairs, wet or oily patches, tyre marks) on the road and parking strips.

    Rectangles 1-6 m long and 0.5-3 m wide with reflectivity 0.04-0.2 cover about
    ``profile.road_dark`` of the carriageway and parking area (real near road: ~4 % of returns
    exactly 0, 10th percentile of remission 0.10; a uniform synthetic road has neither). The
    patches fall anywhere in ``|y| < y_max`` (m: the carriageway and its parking strips).
    """
    mean_area = 3.5 * 1.75
    for _ in range(rng.poisson(plan.profile.road_dark * (x1 - x0) * 2 * y_max / mean_area)):
        length, width = rng.uniform(1.0, 6.0), rng.uniform(0.5, 3.0)
        x, y = rng.uniform(x0, x1), rng.uniform(-y_max, y_max)
        gm.paint(x, x + length, y - width / 2, y + width / 2, None, rng.uniform(0.04, 0.2))
