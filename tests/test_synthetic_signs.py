"""Low sign posts beside the kerbs (world key ``sign_posts``) and the sign / trunk height rows (issue 13, session 41)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from synthetic_street_checks import WORLDS, profile_changes

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


def _post_rows(street, n0):
    """(plates, post) row indices of each post after the first ``n0`` rows."""
    label = street.label
    out, start = [], n0
    for p in np.flatnonzero(label[n0:] == POLE) + n0:
        out.append((np.arange(start, p), p))
        start = p + 1
    return out


def test_two_sided_plates_keep_the_posts_and_split_each_plate():
    """``sign_back_reflect``: each post plate becomes a front and a back half-plate back to back."""
    from panoptic_bench.datasets.synthetic.signs import PLATE_HALF_T, PLATE_REFLECT

    kw = {"sign_posts": 15.0, "sign_post_half": (0.3, 0.5)}
    a, _, _ = _street(seed=9, **kw)
    b, _, _ = _street(seed=9, sign_back_reflect=0.5, **kw)
    base, _, _ = _street(seed=9)
    n0 = len(base.label)
    np.testing.assert_array_equal(_rows(b)[:n0], _rows(a)[:n0])
    pa, pb = _post_rows(a, n0), _post_rows(b, n0)
    assert len(pa) == len(pb) > 5
    fronts_up = 0
    for (plates_a, post_a), (plates_b, post_b) in zip(pa, pb):
        # the posts stand where they stood; two half-plates for each plate
        np.testing.assert_array_equal(b.center[post_b], a.center[post_a])
        np.testing.assert_array_equal(b.half[post_b], a.half[post_a])
        assert len(plates_b) == 2 * len(plates_a)
        for k, pa_row in enumerate(plates_a):
            front, back = plates_b[2 * k], plates_b[2 * k + 1]
            assert b.reflect[front] == pytest.approx(PLATE_REFLECT)
            assert b.reflect[back] == pytest.approx(0.5)
            yaw = a.yaw[pa_row]
            normal = np.array([np.cos(yaw), np.sin(yaw), 0.0])
            for row in (front, back):
                assert b.yaw[row] == yaw and b.label[row] == SIGN and b.kind[row] == BOX
                np.testing.assert_allclose(b.half[row], [PLATE_HALF_T / 2, *a.half[pa_row, 1:]])
            # back to back about the plate's centre, along its normal
            np.testing.assert_allclose((b.center[front] + b.center[back]) / 2, a.center[pa_row])
            off = (b.center[front] - a.center[pa_row]) @ normal
            assert abs(off) == pytest.approx(PLATE_HALF_T / 2)
            fronts_up += off > 0
    n_plates = sum(len(p) for p, _ in pa)
    assert 0 < fronts_up < n_plates  # fronts face either way


def test_bright_fronts_share_and_geometry():
    """``sign_bright`` alone: one-sided plates where they were, a share of them retro-reflective."""
    from panoptic_bench.datasets.synthetic.signs import BRIGHT_REFLECT, PLATE_REFLECT

    kw = {"x_range": (-1000.0, 1000.0), "sign_posts": 20.0}
    n0 = len(_street(seed=4, x_range=kw["x_range"])[0].label)
    a, _, _ = _street(seed=4, **kw)
    b, _, _ = _street(seed=4, sign_bright=0.3, **kw)
    np.testing.assert_array_equal(np.delete(_rows(b), 9, axis=1), np.delete(_rows(a), 9, axis=1))
    np.testing.assert_array_equal(b.reflect[:n0], a.reflect[:n0])  # lamp plates unchanged
    plates = np.flatnonzero(a.label[n0:] == SIGN) + n0
    assert np.all(a.reflect[plates] == np.float32(PLATE_REFLECT))
    bright = b.reflect[plates] == np.float32(BRIGHT_REFLECT)
    assert np.all(bright | (b.reflect[plates] == np.float32(PLATE_REFLECT)))
    n, k = plates.size, int(bright.sum())
    assert n > 100 and abs(k - 0.3 * n) < 4 * np.sqrt(n * 0.3 * 0.7)
    c, _, _ = _street(seed=4, sign_bright=1.0, **kw)
    assert np.all(c.reflect[plates] == np.float32(BRIGHT_REFLECT))


def test_plate_face_values_out_of_range():
    for bad in ({"sign_back_reflect": -0.1}, {"sign_back_reflect": 3.0}, {"sign_bright": 1.5}):
        key = next(iter(bad))
        with pytest.raises(InputError, match=key):
            WorldProfile(**bad)


def test_sign_and_pole_remission_rows_by_hand():
    """20 sign points 10 m ahead, 5 of them brighter than 0.8; 8 pole points, 2 of them 0."""
    from panoptic_bench.datasets.synthetic.realism import scan_measures

    sign = np.column_stack([np.full(20, 10.0), np.linspace(2, 3, 20), np.full(20, 0.5)])
    pole = np.column_stack([np.full(8, 12.0), np.full(8, -3.0), np.linspace(-1, 1, 8)])
    far = np.array([[30.0, 0.0, 0.0]])  # outside 3-20 m: not counted
    pts = np.vstack([sign, pole, far])
    rem = np.concatenate([[0.9] * 5 + [0.75] + [0.3] * 14, [0.0, 0.0] + [0.2] * 6, [0.95]])
    raw = np.concatenate([np.full(20, SIGN), np.full(8, POLE), [SIGN]]).astype(np.uint32)
    m, _ = scan_measures(np.column_stack([pts, rem]).astype(np.float32), raw)
    assert m["rem_sign_bright_pct"] == pytest.approx(25.0)
    assert m["rem_pole_zero_pct"] == pytest.approx(25.0)
    m, _ = scan_measures(np.column_stack([pole, rem[20:28]]).astype(np.float32), raw[20:28])
    assert np.isnan(m["rem_sign_bright_pct"])


@pytest.mark.parametrize("world", WORLDS)
def test_row_58_files_are_row_56_worlds_plus_plate_faces(world):
    changed = profile_changes(f"synth_faces_{world}", f"synth_boards_{world}")
    assert changed == {"sign_back_reflect": 0.5, "sign_bright": 0.25}
