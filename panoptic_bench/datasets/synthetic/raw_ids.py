"""Raw SemanticKITTI label ids (``semantic-kitti.yaml``) that the synthetic world builds and measures.

One place for the ids the street builders (:mod:`street`, :mod:`paint`, :mod:`side_streets`,
:mod:`fences`), the sensor model (:mod:`sensor_real`) and the realism measures (:mod:`realism`)
share, so that no module repeats a bare number.
"""

from __future__ import annotations

__all__ = [
    "BUILDING", "CAR", "FENCE", "MOVING_CAR", "OTHER_GROUND", "OTHER_OBJECT", "OTHER_STRUCTURE",
    "OTHER_VEHICLES", "PARKING", "PEOPLE", "POLE", "ROAD", "SIDEWALK", "SIGN", "TERRAIN", "TRUNK",
    "VEGETATION",
]  # fmt: skip

CAR, MOVING_CAR = 10, 252
ROAD, PARKING, SIDEWALK, OTHER_GROUND = 40, 44, 48, 49
BUILDING, FENCE, OTHER_STRUCTURE = 50, 51, 52
VEGETATION, TRUNK, TERRAIN = 70, 71, 72
POLE, SIGN = 80, 81
OTHER_OBJECT = 99
#: Vehicles that are not cars: bus, motorcycle, truck, other-vehicle (static and moving).
OTHER_VEHICLES = (13, 15, 18, 20, 257, 258, 259)
#: People and bicycles: bicycle, person, bicyclist, motorcyclist (static and moving).
PEOPLE = (11, 30, 31, 32, 253, 254, 255)
