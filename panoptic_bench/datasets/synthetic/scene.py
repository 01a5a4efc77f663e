"""A complete synthetic scene: the street, its things and their motion, and the ego path.

:func:`generate_scene` is a pure function of its seed: the same seed gives the same street,
the same objects with the same instance ids, and the same trajectories. Things are placed where
they occur in real streets: rows of parked cars touching each other in the parking strips (with
the odd truck, trailer or motorcycle), pedestrians alone or in groups on the sidewalks, parked
bicycles, moving vehicles in the lanes of both directions, cyclists at the road edge.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from panoptic_bench.datasets.synthetic.buses import park_buses, park_instead
from panoptic_bench.datasets.synthetic.ground import GroundMap
from panoptic_bench.datasets.synthetic.profile import WorldProfile
from panoptic_bench.datasets.synthetic.profile_files import load_profile
from panoptic_bench.datasets.synthetic.shapes import Primitives
from panoptic_bench.datasets.synthetic.street import (
    PARKING_WIDTH,
    StreetPlan,
    build_street,
    curb_at,
    kerb_at,
)
from panoptic_bench.datasets.synthetic.things import Thing, build
from panoptic_bench.datasets.synthetic.yards import yard_cars

__all__ = ["Scene", "generate_scene"]

MARGIN = 100.0
#: The ego stays this far (m) inside its lane when ``ego_offset`` moves it towards the centre.
EGO_LANE_MARGIN = 0.3


@dataclass
class Scene:
    """A street with its things; the ego vehicle drives along +x at constant speed.

    Attributes
    ----------
    static : Primitives
        Static stuff, world frame.
    ground : GroundMap
        Labels and reflectivity of the ground plane ``z = 0``.
    plan : StreetPlan
        The street's cross-section.
    things : list of Thing
        Every thing; the instance id of ``things[k]`` is ``k + 1`` (unique in the scene).
    ego_speed : float
        m/s along +x.
    ego_y : float
        Lateral position of the ego path (its lane centre, moved by ``profile.ego_offset``).
    ego_phase : float
        Phase of the ego's lateral sway.
    late_things : int
        The last ``late_things`` things were added by a key drawn after every other draw
        (``yard_cars``); the sensor draws their materials from a stream of their own.
    """

    static: Primitives
    ground: GroundMap
    plan: StreetPlan
    things: list[Thing]
    ego_speed: float
    ego_y: float
    ego_phase: float = 0.0
    late_things: int = 0

    def __post_init__(self) -> None:
        parts = []
        for k, thing in enumerate(self.things):
            p = thing.prims.take(slice(None))
            p.owner = np.full(len(p), k, np.int32)
            parts.append(p)
        self._local = Primitives.concat(parts)
        self._xyz0 = np.array([t.xyz for t in self.things]).reshape(-1, 3)
        self._yaw = np.array([t.yaw for t in self.things], float)
        self._vel = np.array([t.velocity for t in self.things]).reshape(-1, 2)

    def thing_poses(self, time: float) -> tuple[np.ndarray, np.ndarray]:
        """Positions ``(K, 3)`` and headings ``(K,)`` of all things at ``time`` seconds."""
        xyz = self._xyz0.copy()
        xyz[:, :2] += self._vel * time
        return xyz, self._yaw

    def primitives_at(self, time: float) -> Primitives:
        """All primitives (static first, then things) in the world frame at ``time``."""
        xyz, yaw = self.thing_poses(time)
        moved = self._local.placed(xyz[:, :2], yaw, self._local.owner)
        moved.center[:, 2] += xyz[self._local.owner, 2]
        return Primitives.concat([self.static, moved])

    def ego_pose(self, time: float) -> tuple[float, float, float]:
        """Ego ``(x, y, yaw)`` at ``time``: constant speed with a gentle lateral sway."""
        w, amp = 0.25, 0.2
        x = self.ego_speed * time
        y = self.ego_y + amp * np.sin(w * time + self.ego_phase)
        yaw = np.arctan2(amp * w * np.cos(w * time + self.ego_phase), self.ego_speed)
        return float(x), float(y), float(yaw)


def _parked_rows(rng, plan: StreetPlan, things: list[Thing]) -> None:
    cats = ["car", "truck", "other-vehicle", "motorcycle", None]
    probs = [0.86, 0.04, 0.03, 0.03, 0.04]
    fill = plan.profile.parked_fill
    for side, x0, x1 in plan.parking:
        if fill < 1.0 and rng.random() >= fill:
            continue
        yaw0 = 0.0 if side < 0 else np.pi
        x = x0 + rng.uniform(0.3, 3.0)
        while x < x1:
            cat = cats[rng.choice(len(cats), p=probs)]
            if cat is None:
                x += rng.uniform(3.0, 6.0)
                continue
            y = side * (plan.road_half + PARKING_WIDTH / 2 + rng.normal(0.0, 0.08))
            thing = build(rng, cat, (0.0, y, 0.0), yaw0 + rng.normal(0.0, 0.025))
            length = thing.size[0]
            if x + length > x1 - 0.3:
                break
            thing.xyz[0] = x + length / 2
            things.append(thing)
            x += length + rng.uniform(0.15, 1.0)
            if rng.random() < 0.08:
                x += rng.uniform(3.0, 8.0)


def _sidewalk(rng, plan: StreetPlan, x_range, things: list[Thing]) -> None:
    x0, x1 = x_range
    sw = plan.sidewalk_width
    for side in (-1, 1):
        for _ in range(rng.poisson((x1 - x0) / plan.profile.ped_spacing)):
            x = rng.uniform(x0, x1)
            yc = curb_at(plan, side, x)
            size = int(rng.choice([1, 2, 3, 4, 5], p=[0.35, 0.3, 0.17, 0.12, 0.06]))
            walking = rng.random() < 0.55
            v = rng.choice([-1.0, 1.0]) * rng.uniform(0.8, 1.6) if walking else 0.0
            lateral = rng.uniform(1.2, max(1.25, sw - 0.8))
            for k in range(size):
                dx = (k // 2) * rng.uniform(0.65, 0.9)
                dy = (k % 2) * rng.uniform(0.75, 0.85)
                y = side * (yc + min(lateral + dy, sw - 0.35))
                heading = (0.0 if v >= 0 else np.pi) if walking else rng.uniform(-np.pi, np.pi)
                kz = kerb_at(plan, side, x + dx)
                things.append(build(rng, "person", (x + dx, y, kz), heading, (v, 0.0)))
        for _ in range(rng.poisson((x1 - x0) / plan.profile.bike_spacing)):
            x = rng.uniform(x0, x1)
            y = side * (curb_at(plan, side, x) + sw - 0.35)
            cat = "bicycle" if rng.random() < 0.85 else "motorcycle"
            for k in range(int(rng.integers(1, 5))):
                things.append(
                    build(
                        rng,
                        cat,
                        (x + k * rng.uniform(0.7, 0.9), y, kerb_at(plan, side, x)),
                        np.pi / 2 + rng.normal(0, 0.05),
                    )
                )


def _traffic(
    rng, plan: StreetPlan, x_range, ego_lane: int, ego_speed: float, things: list[Thing]
) -> None:
    x0, x1 = x_range
    lw, n = plan.lane_width, plan.lanes_per_side
    cats = ["car", "truck", "bus", "other-vehicle", "motorcyclist"]
    probs = [0.8, 0.07, 0.05, 0.03, 0.05]
    for side in (-1, 1):
        direction = -side
        for lane in range(n):
            if side < 0 and lane == ego_lane:
                if rng.random() < plan.profile.lead_car_prob:
                    y = side * (lane + 0.5) * lw
                    lead = build(
                        rng, "car", (rng.uniform(12.0, 25.0), y, 0.0), 0.0, (ego_speed, 0.0)
                    )
                    things.append(lead)
                continue
            y = side * (lane + 0.5) * lw
            speed = rng.uniform(6.0, 13.0)
            x = x0 + rng.uniform(0.0, 30.0)
            while x < x1:
                cat = cats[rng.choice(len(cats), p=probs)]
                yaw = 0.0 if direction > 0 else np.pi
                thing = build(
                    rng, cat, (x, y + rng.normal(0, 0.1), 0.0), yaw, (direction * speed, 0.0)
                )
                things.append(thing)
                x += thing.size[0] + rng.uniform(*plan.profile.traffic_gap)
        y = side * (plan.road_half - 0.6)
        for _ in range(rng.poisson((x1 - x0) / plan.profile.cyclist_spacing)):
            x = rng.uniform(x0, x1)
            moving = rng.random() < 0.75
            v = direction * rng.uniform(3.5, 6.5) if moving else 0.0
            yaw = 0.0 if direction > 0 else np.pi
            things.append(build(rng, "bicyclist", (x, y, 0.0), yaw, (v, 0.0)))
        if rng.random() < 0.2:
            things.append(
                build(
                    rng,
                    "motorcyclist",
                    (rng.uniform(x0, x1), y, 0.0),
                    0.0 if direction > 0 else np.pi,
                )
            )


def street_profile(profile: WorldProfile, seed: int | tuple | list) -> WorldProfile:
    """The profile one street is built with: ``profile`` with its per-street draws made.

    ``road_reflect_range`` (when set) draws this street's ``road_reflect`` from its own stream,
    ``default_rng([*seed, 3])``, so that no other draw of the street changes.

    Parameters
    ----------
    profile : WorldProfile
    seed : int or sequence of int
        The scene's seed (``[seed, key]`` for a :class:`~.sequence.Sequence`).

    Returns
    -------
    WorldProfile
    """
    if not profile.road_reflect_range:
        return profile
    lo, hi = profile.road_reflect_range
    rng = np.random.default_rng([*np.atleast_1d(seed).tolist(), 3])
    return dataclasses.replace(profile, road_reflect=float(rng.uniform(lo, hi)))


def generate_scene(
    seed: int | tuple | list,
    duration: float,
    ego_speed: float | None = None,
    profile: WorldProfile | str | None = None,
) -> Scene:
    """Generate a street scene long enough for ``duration`` seconds of ego driving.

    Parameters
    ----------
    seed : int or sequence of int
        Seed of the scene (``numpy.random.default_rng(seed)``).
    duration : float
        Seconds the ego vehicle drives; the street extends ``100 m`` beyond both ends.
    ego_speed : float, optional
        Ego speed in m/s (random in 5-10 m/s by default).
    profile : WorldProfile or str, optional
        World profile (``classic`` by default, bit-identical to the original world).

    Returns
    -------
    Scene
    """
    rng = np.random.default_rng(seed)
    speed = float(rng.uniform(5.0, 10.0)) if ego_speed is None else float(ego_speed)
    x_range = (-MARGIN, speed * duration + MARGIN)
    static, ground, plan = build_street(rng, x_range, street_profile(load_profile(profile), seed))
    ego_lane = plan.lanes_per_side - 1
    if plan.profile.ego_inner_lane and ego_lane > 0:
        # its own stream, spawned before ego_offset's (which moves only when this key is set)
        if rng.spawn(1)[0].random() < plan.profile.ego_inner_lane:
            ego_lane = 0
    things: list[Thing] = []
    _parked_rows(rng, plan, things)
    n_parked = len(things)
    _sidewalk(rng, plan, x_range, things)
    _traffic(rng, plan, x_range, ego_lane, speed, things)
    ego_y = -(ego_lane + 0.5) * plan.lane_width
    if plan.profile.ego_offset:
        # its own stream (spawning does not advance ``rng``): streets, things and phase unchanged
        shift = float(rng.spawn(1)[0].uniform(*plan.profile.ego_offset))
        ego_y += min(shift, plan.lane_width / 2 - EGO_LANE_MARGIN)
    parked, rest = things[:n_parked], things[n_parked:]
    if plan.profile.parked_bus:
        # its own stream, spawned after every other one: the rest of the scene is unchanged
        parked = park_buses(rng.spawn(1)[0], parked, plan.parking, plan.profile.parked_bus)
    late: list[Thing] = []
    if plan.profile.yard_cars:
        # its own stream, spawned after every other one; the sensor draws their materials apart
        late = yard_cars(rng.spawn(1)[0], plan.yards, plan.profile.yard_cars)
    for category, share in (("truck", plan.profile.parked_truck),
                            ("other-vehicle", plan.profile.parked_trailer)):  # fmt: skip
        if share:  # each its own stream, spawned after every other one (as parked_bus)
            parked = park_instead(rng.spawn(1)[0], parked, plan.parking, share, category)
    things = parked + rest
    phase = float(rng.uniform(0, 2 * np.pi))
    return Scene(static, ground, plan, things + late, speed, ego_y, phase, len(late))
