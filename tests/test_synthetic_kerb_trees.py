"""Kerb trees with a clearance over the carriageway (``kerb_crown_clearance``, ``kerb_tree_keep``; issue 13, session 43)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from synthetic_street_checks import WORLDS, profile_changes

from panoptic_bench.datasets.synthetic.plants import DISCARD, stream_apart, tree
from panoptic_bench.datasets.synthetic.profile import REALISTIC, WorldProfile
from panoptic_bench.datasets.synthetic.raw_ids import TRUNK, VEGETATION
from panoptic_bench.errors import InputError


class _Record:
    def __init__(self):
        self.rows = []

    def add(self, kind, center, half, label, reflect, yaw=0.0, rough=0.0):
        self.rows.append((kind, tuple(center), tuple(half), label, reflect, rough))


def _tree(seed: int, min_bottom: float, lift: float = 0.7):
    rec, rng = _Record(), np.random.default_rng(seed)
    tree(rec, rng, 1.0, 2.0, 0.1, (1.0, 1.5), (0.1, 0.2), lift, min_bottom)
    return rec.rows, rng.random()


@pytest.mark.parametrize("seed", range(6))
def test_clearance_raises_low_crowns_on_longer_trunks_by_hand(seed):
    (trunk0, crown0), after0 = _tree(seed, 0.0)
    (trunk1, crown1), after1 = _tree(seed, 3.0)
    assert after0 == after1  # the same draws, in the same order
    assert trunk0[3] == TRUNK and crown0[3] == VEGETATION
    (_, c0, h0, *_), (_, c1, h1, *_) = crown0, crown1
    bottom0, bottom1 = c0[2] - h0[2] - 0.1, c1[2] - h1[2] - 0.1  # above the tree's foot z = 0.1
    assert h0 == h1 and c0[:2] == c1[:2] and trunk0[4] == trunk1[4]
    assert bottom1 == pytest.approx(max(bottom0, 3.0))
    # the trunk grows by what the crown rose; its foot stays at z, its top under the crown's centre
    rise = bottom1 - bottom0
    assert 2 * trunk1[2][2] == pytest.approx(2 * trunk0[2][2] + rise)
    assert trunk1[1][2] - trunk1[2][2] == pytest.approx(0.1)
    assert c1[2] - (trunk1[1][2] + trunk1[2][2]) == pytest.approx(0.7 * h1[2])


def test_crowns_already_high_enough_do_not_move():
    rows, _ = _tree(3, 0.0, lift=1.5)  # the crown rests well above its 1.0-1.5 m trunk
    low = min(r[1][2] - r[2][2] for r in rows if r[3] == VEGETATION) - 0.1
    assert _tree(3, low - 0.01, lift=1.5)[0] == rows


def test_discard_builder_keeps_nothing_and_stream_apart_leaves_the_parent():
    DISCARD.add(0, (0, 0, 0), (1, 1, 1), TRUNK, 0.3)
    a, b = np.random.default_rng(4), np.random.default_rng(4)
    side = stream_apart(a, 0x7EE)
    assert a.spawn(1)[0].random() == b.spawn(1)[0].random()  # spawns unchanged
    assert a.random() == b.random()
    assert side.random() != np.random.default_rng(4).random()


def _street(seed: int, **kw):
    from panoptic_bench.datasets.synthetic.street import build_street

    prof = dataclasses.replace(REALISTIC, verge_prob=0.35, **kw)
    return build_street(np.random.default_rng(seed), (-150.0, 150.0), prof)


def _rows(p):
    return np.column_stack([p.kind, p.center, p.half, p.yaw, p.label, p.reflect])


def _kerb_tree_rows(prims, plan) -> np.ndarray:
    from panoptic_bench.datasets.synthetic.street import curb_at

    trunk = np.flatnonzero(prims.label == TRUNK)
    off = [abs(abs(prims.center[i, 1]) - curb_at(plan, np.sign(prims.center[i, 1]), prims.center[i, 0]))
           for i in trunk]  # fmt: skip
    return trunk[np.isclose(off, 0.55)]


def test_clearance_moves_only_kerb_trees_and_lifts_their_crowns():
    from panoptic_bench.datasets.synthetic.street import kerb_at

    (a, ga, plan), (b, gb, _) = _street(11), _street(11, kerb_crown_clearance=2.5)
    ra, rb = _rows(a), _rows(b)
    assert ra.shape == rb.shape
    np.testing.assert_array_equal(ga.label, gb.label)
    trunks = _kerb_tree_rows(a, plan)
    assert len(trunks) >= 4
    moved = np.flatnonzero(np.any(ra != rb, axis=1))
    assert set(moved) <= set(trunks) | set(trunks + 1)  # a kerb tree is its trunk, then its crown
    for t in trunks:
        kz = kerb_at(plan, int(np.sign(b.center[t, 1])), b.center[t, 0])
        assert b.center[t + 1, 2] - b.half[t + 1, 2] - kz >= 2.5 - 1e-6
    assert any(a.center[t + 1, 2] - a.half[t + 1, 2] < 2.5 for t in trunks)  # some were low


def test_keep_builds_a_share_of_the_kerb_trees_and_nothing_else_moves():
    (a, _, plan), (b, _, _) = _street(12), _street(12, kerb_tree_keep=0.0)
    trunks = _kerb_tree_rows(a, plan)
    gone = np.zeros(len(a.label), bool)
    gone[trunks], gone[trunks + 1] = True, True
    np.testing.assert_array_equal(_rows(b), _rows(a)[~gone])
    kept = [_kerb_tree_rows(*_street(seed, kerb_tree_keep=0.5)[::2]).size for seed in (12, 13, 14)]
    full = [_kerb_tree_rows(*_street(seed)[::2]).size for seed in (12, 13, 14)]
    share = sum(kept) / sum(full)
    assert sum(full) >= 20 and 0.25 <= share <= 0.75


def test_kerb_tree_values_out_of_range():
    for bad in ({"kerb_crown_clearance": -0.5}, {"kerb_crown_clearance": 9.0},
                {"kerb_tree_keep": -0.1}, {"kerb_tree_keep": 1.5}):  # fmt: skip
        key = next(iter(bad))
        with pytest.raises(InputError, match=key):
            WorldProfile(**bad)


@pytest.mark.parametrize("world", WORLDS)
def test_row_60_files_are_row_56_worlds_plus_kerb_tree_keys(world):
    changed = profile_changes(f"synth_clear_{world}", f"synth_boards_{world}")
    assert changed == {"kerb_crown_clearance": 2.5, "kerb_tree_keep": 0.15}


def test_overhang_rows_by_hand():
    """Flat road at -1.75 m; 3-6 m away 30 upright points: 12 vegetation (5 overhang), 12 building, 6 car."""
    from panoptic_bench.datasets.synthetic.raw_ids import BUILDING, CAR, MOVING_CAR, ROAD
    from panoptic_bench.datasets.synthetic.realism import MEASURES, scan_measures
    from panoptic_bench.datasets.synthetic.realism_layout import NEAR_CLASSES

    xs, ys = np.meshgrid(np.arange(-15.0, 15.0, 0.25), np.arange(-3.0, 3.0, 0.25))
    road = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, -1.75)])
    over = [(4.0 + 0.2 * k, 1.0, -1.75 + 1.5) for k in range(5)]  # 4-4.8 m, |y| 1, 1.5 m up
    side = [(3.0 + 0.2 * k, 3.6, -1.75 + 1.5) for k in range(7)]  # |y| 3.6: not over the road
    wall = [(5.0, -1.0 + 0.1 * k, -1.75 + 1.0) for k in range(18)]  # building, 5 m ahead
    far = [(7.0, 0.5, -1.75 + 2.0)] * 4  # vegetation 7 m away: overhang only
    low = [(4.5, 5.0, -1.75 + 0.2)] * 6  # under 0.45 m: neither row
    xyz = np.vstack([road, over, side, wall, far, low])
    raw = np.r_[
        np.full(len(road), ROAD), np.full(12, VEGETATION), np.full(12, BUILDING), np.full(3, CAR),
        np.full(3, MOVING_CAR), np.full(4, VEGETATION), np.full(6, VEGETATION),
    ].astype(np.uint32)  # fmt: skip
    m, _ = scan_measures(np.column_stack([xyz, np.full(len(xyz), 0.3)]).astype(np.float32), raw)
    keys = {f"near_{key}_pct" for key, _ in NEAR_CLASSES}
    assert keys | {"veg_overhang"} <= set(MEASURES) and len(keys) == 5
    assert m["veg_overhang"] == 9.0
    assert m["near_veg_pct"] == pytest.approx(100.0 * 12 / 30)
    assert m["near_building_pct"] == pytest.approx(100.0 * 12 / 30)
    assert m["near_car_pct"] == pytest.approx(100.0 * 6 / 30)  # parked and moving cars
    assert m["near_fence_pct"] == 0.0 and m["near_trunk_pct"] == 0.0


@pytest.mark.parametrize("world", WORLDS)
def test_row_61_files_are_row_56_worlds_without_kerb_trees(world):
    changed = profile_changes(f"synth_nokerb_{world}", f"synth_boards_{world}")
    assert changed == {"kerb_tree_keep": 0.0}
