"""Parked buses, trucks and trailers (world keys ``parked_bus``, session 27; ``parked_truck``,
``parked_trailer``, session 45).

Real other-vehicle points (0.32 % of the 55 real scans: a bus in sequence 04, trailers in 05, 06
and 09) are far more common than in the worlds of realism rows 18a-22 (0.02 %: buses only in
moving traffic). :func:`park_buses` turns parked cars into parked buses after the scene is built,
from a stream of its own, so that every other primitive, thing and draw of the scene stays as it
was: the bus takes the car's place at its rear end and the parked things its 10-12.5 m cover are
removed; a bus that would leave its parking strip is not built. Trucks (6-12 m) and trailers
(other-vehicle, 4-8 m) replace parked cars the same way (:func:`park_instead`), each from its
own stream, so that the parked-vehicle mix is a world key and not a property of the street's
shared draws.
"""

from __future__ import annotations

import numpy as np

from panoptic_bench.datasets.synthetic.things import Thing, build

__all__ = ["park_buses", "park_instead"]

GAP_M = 0.3  # clearance kept to the next parked thing and to the strip's end (m)


def park_buses(
    rng: np.random.Generator,
    parked: list[Thing],
    strips: list[tuple[int, float, float]],
    share: float,
) -> list[Thing]:
    """The parked things with a share of the cars replaced by buses (:func:`park_instead`)."""
    return park_instead(rng, parked, strips, share, "bus")


def park_instead(
    rng: np.random.Generator,
    parked: list[Thing],
    strips: list[tuple[int, float, float]],
    share: float,
    category: str,
) -> list[Thing]:
    """The parked things with a share of the cars replaced by ``category`` things.

    Parameters
    ----------
    rng : numpy.random.Generator
        The stream of this key alone.
    parked : list of Thing
        Parked things of the scene (static, in parking strips), in any order; not modified.
    strips : list of (side, x0, x1)
        The street's parking strips (``StreetPlan.parking``).
    share : float
        Probability that a parked car (visited front to back along each side) is replaced.
    category : str
        What replaces it: ``"bus"``, ``"truck"`` or ``"other-vehicle"`` (a trailer).

    Returns
    -------
    list of Thing
        ``parked`` in its order, each converted car replaced in place by its new thing (its rear
        end where the car's was) and the things that thing covers left out.
    """
    out: list[Thing | None] = list(parked)
    for side in sorted({int(np.sign(t.xyz[1])) for t in parked}):
        ks = sorted((k for k, t in enumerate(parked) if np.sign(t.xyz[1]) == side),
                    key=lambda k: parked[k].xyz[0])  # fmt: skip
        for k in ks:
            car = out[k]
            if car is None or car.category != "car" or rng.random() >= share:
                continue
            new = build(rng, category, (0.0, car.xyz[1], car.xyz[2]), car.yaw)
            start = car.xyz[0] - car.size[0] / 2
            end = start + new.size[0]
            strip = [s for s in strips if s[0] == side and s[1] <= start < s[2]]
            if not strip or end > strip[0][2] - GAP_M:
                continue
            new.xyz[0] = start + new.size[0] / 2
            for j in ks:
                t = out[j]
                if j != k and t is not None and _overlaps(t, start, end + GAP_M):
                    out[j] = None
            out[k] = new
    return [t for t in out if t is not None]


def _overlaps(t: Thing, start: float, end: float) -> bool:
    return t.xyz[0] - t.size[0] / 2 < end and t.xyz[0] + t.size[0] / 2 > start
