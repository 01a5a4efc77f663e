"""Side streets, the inner-lane ego and the road-far-to-the-side realism rows (issue 13, session 22)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from panoptic_bench.datasets.synthetic.profile import REALISTIC, WorldProfile
from panoptic_bench.datasets.synthetic.shapes import BOX, CYLINDER
from panoptic_bench.datasets.synthetic.side_streets import REACH, clip_rows
from panoptic_bench.errors import InputError


def _row(kind, cx, hx, yaw=0.0):
    return (kind, (cx, 1.0, 0.5), (hx, 0.5, 0.5), yaw, 48, 0.3, 0.0)


def test_clip_rows_by_hand():
    rows = [
        _row(BOX, 5.0, 5.0),  # x 0..10: cut into 0..3 and 5..10
        _row(BOX, 3.5, 0.5),  # x 3..4, inside: gone
        _row(BOX, 20.0, 1.0),  # far away: kept as is
        _row(CYLINDER, 4.5, 0.2),  # a trunk in the mouth: gone
        _row(CYLINDER, 6.0, 0.2),  # beyond it: kept
        _row(BOX, 2.9, 0.2, yaw=0.3),  # a yawed box reaching into the mouth: gone
        _row(BOX, 5.02, 0.04),  # x 4.98..5.06: the 6 cm outside is kept, nothing thinner
    ]
    out = clip_rows(rows, 3.0, 5.0)
    extents = sorted((r[1][0] - r[2][0], r[1][0] + r[2][0], r[0]) for r in out)
    got = [(round(a, 6), round(b, 6), k) for a, b, k in extents]
    assert got == [(0.0, 3.0, BOX), (5.0, 5.06, BOX), (5.0, 10.0, BOX), (5.8, 6.2, CYLINDER),
                   (19.0, 21.0, BOX)]  # fmt: skip
    for r in out:  # everything but x is carried over
        assert r[1][1:] == (1.0, 0.5) and r[2][1:] == (0.5, 0.5) and r[4:] == (48, 0.3, 0.0)


def test_side_streets_open_road_away_from_the_street():
    from panoptic_bench.datasets.synthetic.street import PARKING_WIDTH, ROAD, SIDEWALK, build_street

    def street(p):
        prof = dataclasses.replace(REALISTIC, side_street_prob=p)
        return build_street(np.random.default_rng(4), (-80.0, 80.0), prof)

    (_, ga, _), (b, gb, pb) = street(0.0), street(1.0)
    xs = np.arange(-75.0, 75.0, 0.5)
    for side in (-1, 1):
        y_far = np.full_like(xs, side * 30.0)
        assert not (ga.lookup(xs, y_far)[0] == ROAD).any()  # a closed corridor
        road_far = gb.lookup(xs, y_far)[0] == ROAD
        assert road_far.any()
        mouths = [(a_, b_) for s, a_, b_, h in pb.kerb if s == side and h == 0.0]
        assert mouths  # things standing in a mouth stand on the road
        for x0, x1 in mouths:  # road all the way out, between the flanking sidewalks
            inside = (xs > x0 + 0.3) & (xs < x1 - 0.3)
            assert (
                gb.lookup(xs[inside], np.full(inside.sum(), side * (REACH - 1.0)))[0] == ROAD
            ).all()
            lo, hi = b.center[:, 0] - b.half[:, 0], b.center[:, 0] + b.half[:, 0]
            walks = (b.label == SIDEWALK) & (np.sign(b.center[:, 1]) == side)
            walks &= b.half[:, 1] > 10.0  # the side street's sidewalks run away from the street
            assert (walks & np.isclose(hi, x0)).sum() == 1  # one flanks the mouth on each side
            assert (walks & np.isclose(lo, x1)).sum() == 1
            # nothing of the frontage stands in the carriageway of the side street (street
            # furniture and clutter come later and may stand at its corner, near the kerb)
            near = pb.road_half + PARKING_WIDTH + REALISTIC.sidewalk[1] + 1.0
            behind = (np.sign(b.center[:, 1]) == side) & (np.abs(b.center[:, 1]) > near)
            in_mouth = behind & (hi > x0 + 0.01) & (lo < x1 - 0.01)
            assert not (in_mouth & (b.label != SIDEWALK)).any()
            for s, p0, p1 in pb.parking:  # no parked car across a mouth
                assert s != side or p1 <= x0 or p0 >= x1
    # the same seed, the same street
    (c, gc, _) = street(1.0)
    np.testing.assert_array_equal(b.center, c.center)
    np.testing.assert_array_equal(gb.label, gc.label)
    for bad in ({"side_street_prob": 1.2}, {"side_street_width": (2.0, 8.0)},
                {"side_street_width": (9.0, 7.0)}):  # fmt: skip
        with pytest.raises(InputError, match="side_street"):
            WorldProfile(**bad)


def test_inner_lane_ego_on_two_lane_streets_only():
    from panoptic_bench.datasets.synthetic.scene import generate_scene

    two = dataclasses.replace(REALISTIC, lanes_p=(0.0, 1.0), ego_inner_lane=1.0)
    one = dataclasses.replace(REALISTIC, lanes_p=(1.0, 0.0), ego_inner_lane=1.0)
    for seed in range(3):
        s = generate_scene(seed, 1.0, profile=two)
        assert s.ego_y == pytest.approx(-0.5 * s.plan.lane_width)
        base = generate_scene(seed, 1.0, profile=dataclasses.replace(two, ego_inner_lane=0.0))
        assert base.ego_y == pytest.approx(-1.5 * base.plan.lane_width)
        np.testing.assert_array_equal(s.static.center, base.static.center)
        t = generate_scene(seed, 1.0, profile=one)
        assert t.ego_y == pytest.approx(-0.5 * t.plan.lane_width)
    with pytest.raises(InputError, match="ego_inner_lane"):
        WorldProfile(ego_inner_lane=-0.5)


def test_road_far_to_the_side_by_hand():
    """Ground 6-12 m to the right: 3 road points in 4; on the left: sidewalk only."""
    from panoptic_bench.datasets.synthetic.realism import MEASURES, scan_measures

    xs, ys = np.meshgrid(np.arange(-14.9, 15.0, 0.2), np.arange(-11.95, 12.0, 0.1))
    x, y = xs.ravel(), ys.ravel()
    raw = np.where(np.abs(y) < 4.0, 40, 48).astype(np.uint32)
    raw[(y < -6.0) & (y > -10.5)] = 40  # a side street to the right
    raw[(y < -6.0) & (y > -10.5) & (x > 0) & (x < 3)] = 10  # a car: not ground, not counted
    pts = np.column_stack([x, y, np.full_like(x, -1.75), np.full_like(x, 0.3)]).astype(np.float32)
    m, _ = scan_measures(pts, raw)
    assert "road_far_right_pct" in MEASURES and "road_far_left_pct" in MEASURES
    assert m["road_far_right_pct"] == pytest.approx(75.0, abs=0.5)
    assert m["road_far_left_pct"] == 0.0


def test_out_of_range_value_in_a_profile_file_names_the_file(tmp_path, capsys):
    from panoptic_bench.cli import main
    from panoptic_bench.datasets.synthetic.profile_files import load_profile

    bad = tmp_path / "bad.yaml"
    bad.write_text("base: realistic\nside_street_prob: 1.5\n")
    with pytest.raises(InputError, match="side_street_prob") as err:
        load_profile(str(bad))
    assert err.value.path == bad
    out = tmp_path / "never"
    argv = [
        "synth",
        "semantickitti",
        "--out",
        str(out),
        "--profile",
        str(bad),
        "--sequences",
        "00:1",
    ]
    assert main(argv) == 2 and not out.exists()
    msg = capsys.readouterr().err
    assert str(bad) in msg and "side_street_prob = 1.5 is out of range" in msg
    assert "Traceback" not in msg
