"""World key ``road_reflect_range``: a per-street road reflectivity from its own stream (session 31).

Real road medians (3-15 m) spread 7 % from scan to scan, the worlds' 3 %; the key widens the
road's own spread without touching any other draw of a street.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from synthetic_street_checks import profile_changes

from panoptic_bench.datasets.synthetic import Sequence
from panoptic_bench.datasets.synthetic.profile import REALISTIC, WorldProfile
from panoptic_bench.datasets.synthetic.scene import street_profile
from panoptic_bench.errors import InputError

ROAD = 40


def _sweep(prof):
    return Sequence(0, 4, 1, profile=prof).frame(0).sweep


def test_a_point_range_at_the_base_value_is_bit_identical():
    """Range (r, r) with r = road_reflect: the same world, so no other draw moved."""
    base = _sweep(REALISTIC)
    same = _sweep(dataclasses.replace(REALISTIC, road_reflect_range=(REALISTIC.road_reflect,) * 2))
    for field in ("xyz", "remission", "label", "instance"):
        np.testing.assert_array_equal(getattr(same, field), getattr(base, field))


def test_the_road_alone_changes_and_follows_the_draw():
    bright = dataclasses.replace(REALISTIC, road_reflect_range=(0.6, 0.6))
    base, out = _sweep(REALISTIC), _sweep(bright)
    np.testing.assert_array_equal(out.xyz, base.xyz)
    np.testing.assert_array_equal(out.label, base.label)
    road = base.label == ROAD
    np.testing.assert_array_equal(out.remission[~road], base.remission[~road])
    # remission scales with the reflectivity (0.6 / 0.3 = 2) where it was recorded in both
    both = road & (base.remission > 0) & (out.remission > 0) & (out.remission < 1)
    assert both.sum() > 1000
    assert np.median(out.remission[both] / base.remission[both]) == pytest.approx(2.0, rel=0.05)


def test_per_street_draws_are_in_range_deterministic_and_differ():
    prof = dataclasses.replace(REALISTIC, road_reflect_range=(0.25, 0.35))
    draws = [street_profile(prof, [0, key]).road_reflect for key in range(20)]
    assert all(0.25 <= d <= 0.35 for d in draws)
    assert len(set(draws)) == 20 and np.ptp(draws) > 0.05
    assert draws == [street_profile(prof, [0, key]).road_reflect for key in range(20)]
    assert street_profile(REALISTIC, [0, 1]) is REALISTIC  # no range: the profile itself


@pytest.mark.parametrize("bad", [[0.4, 0.2], [0.3], [-0.1, 0.2], [0.2, 1.2]])
def test_bad_values(bad):
    with pytest.raises(InputError, match="road_reflect_range"):
        WorldProfile.from_dict({"road_reflect_range": bad}, base=REALISTIC)


@pytest.mark.parametrize(
    "name",
    ["low_crowns_low_fences", "low_fences_tight_materials", "low_fences_raised_lots"],
)
def test_row_35_profiles_are_row_34_worlds_plus_a_road_range(name):
    changed = profile_changes(f"synth_order_road_{name}", f"synth_order_flush_{name}")
    assert changed == {"road_reflect_range": (0.31, 0.37)}
