"""Panoptic metric kernel: golden toy example, hand-worked rules and properties."""

from __future__ import annotations

import numpy as np
import pytest

from panoptic_bench.metrics.panoptic import PanopticResult, PanopticStats, panoptic_stats

C = 4  # 0 = ignored, 1-2 = things, 3 = stuff
THINGS, STUFF = (1, 2), (3,)


def seg(n: int, cls: int, inst: int) -> tuple[np.ndarray, np.ndarray]:
    return np.full(n, cls), np.full(n, inst)


def build(*parts: tuple[int, int, int, int, int]) -> tuple[np.ndarray, ...]:
    """Parts of (n points, pred class, pred id, gt class, gt id) -> the four arrays."""
    cols = [np.concatenate([np.full(p[0], p[k]) for p in parts]) for k in range(1, 5)]
    return cols[0], cols[1], cols[2], cols[3]


def stats(*parts, min_points: int = 1, num_classes: int = C) -> PanopticStats:
    sp, ip, sg, ig = build(*parts)
    return panoptic_stats(sp, ip, sg, ig, num_classes=num_classes, min_points=min_points)


def test_he_et_al_toy_example() -> None:
    """Kirillov, He et al. (CVPR 2019) Fig. 2: person class with 3 TP, 1 FN, 1 FP.

    Matched pairs have IoU 1, 0.8 and 9/11; RQ = 3 / (3 + 1/2 + 1/2) = 0.75.
    """
    s = stats(
        (10, 1, 1, 1, 1),  # TP 1: identical
        (8, 1, 2, 1, 2),  # TP 2: prediction covers 8 of 10 gt points -> IoU 0.8
        (2, 3, 0, 1, 2),
        (9, 1, 3, 1, 3),  # TP 3: 9 shared points + 2 extra on stuff -> IoU 9/11
        (2, 1, 3, 3, 0),
        (7, 3, 0, 1, 4),  # FN: a gt person nobody predicted
        (6, 1, 5, 3, 0),  # FP: a predicted person on background
        (40, 3, 0, 3, 0),
    )
    assert (s.tp[1], s.fp[1], s.fn[1]) == (3, 1, 1)
    r = s.compute()
    sq = (1 + 0.8 + 9 / 11) / 3
    assert r.sq[1] == pytest.approx(sq, abs=1e-15)
    assert r.rq[1] == 0.75
    assert r.pq[1] == pytest.approx(sq * 0.75, abs=1e-15)


def test_perfect_prediction_and_absent_classes() -> None:
    s = stats((20, 1, 7, 1, 7), (30, 3, 0, 3, 0), (5, 0, 0, 0, 0))
    r = s.compute()
    assert r.pq[1] == r.sq[1] == r.rq[1] == r.iou[1] == 1.0
    assert r.pq[3] == 1.0
    assert r.pq[2] == 0.0 and r.iou[2] == 0.0  # absent class scores 0 and still enters the mean
    assert r.pq_mean == pytest.approx(2 / 3)
    assert r.include == (1, 2, 3)


def test_iou_exactly_half_is_not_a_match() -> None:
    s = stats((2, 1, 1, 1, 1), (2, 3, 0, 1, 1), (10, 3, 0, 3, 0))
    assert (s.tp[1], s.fp[1], s.fn[1]) == (0, 1, 1)
    s = stats((3, 1, 1, 1, 1), (2, 3, 0, 1, 1), (10, 3, 0, 3, 0))  # IoU 3/5 > 0.5
    assert (s.tp[1], s.fp[1], s.fn[1]) == (1, 0, 0)
    assert s.iou_sum[1] == 0.6


@pytest.mark.parametrize("min_points", [29, 30, 31])
def test_min_points_applies_to_unmatched_only(min_points: int) -> None:
    s = stats(
        (30, 3, 0, 1, 1),  # unmatched gt segment of 30 points
        (30, 1, 2, 3, 0),  # unmatched predicted segment of 30 points
        (5, 2, 3, 2, 3),  # matched 5-point segment: always a TP
        (100, 3, 0, 3, 0),
        min_points=min_points,
    )
    counted = int(30 >= min_points)
    assert s.fn[1] == counted and s.fp[1] == counted
    assert s.tp[2] == 1


def test_ignore_removal_only_by_ground_truth_class() -> None:
    # predicted car over 10 car + 10 unlabeled gt points: the unlabeled points are removed -> IoU 1
    s = stats((10, 1, 1, 1, 1), (10, 1, 1, 0, 0))
    assert s.tp[1] == 1 and s.iou_sum[1] == 1.0 and s.fp[1] == 0
    # predicting the ignored class on car points is not removed: car IoU 5/10 -> no match
    s = stats((5, 1, 1, 1, 1), (5, 0, 0, 1, 1))
    assert (s.tp[1], s.fp[1], s.fn[1]) == (0, 1, 1)
    # a prediction entirely on ignored gt creates nothing
    s = stats((50, 2, 9, 0, 0))
    assert s.tp.sum() == s.fp.sum() == s.fn.sum() == 0


def test_stuff_is_scored_as_segments() -> None:
    # one gt road segment; the prediction splits it 60 / 40 under two ids -> 1 TP (0.6) + 1 FP
    s = stats((60, 3, 1, 3, 0), (40, 3, 2, 3, 0))
    assert (s.tp[3], s.fp[3], s.fn[3]) == (1, 1, 0)
    r = s.compute()
    assert r.sq[3] == pytest.approx(0.6) and r.rq[3] == pytest.approx(1 / 1.5)
    assert r.iou[3] == 1.0  # semantic IoU ignores the ids


def test_same_id_in_two_classes_is_two_segments() -> None:
    s = stats((10, 1, 5, 1, 5), (10, 2, 5, 2, 5))
    assert s.tp[1] == s.tp[2] == 1 and s.fp.sum() == s.fn.sum() == 0


def test_semantic_iou_and_accuracy_by_hand() -> None:
    # rows = prediction, cols = gt
    s = stats((6, 1, 0, 1, 0), (2, 3, 0, 1, 0), (4, 3, 0, 3, 0), (3, 3, 0, 0, 0), (1, 1, 0, 0, 0))
    expected = np.zeros((C, C), np.int64)
    expected[1, 1], expected[3, 1], expected[3, 3], expected[3, 0], expected[1, 0] = 6, 2, 4, 3, 1
    np.testing.assert_array_equal(s.confusion, expected)
    r = s.compute()
    assert r.iou[1] == 6 / 8  # the prediction of car on ignored gt is not a FP
    assert r.iou[3] == 4 / 6
    assert r.miou == pytest.approx((6 / 8 + 0 + 4 / 6) / 3)
    assert r.accuracy == 10 / 12
    # class 2 has no ground truth: the official mean counts it as 0, the present mean skips it
    assert r.present == (1, 3)
    assert r.miou_present == pytest.approx((6 / 8 + 4 / 6) / 2)


def test_present_classes_follow_ground_truth_only() -> None:
    # class 2 predicted on 5 points of class 1 but never in the ground truth: not present
    s = stats((5, 2, 0, 1, 0), (5, 1, 0, 1, 0), (4, 3, 0, 3, 0))
    r = s.compute()
    assert r.present == (1, 3) and r.iou[2] == 0.0
    assert r.miou_present == pytest.approx((5 / 10 + 1.0) / 2)
    # ground truth only on the ignored class: nothing present, the mean is NaN (not 0)
    r = stats((7, 1, 0, 0, 0)).compute()
    assert r.present == () and np.isnan(r.miou_present)


def test_summary_keys_pq_dagger_and_floats() -> None:
    s = stats((10, 1, 1, 1, 1), (30, 3, 0, 3, 0), (10, 1, 0, 3, 0))
    r = s.compute()
    summ = r.summary(THINGS, STUFF)
    keys = "PQ PQ_dagger SQ RQ PQ_th SQ_th RQ_th PQ_st SQ_st RQ_st mIoU accuracy mIoU_present"
    assert list(summ) == keys.split()
    assert summ["mIoU_present"] == pytest.approx((r.iou[1] + r.iou[3]) / 2)  # class 2 absent
    assert all(type(v) is float and 0.0 <= v <= 1.0 for v in summ.values())
    assert summ["PQ_dagger"] == pytest.approx((r.pq[1] + r.pq[2] + r.iou[3]) / 3)
    assert summ["PQ_th"] == pytest.approx((r.pq[1] + r.pq[2]) / 2)
    assert summ["PQ_st"] == r.pq[3]
    assert summ["PQ"] == pytest.approx(r.pq_mean)
    with pytest.raises(ValueError):
        r.summary((1,), (3,))  # class 2 missing
    per = r.per_class(["unlabeled", "car", "person", "road"])
    assert list(per) == ["car", "person", "road"] and set(per["car"]) == {"PQ", "SQ", "RQ", "IoU"}


def test_empty_input_and_bad_input() -> None:
    e = np.zeros(0, np.int64)
    s = panoptic_stats(e, e, e, e, num_classes=C)
    assert s.confusion.sum() == 0 and s.compute().pq_mean == 0.0
    ok = np.ones(3, np.int64)
    with pytest.raises(ValueError, match="same number"):
        panoptic_stats(ok, ok, ok, ok[:2], num_classes=C)
    with pytest.raises(ValueError, match="class ids"):
        panoptic_stats(ok * C, ok, ok, ok, num_classes=C)
    with pytest.raises(ValueError, match="instance ids"):
        panoptic_stats(ok, -ok, ok, ok, num_classes=C)
    with pytest.raises(TypeError):
        panoptic_stats(ok * 1.0, ok, ok, ok, num_classes=C)


def random_scene(rng: np.random.Generator, n: int = 3000) -> tuple[np.ndarray, ...]:
    sg = rng.integers(0, C, n)
    ig = np.where(np.isin(sg, THINGS), rng.integers(0, 6, n), 0) + sg * 1000
    noisy = rng.random(n) < 0.3
    sp = np.where(noisy, rng.integers(0, C, n), sg)
    ip = np.where(rng.random(n) < 0.2, rng.integers(0, 8, n), ig)
    return sp, ip.astype(np.uint32), sg, ig.astype(np.uint32)


def assert_stats_equal(a: PanopticStats, b: PanopticStats) -> None:
    for name in ("tp", "fp", "fn", "confusion"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    np.testing.assert_allclose(a.iou_sum, b.iou_sum, rtol=0, atol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_instance_id_permutation_invariance(seed: int) -> None:
    rng = np.random.default_rng(seed)
    sp, ip, sg, ig = random_scene(rng)
    base = panoptic_stats(sp, ip, sg, ig, num_classes=C, min_points=5)
    for ids in (ip, ig):
        uniq = np.unique(ids)
        new = rng.permutation(np.arange(2**32 - len(uniq), 2**32, dtype=np.uint64))
        ids[:] = new[np.searchsorted(uniq, ids)].astype(np.uint32)
    assert_stats_equal(base, panoptic_stats(sp, ip, sg, ig, num_classes=C, min_points=5))
    order = rng.permutation(len(sp))  # point order is irrelevant too
    perm = panoptic_stats(sp[order], ip[order], sg[order], ig[order], num_classes=C, min_points=5)
    assert_stats_equal(base, perm)


@pytest.mark.parametrize("seed", range(3))
def test_identity_prediction_gives_pq_one(seed: int) -> None:
    _, _, sg, ig = random_scene(np.random.default_rng(seed))
    r = panoptic_stats(sg, ig, sg, ig, num_classes=C, min_points=5).compute()
    assert r.pq_mean == r.sq_mean == r.rq_mean == r.miou == r.accuracy == 1.0
    assert all(type(v) is float for v in r.summary(THINGS, STUFF).values())


def test_accumulator_addition() -> None:
    rng = np.random.default_rng(7)
    parts = [panoptic_stats(*random_scene(rng), num_classes=C, min_points=5) for _ in range(4)]
    total = PanopticStats.zeros(C)
    for p in parts:
        total = total + p
    assert_stats_equal(total, sum(parts))
    assert_stats_equal((parts[0] + parts[1]) + parts[2], parts[0] + (parts[1] + parts[2]))
    assert_stats_equal(total, PanopticStats.from_dict(total.to_dict()))
    assert np.all(total.tp == sum(p.tp for p in parts))
    with pytest.raises(ValueError):
        total + PanopticStats.zeros(C, ignore=(0, 1))
    with pytest.raises(ValueError):
        PanopticStats.from_dict({**total.to_dict(), "extra": 1})
    assert isinstance(total.compute(), PanopticResult)
