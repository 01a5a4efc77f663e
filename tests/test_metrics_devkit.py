"""Cross-check against the reference evaluator (nuscenes-devkit ``PanopticEval`` = semantic-kitti-api
``eval_np``): every count exact and every metric to 1e-12, on random data and on the real scans."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from nuscenes.eval.panoptic.panoptic_seg_evaluator import PanopticEval

from panoptic_bench.datasets import semantickitti as sk
from panoptic_bench.metrics.panoptic import PanopticStats, panoptic_stats

TOL = 1e-12


def compare(scans: list[tuple[np.ndarray, ...]], *, C: int, ignore, min_points: int) -> None:
    ref = PanopticEval(C, ignore=list(ignore), min_points=min_points)
    ours = PanopticStats.zeros(C, ignore)
    for sp, ip, sg, ig in scans:
        ref.addBatch(sp, ip.astype(np.int64), sg, ig.astype(np.int64))
        ours = ours + panoptic_stats(
            sp, ip, sg, ig, num_classes=C, ignore=ignore, min_points=min_points
        )
    np.testing.assert_array_equal(ours.tp, ref.pan_tp)
    np.testing.assert_array_equal(ours.fp, ref.pan_fp)
    np.testing.assert_array_equal(ours.fn, ref.pan_fn)
    np.testing.assert_array_equal(ours.confusion, ref.px_iou_conf_matrix)
    np.testing.assert_allclose(ours.iou_sum, ref.pan_iou, rtol=0, atol=TOL)
    r = ours.compute()
    PQ, SQ, RQ, pq, sq, rq = ref.getPQ()
    miou, iou = ref.getSemIoU()
    for a, b in ((r.pq, pq), (r.sq, sq), (r.rq, rq), (r.iou, iou)):
        np.testing.assert_allclose(a, b, rtol=0, atol=TOL)
    for a, b in (
        (r.pq_mean, PQ),
        (r.sq_mean, SQ),
        (r.rq_mean, RQ),
        (r.miou, miou),
        (r.accuracy, ref.getSemAcc()),
    ):
        assert abs(a - b) <= TOL


def random_scan(rng: np.random.Generator, C: int, n: int, n_inst: int) -> tuple[np.ndarray, ...]:
    """Blobs of points with class-consistent gt ids and a noisy, re-labelled prediction."""
    sizes = rng.integers(1, 400, n_inst)
    sizes = np.maximum(1, (sizes * n / sizes.sum()).astype(int))
    seg_cls = rng.integers(0, C, len(sizes))
    sg = np.repeat(seg_cls, sizes)
    ig = np.repeat(np.arange(len(sizes)) * 7 + 3, sizes).astype(np.uint32)
    m = len(sg)
    sp = np.where(rng.random(m) < 0.15, rng.integers(0, C, m), sg)
    # predicted ids: relabel, then merge / split some segments and add noise
    ip = (ig * 13 + 5) % 1000
    ip = np.where(rng.random(m) < 0.1, rng.integers(0, 50, m), ip)
    order = rng.permutation(m)
    return sp[order], ip[order].astype(np.uint32), sg[order], ig[order]


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("min_points", [1, 30])
def test_random_matches_devkit(seed: int, min_points: int) -> None:
    rng = np.random.default_rng(seed)
    C = int(rng.integers(3, 21))
    ignore = (0,) if seed % 3 else (0, C - 1)
    scans = [random_scan(rng, C, int(rng.integers(500, 5000)), int(rng.integers(2, 60)))]
    scans += [random_scan(rng, C, 2000, 30) for _ in range(2)]
    compare(scans, C=C, ignore=ignore, min_points=min_points)


def perturb(gt: np.ndarray, rng: np.random.Generator, mode: str) -> np.ndarray:
    """A SemanticKITTI prediction (uint32 full labels) made from the ground truth."""
    pred = gt.copy()
    n = len(gt)
    sem, inst = sk.split_label(gt)
    if mode == "noise":  # 20% random raw labels and instance ids
        idx = rng.choice(n, n // 5, replace=False)
        raw = rng.choice(list(sk.LABELS.learning_map), len(idx)).astype(np.uint16)
        pred[idx] = sk.make_label(raw, rng.integers(0, 20, len(idx)))
    elif mode == "instances":  # merge pairs of instances, split others by point order
        new_inst = np.where(inst % 2 == 1, inst - 1, inst)
        new_inst = np.where((inst % 3 == 0) & (np.arange(n) % 2 == 0), inst + 500, new_inst)
        pred = sk.make_label(sem, new_inst)
    elif mode == "classes":  # car <-> moving-car, road -> sidewalk on a slab of points
        raw = sem.copy()
        raw[sem == 10] = 252
        raw[(sem == 40) & (np.arange(n) < n // 3)] = 48
        pred = sk.make_label(raw, inst)
    return pred


@pytest.mark.parametrize("mode", ["noise", "instances", "classes"])
def test_real_scans_match_devkit(kitti_root: Path, mode: str) -> None:
    rng = np.random.default_rng(1)
    scans = []
    for ref in sk.list_scans(kitti_root):
        gt = sk.read_labels(ref.label)
        pred = perturb(gt, rng, mode)
        scans.append((sk.to_train(pred), pred, sk.to_train(gt), gt))
    compare(scans, C=20, ignore=(0,), min_points=50)


def test_real_scans_against_themselves(kitti_root: Path) -> None:
    total = PanopticStats.zeros(20)
    for ref in sk.list_scans(kitti_root):
        gt = sk.read_labels(ref.label)
        sem = sk.to_train(gt)
        total = total + panoptic_stats(sem, gt, sem, gt, num_classes=20, min_points=50)
    r = total.compute()
    present = np.flatnonzero(total.confusion.sum(axis=0))
    present = present[present != 0]
    assert len(present) >= 10
    for c in present:
        assert r.pq[c] == r.sq[c] == r.rq[c] == r.iou[c] == 1.0, sk.LABELS.class_names[c]
    assert total.fp.sum() == total.fn.sum() == 0


@pytest.mark.parametrize("dense_limit", [0, 1 << 21])
def test_cell_counting_paths_agree(kitti_root: Path, monkeypatch, dense_limit: int) -> None:
    """Dense bincount, scatter (class a function of the id) and hash paths give the same stats."""
    import panoptic_bench.metrics.cells as mod

    monkeypatch.setattr(mod, "_DENSE_CELL_LIMIT", dense_limit)
    rng = np.random.default_rng(3)
    compare([random_scan(rng, 20, 4000, 40)], C=20, ignore=(0,), min_points=30)
    gt = sk.read_labels(sk.list_scans(kitti_root)[0].label)
    pred = perturb(gt, rng, "noise")
    compare([(sk.to_train(pred), pred, sk.to_train(gt), gt)], C=20, ignore=(0,), min_points=50)
