"""World profiles: every tunable parameter of the synthetic world and its sensor, in one place.

A :class:`WorldProfile` is a frozen dataclass; :data:`CLASSIC` reproduces the original world bit
for bit (the shipped checkpoints and committed reports were made on it) and :data:`REALISTIC`
matches the statistics of the 55 real HDL-64E scans of ``../shared/data/semantickitti-train``
(measured with ``panoptic-bench synth stats``; the real scans choose world statistics only and
are never used to train or tune a model). Every feature absent from the classic world is off in
:data:`CLASSIC` and draws no random number, so the classic random streams are unchanged.

Select one with ``--profile classic|realistic`` or a YAML file of overrides
(``configs/synth_realistic.yaml``: ``base: realistic`` plus any keys below; the base may also be
another profile file, :mod:`~panoptic_bench.datasets.synthetic.profile_files`).
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from panoptic_bench.datasets.synthetic.profile_values import coerce as _coerce
from panoptic_bench.datasets.synthetic.profile_values import near_upper_ok as _near_upper_ok
from panoptic_bench.datasets.synthetic.profile_values import optional as _optional
from panoptic_bench.errors import InputError

__all__ = ["CLASSIC", "PROFILES", "REALISTIC", "WorldProfile"]


@dataclass(frozen=True)
class WorldProfile:
    """Parameters of the synthetic world and of its sensor model.

    Sensor (applied to every LiDAR model, HDL-64E and HDL-32E alike):

    - ``height_shift``, ``pitch_deg``, ``roll_deg``: (mean, std) per sequence of the sensor
      height change (m) and tilt (degrees; positive pitch looks down, positive roll lowers the
      left side);
    - ``real_elevations``: HDL-64E beams at the real rings' elevations
      (:data:`~panoptic_bench.datasets.synthetic.sensor_real.REAL_HDL64E_ELEVATIONS`);
    - ``low_ring_keep``: keep probability of the lowest rings (ring 0 first);
    - ``ego_box``: ego body hiding rays, ``(x_back, x_front, y_right, y_left, z_top)`` (sensor
      frame, m; empty = none); ``max_range``: cap on the range (0 = the model's);
      ``range_noise``: std (m) of the range noise, clipped at 2.5 std (0 = the model's, 2 cm);
    - ``physical_remission``: remission = reflectivity x incidence^``rem_incidence_exp`` x
      exp(-range / ``rem_range_m``) x lognormal(``rem_spread``), recorded as exactly 0 below
      ``rem_zero_below``; each primitive's reflectivity is spread by lognormal
      (``rem_material_spread``); ``rem_dark_prob`` of vehicle primitives (dark paint, glass) and
      ``rem_dark_stuff`` of the others are dark (x 0.1); far dark returns are kept (as 0)
      instead of dropped. Off: the classic constant x (0.7 + 0.3 cos).
      ``rem_dark_other`` (one number, empty = ``rem_dark_prob``): the dark share of the
      primitives of the vehicles that are not cars (truck, bus, other-vehicle, motorcycle; real
      scans: 9-24 % zero returns on them against 56 % on cars); ``rem_gain_people`` (persons,
      cyclists, bicycles), ``rem_gain_pole``, ``rem_gain_sign``: reflectivity factors of those
      classes (real medians at 3-20 m: person 0.43, pole 0.23, traffic sign 0.39);
      ``rem_stuff_spread`` (one number, empty = ``rem_material_spread``): material spread of the
      primitives that are neither vehicles nor people; ``rem_gain_vegetation``: factor of
      vegetation; ``terrain_reflect``: range of a terrain patch's reflectivity; ``veg_rough``:
      factor on the ray penetration depth of vegetation (crowns 0.25 m, bushes and hedges
      0.12 m mean; same draws, so 1 keeps every world bit for bit); ``rem_grazing``: (terrain,
      sidewalk + parking) cosine c of the cutoff ``1 / (1 + (c / cos)^8)`` (empty: 0.06 for all);
      ``rem_near_upper``: (r0, k, z), empty = off: the beams of the upper block (elevation above
      -8.1 degrees) return dimmer near the sensor, remission x ``f = 1 / (1 + (r0 / range)^k)``,
      and exactly 0 with probability ``z (1 - f)`` (real HDL-64E scans, session 42).

    Ground and world:

    - ``ground_rough``: vertical roughness of the ground (m, std); ``ground_rough_corr``: its
      correlation length (m): 0 draws every return's height independently (a point-to-point
      jitter that real ground does not have: real road is the smoothest surface of a scan, see
      the README's road-cue probes), > 0 makes it one smooth random height field per sequence
      (a sum of random cosines, Gaussian covariance); ``ground_wave``: amplitude (m) of gentle
      undulations (30-80 m wavelengths); ``camber``: road cross-fall towards the kerbs (fraction);
    - ``kerb``: (low, high) kerb height range (m); ``terrain_raise``: (low, high) height of
      green areas above the road (m, empty = flat); ``terrain_rough``: roughness (m, mean ray
      penetration) of those raised green areas (real grass is about twice as rough, point to
      point, as road and sidewalk); ``road_dark``: fraction of the road and parking area covered by
      dark patches (repairs, wet asphalt, tyre marks; reflectivity 0.04-0.2); ``road_reflect``,
      ``sidewalk_reflect``: base reflectivity of the road paint and of the sidewalk boxes (their
      contrast is a road-vs-sidewalk cue: realistic medians 0.26 / 0.34, real 0.28 / 0.31);
      ``road_reflect_range``: (low, high) of a per-street ``road_reflect`` drawn from its own
      stream (``[seed, key, 3]``; empty = ``road_reflect`` on every street; real road medians
      spread 7 % from scan to scan, the worlds' 3 %);
    - street: ``lanes_p`` (probability of 1 and 2 lanes per side), ``lane_width``,
      ``shoulder``, ``sidewalk``, ``green_depth`` ranges (m); ``frontage_p`` (probability of a
      building, green, fence or plaza frontage per segment); ``verge_prob``: probability that a
      segment's sidewalk is a grass verge (terrain at kerb height) instead, drawn from its own
      random stream so that the rest of the street is unchanged; ``verge_raise``: (low, high)
      height (m) of a verge's top above the road (empty: the kerb height); ``back_row_prob``:
      probability of the second row of buildings behind a non-building frontage;
      ``parking_prob`` per segment; ``parking_road``: probability that a parking strip is part of
      the carriageway (labelled and textured as road, as kerb-side parking on KITTI's residential
      streets) instead of a marked parking bay, drawn from its own random stream;
    - object density: mean spacing (m) per side of pedestrian groups ``ped_spacing``, parked
      bicycles ``bike_spacing``, cyclists ``cyclist_spacing``; ``traffic_gap`` range (m);
      ``lead_car_prob``: a car ahead in the ego lane; ``ego_offset``: (low, high) lateral offset (m)
      of the ego from the centre of its lane towards the road centre (it stays 0.3 m inside its
      lane; empty = the lane centre), drawn per sequence from its own random stream;
      ``ego_inner_lane``: probability that on a street with two lanes per side the ego drives
      in the inner lane (traffic then passes in the outer one), its own stream;
      ``side_street_prob``: probability that a frontage segment (15-40 m; skipped when shorter
      than the mouth + 2 m) opens onto a side street (a road ``side_street_width`` wide running away from the street to 60 m,
      flanked by sidewalks, cutting through the segment's frontage), its own stream;
      ``fence_height``: (low, high) height (m) of a fence frontage's fence; ``fence_lattice``:
      probability that such a fence is a see-through lattice of thin bars instead of a solid
      panel (:mod:`~panoptic_bench.datasets.synthetic.fences`), its own stream;
      ``lot_raise``: (low, high) height (m) of building forecourts and plazas built as raised
      boxes (paved: the sidewalk's reflectivity; grass: ``terrain_reflect``), its own stream;
      empty = painted on the ground at road level; ``guard_rail``: probability that a grass
      verge carries a guard rail (a 0.3 m steel beam on posts) along the road edge, its own stream;
      ``verge_flush`` / ``kerb_flush``: probability that a grass verge / a paved sidewalk segment
      is painted on the ground at road level, no step (its height is still drawn), own streams;
      ``verge_shrubs``: probability that a grass verge and the front of a green frontage each
      carry a row of low shrubs (:mod:`~panoptic_bench.datasets.synthetic.plants`), own stream;
      ``planting_beds``: probability that a paved sidewalk segment ends at its back in a
      planting bed (terrain under dense ground cover, :func:`~.plants.planting_bed`), own stream;
      ``parked_fill``: fraction of parking strips filled with cars; ``parked_bus`` /
      ``parked_truck`` / ``parked_trailer``: probability that a parked car is a bus / a truck / a
      trailer (other-vehicle) instead (:mod:`~panoptic_bench.datasets.synthetic.buses`), own streams;
      ``yard_cars``: probability that a green, fence or plaza frontage holds a row of parked cars
      behind its sidewalk (:mod:`~panoptic_bench.datasets.synthetic.yards`), own stream;
    - ``clutter_spacing``: mean spacing (m, 0 = none) per side of unlabelled clutter
      (other-structure, other-object); ``tree_spacing`` / ``bush_spacing`` in green areas;
      ``trunk_height``: (low, high) bare trunk below a tree's crown (m; the crown sits on it, so a
      lower range gives crowns that hang over the trunk; the same random draws for any range);
      ``trunk_radius``: (low, high) trunk radius (m); ``crown_lift``: height of a crown's centre
      above the trunk's top, in crown half heights (0.7: it hangs over the top; 1: it rests on it);
      the same draws for any value of either; ``kerb_crown_clearance``: lowest height (m, 0 = off)
      of the kerb trees' crowns (a lower one is raised on a longer trunk, the same draws);
      ``kerb_tree_keep``: share of the kerb trees built (all drawn; which from an own stream);
    - street furniture: ``lamp_keep``: share of the lamp poles that are built (the draws are made
      for every one, so the rest of the street is unchanged); ``lamp_signs``: probability that a
      lamp pole carries a traffic-sign plate (real lamp posts often do), drawn from its own stream;
      ``lamp_sign_half``: (low, high) half side (m) of those square plates; ``sign_posts``: mean
      spacing (m, 0 = none) per side of low sign posts beside the kerb (one or two plates,
      :mod:`~panoptic_bench.datasets.synthetic.signs`), own stream; ``sign_post_z``: (low, high)
      height (m) of the lowest plate's centre above the kerb; ``sign_post_half``: (low, high)
      half width (m) of their plates; ``sign_back_reflect`` (0 = one-sided plates): back
      reflectivity of two-sided post plates; ``sign_bright``: share of retro-reflective fronts.
    """

    name: str = "classic"
    height_shift: tuple[float, float] = (0.0, 0.0)
    pitch_deg: tuple[float, float] = (0.0, 0.0)
    roll_deg: tuple[float, float] = (0.0, 0.0)
    real_elevations: bool = False
    low_ring_keep: tuple[float, ...] = ()
    ego_box: tuple[float, ...] = ()
    max_range: float = 0.0
    range_noise: float = 0.0
    physical_remission: bool = False
    rem_incidence_exp: float = 0.5
    rem_range_m: float = 60.0
    rem_spread: float = 0.3
    rem_material_spread: float = 0.4
    rem_dark_prob: float = 0.0
    rem_dark_stuff: float = 0.0
    rem_zero_below: float = 0.0
    rem_dark_other: tuple[float, ...] = ()
    rem_gain_people: float = 1.0
    rem_gain_pole: float = 1.0
    rem_gain_sign: float = 1.0
    rem_stuff_spread: tuple[float, ...] = ()
    rem_gain_vegetation: float = 1.0
    veg_rough: float = 1.0
    rem_grazing: tuple[float, ...] = ()
    rem_near_upper: tuple[float, ...] = ()
    terrain_reflect: tuple[float, float] = (0.3, 0.5)
    ground_rough: float = 0.0
    ground_rough_corr: float = 0.0
    ground_wave: float = 0.0
    camber: float = 0.0
    kerb: tuple[float, float] = (0.14, 0.14)
    terrain_raise: tuple[float, ...] = ()
    terrain_rough: float = 0.03
    road_dark: float = 0.0
    road_reflect: float = 0.3
    road_reflect_range: tuple[float, ...] = ()
    sidewalk_reflect: float = 0.4
    lanes_p: tuple[float, float] = (0.45, 0.55)
    lane_width: tuple[float, float] = (3.3, 3.8)
    shoulder: tuple[float, float] = (0.5, 2.0)
    sidewalk: tuple[float, float] = (3.0, 5.5)
    green_depth: tuple[float, float] = (12.0, 22.0)
    frontage_p: tuple[float, float, float, float] = (0.38, 0.36, 0.14, 0.12)
    verge_prob: float = 0.0
    verge_raise: tuple[float, ...] = ()
    back_row_prob: float = 1.0
    parking_prob: float = 0.45
    parking_road: float = 0.0
    parked_fill: float = 1.0
    parked_bus: float = 0.0
    parked_truck: float = 0.0
    parked_trailer: float = 0.0
    yard_cars: float = 0.0
    ped_spacing: float = 30.0
    bike_spacing: float = 60.0
    cyclist_spacing: float = 70.0
    traffic_gap: tuple[float, float] = (25.0, 90.0)
    lead_car_prob: float = 0.5
    ego_offset: tuple[float, ...] = ()
    ego_inner_lane: float = 0.0
    side_street_prob: float = 0.0
    side_street_width: tuple[float, float] = (6.0, 10.0)
    fence_height: tuple[float, float] = (1.0, 2.0)
    fence_lattice: float = 0.0
    lot_raise: tuple[float, ...] = ()
    guard_rail: float = 0.0
    verge_flush: float = 0.0
    kerb_flush: float = 0.0
    verge_shrubs: float = 0.0
    planting_beds: float = 0.0
    clutter_spacing: float = 0.0
    tree_spacing: float = 6.0
    bush_spacing: float = 4.0
    trunk_height: tuple[float, float] = (2.0, 3.5)
    trunk_radius: tuple[float, float] = (0.12, 0.25)
    crown_lift: float = 0.7
    kerb_crown_clearance: float = 0.0
    kerb_tree_keep: float = 1.0
    lamp_keep: float = 1.0
    lamp_signs: float = 0.0
    lamp_sign_half: tuple[float, float] = (0.32, 0.32)
    sign_posts: float = 0.0
    sign_post_z: tuple[float, float] = (1.5, 2.3)
    sign_post_half: tuple[float, float] = (0.25, 0.45)
    sign_back_reflect: float = 0.0
    sign_bright: float = 0.0

    def __post_init__(self) -> None:
        problems = []
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, tuple) and len(v) == 2 and f.name != "lanes_p":
                if v[0] > v[1] and f.name not in ("height_shift", "pitch_deg", "roll_deg"):
                    problems.append(f"{f.name} range {v} is reversed")
        checks = {
            "low_ring_keep": all(0.0 <= k <= 1.0 for k in self.low_ring_keep),
            "ego_box": len(self.ego_box) in (0, 5),
            "terrain_raise": len(self.terrain_raise) in (0, 2),
            "ego_offset": _optional(self.ego_offset, 2, 0.0, 3.0),
            "verge_raise": _optional(self.verge_raise, 2, 0.0, 1.0),
            "lanes_p": abs(sum(self.lanes_p) - 1.0) < 1e-9 and min(self.lanes_p) >= 0,
            "frontage_p": abs(sum(self.frontage_p) - 1.0) < 1e-9 and min(self.frontage_p) >= 0,
            "side_street_width": 3.0 <= (w := self.side_street_width)[0] and w[1] <= 20.0,
            "fence_height": 0.2 <= self.fence_height[0] and self.fence_height[1] <= 4.0,
            "lot_raise": _optional(self.lot_raise, 2, 0.0, 1.0),
            "lamp_sign_half": 0.05 <= self.lamp_sign_half[0] and self.lamp_sign_half[1] <= 1.5,
            "sign_posts": self.sign_posts == 0.0 or self.sign_posts >= 5.0,
            "sign_post_z": 0.3 <= self.sign_post_z[0] and self.sign_post_z[1] <= 6.0,
            "sign_post_half": 0.05 <= self.sign_post_half[0] and self.sign_post_half[1] <= 1.5,
            "sign_back_reflect": 0.0 <= self.sign_back_reflect <= 2.0,
            "sign_bright": 0.0 <= self.sign_bright <= 1.0,
            "rem_zero_below": 0.0 <= self.rem_zero_below < 1.0,
            "rem_dark_other": _optional(self.rem_dark_other, 1, 0.0, 1.0),
            "rem_gain_people": 0.0 < self.rem_gain_people <= 10.0,
            "rem_gain_pole": 0.0 < self.rem_gain_pole <= 10.0,
            "rem_gain_sign": 0.0 < self.rem_gain_sign <= 10.0,
            "rem_stuff_spread": _optional(self.rem_stuff_spread, 1, 0.0, 2.0),
            "rem_gain_vegetation": 0.0 < self.rem_gain_vegetation <= 10.0,
            "veg_rough": 0.0 <= self.veg_rough <= 5.0,
            "rem_grazing": _optional(self.rem_grazing, 2, 0.0, 0.3),
            "rem_near_upper": _near_upper_ok(self.rem_near_upper),
            "terrain_reflect": 0.0 <= self.terrain_reflect[0] and self.terrain_reflect[1] <= 1.0,
            "max_range": 0.0 <= self.max_range <= 250.0,
            "range_noise": 0.0 <= self.range_noise <= 0.5,
            "trunk_height": 0.2 <= self.trunk_height[0] and self.trunk_height[1] <= 6.0,
            "trunk_radius": 0.03 <= self.trunk_radius[0] and self.trunk_radius[1] <= 1.0,
            "crown_lift": 0.0 <= self.crown_lift <= 2.0,
            "kerb_crown_clearance": 0.0 <= self.kerb_crown_clearance <= 8.0,
            "clutter_spacing": self.clutter_spacing >= 0,
            "lane_width": self.lane_width[0] >= 2.0,
            "sidewalk": self.sidewalk[0] >= 0.5,
            "kerb": 0.0 <= self.kerb[0] and self.kerb[1] <= 0.5,
            "ground_rough": 0.0 <= self.ground_rough <= 0.5,
            "ground_rough_corr": 0.0 <= self.ground_rough_corr <= 50.0,
            "ground_wave": 0.0 <= self.ground_wave <= 2.0,
            "camber": 0.0 <= self.camber <= 0.1,
            "terrain_rough": 0.0 <= self.terrain_rough <= 0.5,
            "road_reflect_range": len(self.road_reflect_range) in (0, 2)
            and all(0.0 <= v <= 1.0 for v in self.road_reflect_range)
            and list(self.road_reflect_range) == sorted(self.road_reflect_range),
        }
        checks.update({k: 0.0 <= getattr(self, k) <= 1.0 for k in _PROBABILITIES})
        checks.update({k: getattr(self, k) > 0 for k in _POSITIVE})
        problems += [
            f"{k} = {getattr(self, k)!r} is out of range" for k, ok in checks.items() if not ok
        ]
        if problems:
            raise InputError(f"world profile {self.name!r}: " + "; ".join(problems))

    @property
    def sensor_model(self) -> bool:
        """True when any sensor parameter differs from the classic sensor."""
        return any(getattr(self, k) != getattr(CLASSIC, k) for k in _SENSOR_KEYS)

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping (tuples as lists), the inverse of :meth:`from_dict`."""
        return {
            f.name: list(v) if isinstance(v := getattr(self, f.name), tuple) else v
            for f in dataclasses.fields(self)
        }

    @classmethod
    def from_dict(
        cls,
        mapping: dict[str, Any],
        source: str | Path | None = None,
        base: WorldProfile | None = None,
    ) -> WorldProfile:
        """Profile from a mapping of overrides on ``base`` (classic by default).

        Unknown keys and values of the wrong type are :class:`InputError` naming the key.
        """
        if not isinstance(mapping, dict):
            raise InputError("a world profile must be a mapping of key: value", source)
        hints = typing.get_type_hints(cls)
        unknown = sorted(set(mapping) - set(hints))
        if unknown:
            raise InputError(
                f"unknown world profile key {unknown[0]!r}; known keys: {', '.join(hints)}", source
            )
        values = {k: _coerce(hints[k], v, k, source) for k, v in mapping.items()}
        try:
            return dataclasses.replace(base if base is not None else CLASSIC, **values)
        except InputError as err:  # a value out of range: name the file it came from
            if err.path is not None or source is None:
                raise
            raise InputError(err.message, source) from None


#: Keys that are probabilities or fractions in [0, 1].
_PROBABILITIES = (
    "parking_prob", "parking_road", "ego_inner_lane", "side_street_prob", "fence_lattice",
    "guard_rail", "verge_flush", "kerb_flush", "verge_shrubs", "planting_beds", "lamp_keep",
    "lamp_signs", "verge_prob", "parked_fill", "parked_bus", "parked_truck", "parked_trailer",
    "yard_cars", "lead_car_prob", "back_row_prob", "rem_dark_prob", "rem_dark_stuff", "road_dark",
    "road_reflect", "sidewalk_reflect", "kerb_tree_keep"
)  # fmt: skip

#: Keys that must be positive.
_POSITIVE = ("rem_range_m", "ped_spacing", "bike_spacing", "cyclist_spacing", "tree_spacing",
             "bush_spacing")  # fmt: skip
CLASSIC = WorldProfile()
_SENSOR_KEYS = (
    "height_shift", "pitch_deg", "roll_deg", "real_elevations", "low_ring_keep", "ego_box",
    "max_range", "range_noise", "physical_remission", "rem_incidence_exp", "rem_range_m",
    "rem_spread", "rem_material_spread", "rem_dark_prob", "rem_dark_stuff", "rem_zero_below",
    "rem_dark_other", "rem_gain_people", "rem_gain_pole", "rem_gain_sign", "rem_stuff_spread",
    "rem_gain_vegetation", "veg_rough", "rem_grazing", "rem_near_upper", "ground_rough",
    "ground_rough_corr", "ground_wave", "camber",
)  # fmt: skip

REALISTIC = WorldProfile(
    name="realistic",
    height_shift=(0.07, 0.02),
    pitch_deg=(0.6, 0.3),
    roll_deg=(-0.3, 1.0),
    real_elevations=True,
    low_ring_keep=(0.91, 0.96, 0.93, 0.95, 0.96, 0.98, 0.99),
    ego_box=(-1.4, 1.0, -0.75, 0.9, -0.5),
    max_range=80.0,
    range_noise=0.01,
    physical_remission=True,
    rem_incidence_exp=0.1,
    rem_range_m=50.0,
    rem_spread=0.2,
    rem_material_spread=0.25,
    rem_dark_prob=0.5,
    rem_dark_stuff=0.06,
    rem_zero_below=0.06,
    ground_rough=0.03,
    ground_rough_corr=1.5,
    ground_wave=0.08,
    camber=0.02,
    kerb=(0.04, 0.14),
    terrain_raise=(0.1, 0.45),
    terrain_rough=0.06,
    road_dark=0.15,
    lanes_p=(0.7, 0.3),
    lane_width=(3.0, 3.5),
    shoulder=(0.2, 1.0),
    sidewalk=(2.0, 4.0),
    green_depth=(8.0, 20.0),
    frontage_p=(0.12, 0.65, 0.13, 0.1),
    back_row_prob=0.25,
    parking_prob=0.3,
    parked_fill=0.6,
    ped_spacing=250.0,
    bike_spacing=250.0,
    cyclist_spacing=600.0,
    traffic_gap=(100.0, 300.0),
    lead_car_prob=0.15,
    clutter_spacing=50.0,
    tree_spacing=6.0,
    bush_spacing=2.0,
)

PROFILES = {"classic": CLASSIC, "realistic": REALISTIC}
