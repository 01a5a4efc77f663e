"""Cars parked in yards, driveways and car parks (issue 13, session 36): the ``yard_cars`` world key
adds static cars behind the sidewalks on a stream of its own, and nothing else of the world moves."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from synthetic_street_checks import WORLDS, by_beam, profile_changes

from panoptic_bench.datasets.synthetic import Sequence
from panoptic_bench.datasets.synthetic.profile import REALISTIC, WorldProfile
from panoptic_bench.datasets.synthetic.scene import generate_scene
from panoptic_bench.datasets.synthetic.yards import EDGE_M, yard_cars
from panoptic_bench.errors import InputError

REPO = Path(__file__).resolve().parents[1]
CAR = 10


def test_yard_cars_hand_worked():
    yards = [
        (-1, 0.0, 30.0, 8.0, 24.0, 0.2),
        (1, 0.0, 30.0, 8.0, 12.0, 0.0),
        (1, 40.0, 47.0, 8, 30, 0),
    ]
    cars = yard_cars(np.random.default_rng(0), yards, 1.0)
    # share 1: the deep right-hand yard holds a row; the left one is too shallow for any row
    # (4 m < 2 x 3 m + 2.2 m) and the short one too narrow (7 m < 2 x 3 m + 2 m)
    assert 1 <= len(cars) <= 3
    for car in cars:
        assert car.category == "car" and car.label == CAR and not car.moving
        assert -24.0 + EDGE_M <= car.xyz[1] <= -8.0 - EDGE_M
        assert EDGE_M <= car.xyz[0] <= 30.0 - EDGE_M + 3.2 and car.xyz[2] == 0.2
    assert len({round(float(c.xyz[1]), 9) for c in cars}) == 1  # one row, one depth
    xs = sorted(c.xyz[0] for c in cars)
    assert all(b - a >= 2.5 - 1e-9 for a, b in zip(xs, xs[1:]))  # side by side, never overlapping
    assert yard_cars(np.random.default_rng(0), yards, 0.0) == []
    again = yard_cars(np.random.default_rng(0), yards, 1.0)
    assert [tuple(c.xyz) for c in again] == [tuple(c.xyz) for c in cars]  # deterministic


def test_yard_cars_add_cars_behind_the_sidewalk_and_change_nothing_else():
    base = dataclasses.replace(REALISTIC, frontage_p=(0.1, 0.4, 0.2, 0.3))
    added = 0
    for seed in range(3):
        a = generate_scene(seed, 1.0, profile=base)
        b = generate_scene(seed, 1.0, profile=dataclasses.replace(base, yard_cars=0.5))
        np.testing.assert_array_equal(a.static.center, b.static.center)
        assert (a.ego_y, a.ego_phase, a.ego_speed) == (b.ego_y, b.ego_phase, b.ego_speed)
        n = len(a.things)
        assert [(t.category, *t.xyz, t.yaw) for t in a.things] == [
            (t.category, *t.xyz, t.yaw) for t in b.things[:n]
        ]
        late = b.things[n:]
        assert a.late_things == 0 and b.late_things == len(late)
        for car in late:  # static cars in a yard, beyond its sidewalk edge
            assert car.category == "car" and not car.moving
            assert any(
                s == np.sign(car.xyz[1])
                and x0 <= car.xyz[0] <= x1
                and f + EDGE_M <= abs(car.xyz[1]) <= k
                for s, x0, x1, f, k, _ in b.plan.yards
            )
        added += len(late)
    assert added >= 5


def test_yard_cars_keep_every_other_material_and_return():
    prof = dataclasses.replace(REALISTIC, frontage_p=(0.1, 0.4, 0.2, 0.3))
    sa = Sequence(1, 2, 1, profile=prof)
    sb = Sequence(1, 2, 1, profile=dataclasses.replace(prof, yard_cars=0.6))
    a, b = sa.frame(0).sweep, sb.frame(0).sweep
    assert sb.scene.late_things > 0
    ga, gb = sa.state.gain, sb.state.gain
    np.testing.assert_array_equal(ga, gb[: ga.size])  # the materials of everything else
    assert gb.size > ga.size
    np.testing.assert_array_equal(sa.state.rough, sb.state.rough)
    # a ray that does not hit a yard car sees what it saw without them; only the per-return noise
    # draws (range noise, remission spread, dropout) are drawn in a different order
    key_a, key_b = by_beam(a), by_beam(b)
    first_yard = len(sa.scene.things) + 1
    hit = [ib for ib in key_b.values() if b.instance[ib] >= first_yard]
    pairs = np.array(
        [(key_a[k], ib) for k, ib in key_b.items() if k in key_a and b.instance[ib] < first_yard]
    )
    assert len(hit) > 50 and len(pairs) > 0.95 * (len(key_b) - len(hit))
    ia, ib = pairs[:, 0], pairs[:, 1]
    assert np.mean(a.label[ia] == b.label[ib]) > 0.99
    np.testing.assert_array_equal(a.instance[ia], b.instance[ib])
    assert np.median(np.linalg.norm(a.xyz[ia] - b.xyz[ib], axis=1)) < 0.03


@pytest.mark.parametrize("value", [-0.1, 1.5])
def test_bad_yard_cars(value):
    with pytest.raises(InputError, match="yard_cars"):
        WorldProfile.from_dict({"yard_cars": value}, base=REALISTIC)


@pytest.mark.parametrize("world", WORLDS)
def test_row_44_files_are_row_38_worlds_plus_yard_cars(world):
    assert profile_changes(f"synth_yard_{world}", f"synth_kerb_{world}") == {"yard_cars": 0.4}
