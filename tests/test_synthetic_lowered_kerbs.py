"""Lowered kerbs (world key ``kerb_flush``, issue 13 session 33): a paved sidewalk segment
becomes ground-level sidewalk, everything else is drawn as before, and the row-38 profile files
(bad values and the kerb-step statistic: ``test_synthetic_flush_verges.py``)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from synthetic_street_checks import check_boxes_painted, profile_changes

from panoptic_bench.datasets.synthetic.profile import REALISTIC
from panoptic_bench.datasets.synthetic.realism_layout import terrain_step
from panoptic_bench.datasets.synthetic.sequence import Sequence
from panoptic_bench.datasets.synthetic.street import build_street

REPO = Path(__file__).resolve().parents[1]
SIDEWALK, ROAD = 48, 40
# every segment a paved sidewalk (no verges), kerbs 8-14 cm, frontages buildings only
PAVED = dataclasses.replace(
    REALISTIC, verge_prob=0.0, kerb=(0.08, 0.14), frontage_p=(1.0, 0.0, 0.0, 0.0)
)


def _street(flush: float, seed: int = 3, base=PAVED):
    return build_street(
        np.random.default_rng(seed), (-60.0, 60.0), dataclasses.replace(base, kerb_flush=flush)
    )


def test_lowered_kerbs_paint_the_sidewalk_on_the_ground_and_nothing_else_moves():
    raised, gm0, plan0 = _street(0.0)
    flush, gm1, plan1 = _street(1.0)
    # every other primitive is still there, in order, in place and size; what stood on a
    # sidewalk (poles, signs, clutter, people) stands lower by that kerb's height (8-14 cm)
    boxes = check_boxes_painted(raised, flush, gm1, SIDEWALK, (0.08, 0.14))
    # the boxes' footprints are sidewalk on the ground now, with the sidewalk's reflectivity
    xy = raised.center[boxes, :2]
    _, reflect = gm1.lookup(xy[:, 0], xy[:, 1])
    np.testing.assert_allclose(reflect, PAVED.sidewalk_reflect, atol=1e-6)
    label0, _ = gm0.lookup(xy[:, 0], xy[:, 1])
    assert not np.any(label0 == SIDEWALK)
    # the kerb lines stay where they were, at height 0
    assert [k[:3] for k in plan1.kerb] == [k[:3] for k in plan0.kerb]
    assert all(k[3] == 0.0 for k in plan1.kerb) and all(k[3] >= 0.08 for k in plan0.kerb)
    assert plan1.curb == plan0.curb


def test_probability_zero_is_the_old_world_and_verges_are_untouched():
    a, _, pa = _street(0.0, base=REALISTIC)
    b, _, pb = build_street(np.random.default_rng(3), (-60.0, 60.0), REALISTIC)
    np.testing.assert_array_equal(a.center, b.center)
    assert pa.kerb == pb.kerb
    kerbs = [k[3] for seed in range(4) for k in _street(0.5, seed)[2].kerb]
    assert 0 < sum(k == 0.0 for k in kerbs) < len(kerbs)
    # a grass verge is not a sidewalk: with every segment a raised verge nothing is lowered
    verges = dataclasses.replace(PAVED, verge_prob=1.0, verge_raise=(0.1, 0.3))
    v0, _, _ = _street(0.0, base=verges)
    v1, _, _ = _street(1.0, base=verges)
    np.testing.assert_array_equal(v0.center, v1.center)


def test_scanned_lowered_kerb_meets_the_road_without_a_step():
    """In a rendered sweep, sidewalk within 1 m of road sits at the road's height."""
    steps = {}
    for flush in (0.0, 1.0):
        prof = dataclasses.replace(PAVED, kerb_flush=flush)
        sw = Sequence(0, 5, 1, profile=prof).frame(0).sweep
        x, y, z = (sw.xyz[:, k].astype(float) for k in range(3))
        steps[flush] = terrain_step(x, y, z, np.hypot(x, y), sw.label, raw_id=SIDEWALK)[0]
    assert steps[0.0] > 0.08 and abs(steps[1.0]) < 0.05


@pytest.mark.parametrize(
    "name",
    ["low_crowns_low_fences", "low_fences_tight_materials", "low_fences_raised_lots"],
)
def test_row_38_profiles_are_row_34_worlds_plus_lowered_kerbs(name):
    assert profile_changes(f"synth_kerb_{name}", f"synth_order_flush_{name}") == {"kerb_flush": 0.3}
