"""Fence heights, see-through lattices and the fence realism rows (issue 13, session 23)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from panoptic_bench.datasets.synthetic.fences import build_fence
from panoptic_bench.datasets.synthetic.profile import REALISTIC, WorldProfile
from panoptic_bench.datasets.synthetic.raycast import GROUND, MISS, cast
from panoptic_bench.errors import InputError

FENCE, BUILDING = 51, 50


def _builder():
    from panoptic_bench.datasets.synthetic.street import _Builder

    return _Builder()


def _rays(n_col: int = 4096):
    elev = np.radians(np.linspace(-8.0, -1.0, 24))  # all below the fence's top
    az = -np.pi + (np.arange(n_col) + 0.5) * 2 * np.pi / n_col
    return elev, az


def _hits_in_front(prims, elev, az):
    """Labels hit by the rays looking at the fence (azimuth -20..20 deg, straight ahead)."""
    hits = cast(prims, elev, az, ground_z=-1.7, max_range=80.0)
    cols = np.tile(np.arange(az.size), elev.size)
    front = np.abs(az[cols]) < np.radians(20.0)
    label = np.where(hits.prim >= 0, prims.label[np.maximum(hits.prim, 0)], 0)
    keep = front & (hits.prim != MISS) & (hits.prim != GROUND)
    return label[keep]


def test_solid_panel_blocks_and_lattice_lets_most_rays_through():
    """A fence 5 m ahead in front of a wall 9 m ahead, both 3 m to 0.3 m below the sensor."""
    elev, az = _rays()
    for lattice, lo, hi in ((0.0, 0.999, 1.0), (1.0, 0.05, 0.45)):
        b = _builder()
        rng = np.random.default_rng(0)
        # along the street is x, the fence runs along x at lateral y: here turn it to face the
        # sensor by building it along x and casting from a frame where it lies ahead (y -> x)
        build_fence(b, -6.0, 6.0, 5.0, 1, 1.7, 0.3, rng, lattice)
        b.box(-8.0, 8.0, 9.0, 9.5, 0.0, 3.0, BUILDING, 0.3)
        prims = b.primitives()
        prims = dataclasses.replace(
            prims,
            center=np.column_stack(
                [prims.center[:, 1], -prims.center[:, 0], prims.center[:, 2] - 1.7]
            ),
            half=prims.half[:, [1, 0, 2]],
        )
        seen = _hits_in_front(prims, elev, az)
        share = float(np.mean(seen == FENCE))
        assert lo <= share <= hi, (lattice, share)
        assert set(np.unique(seen)) <= {FENCE, BUILDING}


def test_fence_keys_leave_the_rest_of_the_street_unchanged():
    from panoptic_bench.datasets.synthetic.street import build_street

    fence_front = (0.0, 0.0, 1.0, 0.0)  # every frontage a fence
    base = dataclasses.replace(REALISTIC, frontage_p=fence_front)
    tall = dataclasses.replace(base, fence_height=(2.4, 2.5))
    lat = dataclasses.replace(base, fence_lattice=1.0)
    out = {k: build_street(np.random.default_rng(7), (-60.0, 60.0), p)[0]
           for k, p in (("base", base), ("tall", tall), ("lat", lat))}  # fmt: skip
    for k, s in out.items():
        rest, base_rest = s.label != FENCE, out["base"].label != FENCE
        np.testing.assert_array_equal(s.center[rest], out["base"].center[base_rest], err_msg=k)
        np.testing.assert_array_equal(s.half[rest], out["base"].half[base_rest], err_msg=k)
    top = {k: (s.center[:, 2] + s.half[:, 2])[s.label == FENCE] for k, s in out.items()}
    assert top["base"].min() >= 1.0 - 1e-9 and top["base"].max() <= 2.0 + 1e-9
    assert top["tall"].min() >= 2.4 - 1e-9 and top["tall"].max() <= 2.5 + 1e-9
    thin = out["lat"].half[out["lat"].label == FENCE][:, 0] < 0.03  # the bars
    assert thin.sum() > 10 * (out["base"].label == FENCE).sum() / 3
    assert not (out["base"].half[out["base"].label == FENCE][:, 0] < 0.03).any()


def test_fence_values_out_of_range():
    for bad in ({"fence_height": (0.1, 1.0)}, {"fence_height": (1.0, 5.0)},
                {"fence_height": (2.0, 1.0)}, {"fence_lattice": 1.5}):  # fmt: skip
        with pytest.raises(InputError, match="fence_"):
            WorldProfile(**bad)


def test_fence_rows_by_hand():
    """A road plane at -1.75 m, a fence 1 m tall 10 m ahead with every other column open."""
    from panoptic_bench.datasets.synthetic.realism import MEASURES, scan_measures

    xs, ys = np.meshgrid(np.arange(3.0, 20.0, 0.25), np.arange(-8.0, 8.0, 0.25))
    road = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, -1.75)])
    # one ring of fence points at 0.5 m above the road, recorded in azimuth order; every
    # third point is a return from a wall 4 m behind the fence (seen through it)
    az = np.linspace(-0.3, 0.3, 90)
    rng_ = np.where(np.arange(az.size) % 3 == 2, 14.0, 10.0)
    ring = np.column_stack([rng_ * np.cos(az), rng_ * np.sin(az), np.full(az.size, -1.25)])
    pts = np.vstack([road, ring])
    raw = np.concatenate([np.full(len(road), 40), np.where(rng_ > 12, BUILDING, FENCE)])
    pts = np.column_stack([pts, np.full(len(pts), 0.3)]).astype(np.float32)
    m, _ = scan_measures(pts, raw.astype(np.uint32))
    assert "fence_h" in MEASURES and "fence_through_pct" in MEASURES
    assert m["fence_h"] == pytest.approx(0.5, abs=0.01)
    # 60 fence points, 120 neighbour pairs (the first fence point's previous one is road):
    # every wall point sits between two fence points, so 2 per wall point are farther
    n_fence, n_wall = 60, 30
    assert m["fence_through_pct"] == pytest.approx(100.0 * 2 * n_wall / (2 * n_fence), abs=1.0)
