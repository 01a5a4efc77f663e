"""Guard rails on grass verges (world key ``guard_rail``, issue 13 session 29): geometry by hand,
same draws for everything else, bad values, and the row-30 profile files."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from synthetic_street_checks import profile_changes

from panoptic_bench.datasets.synthetic.fences import RAIL_BEAM
from panoptic_bench.datasets.synthetic.profile import REALISTIC, WorldProfile
from panoptic_bench.datasets.synthetic.street import build_street
from panoptic_bench.errors import InputError

REPO = Path(__file__).resolve().parents[1]
FENCE = 51
# every segment a raised grass verge; frontages are buildings or green areas (no other fence)
VERGES = dataclasses.replace(
    REALISTIC, verge_prob=1.0, verge_raise=(0.1, 0.3), frontage_p=(0.5, 0.5, 0.0, 0.0)
)


def _streets(guard_rail: float, seed: int = 3):
    rails = dataclasses.replace(VERGES, guard_rail=guard_rail)
    return [build_street(np.random.default_rng(seed), (-60.0, 60.0), p)[0] for p in (VERGES, rails)]


def test_rails_stand_on_the_verges_and_nothing_else_moves():
    a, b = _streets(1.0)
    assert not (a.label == FENCE).any()
    new = b.label == FENCE
    # every primitive of the world without rails is still there, in order, unchanged
    np.testing.assert_array_equal(b.center[~new], a.center)
    np.testing.assert_array_equal(b.half[~new], a.half)
    np.testing.assert_array_equal(b.label[~new], a.label)
    top = b.center[new, 2] + b.half[new, 2]
    bottom = b.center[new, 2] - b.half[new, 2]
    beams = b.half[new, 0] > 0.5  # beams run along the street, posts are 0.1 m square
    posts = np.isclose(b.half[new, 0], 0.05) & np.isclose(b.half[new, 1], 0.05)
    assert beams.sum() >= 4 and posts.sum() >= 10 and np.all(beams | posts)
    # a beam is RAIL_BEAM tall, its lower edge 0.3-0.5 m above a verge top (0.1-0.3 m)
    assert np.allclose(top[beams] - bottom[beams], RAIL_BEAM)
    assert np.all((bottom[beams] >= 0.4 - 1e-9) & (bottom[beams] <= 0.8 + 1e-9))
    assert np.allclose(b.half[new][beams, 1], 0.04)  # 0.08 m deep
    # posts stand on a verge top and reach a beam's top
    assert np.all((bottom[posts] >= 0.1 - 1e-9) & (bottom[posts] <= 0.3 + 1e-9))
    assert np.all(np.isin(np.round(top[posts], 9), np.round(top[beams], 9)))
    # the rails stand next to the road edge: 0.3-1.0 m outside a kerb line, on both sides
    y = np.abs(b.center[new, 1])
    assert (b.center[new, 1] > 0).any() and (b.center[new, 1] < 0).any()
    assert np.all((y > 3.0) & (y < 25.0))


def test_probability_zero_is_the_world_without_rails_and_half_builds_some():
    a, b = _streets(0.0)
    np.testing.assert_array_equal(a.center, b.center)
    counts = [int((_streets(0.5, seed)[1].label == FENCE).any()) for seed in range(6)]
    assert 0 < sum(counts)


@pytest.mark.parametrize("bad", [-0.1, 1.5])
def test_bad_values(bad):
    with pytest.raises(InputError, match="guard_rail"):
        WorldProfile.from_dict({"guard_rail": bad}, base=REALISTIC)


@pytest.mark.parametrize(
    ("name", "base"),
    [
        ("synth_rails_low_crowns_low_fences", "synth_realistic_low_crowns_low_fences"),
        ("synth_rails_low_fences_tight_materials", "synth_realistic_low_fences_tight_materials"),
        ("synth_rails_low_fences_raised_lots", "synth_realistic_low_fences_raised_lots"),
    ],
)
def test_row_30_profiles_are_row_22_worlds_plus_rails(name, base):
    assert profile_changes(name, base) == {"guard_rail": 0.5}
