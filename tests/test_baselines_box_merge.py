"""Box-merge baseline (SemanticKITTI boxes): both merge rules by hand, file format, simulated detector."""

from __future__ import annotations

import numpy as np
import pytest

from panoptic_bench.baselines.box_merge import (
    Boxes,
    DetectorNoise,
    MergeMode,
    merge_boxes,
    points_in_boxes,
    read_boxes,
    simulate_detections,
    write_boxes,
)
from panoptic_bench.baselines.panoptic import semantickitti_label
from panoptic_bench.datasets.semantickitti import (
    LABELS,
    list_scans,
    read_labels,
    read_scan,
    to_train,
)
from panoptic_bench.errors import InputError
from panoptic_bench.metrics.panoptic import panoptic_stats

# points on the x axis at 0..5; box A covers x in [0, 2], box B covers x in [1, 5]
XYZ = np.stack([np.arange(6.0), np.zeros(6), np.zeros(6)], 1)
SEM = np.array([1, 1, 4, 1, 9, 1], dtype=np.uint8)  # car car truck car road car
BOXES = Boxes(
    params=np.array([[1, 0, 0, 2, 1, 1, 0], [3, 0, 0, 4, 1, 1, 0]], float),
    cls=np.array([1, 1]),
    score=np.array([0.9, 0.5]),
)


def test_points_in_boxes_inclusive_and_rotated():
    inside = points_in_boxes(XYZ, BOXES.params)
    assert inside.astype(int).tolist() == [[1, 1, 1, 0, 0, 0], [0, 1, 1, 1, 1, 1]]
    rotated = np.array([[0, 0, 0, 4, 1, 1, np.pi / 2]])  # long along y now
    pts = np.array([[0, 1.9, 0], [1.9, 0, 0]])
    assert points_in_boxes(pts, rotated).tolist() == [[True, False]]


def test_merge_devkit_rule():
    sem, inst = merge_boxes(XYZ, SEM, BOXES, MergeMode.DEVKIT, thing_ids=LABELS.thing_ids)
    # A takes cars 0, 1 (truck 2 not its class); B: cars 1, 3, 5 -> 1 of 3 taken (< 50 %): keeps 3, 5
    assert inst.tolist() == [1, 1, 0, 2, 0, 2]
    assert sem.tolist() == [1, 1, 0, 1, 9, 1]  # the truck point is in no same-class box -> 0
    dropped = Boxes(BOXES.params.copy(), BOXES.cls, BOXES.score)
    dropped.params[1] = [
        1.5,
        0,
        0,
        1,
        1,
        1,
        0,
    ]  # B now holds cars 1 only (taken): > 50 % -> dropped
    sem, inst = merge_boxes(XYZ, SEM, dropped, MergeMode.DEVKIT, thing_ids=LABELS.thing_ids)
    assert inst.tolist() == [1, 1, 0, 0, 0, 0]
    assert sem.tolist() == [1, 1, 0, 0, 9, 0]


def test_merge_paper_rule():
    sem, inst = merge_boxes(XYZ, SEM, BOXES, MergeMode.PAPER, thing_ids=LABELS.thing_ids)
    assert inst.tolist() == [1, 1, 1, 2, 2, 2]
    assert sem.tolist() == [1, 1, 1, 1, 1, 1]  # every point in a box takes the box class


def test_boxes_file_roundtrip_and_errors(tmp_path):
    path = tmp_path / "b.txt"
    write_boxes(path, BOXES, comment="simulated detector")
    back = read_boxes(path)
    np.testing.assert_allclose(back.params, BOXES.params)
    assert back.cls.tolist() == [1, 1] and back.score.tolist() == [0.9, 0.5]
    path.write_text("1 2 3 4 2 1.5 0.1 car 0.7\n")
    assert read_boxes(path).cls.tolist() == [1]
    (tmp_path / "e.txt").write_text("")
    assert len(read_boxes(tmp_path / "e.txt")) == 0
    for bad, match in (("1 2 3 4 2 1.5 0.1 car", "got 8 fields"), ("1 2 3 0 2 1.5 0 car 1", "positive"),
                       ("1 2 3 4 2 1.5 0 plane 1", "unknown class"), ("1 2 x 4 2 1 0 car 1", "non-numeric")):  # fmt: skip
        path.write_text(bad + "\n")
        with pytest.raises(InputError, match=match):
            read_boxes(path)
    with pytest.raises(InputError, match="not found"):
        read_boxes(tmp_path / "missing.txt")


def test_simulated_detector_on_real_scans(kitti_root):
    total = {MergeMode.PAPER: None, MergeMode.DEVKIT: None}
    for k, ref in enumerate(list_scans(kitti_root)):
        points, labels = read_scan(ref.scan), read_labels(ref.label)
        sem = to_train(labels)
        exact = DetectorNoise(0, 0, 0, 0, 0)
        boxes = simulate_detections(
            points, sem, labels >> 16, LABELS.thing_ids, noise=exact, seed=k
        )
        assert len(boxes) == 14  # 13 cars + 1 motorcyclist, no misses, no false positives
        noisy = simulate_detections(points, sem, labels >> 16, LABELS.thing_ids, seed=k)
        again = simulate_detections(points, sem, labels >> 16, LABELS.thing_ids, seed=k)
        np.testing.assert_array_equal(noisy.params, again.params)
        for mode in total:
            s, i = merge_boxes(points[:, :3], sem, boxes, mode, thing_ids=LABELS.thing_ids)
            pred = semantickitti_label(s, i)
            st = panoptic_stats(to_train(pred), pred, sem, labels, num_classes=20, min_points=50)
            total[mode] = st if total[mode] is None else total[mode] + st
    for mode, st in total.items():
        things = list(LABELS.thing_ids)
        assert st.tp[things].sum() > 30, mode  # tight GT boxes find the instances
        assert st.fn[things].sum() <= 3, mode


def test_box_merge_cli(kitti_root, tmp_path):
    from panoptic_bench.cli import main

    boxes = tmp_path / "boxes"
    assert main(["box-merge", "simulate-boxes", "--dataset", str(kitti_root), "--output", str(boxes),
                 "--miss-rate", "0", "--fp-rate", "0"]) == 0  # fmt: skip
    first = next((boxes / "sequences/00/boxes").iterdir()).read_text()
    assert first.startswith("# simulated detector")
    pred = tmp_path / "pred"
    argv = ["box-merge", "semantickitti", "--dataset", str(kitti_root), "--semantic", str(kitti_root),
            "--boxes", str(boxes), "--mode", "devkit", "--output", str(pred)]  # fmt: skip
    # the ground truth tree has labels/, not predictions/: a clear error, exit 2
    assert main(argv) == 2
