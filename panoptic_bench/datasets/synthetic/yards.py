"""Cars parked off the street, in yards, driveways and car parks (world key ``yard_cars``, session 36).

On the 55 real scans most car points 15-40 m from the sensor lie more than 10 m to the side of
it (about 500 points a scan: cars in driveways, yards, car parks and side streets, 7.0 car
instances a scan at that range); the worlds park cars only in the strips beside the carriageway
(116 points, 2.8 instances). :func:`yard_cars` parks short rows of cars on the open ground behind
the sidewalk of green, fence and plaza frontages (``StreetPlan.yards``), after the scene is built
and from a stream of its own, so every other thing, primitive and draw of the scene stays as it
was; the sensor draws their materials from a stream of their own too
(:func:`~panoptic_bench.datasets.synthetic.sensor_real.sensor_state`). They stand where trees,
bushes, hedges and fences may hide part of them, as real cars in yards are.
"""

from __future__ import annotations

import numpy as np

from panoptic_bench.datasets.synthetic.things import Thing, build

__all__ = ["yard_cars"]

#: Free ground (m) a row keeps to its yard's ends and to the sidewalk / back edge.
EDGE_M = 3.0
#: Centre-to-centre spacing (m) of cars parked side by side.
SPACING_M = (2.5, 3.2)


def yard_cars(rng: np.random.Generator, yards: list[tuple], share: float) -> list[Thing]:
    """Rows of parked cars in a share of the yards.

    Parameters
    ----------
    rng : numpy.random.Generator
        The yard cars' own stream.
    yards : list of (side, x0, x1, y_front, y_back, z)
        ``StreetPlan.yards``: the open ground of a frontage (side +1 left, -1 right; unsigned
        distances from the centre line, metres) and the height of its surface.
    share : float
        Probability that a yard holds a row (1-3 cars, nose to the street or parallel to it).

    Returns
    -------
    list of Thing
        The parked cars, static, in the order of ``yards``.
    """
    cars: list[Thing] = []
    for side, x0, x1, y_front, y_back, z in yards:
        if rng.random() >= share:
            continue
        n = int(rng.integers(1, 4))
        across = rng.random() < 0.7  # nose to the street (driveways, car parks) or parallel
        depth = 5.0 if across else 2.2
        if y_back - y_front < 2 * EDGE_M + depth or x1 - x0 < 2 * EDGE_M + 2.0:
            continue
        y = side * float(rng.uniform(y_front + EDGE_M, y_back - EDGE_M - depth) + depth / 2)
        x = float(rng.uniform(x0 + EDGE_M, x1 - EDGE_M))
        for _ in range(n):
            yaw = (np.pi / 2 if rng.random() < 0.5 else -np.pi / 2) if across else 0.0
            car = build(rng, "car", (x, y, z), yaw + float(rng.normal(0.0, 0.05)))
            cars.append(car)
            x += float(rng.uniform(*SPACING_M)) if across else car.size[0] + 0.8
            if x > x1 - EDGE_M:
                break
    return cars
