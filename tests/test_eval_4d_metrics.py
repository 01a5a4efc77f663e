"""LSTQ kernel (:mod:`panoptic_bench.metrics.lstq`): hand-worked cases, every reference rule
against 4D-PLS ``Panoptic4DEval`` (imported from ../shared/reference/4d-pls), and one test per
documented difference of the corrected mode."""

from __future__ import annotations

import contextlib
import io
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from panoptic_bench.metrics.lstq import LSTQMode, LSTQStats, lstq_frame_stats

REF_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "reference" / "4d-pls"
C = 20
CAR, PERSON, ROAD, SIDEWALK = 1, 6, 9, 11


def reference_eval(min_points: int):
    """A fresh 4D-PLS evaluator (its prints silenced)."""
    assert REF_DIR.is_dir(), f"4D-PLS reference missing: {REF_DIR}"
    if str(REF_DIR) not in sys.path:
        sys.path.insert(0, str(REF_DIR))
    from eval_np import Panoptic4DEval

    with contextlib.redirect_stdout(io.StringIO()):
        return Panoptic4DEval(C, None, [0], offset=2**32, min_points=min_points)


def frame(*segments: tuple[int, int, int, int, int]):
    """Arrays (sem_pred, inst_pred, sem_gt, inst_gt) from (n, sem_p, id_p, sem_g, id_g) blocks."""
    cols = [
        np.concatenate([np.full(s[0], s[k], dtype=np.int64) for s in segments])
        for k in (1, 2, 3, 4)
    ]
    return cols


def ours(frames, *, min_points: int = 0, mode: LSTQMode = LSTQMode.REFERENCE, seq: str = "00"):
    st = LSTQStats.zeros(C, mode=mode)
    for sp, ip, sg, ig in frames:
        kw = {"num_classes": C, "min_points": min_points, "mode": mode}
        st = st.add_frame(seq, *lstq_frame_stats(sp, ip, sg, ig, **kw))
    return st.compute()


def theirs(frames, *, min_points: int = 0, seq: str = "00"):
    ev = reference_eval(min_points)
    for sp, ip, sg, ig in frames:
        with contextlib.redirect_stdout(io.StringIO()):
            ev.addBatch(seq, sp, ip, sg, ig)
    with contextlib.redirect_stdout(io.StringIO()):
        return ev.getPQ4D()


def assert_same(res, ref) -> None:
    lstq, s_assoc, aq, aq_p, aq_r, iou, s_cls = ref[:7]
    for a, b in ((res.LSTQ, lstq), (res.S_assoc, s_assoc), (res.S_cls, s_cls)):
        assert a == pytest.approx(b, abs=1e-12, nan_ok=True)
    np.testing.assert_allclose(res.aq, aq, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.iou, iou, rtol=0, atol=1e-12)
    assert res.AQ_precision == pytest.approx(aq_p, abs=1e-12)
    assert res.AQ_recall == pytest.approx(aq_r, abs=1e-12)


# ------------------------------------------------------------------ hand-worked (reference mode)


def test_perfect_prediction_one_tube() -> None:
    f = [frame((10, CAR, 3, CAR, 3), (20, ROAD, 0, ROAD, 0)) for _ in range(3)]
    res = ours(f)
    assert (res.LSTQ, res.S_assoc, res.S_cls) == (1.0, 1.0, 1.0)
    assert_same(res, theirs(f))


def test_id_switch_halves_association() -> None:
    # one car tube of 2 x 10 points, predicted id 5 in frame 1 and id 6 in frame 2:
    # each part: |p ∩ t| = 10, IoU = 10 / (20 + 10 - 10) = 1/2 -> S_assoc = (10/2 + 10/2) / 20
    f = [frame((10, CAR, 5, CAR, 1)), frame((10, CAR, 6, CAR, 1))]
    res = ours(f)
    assert res.S_assoc == pytest.approx(0.5, abs=1e-15)
    assert res.S_cls == 1.0
    assert res.LSTQ == pytest.approx(math.sqrt(0.5), abs=1e-15)
    assert_same(res, theirs(f))


def test_consistent_renumbering_changes_nothing() -> None:
    rng = np.random.default_rng(0)
    frames = []
    for _ in range(4):
        sg = rng.choice([0, CAR, PERSON, ROAD, SIDEWALK], 300)
        ig = np.where(np.isin(sg, [CAR, PERSON]), rng.integers(1, 6, 300), 0)
        sp = np.where(rng.random(300) < 0.2, rng.integers(0, C, 300), sg)
        ip = np.where(rng.random(300) < 0.2, rng.integers(0, 9, 300), ig)
        frames.append((sp, ip, sg, ig))
    perm = rng.permutation(np.arange(1, 1000))[:10]  # id k -> perm[k], the same in every frame
    perm[0] = 0
    renamed = [(sp, perm[ip], sg, ig) for sp, ip, sg, ig in frames]
    a, b = ours(frames, min_points=3), ours(renamed, min_points=3)
    assert (a.LSTQ, a.S_assoc, a.S_cls) == (b.LSTQ, b.S_assoc, b.S_cls)
    assert_same(a, theirs(frames, min_points=3))


def test_merge_of_two_tubes() -> None:
    # two cars of 10 points predicted as one id: IoU = 10 / (10 + 20 - 10) = 1/2 for each
    f = [frame((10, CAR, 7, CAR, 1), (10, CAR, 7, CAR, 2))]
    res = ours(f)
    assert res.S_assoc == pytest.approx(0.5, abs=1e-15)
    assert res.aq[CAR] == pytest.approx(0.5, abs=1e-15)
    assert_same(res, theirs(f))


def test_split_of_one_tube() -> None:
    # one car of 20 points predicted as two ids of 10: each IoU 1/2, (10/2 + 10/2) / 20 = 1/2
    f = [frame((10, CAR, 1, CAR, 4), (10, CAR, 2, CAR, 4))]
    res = ours(f)
    assert res.S_assoc == pytest.approx(0.5, abs=1e-15)
    assert_same(res, theirs(f))


def test_min_points_boundary_reference_uses_strictly_greater() -> None:
    # car 1 has exactly min_points = 5 points (no tube), car 2 has 6 (a tube); perfect prediction
    f = [frame((5, CAR, 1, CAR, 1), (6, CAR, 2, CAR, 2))]
    res = ours(f, min_points=5)
    assert res.n_tubes[CAR] == 1
    assert res.S_assoc == 1.0
    assert_same(res, theirs(f, min_points=5))
    corrected = ours(f, min_points=5, mode=LSTQMode.CORRECTED)  # C3: >= min_points
    assert corrected.n_tubes[CAR] == 2


def test_class_zero_prediction_adds_phantom_class() -> None:
    # 10 road points, 5 of them predicted as class 0: IoU(road) = 1/2, IoU(class 0) = 0 counted
    f = [frame((5, ROAD, 0, ROAD, 0), (5, 0, 0, ROAD, 0), (10, CAR, 1, CAR, 1))]
    res = ours(f)
    assert res.phantom_class_0
    assert res.S_cls == pytest.approx((0.5 + 1.0 + 0.0) / 3, abs=1e-15)
    assert_same(res, theirs(f))
    corrected = ours(f, mode=LSTQMode.CORRECTED)  # C6: no phantom class
    assert corrected.S_cls == pytest.approx((0.5 + 1.0) / 2, abs=1e-15)


def test_reference_self_test_example() -> None:
    # the example at the bottom of 4D-PLS eval_np.py, worked by hand: S_assoc 2/3, mIoU 1/2
    sem_gt = np.r_[np.zeros(5), np.ones(5), np.full(10, 2)].astype(np.int64)
    inst_gt = np.r_[np.zeros(5), np.ones(10), np.full(5, 2)].astype(np.int64)
    sem_pred = np.r_[np.zeros(5), np.ones(5), np.full(5, 2), np.ones(5)].astype(np.int64)
    inst_pred = np.r_[np.zeros(5), np.ones(5), np.full(10, 2)].astype(np.int64)
    st = LSTQStats.zeros(3, things=(1, 2))
    st = st.add_frame("1", *lstq_frame_stats(sem_pred, inst_pred, sem_gt, inst_gt, num_classes=3,
                                             things=(1, 2), min_points=1))  # fmt: skip
    res = st.compute()
    assert res.S_assoc == pytest.approx(2 / 3, abs=1e-15)
    assert res.S_cls == pytest.approx(0.5, abs=1e-15)
    assert res.LSTQ == pytest.approx(math.sqrt(1 / 3), abs=1e-15)
    np.testing.assert_allclose(res.aq, [0, 1, 0.5], atol=1e-15)


def test_sequences_are_separate_tubes_and_addition_is_order_free() -> None:
    a = frame((10, CAR, 1, CAR, 1))
    b = frame((10, CAR, 2, CAR, 1))
    st0 = LSTQStats.zeros(C, mode=LSTQMode.REFERENCE)
    s1 = st0.add_frame("00", *lstq_frame_stats(*a, num_classes=C, min_points=0))
    s2 = st0.add_frame("01", *lstq_frame_stats(*b, num_classes=C, min_points=0))
    res = (s1 + s2).compute()
    assert res.S_assoc == 1.0  # same gt id in two sequences: two tubes, each perfect
    assert res.n_tubes[CAR] == 2
    assert (s2 + s1).compute().S_assoc == res.S_assoc
    ref = reference_eval(0)
    with contextlib.redirect_stdout(io.StringIO()):
        ref.addBatch("00", *a)
        ref.addBatch("01", *b)
        assert_same(res, ref.getPQ4D())


def test_kernel_rejects_bad_arrays() -> None:
    sp, ip, sg, ig = frame((4, CAR, 1, CAR, 1))
    with pytest.raises(ValueError, match="2\\*\\*16"):
        lstq_frame_stats(sp, ip + 70000, sg, ig, num_classes=C)
    with pytest.raises(ValueError, match="class ids"):
        lstq_frame_stats(sp + C, ip, sg, ig, num_classes=C)
    with pytest.raises(TypeError):
        lstq_frame_stats(sp.astype(float), ip, sg, ig, num_classes=C)
    with pytest.raises(ValueError, match="same length"):
        lstq_frame_stats(sp[:2], ip, sg, ig, num_classes=C)


# ------------------------------------------------------------------ corrected mode: one per rule


def test_c1_ids_shared_by_two_classes_are_two_tubes() -> None:
    # the ground truth uses id 1 for a car and a person (as SemanticKITTI sequence 06 does)
    f = [frame((10, CAR, 1, CAR, 1), (30, PERSON, 1, PERSON, 1))]
    ref = ours(f)
    # reference: one predicted tube of 40 points; car: 10 * (10/40) / 10, person: 30 * (30/40) / 30
    assert ref.S_assoc == pytest.approx((0.25 + 0.75) / 2, abs=1e-15)
    assert_same(ref, theirs(f))
    assert ours(f, mode=LSTQMode.CORRECTED).S_assoc == 1.0


def test_c2_stuff_instances_are_no_tubes() -> None:
    # ground-truth road points carrying an instance id: the reference adds the road tube to the
    # numerator of S_assoc but not to its denominator (S_assoc = 2 for a perfect prediction)
    f = [frame((10, CAR, 1, CAR, 1), (10, ROAD, 2, ROAD, 2))]
    ref = ours(f)
    assert ref.S_assoc == pytest.approx(2.0, abs=1e-15)
    assert_same(ref, theirs(f))
    res = ours(f, mode=LSTQMode.CORRECTED)
    assert (res.S_assoc, res.n_tubes[ROAD]) == (1.0, 0)


def test_c4_small_segments_are_void_for_predictions_too() -> None:
    # a car of 60 points in frame 1 and 10 points in frame 2 (min_points 50), predicted perfectly:
    # reference tube 60 points, predicted tube 70: 60 * (60/70) / 60 = 6/7
    f = [frame((60, CAR, 1, CAR, 1)), frame((10, CAR, 1, CAR, 1))]
    ref = ours(f, min_points=50)
    assert ref.S_assoc == pytest.approx(6 / 7, abs=1e-15)
    assert_same(ref, theirs(f, min_points=50))
    assert ours(f, min_points=50, mode=LSTQMode.CORRECTED).S_assoc == 1.0


def test_c5_iou_never_exceeds_one() -> None:
    # id 1 on 10 car points, 5 of them predicted as class 0: the reference tube has 5 points but
    # the intersection 10: IoU = 10 / (10 + 5 - 10) = 2 and S_assoc = 2
    f = [frame((5, CAR, 1, CAR, 1), (5, 0, 1, CAR, 1))]
    ref = ours(f)
    assert ref.S_assoc == pytest.approx(2.0, abs=1e-15)
    assert_same(ref, theirs(f))
    # corrected: tube (car, 1) of 5 points, intersection 5: 5 * (5/10) / 10
    assert ours(f, mode=LSTQMode.CORRECTED).S_assoc == pytest.approx(0.25, abs=1e-15)


def test_no_thing_tubes_give_nan_like_the_reference() -> None:
    f = [frame((10, ROAD, 0, ROAD, 0))]
    res = ours(f)
    assert math.isnan(res.S_assoc) and math.isnan(res.LSTQ)
    assert res.S_cls == 1.0
