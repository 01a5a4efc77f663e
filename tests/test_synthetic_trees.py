"""Tree trunk radius and crown lift (world keys ``trunk_radius``, ``crown_lift``; issue 13, session 41)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from panoptic_bench.datasets.synthetic.profile import CLASSIC, REALISTIC, WorldProfile
from panoptic_bench.datasets.synthetic.raw_ids import TRUNK, VEGETATION
from panoptic_bench.errors import InputError


def _street(**kw):
    from panoptic_bench.datasets.synthetic.street import build_street

    prof = dataclasses.replace(REALISTIC, **kw)
    return build_street(np.random.default_rng(8), (-60.0, 60.0), prof)


def test_trunk_radius_and_crown_lift_move_only_the_trees():
    (a, ga, pa), (b, gb, pb) = _street(), _street(trunk_radius=(0.05, 0.1), crown_lift=1.0)
    np.testing.assert_array_equal(a.label, b.label)  # the same draws: the same primitives
    np.testing.assert_array_equal(ga.label, gb.label)
    assert pa.kerb == pb.kerb
    trunk = a.label == TRUNK
    crown = np.zeros_like(trunk)
    crown[1:] = trunk[:-1] & (a.label[1:] == VEGETATION)  # each crown follows its trunk
    assert trunk.sum() >= 5 and crown.sum() == trunk.sum()
    same = ~(trunk | crown)
    np.testing.assert_array_equal(a.center[same], b.center[same])
    np.testing.assert_array_equal(a.half[same], b.half[same])
    # trunk heights and places unchanged, radii in the new range
    np.testing.assert_array_equal(a.half[trunk, 2], b.half[trunk, 2])
    np.testing.assert_array_equal(a.center[trunk], b.center[trunk])
    assert np.all((a.half[trunk, 0] >= 0.12) & (a.half[trunk, 0] <= 0.25))
    assert np.all((b.half[trunk, 0] >= 0.05) & (b.half[trunk, 0] <= 0.1))
    # the crown's centre: 0.7 (default) / 1.0 of its vertical half axis above the trunk's top
    top_a = a.center[trunk, 2] + a.half[trunk, 2]
    np.testing.assert_allclose(a.center[crown, 2] - top_a, 0.7 * a.half[crown, 2], atol=1e-9)
    np.testing.assert_allclose(b.center[crown, 2] - top_a, 1.0 * b.half[crown, 2], atol=1e-9)
    np.testing.assert_array_equal(a.half[crown], b.half[crown])
    assert REALISTIC.crown_lift == CLASSIC.crown_lift == 0.7
    assert REALISTIC.trunk_radius == CLASSIC.trunk_radius == (0.12, 0.25)


def test_tree_values_out_of_range():
    for bad in ({"trunk_radius": [0.01, 0.2]}, {"trunk_radius": [0.3, 0.2]},
                {"trunk_radius": [0.1, 1.5]}, {"crown_lift": -0.1}, {"crown_lift": 2.5}):  # fmt: skip
        with pytest.raises(InputError, match=next(iter(bad))):
            WorldProfile.from_dict(bad)


def test_trunk_height_row_by_hand():
    """A road plane at -1.75 m and a trunk 8 m ahead whose points lie 0.5-2.1 m above it."""
    from panoptic_bench.datasets.synthetic.realism import MEASURES, scan_measures

    xs, ys = np.meshgrid(np.arange(3.0, 20.0, 0.25), np.arange(-8.0, 8.0, 0.25))
    road = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, -1.75)])
    z = -1.75 + np.linspace(0.5, 2.1, 17)  # median 1.3 m above the road
    trunk = np.column_stack([np.full(z.size, 8.0), np.full(z.size, 3.0), z])
    pts = np.vstack([road, trunk])
    pts = np.column_stack([pts, np.full(len(pts), 0.3)]).astype(np.float32)
    raw = np.concatenate([np.full(len(road), 40), np.full(len(trunk), TRUNK)]).astype(np.uint32)
    m, _ = scan_measures(pts, raw)
    assert "trunk_h" in MEASURES
    assert m["trunk_h"] == pytest.approx(1.3, abs=0.01)
