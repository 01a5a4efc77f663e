"""Planting beds (world key ``planting_beds``, issue 13 session 34): the back of a paved sidewalk
segment becomes a strip of terrain at the sidewalk's height under dense low shrubs, everything
else is drawn as before; flush kerbs get painted beds; the row-39 and row-40 profile files; bad
values."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from synthetic_street_checks import profile_changes

from panoptic_bench.datasets.synthetic.plants import BED_WIDTH, SHRUB_HALF, SHRUB_HEIGHT
from panoptic_bench.datasets.synthetic.profile import REALISTIC, WorldProfile
from panoptic_bench.datasets.synthetic.sequence import Sequence
from panoptic_bench.datasets.synthetic.shapes import BOX, ELLIPSOID
from panoptic_bench.datasets.synthetic.street import build_street
from panoptic_bench.errors import InputError

REPO = Path(__file__).resolve().parents[1]
SIDEWALK, TERRAIN, VEGETATION = 48, 72, 70
# every segment a paved sidewalk (no verges), kerbs 8-14 cm, frontages buildings only, so the
# bare street holds no terrain box and its only vegetation is the street trees' crowns
PAVED = dataclasses.replace(
    REALISTIC, verge_prob=0.0, kerb=(0.08, 0.14), frontage_p=(1.0, 0.0, 0.0, 0.0)
)


def _street(beds: float, seed: int = 3, base=PAVED):
    prof = dataclasses.replace(base, planting_beds=beds)
    return build_street(np.random.default_rng(seed), (-60.0, 60.0), prof)


def _segment(rows, side: int, x: float):
    """The one entry of ``rows`` (side, x0, x1, value) whose span holds ``x`` on ``side``."""
    hit = [r for r in rows if r[0] == side and r[1] - 1e-9 <= x <= r[2] + 1e-9]
    assert hit
    return hit[0]


def _inserted(bedded, bare) -> np.ndarray:
    """Rows of ``bedded`` that are not the next row of ``bare`` (walked in order), sidewalks aside."""
    extra, j = np.zeros(len(bedded.kind), bool), 0
    rows = np.flatnonzero(bare.label != SIDEWALK)
    for i in np.flatnonzero(bedded.label != SIDEWALK):
        same = j < len(rows) and np.array_equal(bedded.center[i], bare.center[rows[j]])
        same = same and np.array_equal(bedded.half[i], bare.half[rows[j]])
        extra[i], j = not same, j + same
    assert j == len(rows)  # every row of the bare street but its sidewalks is there, in order
    return extra


def _area(prims, label: int) -> float:
    box = (prims.kind == BOX) & (prims.label == label)
    return float(4 * (prims.half[box, 0] * prims.half[box, 1]).sum())


def test_beds_line_the_back_of_the_sidewalk_and_nothing_else_moves():
    bare, _, plan = _street(0.0)
    bedded, _, plan1 = _street(1.0)
    assert plan1.kerb == plan.kerb and plan1.curb == plan.curb
    assert not (bare.label == TERRAIN).any()
    # every primitive but the sidewalk boxes is the bare street's, in order, same place and size;
    # what is new is the beds and their shrubs
    new = _inserted(bedded, bare)
    assert set(np.unique(bedded.label[new])) == {TERRAIN, VEGETATION}
    # the beds: terrain boxes from the road up to the kerb, their outer edge the sidewalk's
    bed = bedded.label == TERRAIN
    assert bed.sum() >= 10 and np.all(bedded.kind[bed] == BOX)
    for (x, y, z), (_hx, hy, hz) in zip(bedded.center[bed], bedded.half[bed]):
        side = 1 if y > 0 else -1
        curb, kerb = _segment(plan.curb, side, x)[3], _segment(plan.kerb, side, x)[3]
        assert z - hz == pytest.approx(0.0) and z + hz == pytest.approx(kerb)
        assert abs(y) + hy == pytest.approx(curb + plan.sidewalk_width)
        assert BED_WIDTH[0] - 1e-9 <= 2 * hy <= BED_WIDTH[1] + 1e-9
    # what the beds take, the sidewalk loses: the paved area shrinks by exactly the beds' area
    assert _area(bedded, SIDEWALK) + _area(bedded, TERRAIN) == pytest.approx(_area(bare, SIDEWALK))
    # dense low shrubs standing on the beds' tops
    shrub = new & (bedded.label == VEGETATION)
    assert shrub.sum() >= 40 and np.all(bedded.kind[shrub] == ELLIPSOID)
    half = bedded.half[shrub]
    assert np.all((half[:, :2] >= SHRUB_HALF[0]) & (half[:, :2] <= SHRUB_HALF[1]))
    assert np.all((half[:, 2] >= SHRUB_HEIGHT[0]) & (half[:, 2] <= SHRUB_HEIGHT[1]))
    # each within its own segment's bed (a shrub's start, centre minus half length, is in it)
    at = [(np.sign(y), x - hx) for (x, y, _), hx in zip(bedded.center[shrub], half[:, 0])]
    curb = np.array([_segment(plan.curb, side, x)[3] for side, x in at])
    ay = np.abs(bedded.center[shrub, 1]) - curb - plan.sidewalk_width
    assert np.all((ay >= -BED_WIDTH[1] + 0.15 - 1e-9) & (ay <= -0.15 + 1e-9))
    kerbs = np.array([_segment(plan.kerb, side, x)[3] for side, x in at])
    np.testing.assert_allclose(bedded.center[shrub, 2], kerbs + 0.5 * half[:, 2])


def test_flush_kerbs_get_beds_painted_on_the_ground():
    flush = dataclasses.replace(PAVED, kerb_flush=1.0)
    bare, gm0, _ = _street(0.0, base=flush)
    bedded, gm1, _ = _street(1.0, base=flush)
    assert not (bedded.label == TERRAIN).any()  # no box: the beds are paint at road level
    shrub = _inserted(bedded, bare)
    assert np.all(bedded.label[shrub] == VEGETATION)
    assert shrub.sum() >= 40
    np.testing.assert_allclose(bedded.center[shrub, 2], 0.5 * bedded.half[shrub, 2])
    x, y = bedded.center[shrub, 0], bedded.center[shrub, 1]
    before, _ = gm0.lookup(x, y)
    after, _ = gm1.lookup(x, y)
    assert np.all(before == SIDEWALK) and np.mean(after == TERRAIN) > 0.9


def test_probability_zero_is_the_old_world_and_a_half_plants_fewer():
    a, _, _ = _street(0.0, base=REALISTIC)
    b, _, _ = build_street(np.random.default_rng(3), (-60.0, 60.0), REALISTIC)
    np.testing.assert_array_equal(a.center, b.center)
    counts = []
    for seed in range(6):
        half, _, _ = _street(0.5, seed)
        full, _, _ = _street(1.0, seed)
        counts.append([int((p.label == TERRAIN).sum()) for p in (half, full)])
    assert all(h <= f for h, f in counts) and 0 < sum(h for h, _ in counts) < sum(
        f for _, f in counts
    )


def test_scanned_beds_add_vegetation_under_half_a_metre():
    low = {}
    for beds in (0.0, 1.0):
        sw = (
            Sequence(0, 5, 1, profile=dataclasses.replace(PAVED, planting_beds=beds)).frame(0).sweep
        )
        r = np.hypot(sw.xyz[:, 0], sw.xyz[:, 1])
        road_z = np.median(sw.xyz[(sw.label == 40) & (r < 10), 2])
        veg = (sw.label == VEGETATION) & (r > 3) & (r < 20)
        low[beds] = int((veg & (sw.xyz[:, 2] < road_z + 0.5)).sum())
    assert low[0.0] < 50 and low[1.0] > 300


@pytest.mark.parametrize("bad", [-0.1, 1.5])
def test_bad_values(bad):
    with pytest.raises(InputError, match="planting_beds"):
        WorldProfile.from_dict({"planting_beds": bad}, base=REALISTIC)


@pytest.mark.parametrize(
    "name", ["low_crowns_low_fences", "low_fences_tight_materials", "low_fences_raised_lots"]
)
def test_row_39_profiles_are_row_38_worlds_plus_beds_and_shrubs(name):
    changed = profile_changes(f"synth_bed_{name}", f"synth_kerb_{name}")
    assert changed == {"planting_beds": 0.6, "verge_shrubs": 1.0}


@pytest.mark.parametrize(
    "name", ["low_crowns_low_fences", "low_fences_tight_materials", "low_fences_raised_lots"]
)
def test_row_40_profiles_are_row_39_worlds_with_the_real_ground_shares(name):
    changed = profile_changes(f"synth_ground_{name}", f"synth_bed_{name}")
    assert changed == {"verge_prob": 0.2, "sidewalk": (3.0, 6.0), "parked_fill": 0.5}
