"""Panoptic assembly, consensus fusion, centre files and simulated regression (real scans)."""

from __future__ import annotations

import numpy as np
import pytest

from panoptic_bench.baselines.centers import read_centers, write_centers
from panoptic_bench.baselines.clustering import BFS, DBSCAN, HDBSCAN, MeanShift
from panoptic_bench.baselines.panoptic import (
    SmallInstance,
    assemble_panoptic,
    consensus_fusion,
    filter_small_instances,
    nuscenes_panoptic,
    orphans_to_stuff,
    semantickitti_label,
)
from panoptic_bench.baselines.regression import RegressionNoise, gt_box_centers, simulate_offsets
from panoptic_bench.datasets.semantickitti import (
    LABELS,
    list_scans,
    read_labels,
    read_scan,
    to_train,
)
from panoptic_bench.errors import InputError
from panoptic_bench.metrics.panoptic import panoptic_stats


def test_fusion_majority_vote():
    sem = np.array([1, 1, 2, 2, 2, 3, 4, 9, 9], dtype=np.uint8)
    inst = np.array([1, 1, 1, 2, 2, 2, 0, 0, 3])
    out = consensus_fusion(sem, inst)
    assert out.tolist() == [1, 1, 1, 2, 2, 2, 4, 9, 9]
    assert out.dtype == np.uint8


def test_fusion_tie_goes_to_smallest_class():
    sem = np.array([5, 3, 3, 5, 7])
    inst = np.array([4, 4, 4, 4, 4])
    assert consensus_fusion(sem, inst).tolist() == [3] * 5
    assert consensus_fusion(sem[::-1], inst).tolist() == [3] * 5


def test_filter_small_instances():
    labels = np.array([2, 2, 0, 1, 1, 1, 2])
    assert filter_small_instances(labels, 3).tolist() == [2, 2, 0, 1, 1, 1, 2]
    assert filter_small_instances(labels, 1).tolist() == [3, 3, 1, 2, 2, 2, 3]
    assert filter_small_instances(labels, 4).tolist() == [0] * 7
    with pytest.raises(ValueError):
        filter_small_instances(np.array([0, -1]), 1)


def toy_scene():
    """Two cars (class 1) 10 m apart, one point of the first car predicted as truck (4); road."""
    rng = np.random.default_rng(0)
    car1 = rng.normal([5, 0, 0], 0.5, (6, 3))
    car2 = rng.normal([15, 0, 0], 0.5, (4, 3))
    road = rng.uniform(-20, 20, (5, 3))
    points = np.concatenate([car1, car2, road])
    sem = np.array([1, 1, 4, 1, 1, 1, 1, 1, 1, 1, 9, 9, 9, 9, 9], dtype=np.uint8)
    centers = np.concatenate([np.tile([5, 0, 0], (6, 1)), np.tile([15, 0, 0], (4, 1)), road])
    return points, sem, centers - points


def test_assemble_fusion_on_off_and_min_points():
    points, sem, offset = toy_scene()
    kw = dict(thing_ids=LABELS.thing_ids, num_classes=20)
    s, i = assemble_panoptic(points, sem, offset, BFS(1.0), min_points=1, **kw)
    assert i.tolist() == [1] * 6 + [2] * 4 + [0] * 5
    assert s.tolist() == [1] * 10 + [9] * 5  # the truck point joins its car
    s, i = assemble_panoptic(points, sem, offset, BFS(1.0), min_points=1, fusion=False, **kw)
    assert s.tolist() == sem.tolist() and i.tolist() == [1] * 6 + [2] * 4 + [0] * 5
    s, i = assemble_panoptic(points, sem, offset, BFS(1.0), min_points=5, **kw)
    assert i.tolist() == [1] * 6 + [0] * 9  # the 4-point car is dropped: no instance, class kept
    assert s.tolist() == [1] * 10 + [9] * 5
    s, i = assemble_panoptic(
        points, sem, offset, BFS(1.0), min_points=5, small=SmallInstance.UNLABELED, **kw
    )
    assert s.tolist() == [1] * 6 + [0] * 4 + [9] * 5


def test_assemble_empty_things_and_bad_input():
    points, sem, offset = toy_scene()
    stuff = np.full_like(sem, 9)
    s, i = assemble_panoptic(points, stuff, offset, MeanShift(1.2), thing_ids=(1,), min_points=1)
    assert (i == 0).all() and (s == 9).all()
    with pytest.raises(ValueError, match="disagree"):
        assemble_panoptic(points[:-1], sem, offset, BFS(1), thing_ids=(1,), min_points=1)
    offset[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        assemble_panoptic(points, sem, offset, BFS(1), thing_ids=(1,), min_points=1)


def test_encoders():
    label = semantickitti_label(np.array([1, 9, 0]), np.array([3, 0, 0]))
    assert label.dtype == np.uint32
    assert label.tolist() == [(3 << 16) | 10, 40, 0]
    pan = nuscenes_panoptic(np.array([17 - 1, 2, 0]), np.array([0, 7, 0]))
    assert pan.dtype == np.uint16 and pan.tolist() == [16000, 2007, 0]
    with pytest.raises(ValueError, match="1000"):
        nuscenes_panoptic(np.array([2]), np.array([1000]))


def test_centers_roundtrip_and_errors(tmp_path):
    sem = np.array([1, 9, 1], dtype=np.uint8)
    offset = np.zeros((3, 3), np.float32)
    path = tmp_path / "c.npz"
    write_centers(path, sem, offset, score=np.ones(3), source="simulated regression")
    c = read_centers(path, n_points=3, num_classes=20)
    assert c.sem.tolist() == [1, 9, 1] and c.source == "simulated regression"
    assert c.offset.shape == (3, 3) and c.features is None
    with pytest.raises(InputError, match="scan has 4"):
        read_centers(path, n_points=4)
    with pytest.raises(InputError, match="not found"):
        read_centers(tmp_path / "missing.npz")
    np.savez(tmp_path / "nan.npz", sem=sem, offset=np.array([[0, 0, np.nan]] * 3, np.float32))
    with pytest.raises(InputError, match="NaN"):
        read_centers(tmp_path / "nan.npz")
    np.savez(tmp_path / "nosem.npz", offset=offset)
    with pytest.raises(InputError, match="lacks key"):
        read_centers(tmp_path / "nosem.npz")
    np.savez(tmp_path / "shape.npz", sem=sem, offset=offset[:, :2])
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        read_centers(tmp_path / "shape.npz")
    np.savez(tmp_path / "cls.npz", sem=np.array([1, 25, 1], np.uint8), offset=offset)
    with pytest.raises(InputError, match="0, 20"):
        read_centers(tmp_path / "cls.npz", num_classes=20)
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="cannot read"):
        read_centers(tmp_path / "junk.npz")


def test_gt_box_centers():
    xyz = np.array([[0, 0, 0], [2, 4, 1], [1, 0, 0], [10, 10, 10]], float)
    c, d = gt_box_centers(xyz, np.array([7, 7, 7, 3]))
    np.testing.assert_allclose(c[:3], [[1, 2, 0.5]] * 3)
    np.testing.assert_allclose(c[3], [10, 10, 10])
    np.testing.assert_allclose(d, [np.sqrt(4 + 16 + 1)] * 3 + [0])


def test_simulated_regression_properties():
    rng = np.random.default_rng(1)
    car = rng.normal([30, 0, 0], [2, 1, 0.5], (2000, 3))
    sem = np.ones(2000, dtype=np.uint8)
    inst = np.ones(2000, dtype=np.int64)
    noise = RegressionNoise(
        base_sigma=0.2, size_gain=0, range_gain=0, across_ratio=0.2, outlier_rate=0
    )
    a = simulate_offsets(car, sem, inst, (1,), noise=noise, seed=3)
    assert np.array_equal(a, simulate_offsets(car, sem, inst, (1,), noise=noise, seed=3))
    assert not np.array_equal(a, simulate_offsets(car, sem, inst, (1,), noise=noise, seed=4))
    err = car + a - gt_box_centers(car, inst)[0]
    along = np.abs(err[:, 0]).mean()  # the viewing ray is ~ +x here
    across = np.abs(err[:, 1:]).mean()
    assert along > 3 * across  # elongated along the ray
    zero = simulate_offsets(car, sem, inst, (1,), noise=RegressionNoise.zero())
    np.testing.assert_allclose(car + zero, gt_box_centers(car, inst)[0], atol=1e-5)
    stuff = simulate_offsets(car, sem * 9, inst, (1,))
    assert (stuff == 0).all()
    with pytest.raises(ValueError, match="unknown"):
        RegressionNoise.from_dict({"sigma": 1})
    assert RegressionNoise.from_dict(noise.to_dict()) == noise


CLUSTERERS = {
    "bfs": BFS(0.5),
    "dbscan": DBSCAN(eps=0.5, min_samples=5),
    "hdbscan": HDBSCAN(min_cluster_size=5, cluster_selection_epsilon=0.5),
    "meanshift": MeanShift(1.2),
    "meanshift-bin": MeanShift(0.65, bin_seeding=True),
}


@pytest.fixture(scope="module")
def real_scans(kitti_root):
    out = []
    for ref in list_scans(kitti_root):
        points, labels = read_scan(ref.scan), read_labels(ref.label)
        sem = to_train(labels)
        offset = simulate_offsets(
            points, sem, labels >> 16, LABELS.thing_ids, noise=RegressionNoise.zero()
        )
        out.append((points, labels, sem, offset))
    return out


@pytest.mark.parametrize("name", sorted(CLUSTERERS))
@pytest.mark.parametrize(
    "small,min_points", [(SmallInstance.NO_INSTANCE, 1), (SmallInstance.UNLABELED, 50)]
)
def test_gt_centers_give_perfect_things(real_scans, name, small, min_points):
    total = None
    for points, labels, sem, offset in real_scans:
        s, i = assemble_panoptic(
            points,
            sem,
            offset,
            CLUSTERERS[name],
            thing_ids=LABELS.thing_ids,
            min_points=min_points,
            small=small,
            num_classes=20,
        )
        pred = semantickitti_label(s, i)
        stats = panoptic_stats(
            to_train(pred),
            pred,
            sem,
            labels,
            num_classes=20,
            ignore=LABELS.ignore_ids,
            min_points=50,
        )
        total = stats if total is None else total + stats
    things = list(LABELS.thing_ids)
    present = [c for c in things if total.tp[c] + total.fn[c] > 0]
    assert present == [1, 8]  # car and (moving) motorcyclist in the real scans
    assert total.fp[things].sum() == 0 and total.fn[things].sum() == 0
    np.testing.assert_allclose(total.compute().pq[present], 1.0)


def test_orphans_to_stuff_hand_worked():
    # classes 0 ignored, 1-2 things, 3-4 stuff; points 1 and 3 are orphans (thing, instance 0)
    sem, inst = np.array([1, 1, 3, 2, 4]), np.array([7, 0, 0, 0, 0])
    scores = np.array([[-np.inf, 9.0, 0.0, 1.0, 2.0], [-np.inf, 0.0, 9.0, 3.0, 3.0]])
    out = orphans_to_stuff(sem, inst, scores, thing_ids=[1, 2])
    assert out.tolist() == [1, 4, 3, 3, 4]  # tie 3 / 4 goes to the smaller id
    assert sem.tolist() == [1, 1, 3, 2, 4]  # input untouched
    with pytest.raises(ValueError, match="one row per orphan"):
        orphans_to_stuff(sem, inst, scores[:1], thing_ids=[1, 2])


def test_orphans_to_stuff_property():
    rng = np.random.default_rng(0)
    things = [1, 2, 3]
    sem = rng.integers(1, 8, 500)
    inst = np.where(rng.random(500) < 0.5, rng.integers(1, 6, 500), 0)
    orphan = np.isin(sem, things) & (inst == 0)
    scores = rng.normal(size=(orphan.sum(), 8))
    scores[:, 0] = -np.inf
    out = orphans_to_stuff(sem, inst, scores, thing_ids=things)
    assert np.array_equal(out[~orphan], sem[~orphan])
    assert not np.isin(out, things)[inst == 0].any()  # no thing class without an instance
    stuff = scores.copy()
    stuff[:, things] = -np.inf
    assert np.array_equal(out[orphan], stuff.argmax(1))
    # nothing to do: no orphans, no rows
    kept = orphans_to_stuff(sem, np.ones_like(inst), np.zeros((0, 8)), thing_ids=things)
    assert np.array_equal(kept, sem)


def test_orphans_config_value_is_validated():
    from panoptic_bench.dsnet.config import DSNetConfig
    from panoptic_bench.errors import InputError

    cfg = DSNetConfig.from_dict({"inference": {"orphans": "stuff"}})
    assert cfg.inference.orphans == "stuff"
    assert DSNetConfig.from_dict(cfg.to_dict()) == cfg
    assert DSNetConfig().inference.orphans == "keep"
    with pytest.raises(InputError, match="orphans"):
        DSNetConfig.from_dict({"inference": {"orphans": "unlabeled"}})
