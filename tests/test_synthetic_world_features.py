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


def test_trunk_height_lowers_crowns_and_changes_nothing_else():
    """trunk_height: the same draws, so only tree trunks and the crowns on them move."""
    from panoptic_bench.datasets.synthetic.street import TRUNK, VEGETATION, build_street

    def street(**kw):
        prof = dataclasses.replace(REALISTIC, **kw)
        return build_street(np.random.default_rng(5), (-60.0, 60.0), prof)

    (a, ga, pa), (b, gb, pb) = street(), street(trunk_height=(1.0, 2.0))
    np.testing.assert_array_equal(a.label, b.label)
    np.testing.assert_array_equal(ga.label, gb.label)
    assert pa.curb == pb.curb and pa.kerb == pb.kerb
    trunk = a.label == TRUNK
    crown = np.zeros_like(trunk)
    crown[1:] = trunk[:-1] & (a.label[1:] == VEGETATION)  # each crown follows its trunk
    assert trunk.sum() >= 5 and crown.sum() == trunk.sum()
    same = ~(trunk | crown)
    np.testing.assert_array_equal(a.center[same], b.center[same])
    np.testing.assert_array_equal(a.half[same], b.half[same])
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
