"""Side streets: a road running away from the street through one frontage segment.

Real streets are not closed corridors: in the 55 real SemanticKITTI scans about a quarter of
the ground 6-12 m to the right of the sensor (5-15 m ahead and behind) is road (side streets,
inner lanes, junctions), where the straight synthetic street had none. :func:`open_side_street`
cuts a mouth ``side_street_width`` wide plus a sidewalk on each side out of a segment that has
just been built: every primitive of the segment is clipped away from the mouth (boxes are cut
along x, other shapes inside it are dropped), the road is painted from the carriageway edge out
to :data:`REACH`, two sidewalks flank it, the parking strip is split, and things standing in
the mouth stand on the road (a kerb height of 0 is listed first for it in the plan). Known
simplifications: the side street's road has the road's base reflectivity without the main
road's texture and dark patches; its sidewalks take the segment's kerb height, which is the
bank's height (up to ``verge_raise``) where the segment is a raised grass verge; and the street
furniture, clutter and pedestrians placed after the street is built (lamp posts, signs, street
trees, bins, people on the sidewalk line) may stand in the mouth near the main street's kerb.
"""

from __future__ import annotations

import numpy as np

from panoptic_bench.datasets.synthetic.raw_ids import ROAD, SIDEWALK
from panoptic_bench.datasets.synthetic.shapes import BOX

__all__ = ["REACH", "clip_rows", "open_side_street"]

#: How far from the centre line the side street runs (m).
REACH = 60.0
_MIN_PIECE = 0.05


def clip_rows(rows: list[tuple], xa: float, xb: float) -> list[tuple]:
    """Primitive rows with ``[xa, xb)`` along x removed.

    Parameters
    ----------
    rows : list of tuple
        ``(kind, center, half, yaw, label, reflect, rough)`` rows of ``street._Builder``.
    xa, xb : float
        The interval to clear, metres.

    Returns
    -------
    list of tuple
        Unyawed boxes overlapping the interval are cut into the parts outside it (parts thinner
        than 5 cm are dropped); any other shape whose x extent overlaps it is dropped.
    """
    out = []
    for row in rows:
        kind, center, half, yaw = row[0], row[1], row[2], row[3]
        lo, hi = center[0] - half[0], center[0] + half[0]
        if kind != BOX or yaw != 0.0:
            reach = max(half[0], half[1])
            lo, hi = center[0] - reach, center[0] + reach
            if hi <= xa or lo >= xb:
                out.append(row)
            continue
        if hi <= xa or lo >= xb:
            out.append(row)
            continue
        for a, b in ((lo, min(hi, xa)), (max(lo, xb), hi)):
            if b - a > _MIN_PIECE:
                piece = ((a + b) / 2, center[1], center[2])
                out.append((kind, piece, ((b - a) / 2, half[1], half[2])) + tuple(row[3:]))
    return out


def open_side_street(
    builder, start: int, gm, plan, rng: np.random.Generator, side: int, x0: float, x1: float
) -> bool:
    """Maybe turn part of the segment ``[x0, x1)`` on ``side`` into a side-street mouth.

    Parameters
    ----------
    builder : street._Builder
        Its ``rows[start:]`` are the segment's primitives.
    start : int
    gm : GroundMap
    plan : StreetPlan
        ``plan.curb[-1]`` / ``plan.kerb[-1]`` are the segment's; parking strips and kerbs are
        updated.
    rng : numpy.random.Generator
        The side streets' own stream (every segment draws from it the same way).
    side : int
        -1 (right, y < 0) or +1 (left).
    x0, x1 : float
        The segment's extent along x, metres.

    Returns
    -------
    bool
        Whether a side street was opened.
    """
    prof = plan.profile
    u, width, walk, at = (
        rng.random(),
        rng.uniform(*prof.side_street_width),
        rng.random(),
        rng.random(),
    )
    if u >= prof.side_street_prob:
        return False
    walk = float(min(prof.sidewalk[0] + walk * (prof.sidewalk[1] - prof.sidewalk[0]), 3.0))
    span = width + 2 * walk
    if x1 - x0 < span + 2.0:
        return False
    xa = x0 + 1.0 + at * (x1 - x0 - 2.0 - span)
    xb = xa + span
    builder.rows[start:] = clip_rows(builder.rows[start:], xa, xb)
    y_curb, kerb = plan.curb[-1][3], plan.kerb[-1][3]
    ys = sorted((side * plan.road_half, side * REACH))
    gm.paint(xa + walk, xb - walk, ys[0], ys[1], ROAD, prof.road_reflect)
    for a in (xa, xb - walk):
        builder.box(a, a + walk, side * y_curb, side * REACH, 0.0, kerb, SIDEWALK,
                    prof.sidewalk_reflect)  # fmt: skip
    strips = []
    for s, a, b in plan.parking:
        if s != side or b <= xa or a >= xb:
            strips.append((s, a, b))
            continue
        strips += [(s, a, xa)] if xa - a > 5.0 else []
        strips += [(s, xb, b)] if b - xb > 5.0 else []
    plan.parking[:] = strips
    plan.kerb.insert(0, (side, xa + walk, xb - walk, 0.0))
    return True
