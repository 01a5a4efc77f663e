"""The viewer's per-segment matching gives the evaluator's TP / FP / FN, segment by segment."""

from __future__ import annotations

import numpy as np
import pytest
from nuscenes.eval.panoptic.panoptic_seg_evaluator import PanopticEval

from panoptic_bench.datasets import semantickitti as sk
from panoptic_bench.metrics.panoptic import panoptic_stats
from panoptic_bench.viewer.matching import match_segments
from panoptic_bench.viewer.scene import ViewScan, kitti_classes, scan_pq


def _random_scan(rng: np.random.Generator, C: int, n: int, n_inst: int):
    sizes = rng.integers(1, 300, n_inst)
    sizes = np.maximum(1, (sizes * n / sizes.sum()).astype(int))
    sg = np.repeat(rng.integers(0, C, len(sizes)), sizes)
    ig = np.repeat(np.arange(len(sizes)) * 5 + 1, sizes)
    m = len(sg)
    sp = np.where(rng.random(m) < 0.2, rng.integers(0, C, m), sg)
    ip = np.where(rng.random(m) < 0.15, rng.integers(0, 30, m), (ig * 11 + 3) % 500)
    order = rng.permutation(m)
    return sp[order], ip[order], sg[order], ig[order]


def _check_against_evaluators(sp, ip, sg, ig, *, C, ignore, min_points):
    m = match_segments(sp, ip, sg, ig, num_classes=C, ignore=ignore, min_points=min_points)
    ours = panoptic_stats(sp, ip, sg, ig, num_classes=C, ignore=ignore, min_points=min_points)
    ref = PanopticEval(C, ignore=list(ignore), min_points=min_points)
    ref.addBatch(sp, ip.astype(np.int64), sg, ig.astype(np.int64))
    for counts in (ours.tp, ref.pan_tp):
        np.testing.assert_array_equal(m.pred.counts(0, C), counts)
        np.testing.assert_array_equal(m.gt.counts(0, C), counts)
    for fp in (ours.fp, ref.pan_fp):
        np.testing.assert_array_equal(m.pred.counts(1, C), fp)
    for fn in (ours.fn, ref.pan_fn):
        np.testing.assert_array_equal(m.gt.counts(1, C), fn)
    matched = m.pred.match >= 0
    iou_sum = np.bincount(m.pred.cls[matched], weights=m.pred.iou[matched], minlength=C)
    np.testing.assert_allclose(iou_sum, ref.pan_iou, rtol=0, atol=1e-9)
    # matches are mutual, of one class, and every matched IoU is > 0.5
    assert (m.gt.match[m.pred.match[matched]] == np.flatnonzero(matched)).all()
    assert (m.gt.cls[m.pred.match[matched]] == m.pred.cls[matched]).all()
    assert (m.pred.iou[matched] > 0.5).all() and (m.pred.iou[~matched] <= 0.5).all()
    # points on ignored ground truth are in no segment; every other gt point is in one
    ign = np.isin(sg, ignore)
    assert (m.gt_segment[ign] == -1).all() and (m.pred_segment[ign] == -1).all()
    assert (m.gt_segment[~ign] >= 0).all()
    assert (m.pred_segment[np.isin(sp, ignore)] == -1).all()
    # segment sizes are the point counts of their members
    np.testing.assert_array_equal(np.bincount(m.gt_segment[~ign], minlength=len(m.gt)), m.gt.size)
    return m


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("min_points", [1, 15, 50])
def test_random_scans_match_the_evaluators(seed, min_points):
    rng = np.random.default_rng(seed)
    C = 6
    sp, ip, sg, ig = _random_scan(rng, C, 3000, 40)
    _check_against_evaluators(sp, ip, sg, ig, C=C, ignore=(0,), min_points=min_points)


def test_hand_cases_iou_exactly_half_and_small_segments():
    # gt segment A: 4 points of class 1; prediction covers 2 of them + 2 others -> IoU 2/6
    # gt segment B: 2 points of class 1 predicted exactly -> IoU 1 (TP)
    # gt C: 4 points class 2; pred covers 2 of them plus 0 others -> IoU 2/4 = 0.5: NOT matched
    sg = np.array([1, 1, 1, 1, 1, 1, 2, 2, 2, 2, 0, 0])
    ig = np.array([1, 1, 1, 1, 2, 2, 3, 3, 3, 3, 0, 0])
    sp = np.array([1, 1, 0, 0, 1, 1, 2, 2, 0, 0, 1, 1])
    ip = np.array([7, 7, 0, 0, 8, 8, 9, 9, 0, 0, 7, 7])
    m = match_segments(sp, ip, sg, ig, num_classes=3, ignore=(0,), min_points=3)
    table = {(int(c), int(i)): k for k, (c, i) in enumerate(zip(m.gt.cls, m.gt.inst))}
    assert m.gt.status[table[(1, 2)]] == 0 and m.gt.iou[table[(1, 2)]] == 1.0
    assert m.gt.status[table[(2, 3)]] == 1 and m.gt.iou[table[(2, 3)]] == 0.5  # FN at IoU 0.5
    assert m.gt.status[table[(1, 1)]] == 1
    # the prediction (1, 7) has 2 points once ignored gt points are removed: small, not FP
    ptable = {(int(c), int(i)): k for k, (c, i) in enumerate(zip(m.pred.cls, m.pred.inst))}
    assert m.pred.size[ptable[(1, 7)]] == 2 and m.pred.status[ptable[(1, 7)]] == 2
    assert m.pred_segment[-1] == -1 and m.gt_segment[-1] == -1
    _check_against_evaluators(sp, ip, sg, ig, C=3, ignore=(0,), min_points=3)


def test_real_scan_with_a_damaged_prediction(kitti_root):
    gt = sk.read_labels(kitti_root / "sequences" / "00" / "labels" / "000000.label")
    rng = np.random.default_rng(3)
    inst = gt >> 16
    ids = np.unique(inst[inst > 0])
    pred = gt.copy()
    pred[np.isin(inst, ids[::3])] = 10  # merge a third of the instances into one car segment
    flip = rng.random(len(gt)) < 0.05
    pred[flip] = 40  # road
    sp, sg = sk.to_train(pred), sk.to_train(gt)
    C = sk.LABELS.num_classes
    m = _check_against_evaluators(
        sp, pred.astype(np.int64), sg, gt.astype(np.int64), C=C, ignore=(0,), min_points=50
    )
    assert m.pred.counts(1, C).sum() + m.gt.counts(1, C).sum() > 0  # the damage shows
    # the per-scan PQ is the mean over the classes present, below the undamaged 1.0
    classes = kitti_classes()
    xyz = np.zeros((len(gt), 3), np.float32)
    damaged = ViewScan("00/000000", xyz, sp, pred, sg, gt)
    perfect = ViewScan("00/000000", xyz, sg, gt, sg, gt)
    assert scan_pq(perfect, classes) == 1.0
    assert 0.0 < scan_pq(damaged, classes) < 1.0


def test_bad_arrays_are_rejected():
    with pytest.raises(ValueError, match="length"):
        match_segments(
            np.zeros(3, int), np.zeros(2, int), np.zeros(3, int), np.zeros(3, int), num_classes=2
        )
    with pytest.raises(ValueError, match="class ids"):
        match_segments(
            np.full(3, 5), np.zeros(3, int), np.zeros(3, int), np.zeros(3, int), num_classes=2
        )
