"""Plants of a street: trees, bushes, the low shrubs of world key ``verge_shrubs`` and the
planting beds of world key ``planting_beds``.

Of the vegetation points of the 55 real training scans 3-20 m away, 23 % lie within 0.5 m of the
road plane (ground cover and low planting beside the road; at least 10 % in every sequence), in
the worlds of realism rows 34 and 38 under 7 %: their bushes stand on the raised green areas
behind the sidewalk and their hedges' lower halves hide behind the raised terrain. The networks
trained on them call real stuff 0.3-0.9 m tall (low vegetation, low fences) bicycle.
:func:`plant_shrubs` fills a grass verge, or the front of a green frontage, with a row of low,
rough ellipsoids; the world key is the probability that each of them gets one, drawn with every
shape from a stream of its own, so a world without it is unchanged. Because the verges and green
areas are raised 0.1-0.45 m, those shrubs lift the share only to ~11 %. :func:`planting_bed`
(world key ``planting_beds``) turns the back of a paved sidewalk segment into a strip of soil
(terrain) at the sidewalk's own height, raised or flush, densely covered with ground cover, the
low planting between footway and frontage of many real streets. (A bed on the kerb side instead
hid most of the sidewalk behind it: sidewalk 8.4 -> 3.7 % of the points at probability 0.6.)
"""

from __future__ import annotations

import numpy as np

from panoptic_bench.datasets.synthetic.raw_ids import TERRAIN, TRUNK, VEGETATION
from panoptic_bench.datasets.synthetic.shapes import CYLINDER, ELLIPSOID

__all__ = [
    "DISCARD",
    "BED_ROUGH",
    "BED_WIDTH",
    "SHRUB_HALF",
    "SHRUB_HEIGHT",
    "bush",
    "plant_shrubs",
    "planting_bed",
    "stream_apart",
    "tree",
]

#: Range of a shrub's horizontal half axes (m).
SHRUB_HALF = (0.3, 0.8)
#: Range of a shrub's vertical half axis (m); it shows 0 to 1.5 x that above the verge.
SHRUB_HEIGHT = (0.15, 0.4)
#: Range of the gap between neighbouring shrubs along the verge (m).
_GAP = (0.2, 2.0)
#: Range of a planting bed's width across the street (m) and of the gaps of its ground cover.
BED_WIDTH = (0.6, 1.0)
_BED_GAP = (0.0, 0.5)
#: Roughness (m, mean ray penetration) of a bed's soil: raked earth, smoother than the profile's
#: ``terrain_rough`` grass (0.06 m in rows 39-40's worlds, which were generated with this value).
BED_ROUGH = 0.03


def plant_shrubs(
    builder, rng: np.random.Generator, x0, x1, y_near, y_far, side, z, gap=_GAP
) -> int:
    """Add low shrubs along the verge ``[x0, x1] x side * [y_near, y_far]`` standing at ``z``.

    Parameters
    ----------
    builder : street._Builder
        Receives the ellipsoids (label vegetation).
    rng : numpy.random.Generator
        The shrubs' own stream.
    x0, x1 : float
        Extent of the verge along the street (m).
    y_near, y_far : float
        Distances of the verge's road edge and outer edge from the centre line (m, > 0).
    side : {-1, 1}
        Side of the street.
    z : float
        Height of the verge's top (m).
    gap : tuple of float
        Range of the gap between neighbouring shrubs (m).

    Returns
    -------
    int
        Number of shrubs added.
    """
    n, x = 0, x0 + rng.uniform(*gap)
    lo, hi = y_near + 0.3, max(y_near + 0.3, y_far - 0.3)
    while x < x1 - 0.5:
        rx, ry = rng.uniform(*SHRUB_HALF, size=2)
        rz = rng.uniform(*SHRUB_HEIGHT)
        y = side * rng.uniform(lo, hi)
        centre = (x + rx, y, z + 0.5 * rz)
        builder.add(
            ELLIPSOID, centre, (rx, ry, rz), VEGETATION, 0.45, yaw=rng.uniform(0, np.pi), rough=0.12
        )
        n += 1
        x += 2 * rx + rng.uniform(*gap)
    return n


def planting_bed(builder, ground, rng: np.random.Generator, x0, x1, y_back, side, z, refl) -> float:
    """Make ``[x0, x1] x side * [y_back - w, y_back]`` a planting bed; return its width ``w`` (m).

    The bed lines the back of a sidewalk (``y_back``: its outer edge, m from the centre line):
    terrain at the sidewalk's height ``z`` (a box from the road up, or painted on the ground when
    ``z == 0``, a flush kerb) of reflectivity ``refl``, densely covered with low shrubs. ``w`` is
    drawn from :data:`BED_WIDTH`, every draw from ``rng``, the bed's own stream.
    """
    w = float(rng.uniform(*BED_WIDTH))
    ys = sorted((side * (y_back - w), side * y_back))
    if z > 0.0:
        builder.box(x0, x1, *ys, 0.0, z, TERRAIN, refl, rough=BED_ROUGH)
    else:
        ground.paint(x0, x1, *ys, TERRAIN, refl)
    plant_shrubs(builder, rng, x0, x1, y_back - w - 0.15, y_back + 0.15, side, z, gap=_BED_GAP)
    return w


class Discard:
    """A builder that keeps nothing: a thing drawn but not built leaves every draw in place."""

    def add(self, *args, **kwargs) -> None:
        pass


DISCARD = Discard()


def stream_apart(rng: np.random.Generator, key: int) -> np.random.Generator:
    """A stream derived from ``rng``'s seed at a fixed spawn key, without advancing its spawns."""
    seq = rng.bit_generator.seed_seq
    return np.random.default_rng(
        np.random.SeedSequence(seq.entropy, spawn_key=(*seq.spawn_key, key))
    )


def tree(
    b,
    rng: np.random.Generator,
    x: float,
    y: float,
    z: float,
    trunk_height: tuple[float, float] = (2.0, 3.5),
    trunk_radius: tuple[float, float] = (0.12, 0.25),
    crown_lift: float = 0.7,
    min_bottom: float = 0.0,
) -> None:
    """A tree standing at ``(x, y, z)``: a trunk (cylinder) and a crown (ellipsoid) on it.

    The crown's centre sits ``crown_lift`` of its vertical half axis above the trunk's top (0.7:
    the crown hangs 0.3 of it below the top and hides it; 1: it rests on the top). A crown whose
    lowest point would be less than ``min_bottom`` (m, 0 = off) above ``z`` is raised to it, its
    trunk lengthened by the same amount (clearance over a carriageway). The random draws are the
    same for any ``trunk_height``, ``trunk_radius``, ``crown_lift`` and ``min_bottom``.
    """
    trunk_h = rng.uniform(*trunk_height)
    r = rng.uniform(*trunk_radius)
    bark = rng.uniform(0.25, 0.4)
    rc = rng.uniform(1.4, 3.2)
    rz = rc * rng.uniform(0.8, 1.3)
    cx, cy = x + rng.normal(0, 0.2), y + rng.normal(0, 0.2)
    if min_bottom > 0.0:
        trunk_h += max(0.0, min_bottom - (trunk_h + (crown_lift - 1.0) * rz))
    b.add(CYLINDER, (x, y, z + trunk_h / 2), (r, r, trunk_h / 2), TRUNK, bark)
    center = (cx, cy, z + trunk_h + crown_lift * rz)
    b.add(ELLIPSOID, center, (rc, rc * rng.uniform(0.8, 1.2), rz), VEGETATION, 0.45, rough=0.25)


def bush(b, rng: np.random.Generator, x: float, y: float, z: float = 0.0) -> None:
    """A bush (rough ellipsoid, 0.4-1.1 m vertical half axis) standing at ``(x, y, z)``."""
    rx, ry, rz = rng.uniform(0.5, 1.6), rng.uniform(0.5, 1.6), rng.uniform(0.4, 1.1)
    b.add(
        ELLIPSOID,
        (x, y, z + 0.6 * rz if z else 0.6 * rz),
        (rx, ry, rz),
        VEGETATION,
        0.45,
        yaw=rng.uniform(0, np.pi),
        rough=0.12,
    )
