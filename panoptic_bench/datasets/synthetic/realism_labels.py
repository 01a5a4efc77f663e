"""Names of the realism measures: key -> (label in the tables, aggregation over scans).

:func:`panoptic_bench.datasets.synthetic.realism.scan_measures` computes them for one scan;
``"mean"`` measures are averaged over scans, ``"median"`` ones take the median over scans
(``"cv"``: std / mean over scans of the per-scan value, see
:mod:`~panoptic_bench.datasets.synthetic.realism_materials`). ``synth stats`` writes one table row
per key, in this order.
"""

from __future__ import annotations

from panoptic_bench.datasets.synthetic.realism_materials import MATERIAL_MEASURES

__all__ = ["MEASURES"]

#: Scalar measures: key -> (label, aggregation over scans: "mean" or "median").
MEASURES: dict[str, tuple[str, str]] = {
    "rem_zero_pct": ("remission: % of points exactly 0", "mean"),
    "rem_dark_pct": ("remission: % of points below 0.1", "mean"),
    "rem_dark_road_pct": ("remission: % of the points below 0.1 that are road", "mean"),
    "rem_dark_car_pct": ("remission: % of the points below 0.1 that are car", "mean"),
    "rem_std": ("remission: standard deviation", "mean"),
    "rem_car_median": ("remission: car median", "median"),
    "rem_car_zero_pct": ("remission: % of car points exactly 0", "mean"),
    "rem_other_vehicle_median": (
        "remission: truck, bus, other-vehicle, motorcycle median (3-20 m)",
        "median",
    ),
    "rem_other_vehicle_zero_pct": (
        "remission: % of truck, bus, other-vehicle, motorcycle points exactly 0",
        "mean",
    ),
    "rem_people_median": ("remission: person, cyclist, bicycle median (3-20 m)", "median"),
    "rem_pole_median": ("remission: pole median (3-20 m)", "median"),
    "rem_sign_median": ("remission: traffic-sign median (3-20 m)", "median"),
    "rem_sign_bright_pct": (
        "remission: % of traffic-sign points above 0.8 (3-20 m, session 42)",
        "mean",
    ),
    "rem_pole_zero_pct": ("remission: % of pole points exactly 0 (3-20 m, session 42)", "mean"),
    "rem_road_lt5": ("remission: road median under 5 m", "median"),
    "rem_road_20_40": ("remission: road median at 20-40 m", "median"),
    "rem_road_gt40": ("remission: road median beyond 40 m", "median"),
    "rem_sidewalk_20_40": ("remission: sidewalk median at 20-40 m (session 36)", "median"),
    "rem_terrain_20_40": ("remission: terrain median at 20-40 m (session 36)", "median"),
    "rem_terrain_gt40": ("remission: terrain median beyond 40 m (session 36)", "median"),
    "road_z": ("ground: road plane height under the sensor (m)", "median"),
    "pitch_deg": ("pose: sensor pitch from the road plane (deg)", "median"),
    "roll_deg": ("pose: sensor roll from the road plane (deg)", "median"),
    "road_rough_cm": ("ground: road roughness, residual std (cm)", "median"),
    "road_jitter_mm": ("ground: road jitter, 2nd z difference along the ring (mm)", "median"),
    "sidewalk_jitter_mm": ("ground: sidewalk jitter (mm)", "median"),
    "terrain_jitter_mm": ("ground: terrain jitter (mm)", "median"),
    "vegetation_texture_mm": (
        "content: vegetation texture, 2nd range difference along the ring, 3-20 m (mm)",
        "median",
    ),
    "building_texture_mm": ("content: building texture, the same measure (mm)", "median"),
    "below_185_pct": ("ground: % of points below z = -1.85 m", "mean"),
    "verge_terrain_pct": ("layout: % terrain among the ground points beside the road", "mean"),
    "sidewalk_h": ("ground: sidewalk height above the road (m)", "median"),
    "terrain_h": ("ground: terrain height above the road (m)", "median"),
    "other_ground_h": ("ground: other-ground height above the road (m)", "median"),
    "terrain_step": (
        "ground: step from the road up to terrain within 1 m of it (m) (session 30)",
        "median",
    ),
    "terrain_flush_pct": (
        "ground: % of that terrain flush with the road (step under 5 cm either way) (session 30)",
        "mean",
    ),
    "kerb_step": (
        "ground: kerb step from the road up to the sidewalk within 1 m of it (m) (session 33)",
        "median",
    ),
    "kerb_flush_pct": (
        "ground: % of that sidewalk flush with the road (under 5 cm either way) (session 33)",
        "mean",
    ),
    "building_y": ("layout: building median lateral distance (m)", "median"),
    "car_y": ("layout: car median lateral distance (m)", "median"),
    "road_right": ("layout: road edge to the right of the sensor (m)", "median"),
    "road_left": ("layout: road edge to the left of the sensor (m)", "median"),
    "road_far_right_pct": ("layout: % road among the ground 6-12 m to the right", "mean"),
    "road_far_left_pct": ("layout: % road among the ground 6-12 m to the left", "mean"),
    "fence_h": ("content: fence height above the road, median of its points 3-20 m (m)", "median"),
    "sign_h": (
        "content: traffic-sign height above the road, median of its points 3-20 m (m) (session 41)",
        "median",
    ),
    "trunk_h": (
        "content: trunk height above the road, median of its points 3-20 m (m) (session 41)",
        "median",
    ),
    "veg_low_pct": (
        "content: % of the vegetation points 3-20 m away under 0.5 m above the road plane (session 33)",
        "mean",
    ),
    "veg_overhang": (
        "content: vegetation points a scan 3-8 m away, within 3.5 m of the sensor's axis, 1-2.5 m "
        "above the road plane (crowns over the carriageway; session 43)",
        "mean",
    ),
    **{
        f"near_{key}_pct": (
            f"content: % {name} among the points 3-6 m away over 0.45 m above the road plane "
            "(what stands beside the sensor; session 43)",
            "mean",
        )
        for key, name in (
            ("veg", "vegetation"),
            ("fence", "fence"),
            ("building", "building"),
            ("car", "car"),
            ("trunk", "trunk"),
        )
    },
    "fence_through_pct": (
        "content: % of fence points whose ring neighbour is > 1 m farther",
        "mean",
    ),
    "car_range": ("layout: car points median range (m)", "median"),
    "near5_pct": ("layout: % of points under 5 m", "mean"),
    "far_max": ("layout: farthest point (m)", "median"),
    "hole_min": ("ego hole: smallest sector minimum range (m)", "median"),
    "hole_max": ("ego hole: largest sector minimum range (m)", "median"),
    "low_ring_ratio": ("rings: points per ring, lowest 12 / others", "median"),
    "n_rings": ("rings: rings recovered", "median"),
    "clutter_pct": ("content: % unlabelled clutter (other-structure, other-object)", "mean"),
    "unlabeled_pct": ("content: % of points ignored (unlabeled, outlier, clutter)", "mean"),
    **MATERIAL_MEASURES,
}
