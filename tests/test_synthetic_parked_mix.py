"""The parked-vehicle mix as world keys (``parked_truck``, ``parked_trailer``, session 45)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from panoptic_bench.datasets.synthetic.buses import park_instead
from panoptic_bench.datasets.synthetic.profile import REALISTIC, WorldProfile
from panoptic_bench.datasets.synthetic.scene import generate_scene
from panoptic_bench.datasets.synthetic.things import STATIC_LABEL, build
from panoptic_bench.errors import InputError

BASE = dataclasses.replace(REALISTIC, parking_prob=0.8, parked_fill=1.0)


def _parked(scene, category):
    return [t for t in scene.things if t.category == category and not t.moving]


def _key(scene):
    """Everything but the parked cars: streets stay, only cars may be replaced."""
    return {(t.category, *t.xyz) for t in scene.things if t.moving or t.category != "car"}


@pytest.mark.parametrize(("key", "category", "length"), [
    ("parked_truck", "truck", (6.0, 12.0)),
    ("parked_trailer", "other-vehicle", (4.0, 8.0)),
])  # fmt: skip
def test_parked_mix_replaces_parked_cars_and_nothing_else(key, category, length):
    replaced = 0
    for seed in range(4):
        a = generate_scene(seed, 1.0, profile=BASE)
        b = generate_scene(seed, 1.0, profile=dataclasses.replace(BASE, **{key: 0.3}))
        # own stream: street, ego and every moving or sidewalk thing unchanged
        np.testing.assert_array_equal(a.static.center, b.static.center)
        np.testing.assert_array_equal(a.ground.label, b.ground.label)
        assert (a.ego_y, a.ego_phase, a.ego_speed) == (b.ego_y, b.ego_phase, b.ego_speed)
        new = {(t.category, *t.xyz) for t in _parked(b, category)} - _key(a)
        assert _key(b) - _key(a) == new  # what is new is this key's category, nothing else
        for t in _parked(b, category):
            if (t.category, *t.xyz) not in new:
                continue
            assert t.label == STATIC_LABEL[category]
            assert length[0] <= t.size[0] <= length[1]
            lo, hi = t.xyz[0] - t.size[0] / 2, t.xyz[0] + t.size[0] / 2
            assert any(
                s == np.sign(t.xyz[1]) and x0 <= lo and hi <= x1 for s, x0, x1 in b.plan.parking
            )
        replaced += len(new)
        # a car that is not replaced stands where it stood
        cars_b = {tuple(t.xyz) for t in _parked(b, "car")}
        assert cars_b <= {tuple(t.xyz) for t in _parked(a, "car")}
    assert replaced >= 3


def test_parked_mix_keys_are_independent_streams():
    """Trucks and trailers together: the trucks are those of trucks alone, less those a trailer covers."""
    seed = 2
    trucks = generate_scene(seed, 1.0, profile=dataclasses.replace(BASE, parked_truck=0.2))
    both = generate_scene(
        seed, 1.0, profile=dataclasses.replace(BASE, parked_truck=0.2, parked_trailer=0.2)
    )
    t_alone = {tuple(t.xyz): t for t in _parked(trucks, "truck")}
    t_both = {tuple(t.xyz) for t in _parked(both, "truck")}
    assert t_both and t_both <= set(t_alone)
    trailers = _parked(both, "other-vehicle")
    for xyz in set(t_alone) - t_both:  # a truck gone is one a trailer now covers
        t = t_alone[xyz]
        assert any(
            np.sign(o.xyz[1]) == np.sign(t.xyz[1])
            and abs(o.xyz[0] - t.xyz[0]) < (o.size[0] + t.size[0]) / 2 + 0.3
            for o in trailers
        )
    # trailers replace only cars that stayed cars
    assert {tuple(t.xyz) for t in _parked(both, "car")} <= {
        tuple(t.xyz) for t in _parked(trucks, "car")
    }


def test_park_instead_hand_worked():
    rng = np.random.default_rng(0)
    cars = [build(rng, "car", (x, 6.0, 0.0), np.pi) for x in (3.0, 8.0, 13.0, 30.0)]
    out = park_instead(np.random.default_rng(1), cars, [(1, 0.0, 31.5)], 1.0, "other-vehicle")
    # cars 4.2-4.6 m long. Share 1: the car at 3 m becomes a trailer from its rear end (~0.8 m);
    # this stream draws it 7.8 m long, so it covers the car at 8 m (from ~5.7 m); the car at 13 m
    # becomes the next trailer; the car at 30 m never can: a trailer (>= 4 m) from its rear end
    # (27.9 m) ends past 31.9 m, beyond the strip's 31.5 m less the 0.3 m gap
    first, second, last = out
    assert [t.category for t in out] == ["other-vehicle", "other-vehicle", "car"]
    assert first.size[0] == pytest.approx(7.80, abs=0.01) and last is cars[-1]
    assert first.xyz[0] - first.size[0] / 2 == pytest.approx(3.0 - cars[0].size[0] / 2)
    assert second.xyz[0] - second.size[0] / 2 == pytest.approx(13.0 - cars[2].size[0] / 2)
    assert first.xyz[1] == second.xyz[1] == 6.0 and first.yaw == cars[0].yaw
    assert [c.category for c in cars] == ["car"] * 4  # input untouched
    same = park_instead(np.random.default_rng(1), cars, [(1, 0.0, 31.5)], 0.0, "truck")
    assert same == cars


def test_parked_mix_defaults_off_and_out_of_range():
    assert REALISTIC.parked_truck == 0.0 and REALISTIC.parked_trailer == 0.0
    for key in ("parked_truck", "parked_trailer"):
        with pytest.raises(InputError, match=key):
            WorldProfile.from_dict({key: 1.5})
        with pytest.raises(InputError, match=key):
            WorldProfile.from_dict({key: -0.1})
