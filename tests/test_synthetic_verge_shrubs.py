"""Low shrubs on the grass verges (world key ``verge_shrubs``, issue 13 session 33): rows of low
ellipsoids on the verges, everything else drawn as before; bad values."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from panoptic_bench.datasets.synthetic.plants import SHRUB_HALF, SHRUB_HEIGHT
from panoptic_bench.datasets.synthetic.profile import REALISTIC, WorldProfile
from panoptic_bench.datasets.synthetic.sequence import Sequence
from panoptic_bench.datasets.synthetic.shapes import ELLIPSOID
from panoptic_bench.datasets.synthetic.street import build_street
from panoptic_bench.errors import InputError

VEGETATION = 70
# every segment a raised grass verge (0.1-0.3 m), frontages buildings only (no bushes or trees)
VERGES = dataclasses.replace(
    REALISTIC, verge_prob=1.0, verge_raise=(0.1, 0.3), frontage_p=(1.0, 0.0, 0.0, 0.0)
)


def _street(shrubs: float, seed: int = 3, base=VERGES):
    prof = dataclasses.replace(base, verge_shrubs=shrubs)
    return build_street(np.random.default_rng(seed), (-60.0, 60.0), prof)


def _inserted(planted, bare) -> np.ndarray:
    """Rows of ``planted`` that are not the next row of ``bare`` (walked in order)."""
    extra, j = np.zeros(len(planted.kind), bool), 0
    for i in range(len(planted.kind)):
        same = j < len(bare.kind) and np.array_equal(planted.center[i], bare.center[j])
        extra[i], j = not same, j + same
    assert j == len(bare.kind)  # every row of the bare street is there, in order
    return extra


def test_shrubs_stand_on_the_verges_and_nothing_else_moves():
    bare, _, plan = _street(0.0)
    planted, _, plan1 = _street(1.0)
    shrub = _inserted(planted, bare)
    assert shrub.sum() >= 20
    assert np.all(planted.kind[shrub] == ELLIPSOID) and np.all(planted.label[shrub] == VEGETATION)
    # the rest of the street is the bare street, in order, same places and sizes
    np.testing.assert_array_equal(planted.center[~shrub], bare.center)
    np.testing.assert_array_equal(planted.half[~shrub], bare.half)
    assert plan1.kerb == plan.kerb and plan1.curb == plan.curb
    half = planted.half[shrub]
    assert np.all((half[:, :2] >= SHRUB_HALF[0]) & (half[:, :2] <= SHRUB_HALF[1]))
    assert np.all((half[:, 2] >= SHRUB_HEIGHT[0]) & (half[:, 2] <= SHRUB_HEIGHT[1]))
    # each shrub sits on its verge: between the kerb line and the verge's outer edge, its
    # centre half its height above the verge top
    for (x, y, z), rz in zip(planted.center[shrub], half[:, 2]):
        side = 1 if y > 0 else -1
        seg = [k for k in plan.kerb if k[0] == side and k[1] <= x <= k[2] + SHRUB_HALF[1]]
        curb = [c for c in plan.curb if c[0] == side and c[1] <= x <= c[2] + SHRUB_HALF[1]]
        assert seg and curb
        assert curb[0][3] + 0.3 - 1e-9 <= abs(y) <= curb[0][3] + plan.sidewalk_width
        assert z == pytest.approx(seg[0][3] + 0.5 * rz)


def test_probability_zero_is_the_old_world_and_a_half_plants_some():
    a, _, _ = _street(0.0, base=REALISTIC)
    b, _, _ = build_street(np.random.default_rng(3), (-60.0, 60.0), REALISTIC)
    np.testing.assert_array_equal(a.center, b.center)
    counts = []
    for seed in range(6):
        bare, _, _ = _street(0.0, seed)
        half, _, _ = _street(0.5, seed)
        full, _, _ = _street(1.0, seed)
        counts.append((len(half.kind) - len(bare.kind), len(full.kind) - len(bare.kind)))
    assert all(0 <= h <= f for h, f in counts) and 0 < sum(h for h, _ in counts) < sum(
        f for _, f in counts
    )


def test_scanned_shrubs_add_vegetation_under_half_a_metre():
    low = {}
    for shrubs in (0.0, 1.0):
        sw = (
            Sequence(0, 5, 1, profile=dataclasses.replace(VERGES, verge_shrubs=shrubs))
            .frame(0)
            .sweep
        )
        r = np.hypot(sw.xyz[:, 0], sw.xyz[:, 1])
        road_z = np.median(sw.xyz[(sw.label == 40) & (r < 10), 2])
        veg = (sw.label == VEGETATION) & (r < 20)
        low[shrubs] = int((veg & (sw.xyz[:, 2] < road_z + 0.5)).sum())
    assert low[0.0] < 50 and low[1.0] > 200


@pytest.mark.parametrize("bad", [-0.1, 1.5])
def test_bad_values(bad):
    with pytest.raises(InputError, match="verge_shrubs"):
        WorldProfile.from_dict({"verge_shrubs": bad}, base=REALISTIC)


def test_green_frontages_get_shrubs_in_front_on_their_raised_ground():
    # paved sidewalks, every frontage green on ground raised 0.2-0.3 m
    green = dataclasses.replace(
        REALISTIC, verge_prob=0.0, frontage_p=(0.0, 1.0, 0.0, 0.0), terrain_raise=(0.2, 0.3)
    )
    bare, _, plan = _street(0.0, base=green)
    planted, _, _ = _street(1.0, base=green)
    shrub = _inserted(planted, bare)
    assert shrub.sum() >= 20
    for (x, y, z), rz in zip(planted.center[shrub], planted.half[shrub, 2]):
        side = 1 if y > 0 else -1
        curb = [c for c in plan.curb if c[0] == side and c[1] <= x <= c[2] + SHRUB_HALF[1]]
        front = curb[0][3] + plan.sidewalk_width
        assert front + 0.1 - 1e-9 <= abs(y) <= front + 1.4 + 1e-9
        assert 0.2 - 1e-9 <= z - 0.5 * rz <= 0.3 + 1e-9  # on the raised green ground


def test_low_vegetation_statistic_hand_worked():
    """Flat road at -1.75 m; vegetation columns 5-15 m away: a quarter of their points under 0.5 m."""
    from panoptic_bench.datasets.synthetic.realism import MEASURES, scan_measures

    xs, ys = np.meshgrid(np.arange(-15.0, 15.0, 0.25), np.arange(-3.0, 3.0, 0.25))
    road = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, -1.75)])
    vx = np.linspace(5.0, 15.0, 40)
    heights = np.arange(0.05, 2.0, 0.125)  # 16 heights, 4 of them under 0.5 m
    veg = np.array([(x, 6.0, -1.75 + h) for x in vx for h in heights])
    far = np.array([(25.0, 6.0, -1.75 + 0.1)] * 50)  # beyond 20 m: not counted
    xyz = np.vstack([road, veg, far])
    raw = np.r_[np.full(len(road), 40), np.full(len(veg) + len(far), VEGETATION)].astype(np.uint32)
    pts = np.column_stack([xyz, np.full(len(xyz), 0.3)]).astype(np.float32)
    m, _ = scan_measures(pts, raw)
    assert "veg_low_pct" in MEASURES
    assert m["veg_low_pct"] == pytest.approx(25.0, abs=1e-6)
    with warnings.catch_warnings():  # no ground at all: the ego-hole rows warn, as they should
        warnings.simplefilter("ignore", RuntimeWarning)
        m2, _ = scan_measures(pts[len(road) :], raw[len(road) :])  # no road: no plane, nan
    assert np.isnan(m2["veg_low_pct"])
