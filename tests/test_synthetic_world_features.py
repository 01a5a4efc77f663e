"""World features of the street builder: grass verges and tree crowns (one change each, own streams)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from panoptic_bench.datasets.synthetic import Sequence
from panoptic_bench.datasets.synthetic.profile import CLASSIC, REALISTIC, WorldProfile
from panoptic_bench.errors import InputError


def test_verges_replace_sidewalks_by_terrain():
    from panoptic_bench.datasets.synthetic.street import SIDEWALK, TERRAIN, build_street

    def labels(verge_prob):
        prof = dataclasses.replace(REALISTIC, verge_prob=verge_prob)
        static, _, plan = build_street(np.random.default_rng(7), (-60.0, 60.0), prof)
        return static.label, plan

    lab, plan = labels(0.0)
    assert (lab == SIDEWALK).any()
    lab, plan = labels(1.0)
    assert not (lab == SIDEWALK).any() and (lab == TERRAIN).any()
    assert plan.curb  # things are still placed at the kerb line
    kerbs = [h for *_, h in plan.kerb]
    assert max(kerbs) <= REALISTIC.kerb[1]


def test_verges_change_only_the_sidewalks_they_replace():
    """Verges draw from their own stream: same streets, same primitives, only labels move."""
    from panoptic_bench.datasets.synthetic.street import SIDEWALK, TERRAIN, build_street

    def street(verge_prob):
        prof = dataclasses.replace(REALISTIC, verge_prob=verge_prob)
        return build_street(np.random.default_rng(11), (-60.0, 60.0), prof)

    (a, ga, pa), (b, gb, pb) = street(0.0), street(0.5)
    np.testing.assert_array_equal(a.center, b.center)
    np.testing.assert_array_equal(a.half, b.half)
    np.testing.assert_array_equal(ga.label, gb.label)
    moved = a.label != b.label
    assert moved.any() and (a.label[moved] == SIDEWALK).all() and (b.label[moved] == TERRAIN).all()
    assert (b.label == SIDEWALK).any()  # about half stay paved
    assert pa.curb == pb.curb and pa.kerb == pb.kerb
    # the whole scene (things, sensor draws) is the same street with or without verges
    fa = Sequence(0, 3, 1, profile=REALISTIC).frame(0).sweep
    fb = Sequence(0, 3, 1, profile=dataclasses.replace(REALISTIC, verge_prob=0.5)).frame(0).sweep
    assert len(fa.xyz) > 0.9 * len(fb.xyz)
    np.testing.assert_array_equal(np.unique(fa.instance), np.unique(fb.instance))


def test_raised_verges_stand_higher_and_carry_what_stands_on_them():
    from panoptic_bench.datasets.synthetic.street import TERRAIN, build_street, kerb_at

    def street(**kw):
        prof = dataclasses.replace(REALISTIC, verge_prob=1.0, **kw)
        return build_street(np.random.default_rng(7), (-60.0, 60.0), prof)

    flat, _, flat_plan = street()
    high, _, high_plan = street(verge_raise=(0.3, 0.4))
    heights = [h for *_, h in high_plan.kerb]
    assert all(0.3 <= h <= 0.4 for h in heights)
    side, x0, x1, h = high_plan.kerb[0]
    assert kerb_at(high_plan, side, 0.5 * (x0 + x1)) == h  # objects stand on the verge top

    def verge_tops(prims, plan):  # tops of the terrain boxes whose inner edge is a kerb line
        inner = np.abs(np.abs(prims.center[:, 1]) - prims.half[:, 1])
        curbs = np.array([abs(c[3]) for c in plan.curb])
        at_kerb = np.isclose(inner[:, None], curbs[None, :], atol=1e-6).any(1)
        sel = (prims.label == TERRAIN) & at_kerb
        return prims.center[sel, 2] + prims.half[sel, 2]

    flat_tops = verge_tops(flat, flat_plan)
    assert len(flat_tops) >= 2 and np.all(flat_tops <= REALISTIC.kerb[1] + 1e-9)
    tops = verge_tops(high, high_plan)
    assert len(tops) >= 2 and np.all((tops >= 0.3 - 1e-9) & (tops <= 0.4 + 1e-9))
    with pytest.raises(InputError, match="verge_raise"):
        WorldProfile.from_dict({"verge_raise": [0.2]})
    with pytest.raises(InputError, match="verge_raise"):
        WorldProfile.from_dict({"verge_raise": [0.5, 0.2]})


def _only_trees_moved(a, ga, pa, b, gb, pb):
    """Assert that streets ``a`` and ``b`` differ in their trees only; their trunk and crown masks."""
    from panoptic_bench.datasets.synthetic.raw_ids import TRUNK, VEGETATION

    np.testing.assert_array_equal(a.label, b.label)  # the same draws: the same primitives
    np.testing.assert_array_equal(ga.label, gb.label)
    assert pa.curb == pb.curb and pa.kerb == pb.kerb
    trunk = a.label == TRUNK
    crown = np.zeros_like(trunk)
    crown[1:] = trunk[:-1] & (a.label[1:] == VEGETATION)  # each crown follows its trunk
    assert trunk.sum() >= 5 and crown.sum() == trunk.sum()
    same = ~(trunk | crown)
    np.testing.assert_array_equal(a.center[same], b.center[same])
    np.testing.assert_array_equal(a.half[same], b.half[same])
    return trunk, crown


def test_trunk_height_lowers_crowns_and_changes_nothing_else():
    """trunk_height: the same draws, so only tree trunks and the crowns on them move."""
    from panoptic_bench.datasets.synthetic.street import build_street

    def street(**kw):
        prof = dataclasses.replace(REALISTIC, **kw)
        return build_street(np.random.default_rng(5), (-60.0, 60.0), prof)

    (a, ga, pa), (b, gb, pb) = street(), street(trunk_height=(1.0, 2.0))
    trunk, crown = _only_trees_moved(a, ga, pa, b, gb, pb)
    # bare trunk = 2 x half height, in the profile's range; crowns come down by the same amount
    assert np.all((2 * a.half[trunk, 2] >= 2.0 - 1e-9) & (2 * a.half[trunk, 2] <= 3.5 + 1e-9))
    assert np.all((2 * b.half[trunk, 2] >= 1.0 - 1e-9) & (2 * b.half[trunk, 2] <= 2.0 + 1e-9))
    drop = 2 * (a.half[trunk, 2] - b.half[trunk, 2])
    np.testing.assert_allclose(a.center[crown, 2] - b.center[crown, 2], drop, atol=1e-9)
    np.testing.assert_array_equal(a.center[crown, :2], b.center[crown, :2])
    assert REALISTIC.trunk_height == CLASSIC.trunk_height == (2.0, 3.5)
    with pytest.raises(InputError, match="trunk_height"):
        WorldProfile.from_dict({"trunk_height": [2.0, 1.0]})
    with pytest.raises(InputError, match="trunk_height"):
        WorldProfile.from_dict({"trunk_height": [0.1, 1.0]})


def test_parking_road_turns_parking_strips_into_road_and_nothing_else():
    """Road-labelled parking strips draw from their own stream: primitives and plan are unchanged."""
    from panoptic_bench.datasets.synthetic.street import PARKING, ROAD, build_street

    def street(**kw):
        prof = dataclasses.replace(REALISTIC, parking_prob=0.6, verge_prob=0.35, **kw)
        return build_street(np.random.default_rng(5), (-60.0, 60.0), prof)

    (a, ga, pa), (b, gb, pb) = street(), street(parking_road=1.0)
    (_, gh, _) = street(parking_road=0.5)
    assert pa.parking and (ga.label == PARKING).any()
    assert not (gb.label == PARKING).any()  # every strip is carriageway
    moved = ga.label != gb.label
    assert moved.any() and (ga.label[moved] == PARKING).all() and (gb.label[moved] == ROAD).all()
    # the strips take the road's paint and texture, not the parking bay's flat 0.32
    strip = gb.reflect[moved]
    assert abs(float(np.median(strip)) - REALISTIC.road_reflect) < 0.01 and strip.std() > 0.01
    for x, y in ((a.center, b.center), (a.half, b.half), (a.label, b.label)):
        np.testing.assert_array_equal(x, y)
    assert pa.parking == pb.parking and pa.curb == pb.curb and pa.kerb == pb.kerb
    assert (gh.label == PARKING).any() and ((ga.label == PARKING) & (gh.label == ROAD)).any()
    with pytest.raises(InputError, match="parking_road"):
        WorldProfile(parking_road=1.5)


def test_ego_offset_moves_only_the_ego_towards_the_road_centre():
    from panoptic_bench.datasets.synthetic.scene import EGO_LANE_MARGIN, generate_scene

    for seed in range(6):
        a = generate_scene(seed, 1.0, profile=REALISTIC)
        b = generate_scene(seed, 1.0, profile=dataclasses.replace(REALISTIC, ego_offset=(0.0, 1.5)))
        shift = b.ego_y - a.ego_y
        assert 0.0 <= shift <= a.plan.lane_width / 2 - EGO_LANE_MARGIN + 1e-12
        assert a.ego_phase == b.ego_phase and a.ego_speed == b.ego_speed
        np.testing.assert_array_equal(a.static.center, b.static.center)
        np.testing.assert_array_equal(a._xyz0, b._xyz0)
    c = generate_scene(3, 1.0, profile=dataclasses.replace(REALISTIC, ego_offset=(3.0, 3.0)))
    assert c.ego_y == pytest.approx(
        -(c.plan.lanes_per_side - 0.5) * c.plan.lane_width + c.plan.lane_width / 2 - EGO_LANE_MARGIN
    )
    for bad in ((1.0,), (2.0, 1.0), (0.0, 3.5)):
        with pytest.raises(InputError, match="ego_offset"):
            WorldProfile(ego_offset=bad)


def test_road_edges_on_a_hand_made_street():
    """Road from 3 m right to 5 m left of the sensor, sidewalk beyond, a car on the road."""
    from panoptic_bench.datasets.synthetic.realism import MEASURES, scan_measures

    xs, ys = np.meshgrid(np.arange(-11.9, 12.0, 0.2), np.arange(-8.0, 8.0, 0.1))
    x, y = xs.ravel(), ys.ravel() + 0.05
    raw = np.where((y > -3.0) & (y < 5.0), 40, 48).astype(np.uint32)
    raw[(y > 1.0) & (y < 2.5)] = 10  # a car in the left lane does not end the road
    raw[(y < -3.0) & (y > -4.0) & (x > 0)] = 44  # parking is carriageway too
    pts = np.column_stack([x, y, np.full_like(x, -1.75), np.full_like(x, 0.3)]).astype(np.float32)
    m, _ = scan_measures(pts, raw)
    assert "road_right" in MEASURES and "road_left" in MEASURES
    # eight slabs end at 3.05 m (sidewalk), eight at 4.05 m (behind the parking): median of 16 = 3.55
    assert m["road_right"] == pytest.approx(3.55, abs=1e-3)
    assert m["road_left"] == pytest.approx(5.05, abs=1e-3)


def test_lamp_keys_thin_the_lamp_poles_and_hang_signs_on_them_only():
    from panoptic_bench.datasets.synthetic.street import POLE, SIGN, build_street

    def street(**kw):
        prof = dataclasses.replace(REALISTIC, verge_prob=0.35, **kw)
        return build_street(np.random.default_rng(3), (-80.0, 80.0), prof)[0]

    a = street()
    b = street(lamp_keep=0.6, lamp_signs=1.0, lamp_sign_half=(0.4, 0.8))
    rows = lambda p, m: np.column_stack([p.center[m], p.half[m]])  # noqa: E731
    other_a, other_b = ~np.isin(a.label, (POLE, SIGN)), ~np.isin(b.label, (POLE, SIGN))
    np.testing.assert_array_equal(rows(a, other_a), rows(b, other_b))  # trees, buildings: same
    poles_a, poles_b = rows(a, a.label == POLE), rows(b, b.label == POLE)
    assert 0 < len(poles_b) < len(poles_a)
    assert {tuple(r) for r in poles_b} <= {tuple(r) for r in poles_a}
    signs_a, signs_b = rows(a, a.label == SIGN), rows(b, b.label == SIGN)
    assert {tuple(r) for r in signs_a} <= {tuple(r) for r in signs_b}
    new = np.array([r for r in signs_b if tuple(r) not in {tuple(s) for s in signs_a}])
    lamps = (b.label == POLE) & (b.half[:, 2] > 2.0)  # the lamp posts (6-9 m tall)
    assert len(new) == lamps.sum()  # lamp_signs 1.0: one plate on every lamp post standing
    assert np.all((new[:, 4] >= 0.4) & (new[:, 4] <= 0.8)) and np.all(new[:, 3] == 0.01)
    with pytest.raises(InputError, match="lamp_keep"):
        WorldProfile(lamp_keep=-0.1)
    with pytest.raises(InputError, match="lamp_sign_half"):
        WorldProfile(lamp_sign_half=(0.01, 0.5))


def test_parked_buses_replace_parked_cars_and_nothing_else():
    from panoptic_bench.datasets.synthetic.scene import generate_scene

    base = dataclasses.replace(REALISTIC, parking_prob=0.8, parked_fill=1.0)
    buses = 0
    for seed in range(4):
        a = generate_scene(seed, 1.0, profile=base)
        b = generate_scene(seed, 1.0, profile=dataclasses.replace(base, parked_bus=0.3))
        # own stream: street, ego and every moving or sidewalk thing are unchanged
        np.testing.assert_array_equal(a.static.center, b.static.center)
        assert (a.ego_y, a.ego_phase, a.ego_speed) == (b.ego_y, b.ego_phase, b.ego_speed)
        key = [(t.category, *t.xyz) for t in a.things if t.moving or t.category != "car"]
        new = [t for t in b.things if t.category == "bus" and not t.moving]
        assert not [t for t in a.things if t.category == "bus" and not t.moving]
        left = [(t.category, *t.xyz) for t in b.things if t.moving or t.category != "car"]
        assert set(left) - set(key) == {(t.category, *t.xyz) for t in new}
        buses += len(new)
        parked = sorted(
            (t for t in b.things if not t.moving and abs(t.xyz[1]) > 2), key=lambda t: t.xyz[0]
        )
        for t in new:  # a static bus (raw 13 = other-vehicle) inside a strip, overlapping nothing
            assert t.label == 13 and 10.0 <= t.size[0] <= 12.5
            lo, hi = t.xyz[0] - t.size[0] / 2, t.xyz[0] + t.size[0] / 2
            assert any(
                s == np.sign(t.xyz[1]) and x0 <= lo and hi <= x1 for s, x0, x1 in b.plan.parking
            )
            for o in parked:
                if (
                    o is not t
                    and np.sign(o.xyz[1]) == np.sign(t.xyz[1])
                    and abs(o.xyz[1] - t.xyz[1]) < 1
                ):
                    assert o.xyz[0] + o.size[0] / 2 <= lo or o.xyz[0] - o.size[0] / 2 >= hi
    assert buses >= 2
    with pytest.raises(InputError, match="parked_bus"):
        WorldProfile.from_dict({"parked_bus": 1.5})


def test_park_buses_hand_worked():
    from panoptic_bench.datasets.synthetic.buses import park_buses
    from panoptic_bench.datasets.synthetic.things import build

    rng = np.random.default_rng(0)
    cars = [build(rng, "car", (x, -6.0, 0.0), 0.0) for x in (3.0, 8.0, 13.0, 18.0, 40.0)]
    out = park_buses(np.random.default_rng(1), cars, [(-1, 0.0, 45.0)], 1.0)
    # share 1: the car at 3 m becomes a bus from its rear end (10-12.5 m long) and covers the cars
    # at 8 and 13 m; the car at 18 m becomes the next bus; the one at 40 m stays a car (a bus from
    # its rear end would leave the strip at 45 m)
    assert [t.category for t in out] == ["bus", "bus", "car"]
    first, second, last = out
    assert first.xyz[0] - first.size[0] / 2 == pytest.approx(3.0 - cars[0].size[0] / 2)
    assert second.xyz[0] - second.size[0] / 2 == pytest.approx(18.0 - cars[3].size[0] / 2)
    assert first.xyz[1] == second.xyz[1] == -6.0 and last is cars[4]
    assert cars[0].category == "car"  # input untouched
    none = park_buses(np.random.default_rng(1), cars, [(-1, 0.0, 45.0)], 0.0)
    assert [t.category for t in none] == ["car"] * 5
    short = park_buses(np.random.default_rng(1), cars, [(-1, 0.0, 10.0), (-1, 10.0, 45.0)], 1.0)
    assert short[0].category == "car"  # a bus may not leave its strip


def test_trunk_radius_and_crown_lift_move_only_the_trees():
    """trunk_radius, crown_lift (session 41): the same draws; trunk radii and crown heights move."""
    from panoptic_bench.datasets.synthetic.street import build_street

    def street(**kw):
        prof = dataclasses.replace(REALISTIC, **kw)
        return build_street(np.random.default_rng(8), (-60.0, 60.0), prof)

    (a, ga, pa), (b, gb, pb) = street(), street(trunk_radius=(0.05, 0.1), crown_lift=1.0)
    trunk, crown = _only_trees_moved(a, ga, pa, b, gb, pb)
    np.testing.assert_array_equal(a.half[trunk, 2], b.half[trunk, 2])  # heights and places kept
    np.testing.assert_array_equal(a.center[trunk], b.center[trunk])
    assert np.all((a.half[trunk, 0] >= 0.12) & (a.half[trunk, 0] <= 0.25))
    assert np.all((b.half[trunk, 0] >= 0.05) & (b.half[trunk, 0] <= 0.1))
    # the crown's centre: 0.7 (default) / 1.0 of its vertical half axis above the trunk's top
    top = a.center[trunk, 2] + a.half[trunk, 2]
    np.testing.assert_allclose(a.center[crown, 2] - top, 0.7 * a.half[crown, 2], atol=1e-9)
    np.testing.assert_allclose(b.center[crown, 2] - top, 1.0 * b.half[crown, 2], atol=1e-9)
    np.testing.assert_array_equal(a.half[crown], b.half[crown])
    assert REALISTIC.crown_lift == CLASSIC.crown_lift == 0.7
    assert REALISTIC.trunk_radius == CLASSIC.trunk_radius == (0.12, 0.25)
    for bad in ({"trunk_radius": [0.01, 0.2]}, {"trunk_radius": [0.3, 0.2]},
                {"trunk_radius": [0.1, 1.5]}, {"crown_lift": -0.1}, {"crown_lift": 2.5}):  # fmt: skip
        with pytest.raises(InputError, match=next(iter(bad))):
            WorldProfile.from_dict(bad)
