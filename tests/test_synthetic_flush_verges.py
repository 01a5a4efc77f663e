"""Grass verges flush with the road (world key ``verge_flush``, issue 13 session 30): the
verge becomes ground-level terrain, everything else is drawn as before, bad values (also of
``kerb_flush``), the row-32 profile files, and the step statistics of terrain and sidewalk."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree
from synthetic_street_checks import check_boxes_painted, profile_changes

from panoptic_bench.datasets.synthetic.profile import REALISTIC, WorldProfile
from panoptic_bench.datasets.synthetic.sequence import Sequence
from panoptic_bench.datasets.synthetic.street import build_street
from panoptic_bench.errors import InputError

REPO = Path(__file__).resolve().parents[1]
TERRAIN, ROAD, SIDEWALK = 72, 40, 48
# every segment a raised grass verge (0.1-0.3 m), frontages buildings only (no other terrain)
VERGES = dataclasses.replace(
    REALISTIC, verge_prob=1.0, verge_raise=(0.1, 0.3), frontage_p=(1.0, 0.0, 0.0, 0.0)
)


def _street(flush: float, seed: int = 3, base=VERGES):
    return build_street(
        np.random.default_rng(seed), (-60.0, 60.0), dataclasses.replace(base, verge_flush=flush)
    )


def test_flush_verges_become_ground_terrain_and_nothing_else_moves():
    raised, gm0, plan0 = _street(0.0)
    flush, gm1, plan1 = _street(1.0)
    # every other primitive is still there, in order, same place and size; what stood on a
    # verge top (poles, signs, clutter) now stands lower by that verge's height (0.1-0.3 m);
    # the verges' footprints are terrain on the ground now, at road level
    boxes = check_boxes_painted(raised, flush, gm1, TERRAIN, (0.1, 0.3))
    # with the verge's own reflectivity (the blank ground is terrain too, of another reflectivity)
    xy = raised.center[boxes, :2]
    _, reflect = gm1.lookup(xy[:, 0], xy[:, 1])
    np.testing.assert_allclose(reflect, raised.reflect[boxes], atol=1e-6)
    _, reflect0 = gm0.lookup(xy[:, 0], xy[:, 1])
    assert not np.allclose(reflect0, raised.reflect[boxes], atol=1e-6)
    # what stands on a verge stands at road level; the kerb lines are where they were
    assert [k[:3] for k in plan1.kerb] == [k[:3] for k in plan0.kerb]
    assert all(k[3] == 0.0 for k in plan1.kerb) and all(k[3] >= 0.1 for k in plan0.kerb)
    assert plan1.curb == plan0.curb


def test_probability_zero_is_the_old_world_and_a_half_flushes_some():
    a, _, pa = _street(0.0, base=REALISTIC)
    b, _, pb = build_street(np.random.default_rng(3), (-60.0, 60.0), REALISTIC)
    np.testing.assert_array_equal(a.center, b.center)
    assert pa.kerb == pb.kerb
    kerbs = [k[3] for seed in range(4) for k in _street(0.5, seed)[2].kerb]
    assert 0 < sum(k == 0.0 for k in kerbs) < len(kerbs)


def test_scanned_flush_verge_meets_the_road_without_a_step():
    """In a rendered sweep, terrain within 1 m of road sits at the road's height."""
    prof = dataclasses.replace(REALISTIC, verge_prob=1.0, verge_raise=(0.2, 0.3))
    steps = {}
    for flush in (0.0, 1.0):
        sw = Sequence(0, 5, 1, profile=dataclasses.replace(prof, verge_flush=flush)).frame(0).sweep
        lab = sw.label
        r = np.hypot(sw.xyz[:, 0], sw.xyz[:, 1])
        road, ter = (lab == ROAD) & (r < 25), (lab == TERRAIN) & (r < 25)
        dist, idx = cKDTree(sw.xyz[road, :2]).query(sw.xyz[ter, :2])
        near = dist < 1.0
        assert near.sum() > 50
        steps[flush] = np.median(sw.xyz[ter][near, 2] - sw.xyz[road][idx[near], 2])
    assert steps[0.0] > 0.1 and abs(steps[1.0]) < 0.05


@pytest.mark.parametrize("key", ["verge_flush", "kerb_flush"])
@pytest.mark.parametrize("bad", [-0.1, 1.5])
def test_bad_values(key, bad):
    with pytest.raises(InputError, match=key):
        WorldProfile.from_dict({key: bad}, base=REALISTIC)


@pytest.mark.parametrize(
    "name",
    ["low_crowns_low_fences", "low_fences_tight_materials", "low_fences_raised_lots"],
)
def test_row_32_profiles_are_row_30_worlds_plus_flush_verges(name):
    assert profile_changes(f"synth_flush_{name}", f"synth_rails_{name}") == {"verge_flush": 0.5}


@pytest.mark.parametrize(
    ("raw_id", "other", "step", "flush"),
    [(TERRAIN, "kerb", "terrain_step", "terrain_flush_pct"),
     (SIDEWALK, "terrain", "kerb_step", "kerb_flush_pct")],
)  # fmt: skip
def test_ground_step_statistic_hand_worked(raw_id, other, step, flush):
    """Road at -1.75 m up to y = 2.9 m; terrain (or sidewalk) beyond, flush for x < -4, 0.2 m up
    elsewhere; the other class's pair of rows stays nan."""
    from panoptic_bench.datasets.synthetic.realism import MEASURES, scan_measures

    xs, ys = np.meshgrid(np.arange(-11.95, 12.0, 0.1), np.arange(-2.95, 6.0, 0.15))
    x, y = xs.ravel(), ys.ravel()
    raw = np.where(y < 3.0, ROAD, raw_id).astype(np.uint32)
    z = np.where((raw == raw_id) & (x > -4), -1.55, -1.75)
    z[(raw == raw_id) & (x < -4)] += 0.02  # flush: within 5 cm
    pts = np.column_stack([x, y, z, np.full_like(x, 0.3)]).astype(np.float32)
    m, _ = scan_measures(pts, raw)
    assert step in MEASURES and flush in MEASURES
    # rows within 1 m of the road's last row (2.9): y = 3.05 ... 3.8; a third is flush
    near = (raw == raw_id) & (y < 3.85) & (np.hypot(x, y) >= 3)
    is_flush = near & (x < -4)
    assert m[flush] == pytest.approx(100.0 * is_flush.sum() / near.sum(), abs=0.01)
    assert m[step] == pytest.approx(0.2, abs=1e-5)
    assert np.isnan(m[f"{other}_step"]) and np.isnan(m[f"{other}_flush_pct"])
    # nothing near any road: nan, not a number that looks measured
    far = raw == ROAD
    m2, _ = scan_measures(pts[far], raw[far])
    assert np.isnan(m2[step]) and np.isnan(m2[flush])
