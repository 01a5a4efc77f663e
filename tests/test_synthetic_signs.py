"""Low sign posts beside the kerbs (world key ``sign_posts``) and the sign / trunk height rows (issue 13, session 41)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from panoptic_bench.datasets.synthetic.profile import REALISTIC, WorldProfile
from panoptic_bench.datasets.synthetic.raw_ids import POLE, SIGN, TRUNK
from panoptic_bench.datasets.synthetic.shapes import BOX, CYLINDER
from panoptic_bench.errors import InputError


def _street(seed: int = 5, x_range=(-80.0, 80.0), **kw):
    from panoptic_bench.datasets.synthetic.street import build_street

    prof = dataclasses.replace(REALISTIC, verge_prob=0.35, **kw)
    return build_street(np.random.default_rng(seed), x_range, prof)


def _rows(p):
    return np.column_stack([p.kind, p.center, p.half, p.yaw, p.label, p.reflect])


def test_sign_posts_add_rows_at_the_end_and_change_nothing_else():
    (a, ga, plan_a), (b, gb, plan_b) = _street(), _street(sign_posts=20.0)
    ra, rb = _rows(a), _rows(b)
    np.testing.assert_array_equal(rb[: len(ra)], ra)  # every other primitive as it was
    np.testing.assert_array_equal(ga.label, gb.label)
    assert plan_a.kerb == plan_b.kerb and plan_a.parking == plan_b.parking
    new = rb[len(ra) :]
    assert len(new) > 0 and set(new[:, 8]) == {POLE, SIGN}


def test_sign_post_geometry():
    from panoptic_bench.datasets.synthetic.street import curb_at, kerb_at

    z_range, half = (1.2, 1.6), (0.3, 0.5)
    a, _, _ = _street(seed=9)
    b, _, plan = _street(seed=9, sign_posts=15.0, sign_post_z=z_range, sign_post_half=half)
    n0 = len(a.label)
    kind, center, hf, label = b.kind[n0:], b.center[n0:], b.half[n0:], b.label[n0:]
    posts = np.flatnonzero(label == POLE)
    assert len(posts) > 5 and np.all(kind[posts] == CYLINDER) and np.all(kind[label == SIGN] == BOX)
    start = 0
    for p in posts:  # rows come as the plates of a post, then its post
        plates = np.arange(start, p)
        assert len(plates) in (1, 2)
        x, y = center[plates[0], :2]
        side = 1 if y > 0 else -1
        kz, curb = kerb_at(plan, side, x), curb_at(plan, side, x)
        assert 0.3 - 1e-9 <= abs(y) - curb <= 0.8 + 1e-9  # just behind the kerb line
        assert z_range[0] <= center[plates[0], 2] - kz <= z_range[1]
        assert np.all((hf[plates, 1] >= half[0]) & (hf[plates, 1] <= half[1]))
        assert np.all(hf[plates, 2] <= hf[plates, 1]) and np.all(hf[plates, 0] == 0.01)
        top = center[plates, 2] + hf[plates, 2]
        if len(plates) == 2:  # stacked, not overlapping
            assert center[plates[1], 2] - hf[plates[1], 2] > center[plates[0], 2] + hf[plates[0], 2]
        # the post stands on the kerb and reaches the top of its highest plate
        assert center[p, 2] - hf[p, 2] == pytest.approx(kz)
        assert center[p, 2] + hf[p, 2] == pytest.approx(top.max())
        assert np.hypot(*(center[p, :2] - center[plates[0], :2])) < 0.1
        start = p + 1
    assert start == len(label)


def test_sign_post_count_follows_the_spacing():
    """Poisson posts per side: mean 2 * length / spacing over a long street."""
    b, _, _ = _street(seed=2, x_range=(-1000.0, 1000.0), sign_posts=40.0)
    a, _, _ = _street(seed=2, x_range=(-1000.0, 1000.0))
    posts = int(np.sum(b.label[len(a.label) :] == POLE))
    expected = 2 * 2000.0 / 40.0
    assert abs(posts - expected) < 4 * np.sqrt(expected)


def test_sign_post_values_out_of_range():
    for bad in (
        {"sign_posts": 2.0},
        {"sign_posts": -1.0},
        {"sign_post_z": (0.1, 1.0)},
        {"sign_post_z": (2.0, 1.0)},
        {"sign_post_half": (0.01, 0.4)},
        {"sign_post_half": (0.4, 2.0)},
    ):
        key = next(iter(bad))
        with pytest.raises(InputError, match=key):
            WorldProfile(**bad)


@pytest.mark.parametrize(("raw_id", "key"), [(SIGN, "sign_h"), (TRUNK, "trunk_h")])
def test_height_rows_by_hand(raw_id, key):
    """A road plane at -1.75 m and 63 points 10 m ahead whose heights above it are 1.3-1.7 m."""
    from panoptic_bench.datasets.synthetic.realism import MEASURES, scan_measures

    xs, ys = np.meshgrid(np.arange(3.0, 20.0, 0.25), np.arange(-8.0, 8.0, 0.25))
    road = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, -1.75)])
    zs, yp = np.meshgrid(np.linspace(-0.45, -0.05, 9), np.linspace(2.0, 2.6, 7))
    thing = np.column_stack([np.full(zs.size, 10.0), yp.ravel(), zs.ravel()])
    pts = np.vstack([road, thing])
    pts = np.column_stack([pts, np.full(len(pts), 0.3)]).astype(np.float32)
    raw = np.concatenate([np.full(len(road), 40), np.full(len(thing), raw_id)]).astype(np.uint32)
    m, _ = scan_measures(pts, raw)
    assert key in MEASURES
    assert m[key] == pytest.approx(1.5, abs=0.01)
    m, _ = scan_measures(pts[: len(road)], raw[: len(road)])
    assert np.isnan(m[key])  # none in the scan: no value
