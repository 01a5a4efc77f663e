"""Procedural street layout: the static "stuff" of the synthetic world.

A straight street along the world x axis, centred on ``y = 0``: a road with lanes and lane
markings, parking strips in some segments, raised sidewalks with kerbs, and behind them a
frontage chosen per segment (building facades, green areas with terrain, bushes and trees,
fences, paved plazas of other-ground), with a second row of buildings further back, and
optionally side streets cut through it (:mod:`.side_streets`). Lamp poles,
traffic signs on poles (low sign posts too, :mod:`.signs`) and street trees stand on the sidewalks. The returned
:class:`StreetPlan` says where things may be placed (parking strips, sidewalks, lanes).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from panoptic_bench.datasets.synthetic import plants
from panoptic_bench.datasets.synthetic.fences import build_fence, build_guard_rail
from panoptic_bench.datasets.synthetic.ground import GroundMap
from panoptic_bench.datasets.synthetic.lots import raised_lot
from panoptic_bench.datasets.synthetic.paint import ROAD_TEXTURE, dark_patches, markings
from panoptic_bench.datasets.synthetic.plants import bush, plant_shrubs, planting_bed, tree
from panoptic_bench.datasets.synthetic.profile import CLASSIC, WorldProfile
from panoptic_bench.datasets.synthetic.raw_ids import (
    BUILDING,
    OTHER_GROUND,
    OTHER_OBJECT,
    OTHER_STRUCTURE,
    PARKING,
    POLE,
    ROAD,
    SIDEWALK,
    SIGN,
    TERRAIN,
    VEGETATION,
)
from panoptic_bench.datasets.synthetic.shapes import BOX, CYLINDER, Primitives
from panoptic_bench.datasets.synthetic.side_streets import open_side_street
from panoptic_bench.datasets.synthetic.signs import sign_posts

__all__ = ["StreetPlan", "build_street", "curb_at", "kerb_at"]

KERB = 0.14
PARKING_WIDTH = 2.3


@dataclass
class StreetPlan:
    """Where things can go on a generated street (distances are unsigned, per side).

    Attributes
    ----------
    lane_width : float
    lanes_per_side : int
    road_half : float
        Half width of the carriageway (lanes of both directions).
    sidewalk_width : float
    parking : list of (side, x0, x1)
        Parking strips; ``side`` is +1 (left, y > 0) or -1 (right).
    curb : list of (side, x0, x1, y_curb)
        Per segment, the distance of the kerb (sidewalk inner edge) from the centre line.
    kerb : list of (side, x0, x1, height)
        Per segment, the kerb (sidewalk) height; :data:`KERB` where no segment is listed.
    yards : list of (side, x0, x1, y_front, y_back, z)
        Per green, fence or plaza frontage, the open ground behind the sidewalk (unsigned
        distances from the centre line) and its height: where ``yard_cars`` parks cars.
    profile : WorldProfile
        The world profile the street was built with.
    """

    lane_width: float
    lanes_per_side: int
    road_half: float
    sidewalk_width: float
    parking: list = field(default_factory=list)
    curb: list = field(default_factory=list)
    kerb: list = field(default_factory=list)
    yards: list = field(default_factory=list)
    profile: WorldProfile = CLASSIC


class _Builder:
    """Accumulates primitive rows, splitting long boxes so angular culling stays tight."""

    def __init__(self) -> None:
        self.rows: list[tuple] = []

    def add(self, kind, center, half, label, reflect, yaw=0.0, rough=0.0) -> None:
        self.rows.append((kind, center, half, yaw, label, reflect, rough))

    def box(self, x0, x1, y0, y1, z0, z1, label, reflect, rough=0.0, piece=6.0) -> None:
        y0, y1 = min(y0, y1), max(y0, y1)
        n = max(1, int(np.ceil((x1 - x0) / piece)))
        edges = np.linspace(x0, x1, n + 1)
        for a, b in zip(edges[:-1], edges[1:]):
            center = ((a + b) / 2, (y0 + y1) / 2, (z0 + z1) / 2)
            self.add(
                BOX,
                center,
                ((b - a) / 2, (y1 - y0) / 2, (z1 - z0) / 2),
                label,
                reflect,
                rough=rough,
            )

    def primitives(self) -> Primitives:
        n = len(self.rows)
        if n == 0:
            return Primitives.empty()
        return Primitives(
            np.array([r[0] for r in self.rows], np.int8),
            np.array([r[1] for r in self.rows], float),
            np.array([r[2] for r in self.rows], float),
            np.array([r[3] for r in self.rows], float),
            np.array([r[4] for r in self.rows], np.uint16),
            np.full(n, -1, np.int32),
            np.array([r[5] for r in self.rows], np.float32),
            np.array([r[6] for r in self.rows], np.float32),
        )


def _buildings(b: _Builder, rng, x0, x1, side, y_near, heights=(6.0, 22.0)) -> None:
    x = x0
    while x < x1 - 2.0:
        w = min(rng.uniform(8.0, 20.0), x1 - x)
        h = rng.uniform(*heights)
        depth = rng.uniform(6.0, 12.0)
        inset = rng.uniform(0.0, 1.0)
        y_a = side * (y_near + inset)
        b.box(x, x + w, y_a, y_a + side * depth, 0.0, h, BUILDING, rng.uniform(0.25, 0.55))
        x += w + (rng.uniform(1.0, 4.0) if rng.random() < 0.3 else 0.0)


def _segment(
    b: _Builder,
    gm: GroundMap,
    rng,
    plan: StreetPlan,
    side: int,
    x0: float,
    x1: float,
    verge_rng: np.random.Generator | None = None,
    strip_rng: np.random.Generator | None = None,
    fence_rng: np.random.Generator | None = None,
    lot_rng: np.random.Generator | None = None,
    rail_rng: np.random.Generator | None = None,
    flush_rng: np.random.Generator | None = None,
    kerb_rng: np.random.Generator | None = None,
    shrub_rng: np.random.Generator | None = None,
    bed_rng: np.random.Generator | None = None,
) -> None:
    prof = plan.profile
    parking = rng.random() < prof.parking_prob
    y_curb = plan.road_half + (PARKING_WIDTH if parking else 0.0)
    if parking:
        plan.parking.append((side, x0, x1))
        ys = sorted((side * plan.road_half, side * y_curb))
        if prof.parking_road and strip_rng.random() < prof.parking_road:
            # kerb-side parking on the carriageway: road label and the road's texture
            gm.paint(x0, x1, ys[0], ys[1], ROAD, prof.road_reflect)
            gm.add_noise(x0, x1, ys[0], ys[1], strip_rng, ROAD_TEXTURE)
        else:
            gm.paint(x0, x1, ys[0], ys[1], PARKING, 0.32)
    plan.curb.append((side, x0, x1, y_curb))
    y_front = y_curb + plan.sidewalk_width
    kerb = KERB if prof.kerb[0] == prof.kerb[1] == KERB else float(rng.uniform(*prof.kerb))
    if prof.verge_prob and verge_rng.random() < prof.verge_prob:
        # a grass verge instead of the paved sidewalk: real roads are often bordered by terrain
        y0, y1, refl = side * y_curb, side * y_front, verge_rng.uniform(*prof.terrain_reflect)
        if prof.verge_raise:  # a raised bank (real terrain sits higher than sidewalks)
            kerb = float(verge_rng.uniform(*prof.verge_raise))
        if flush_rng is not None and flush_rng.random() < prof.verge_flush:
            kerb = 0.0  # flush with the road, no step: grass painted on the ground
            gm.paint(*sorted((x0, x1)), *sorted((y0, y1)), TERRAIN, refl)
        else:
            b.box(x0, x1, y0, y1, 0.0, kerb, TERRAIN, refl, rough=prof.terrain_rough)
        plan.kerb.append((side, x0, x1, kerb))  # what stands on the verge stands on its top
        if prof.guard_rail and rail_rng.random() < prof.guard_rail:
            y_rail = side * (y_curb + rail_rng.uniform(0.3, 1.0))
            build_guard_rail(b, x0 + 0.5, x1 - 0.5, y_rail, side, kerb, rail_rng)
        if shrub_rng is not None and shrub_rng.random() < prof.verge_shrubs:
            plant_shrubs(b, shrub_rng, x0, x1, y_curb, y_front, side, kerb)
    else:
        if kerb_rng is not None and kerb_rng.random() < prof.kerb_flush:
            kerb = 0.0  # a lowered kerb: the sidewalk painted on the ground at road level
        plan.kerb.append((side, x0, x1, kerb))
        y_walk = y_front
        if bed_rng is not None and bed_rng.random() < prof.planting_beds:
            refl = bed_rng.uniform(*prof.terrain_reflect)
            y_walk -= planting_bed(b, gm, bed_rng, x0, x1, y_front, side, kerb, refl)
        ys = sorted((side * y_curb, side * y_walk))
        if kerb:
            b.box(x0, x1, *ys, 0.0, kerb, SIDEWALK, prof.sidewalk_reflect)
        else:
            gm.paint(x0, x1, *ys, SIDEWALK, prof.sidewalk_reflect)
    kind = rng.choice(["building", "green", "fence", "plaza"], p=list(prof.frontage_p))
    back = y_front + rng.uniform(*prof.green_depth)
    if kind == "building":
        setback = rng.uniform(0.0, 3.0)
        if setback > 0.5:
            ys = sorted((side * y_front, side * (y_front + setback)))
            label = OTHER_GROUND if rng.random() < 0.6 else TERRAIN
            if lot_rng is None:
                gm.paint(x0, x1, ys[0], ys[1], label, 0.3)
            else:
                raised_lot(b, lot_rng, prof, x0, x1, ys, label)
        _buildings(b, rng, x0, x1, side, y_front + setback)
        return
    z = 0.0
    if kind == "plaza":
        ys = sorted((side * y_front, side * back))
        if lot_rng is None:
            gm.paint(x0, x1, ys[0], ys[1], OTHER_GROUND, 0.28)
        else:
            z = raised_lot(b, lot_rng, prof, x0, x1, ys, OTHER_GROUND)
    else:
        if prof.terrain_raise:
            z = float(rng.uniform(*prof.terrain_raise))
            ys = sorted((side * y_front, side * back))
            refl = rng.uniform(*prof.terrain_reflect)
            b.box(x0, x1, ys[0], ys[1], 0.0, z, TERRAIN, refl, rough=prof.terrain_rough)
        if shrub_rng is not None and kind == "green" and shrub_rng.random() < prof.verge_shrubs:
            plant_shrubs(b, shrub_rng, x0, x1, y_front - 0.2, y_front + 1.7, side, z)
        if kind == "fence":
            fh = rng.uniform(*prof.fence_height)
            yf, refl = side * (y_front + 0.3), rng.uniform(0.2, 0.5)
            build_fence(b, x0 + 0.5, x1 - 0.5, yf, side, fh, refl, fence_rng, prof.fence_lattice)
        else:
            hedge = rng.random() < 0.5
            if hedge:
                yh = side * (y_front + 0.2)
                b.box(
                    x0 + 0.5,
                    x1 - 0.5,
                    yh,
                    yh + side * 0.9,
                    0.0,
                    rng.uniform(0.8, 1.6),
                    VEGETATION,
                    0.45,
                    rough=0.12,
                )
        if rng.random() < 0.5 and x1 - x0 > 4.0:
            xp = rng.uniform(x0, x1 - 2.0)
            ys = sorted((side * y_front, side * back))
            gm.paint(xp, xp + 2.0, ys[0], ys[1], OTHER_GROUND, 0.28)
        length = x1 - x0
        for _ in range(rng.poisson(length / prof.tree_spacing)):
            xt, yt = rng.uniform(x0, x1), side * rng.uniform(y_front + 2.5, back - 2.0)
            tree(b, rng, xt, yt, z, prof.trunk_height, prof.trunk_radius, prof.crown_lift)
        for _ in range(rng.poisson(length / prof.bush_spacing)):
            bush(b, rng, rng.uniform(x0, x1), side * rng.uniform(y_front + 1.5, back - 1.0), z)
    plan.yards.append((side, x0, x1, y_front, back, z))
    if prof.back_row_prob >= 1.0 or rng.random() < prof.back_row_prob:
        _buildings(b, rng, x0, x1, side, back, heights=(8.0, 25.0))


def curb_at(plan: StreetPlan, side: int, x: float) -> float:
    """Distance of the kerb from the centre line on ``side`` at ``x``."""
    for s, a, b, y in plan.curb:
        if s == side and a <= x < b:
            return y
    return plan.road_half


def kerb_at(plan: StreetPlan, side: int, x: float) -> float:
    """Height of the kerb (sidewalk surface) on ``side`` at ``x``, metres."""
    for s, a, b, h in plan.kerb:
        if s == side and a <= x < b:
            return h
    return KERB


def _clutter(b: _Builder, rng, plan: StreetPlan, x0: float, x1: float) -> None:
    """Unlabelled clutter on the sidewalks: bins, bollards, benches, boxes, shelters, walls."""
    for side in (-1, 1):
        for _ in range(rng.poisson((x1 - x0) / plan.profile.clutter_spacing)):
            x = rng.uniform(x0, x1)
            kz = kerb_at(plan, side, x)
            y = side * (curb_at(plan, side, x) + rng.uniform(0.3, plan.sidewalk_width))
            refl = float(rng.uniform(0.1, 0.6))
            if rng.random() < 0.7:
                r, h = rng.uniform(0.1, 0.45), rng.uniform(0.4, 1.3)
                kind = CYLINDER if rng.random() < 0.5 else BOX
                b.add(kind, (x, y, kz + h / 2), (r, r, h / 2), OTHER_OBJECT, refl,
                      yaw=rng.uniform(0, np.pi))  # fmt: skip
            else:
                hx, hy, h = rng.uniform(0.5, 2.5), rng.uniform(0.2, 1.0), rng.uniform(1.0, 2.8)
                b.add(BOX, (x, y, kz + h / 2), (hx, hy, h / 2), OTHER_STRUCTURE, refl)


def _furniture(b: _Builder, rng, plan: StreetPlan, x0: float, x1: float) -> None:
    prof = plan.profile
    # which lamp poles stand and which carry a sign: their own stream (after the verges and strips)
    lamp_rng = rng.spawn(1)[0] if prof.lamp_signs or prof.lamp_keep < 1.0 else None
    # which kerb trees stand: a stream apart from every spawn, so nothing else moves
    tree_rng = plants.stream_apart(rng, 0x7EE) if prof.kerb_tree_keep < 1.0 else None
    kerb_tree = (prof.trunk_height, prof.trunk_radius, prof.crown_lift, prof.kerb_crown_clearance)
    for side in (-1, 1):

        def y_curb_at(x: float, side: int = side) -> float:
            return curb_at(plan, side, x)

        x = x0 + rng.uniform(0, 20)
        while x < x1:
            y = side * (y_curb_at(x) + 0.45)
            h = rng.uniform(6.0, 9.0)
            kz = kerb_at(plan, side, x)
            if prof.lamp_keep >= 1.0 or lamp_rng.random() < prof.lamp_keep:
                b.add(CYLINDER, (x, y, kz + h / 2), (0.1, 0.1, h / 2), POLE, 0.4)
                b.add(BOX, (x, y - side * 0.8, kz + h - 0.1), (0.08, 0.8, 0.06), POLE, 0.4)
                if prof.lamp_signs and lamp_rng.random() < prof.lamp_signs:
                    half = lamp_rng.uniform(*prof.lamp_sign_half)  # plates, street-name boards
                    zs = kz + lamp_rng.uniform(2.2, 3.0) + half
                    b.add(BOX, (x + 0.12, y, zs), (0.01, half, half), SIGN, 0.95)
            x += rng.uniform(18.0, 32.0)
        x = x0 + rng.uniform(0, 30)
        while x < x1:
            y = side * (y_curb_at(x) + 0.5)
            h = rng.uniform(2.2, 2.8)
            kz = kerb_at(plan, side, x)
            b.add(CYLINDER, (x, y, kz + h / 2), (0.035, 0.035, h / 2), POLE, 0.4)
            b.add(BOX, (x + 0.05, y, kz + h + 0.3), (0.01, 0.32, 0.32), SIGN, 0.95)
            x += rng.uniform(25.0, 60.0)
        x = x0
        while x < x1:
            seg = rng.uniform(20.0, 50.0)
            if rng.random() < 0.55:
                xt = x + rng.uniform(2.0, 6.0)
                while xt < min(x + seg, x1):
                    zt = kerb_at(plan, side, xt)
                    yt = side * (y_curb_at(xt) + 0.55)
                    kept = tree_rng is None or tree_rng.random() < prof.kerb_tree_keep
                    tree(b if kept else plants.DISCARD, rng, xt, yt, zt, *kerb_tree)
                    xt += rng.uniform(7.0, 12.0)
            x += seg


def build_street(
    rng: np.random.Generator, x_range: tuple[float, float], profile: WorldProfile = CLASSIC
) -> tuple[Primitives, GroundMap, StreetPlan]:
    """Generate the static world of one street.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of randomness (the street is a pure function of its state).
    x_range : tuple of float
        Extent of the street along x, metres.
    profile : WorldProfile
        Street dimensions, kerbs, terrain, vegetation and clutter (classic by default).

    Returns
    -------
    static : Primitives
        Every static stuff primitive, world frame.
    ground : GroundMap
        Labels and reflectivity of the ground plane.
    plan : StreetPlan
        Where things can be placed.
    """
    x0, x1 = x_range
    lanes = int(rng.choice([1, 2], p=list(profile.lanes_p)))
    lane_w = float(rng.uniform(*profile.lane_width))
    shoulder = float(rng.uniform(*profile.shoulder))
    sidewalk = float(rng.uniform(*profile.sidewalk))
    plan = StreetPlan(lane_w, lanes, lanes * lane_w + shoulder, sidewalk, profile=profile)
    gm = GroundMap.blank((x0 - 5.0, x1 + 5.0), (-70.0, 70.0))
    markings(gm, rng, plan, x0 - 5.0, x1 + 5.0)
    if profile.road_dark:
        dark_patches(gm, rng, plan, x0 - 5.0, x1 + 5.0, plan.road_half + PARKING_WIDTH)
    b = _Builder()
    # each optional part draws from its own stream, spawned only when its key is on and in this
    # order (spawning does not advance ``rng``): a world without it, or with a key added after it,
    # holds the same streets, objects and sensor draws; a new key goes at the end of the list
    optional = ("verge_prob", "parking_road", "side_street_prob", "fence_lattice", "lot_raise")
    optional += ("guard_rail", "verge_flush", "kerb_flush", "verge_shrubs", "planting_beds")
    verge_rng, strip_rng, side_rng, *rest = (
        rng.spawn(1)[0] if getattr(profile, key) else None for key in optional
    )
    for side in (-1, 1):
        x = x0
        while x < x1:
            length = rng.uniform(15.0, 40.0)
            if x1 - (x + length) < 10.0:
                length = x1 - x
            start = len(b.rows)
            _segment(b, gm, rng, plan, side, x, x + length, verge_rng, strip_rng, *rest)
            if side_rng is not None:
                open_side_street(b, start, gm, plan, side_rng, side, x, x + length)
            x += length
    _furniture(b, rng, plan, x0, x1)
    if profile.clutter_spacing:
        _clutter(b, rng, plan, x0, x1)
    if profile.sign_posts:  # its own stream, spawned after every other one
        sign_posts(b, rng.spawn(1)[0], plan, x0, x1)
    return b.primitives(), gm, plan
