"""Building forecourts and plazas as raised boxes (world key ``lot_raise``, session 24).

Real other-ground (forecourts, plazas, driveways) sits a little above the road plane (a median
0.08 m over the 55 real scans) at about the sidewalk's remission (0.325); without ``lot_raise`` the
world paints it on the ground at road level (:func:`panoptic_bench.datasets.synthetic.street.build_street`).
"""

from __future__ import annotations

import numpy as np

from panoptic_bench.datasets.synthetic.profile import WorldProfile
from panoptic_bench.datasets.synthetic.raw_ids import TERRAIN

__all__ = ["raised_lot"]


def raised_lot(
    builder,
    rng: np.random.Generator,
    prof: WorldProfile,
    x0: float,
    x1: float,
    ys: list[float],
    label: int,
) -> float:
    """Add one lot ``[x0, x1) x [ys[0], ys[1])`` as a box from the ground up to a height drawn
    from ``prof.lot_raise`` (paved: the sidewalk's reflectivity; grass, ``label`` TERRAIN: a draw
    from ``prof.terrain_reflect`` and the terrain's roughness). ``builder``: the street builder
    (its ``box`` method); ``rng``: the lots' own stream. Returns the lot's height (m)."""
    z = float(rng.uniform(*prof.lot_raise))
    if label == TERRAIN:
        refl, rough = float(rng.uniform(*prof.terrain_reflect)), prof.terrain_rough
    else:
        refl, rough = prof.sidewalk_reflect, 0.0
    builder.box(x0, x1, ys[0], ys[1], 0.0, z, label, refl, rough=rough)
    return z
