"""Countable objects ("things") built from a few primitives with realistic size distributions.

Each builder returns the primitives of one object in its own frame (x forward, y left, z up,
origin on the ground under the object's centre) and the tight size ``(length, width, height)`` of
the box that contains them. Sizes follow rough real-world distributions (a car is about
4.5 x 1.8 x 1.5 m); shapes are several primitives, never a single box: a car has a body, a cabin
and wheels, a person has legs, arms, a torso and a head.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from panoptic_bench.datasets.synthetic.shapes import BOX, CYLINDER, ELLIPSOID, Primitives

__all__ = ["BUILDERS", "MOVING_LABEL", "STATIC_LABEL", "Thing", "build"]

#: Raw SemanticKITTI id of each thing category when still / when moving.
STATIC_LABEL = {
    "car": 10,
    "bicycle": 11,
    "bus": 13,
    "motorcycle": 15,
    "truck": 18,
    "other-vehicle": 20,
    "person": 30,
    "bicyclist": 31,
    "motorcyclist": 32,
}
MOVING_LABEL = {
    "car": 252,
    "bicyclist": 253,
    "person": 254,
    "motorcyclist": 255,
    "bus": 257,
    "truck": 258,
    "other-vehicle": 259,
}


@dataclass
class Thing:
    """One object of a scene and its straight-line motion.

    Attributes
    ----------
    category : str
        Key of :data:`STATIC_LABEL` (``"car"``, ``"person"``, ...).
    label : int
        Raw SemanticKITTI id of its points (moving variant when ``velocity`` is non-zero).
    prims : Primitives
        Primitives in the object frame.
    size : tuple of float
        ``(length, width, height)`` of the tight box, metres; the box bottom is at the object's
        base height.
    xyz : ndarray of shape (3,)
        Position of the object frame origin at time 0 (z = base height, e.g. a kerb).
    yaw : float
        Heading in radians.
    velocity : ndarray of shape (2,)
        Ground velocity in m/s (zero for parked objects).
    """

    category: str
    label: int
    prims: Primitives
    size: tuple[float, float, float]
    xyz: np.ndarray
    yaw: float
    velocity: np.ndarray

    @property
    def moving(self) -> bool:
        """True when the object moves."""
        return bool(np.any(self.velocity != 0))


def _make(parts: list[tuple[int, tuple, tuple, int, float]], rough: float = 0.0) -> Primitives:
    """Primitives from ``(kind, centre, half, label, reflectivity)`` rows."""
    n = len(parts)
    return Primitives(
        np.array([p[0] for p in parts], np.int8),
        np.array([p[1] for p in parts], float).reshape(n, 3),
        np.array([p[2] for p in parts], float).reshape(n, 3),
        np.zeros(n),
        np.array([p[3] for p in parts], np.uint16),
        np.full(n, -1, np.int32),
        np.array([p[4] for p in parts], np.float32),
        np.full(n, rough, np.float32),
    )


def _wheels(length_pos: list[float], half_track: float, radius: float, width: float, label: int):
    return [
        (BOX, (x, s * half_track, radius), (radius, width / 2, radius), label, 0.06)
        for x in length_pos
        for s in (-1.0, 1.0)
    ]


def car(rng: np.random.Generator, label: int) -> tuple[Primitives, tuple]:
    """A passenger car: body, cabin and four wheels (about 4.5 x 1.8 x 1.5 m)."""
    ln = float(np.clip(rng.normal(4.45, 0.3), 3.6, 5.2))
    w = float(np.clip(rng.normal(1.8, 0.07), 1.6, 2.0))
    h = float(np.clip(rng.normal(1.5, 0.1), 1.35, 1.85))
    paint = float(rng.uniform(0.08, 0.6))
    z0, z1 = 0.3, 0.3 + 0.42 * h
    cab = ln * rng.uniform(0.45, 0.6)
    parts = [
        (BOX, (0.0, 0.0, (z0 + z1) / 2), (ln / 2, w / 2, (z1 - z0) / 2), label, paint),
        (BOX, (-0.06 * ln, 0.0, (z1 + h) / 2), (cab / 2, 0.45 * w, (h - z1) / 2), label, 0.15),
    ]
    parts += _wheels([0.32 * ln, -0.32 * ln], w / 2 - 0.12, 0.32, 0.22, label)
    return _make(parts), (ln, w, h)


def truck(rng: np.random.Generator, label: int) -> tuple[Primitives, tuple]:
    """A truck 6-12 m long: cab, cargo box, chassis and wheels."""
    ln, w, h = (
        float(rng.uniform(6.0, 12.0)),
        float(rng.uniform(2.3, 2.55)),
        float(rng.uniform(3.0, 3.8)),
    )
    cab = 2.2
    parts = [
        (
            BOX,
            (ln / 2 - cab / 2, 0.0, 0.5 + 0.4 * (h - 0.5)),
            (cab / 2, w / 2, 0.4 * (h - 0.5)),
            label,
            0.4,
        ),
        (
            BOX,
            (-cab / 2 - 0.1, 0.0, (1.0 + h) / 2),
            ((ln - cab - 0.2) / 2, w / 2, (h - 1.0) / 2),
            label,
            float(rng.uniform(0.2, 0.7)),
        ),
        (BOX, (0.0, 0.0, 0.7), (ln / 2 - 0.2, w / 2 - 0.3, 0.2), label, 0.1),
    ]
    parts += _wheels([ln / 2 - 1.2, -ln / 2 + 1.4, -ln / 2 + 2.6], w / 2 - 0.2, 0.5, 0.35, label)
    return _make(parts), (ln, w, h)


def bus(rng: np.random.Generator, label: int) -> tuple[Primitives, tuple]:
    """A rigid bus (10-12.5 m): one tall body on wheels and a roof unit."""
    ln, w, h = float(rng.uniform(10.0, 12.5)), 2.55, float(rng.uniform(3.0, 3.3))
    parts = [
        (
            BOX,
            (0.0, 0.0, (0.35 + h - 0.25) / 2),
            (ln / 2, w / 2, (h - 0.6) / 2),
            label,
            float(rng.uniform(0.3, 0.6)),
        ),
        (BOX, (-ln * 0.2, 0.0, h - 0.125), (ln * 0.2, w / 2 - 0.3, 0.125), label, 0.3),
    ]
    parts += _wheels([ln / 2 - 2.5, -ln / 2 + 3.0], w / 2 - 0.25, 0.5, 0.3, label)
    return _make(parts), (ln, w, h)


def other_vehicle(rng: np.random.Generator, label: int) -> tuple[Primitives, tuple]:
    """A trailer or caravan (4-8 m): box on two axles with a drawbar."""
    ln, w, h = (
        float(rng.uniform(4.0, 8.0)),
        float(rng.uniform(2.0, 2.5)),
        float(rng.uniform(2.4, 3.4)),
    )
    box_len = ln - 1.0
    parts = [
        (
            BOX,
            (-0.5, 0.0, (0.6 + h) / 2),
            (box_len / 2, w / 2, (h - 0.6) / 2),
            label,
            float(rng.uniform(0.3, 0.7)),
        ),
        (BOX, (ln / 2 - 0.55, 0.0, 0.45), (0.55, 0.06, 0.05), label, 0.1),
    ]
    parts += _wheels([-0.5 + 0.4, -0.5 - 0.4], w / 2 - 0.2, 0.35, 0.22, label)
    return _make(parts), (ln, w, h)


def _bike_parts(label: int, ln: float, wheel_r: float, motor: bool) -> list:
    thick = 0.14 if motor else 0.05
    parts = [
        (BOX, (ln / 2 - wheel_r, 0.0, wheel_r), (wheel_r, thick / 2, wheel_r), label, 0.1),
        (BOX, (-ln / 2 + wheel_r, 0.0, wheel_r), (wheel_r, thick / 2, wheel_r), label, 0.1),
        (
            BOX,
            (ln / 2 - 2 * wheel_r - 0.05, 0.0, 2 * wheel_r + 0.25),
            (0.04, 0.3 if motor else 0.25, 0.04),
            label,
            0.3,
        ),
    ]
    if motor:
        parts.append((BOX, (0.0, 0.0, 0.6), (0.55, 0.2, 0.22), label, 0.45))
    else:
        parts.append((BOX, (0.0, 0.0, wheel_r + 0.2), (0.3, 0.03, 0.15), label, 0.35))
    return parts


def bicycle(rng: np.random.Generator, label: int) -> tuple[Primitives, tuple]:
    """A parked bicycle (about 1.75 x 0.5 x 1.05 m): wheels, frame and handlebar."""
    parts = _bike_parts(label, 1.75, 0.34, motor=False)
    return _make(parts), (1.75, 0.5, 1.0)


def motorcycle(rng: np.random.Generator, label: int) -> tuple[Primitives, tuple]:
    """A parked motorcycle (about 2.1 x 0.8 x 1.2 m)."""
    parts = _bike_parts(label, 2.1, 0.3, motor=True)
    parts.append((BOX, (0.55, 0.0, 1.05), (0.12, 0.2, 0.1), label, 0.5))
    return _make(parts), (2.1, 0.6, 1.15)


def _person_parts(
    rng: np.random.Generator, label: int, x: float, z: float, seated: bool
) -> tuple[list, float]:
    h = float(np.clip(rng.normal(1.72, 0.09), 1.5, 1.98))
    cloth = float(rng.uniform(0.15, 0.5))
    leg = 0.47 * h
    torso_lo = z + (0.0 if seated else leg)
    torso_hi = torso_lo + 0.33 * h
    parts = [
        (
            BOX,
            (x, 0.0, (torso_lo + torso_hi) / 2),
            (0.12, 0.2, (torso_hi - torso_lo) / 2),
            label,
            cloth,
        ),
        (ELLIPSOID, (x, 0.0, torso_hi + 0.13), (0.1, 0.09, 0.12), label, 0.25),
        (CYLINDER, (x + 0.03, 0.25, torso_hi - 0.28), (0.045, 0.045, 0.26), label, cloth),
        (CYLINDER, (x + 0.03, -0.25, torso_hi - 0.28), (0.045, 0.045, 0.26), label, cloth),
    ]
    if not seated:
        parts += [
            (CYLINDER, (x, 0.1, leg / 2), (0.075, 0.075, leg / 2), label, cloth),
            (CYLINDER, (x, -0.1, leg / 2), (0.075, 0.075, leg / 2), label, cloth),
        ]
    return parts, torso_hi + 0.25


def person(rng: np.random.Generator, label: int) -> tuple[Primitives, tuple]:
    """A pedestrian (height about 1.72 m): two legs, two arms, torso and head."""
    parts, top = _person_parts(rng, label, 0.0, 0.0, seated=False)
    return _make(parts), (0.3, 0.6, top)


def bicyclist(rng: np.random.Generator, label: int) -> tuple[Primitives, tuple]:
    """A person riding a bicycle; both carry the bicyclist label (as in SemanticKITTI)."""
    parts = _bike_parts(label, 1.75, 0.34, motor=False)
    rider, top = _person_parts(rng, label, -0.15, 0.95, seated=True)
    parts += rider + [
        (CYLINDER, (0.0, s * 0.12, 0.6), (0.06, 0.06, 0.35), label, 0.3) for s in (-1, 1)
    ]
    return _make(parts), (1.75, 0.6, top)


def motorcyclist(rng: np.random.Generator, label: int) -> tuple[Primitives, tuple]:
    """A person riding a motorcycle; both carry the motorcyclist label."""
    parts = _bike_parts(label, 2.1, 0.3, motor=True)
    rider, top = _person_parts(rng, label, -0.2, 0.82, seated=True)
    parts += rider
    return _make(parts), (2.1, 0.6, max(top, 1.15))


BUILDERS: dict[str, Callable[[np.random.Generator, int], tuple[Primitives, tuple]]] = {
    "car": car,
    "truck": truck,
    "bus": bus,
    "other-vehicle": other_vehicle,
    "bicycle": bicycle,
    "motorcycle": motorcycle,
    "person": person,
    "bicyclist": bicyclist,
    "motorcyclist": motorcyclist,
}


def build(
    rng: np.random.Generator,
    category: str,
    xyz: tuple[float, float, float],
    yaw: float,
    velocity: tuple[float, float] = (0.0, 0.0),
) -> Thing:
    """Build one thing of ``category`` at ``xyz`` with heading ``yaw`` and a ground velocity.

    The moving label variant (e.g. 252 moving-car) is used when ``velocity`` is non-zero.
    """
    vel = np.asarray(velocity, float)
    moving = bool(np.any(vel != 0)) and category in MOVING_LABEL
    label = MOVING_LABEL[category] if moving else STATIC_LABEL[category]
    prims, size = BUILDERS[category](rng, label)
    return Thing(
        category,
        label,
        prims,
        tuple(float(s) for s in size),
        np.asarray(xyz, float),
        float(yaw),
        vel,
    )
