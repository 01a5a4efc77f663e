"""Instance bank (class-balanced pasting of rare thing instances): hand-worked cases, properties."""

from __future__ import annotations

import math

import numpy as np
import pytest

from panoptic_bench.dsnet.config import AugmentConfig, DSNetConfig
from panoptic_bench.dsnet.data.bank import (
    BankInstance,
    InstanceBank,
    footprint_mask,
    open_bank,
    placement_ok,
    rotate_z,
)
from panoptic_bench.dsnet.data.datasets import ClassMap, LidarSample, SemanticKittiDataset
from panoptic_bench.dsnet.data.training_set import TrainingSet
from panoptic_bench.errors import InputError

GROUND_Z = -1.7


def _ground(key=("00", "000000"), spacing=0.25, extent=25.0) -> LidarSample:
    """A flat road disc of grid points (sem 9), no instances."""
    g = np.arange(-extent, extent + 1e-9, spacing)
    x, y = np.meshgrid(g, g)
    keep = np.hypot(x, y) <= extent
    xyz = np.stack([x[keep], y[keep], np.full(keep.sum(), GROUND_Z)], 1).astype(np.float32)
    n = len(xyz)
    return LidarSample(
        xyz,
        np.full(n, 0.3, np.float32),
        np.full(n, 9, np.int64),
        np.zeros(n, np.int64),
        key,
    )


def _box(center, size=(0.6, 0.6, 1.7), n=200, seed=0) -> np.ndarray:
    """Points filling a box standing on the ground at ``center`` (x, y)."""
    rng = np.random.default_rng(seed)
    lo = np.array([center[0] - size[0] / 2, center[1] - size[1] / 2, GROUND_Z])
    return (lo + rng.random((n, 3)) * np.array(size)).astype(np.float32)


def _person(center=(10.0, 0.0), seed=0) -> BankInstance:
    xyz = _box(center, seed=seed)
    return BankInstance(xyz, np.full(len(xyz), 0.2, np.float32), 6)


def test_rotate_z_keeps_range_and_height():
    xyz = np.random.default_rng(1).normal(size=(50, 3)).astype(np.float32) * 10
    out = rotate_z(xyz, 1.1)
    assert np.allclose(np.hypot(*out[:, :2].T), np.hypot(*xyz[:, :2].T), atol=1e-4)
    assert np.array_equal(out[:, 2], xyz[:, 2])
    phi = np.mod(np.arctan2(out[:, 1], out[:, 0]) - np.arctan2(xyz[:, 1], xyz[:, 0]), 2 * math.pi)
    assert np.allclose(phi, 1.1, atol=1e-4)


def test_footprint_mask_hand_worked():
    obj = np.array([[0, 0, 0], [1, 2, 1]], np.float32)  # xy box [0, 1] x [0, 2]
    scan = np.array([[0.5, 1, -5], [1.05, 2.05, 9], [1.2, 1, 0], [-0.2, 0, 0]], np.float32)
    assert footprint_mask(scan, obj, margin=0.1).tolist() == [True, True, False, False]
    assert footprint_mask(scan, obj, margin=0.3).tolist() == [True, True, True, True]


def test_placement_needs_ground_and_free_space():
    ground = _ground().xyz
    obj = _box((10.0, 0.0))
    ok, above = placement_ok(ground, obj)
    assert ok and not above.any()
    # a wall in the footprint: refused, and the wall points are the ones reported above
    wall = _box((10.0, 0.0), size=(0.1, 0.4, 2.0), n=20, seed=3) + np.float32([0, 0, 0.5])
    ok, above = placement_ok(np.concatenate([ground, wall]), obj)
    assert not ok and above[len(ground) :].all() and not above[: len(ground)].any()
    # two stray points above are tolerated (max_clutter), and reported for removal
    ok, above = placement_ok(np.concatenate([ground, wall[:2]]), obj)
    assert ok and above.sum() == 2
    # no ground under it (floating 1 m above the road): refused
    assert not placement_ok(ground, obj + np.float32([0, 0, 1.0]))[0]
    # beyond the scanned disc: no support
    assert not placement_ok(ground, _box((40.0, 0.0)))[0]


def test_draw_is_class_balanced():
    rare = [_person(seed=0)]
    common = [BankInstance(_box((10, 0), seed=i), np.zeros(200, np.float32), 1) for i in range(99)]
    bank = InstanceBank(rare + common)
    assert bank.counts() == {1: 99, 6: 1}
    rng = np.random.default_rng(0)
    draws = [bank.draw(rng).sem for _ in range(2000)]
    assert 0.45 < np.mean(np.array(draws) == 6) < 0.55


def test_paste_on_flat_ground_places_every_instance():
    scan = _ground()
    before = (scan.xyz.copy(), scan.sem.copy(), scan.inst.copy())
    bank = InstanceBank([_person((10.0, 0.0), seed=s) for s in range(3)])
    out = bank.paste(scan, np.random.default_rng(5), 3)
    # the input is not modified
    assert np.array_equal(scan.xyz, before[0]) and np.array_equal(scan.inst, before[2])
    new = out.inst > 0
    assert new.sum() == 3 * 200 and len(out.xyz) == len(scan.xyz) + 600
    assert sorted(np.unique(out.inst[new]).tolist()) == [1, 2, 3]
    assert (out.sem[new] == 6).all() and (out.sem[~new] == 9).all()
    # rotated about the sensor: every pasted point keeps a range of a bank point
    r = np.hypot(*out.xyz[new, :2].T)
    assert r.min() >= 9.5 and r.max() <= 10.5
    assert GROUND_Z - 1e-5 <= out.xyz[new, 2].min() and out.xyz[new, 2].max() <= GROUND_Z + 1.7
    assert out.key == scan.key
    # three copies never overlap: each is refused where an earlier one stands
    for a in (1, 2):
        for b in range(a + 1, 4):
            pa, pb = out.xyz[out.inst == a], out.xyz[out.inst == b]
            assert not footprint_mask(pa, pb, margin=0.0).any()


def test_paste_is_deterministic_and_skips_what_does_not_fit():
    scan = _ground()
    bank = InstanceBank([_person(seed=1)])
    a = bank.paste(scan, np.random.default_rng(7), 2)
    b = bank.paste(scan, np.random.default_rng(7), 2)
    assert np.array_equal(a.xyz, b.xyz) and np.array_equal(a.inst, b.inst)
    # an instance standing 30 m away never finds ground in a 25 m disc: nothing is pasted
    far = InstanceBank([_person((30.0, 0.0))])
    out = far.paste(scan, np.random.default_rng(0), 4)
    assert len(out.xyz) == len(scan.xyz) and not (out.inst > 0).any()
    # existing ids are kept; new ones start past the largest
    scan.inst[:10] = 7
    out = bank.paste(scan, np.random.default_rng(7), 1)
    assert set(np.unique(out.inst).tolist()) == {0, 7, 8}


class _Scans:
    """Two scans of ground with instances of classes 1 (car) and 6 (person)."""

    class_map = ClassMap("semantickitti", tuple(f"c{i}" for i in range(20)), (1, 6), (9,), (0,))

    def __init__(self, n_person: int = 30):
        self.n_person = n_person

    def __len__(self):
        return 2

    def keys(self):
        return [("00", "0"), ("01", "0")]

    def load(self, index):
        s = _ground(self.keys()[index])
        car = _box((5.0, 5.0), size=(4, 2, 1.5), n=300)
        person = _box((-8.0, 3.0), n=self.n_person)
        xyz = np.concatenate([s.xyz, car, person])
        sem = np.concatenate([s.sem, np.full(300, 1), np.full(len(person), 6)])
        inst = np.concatenate([s.inst, np.full(300, 1), np.full(len(person), 2)])
        return LidarSample(xyz, np.zeros(len(xyz), np.float32), sem, inst, self.keys()[index])


def test_bank_from_dataset_keeps_chosen_classes_and_min_points():
    bank = InstanceBank.from_dataset(_Scans(), [6], min_points=20)
    assert bank.counts() == {6: 2} and all(len(i.xyz) == 30 for i in bank.instances)
    assert InstanceBank.from_dataset(_Scans(), [1, 6], min_points=100).counts() == {1: 2}
    with pytest.raises(InputError, match="no instance.*lower augment.paste_min_points"):
        InstanceBank.from_dataset(_Scans(n_person=5), [6], min_points=20)


def _paste_cfg(**kw) -> AugmentConfig:
    base = dict(
        rotate=False,
        flip=False,
        scale_range=(1.0, 1.0),
        translate_std=(0, 0, 0),
        paste_prob=1.0,
        paste_count=(2, 2),
        paste_classes=("c6",),
    )
    base.update(kw)
    return AugmentConfig(**base)


def test_training_set_pastes_from_its_own_scans_reproducibly():
    aug = _paste_cfg()
    ds = _Scans()
    ts = TrainingSet(ds, aug, seed=0, bank=open_bank(aug, ds))
    s = ts[0]
    assert (s.sem == 6).sum() == 30 * 3  # its own person + two pasted copies
    assert np.array_equal(s.xyz, ts[0].xyz)
    ts.set_epoch(1)
    assert not np.array_equal(s.xyz, ts[0].xyz)
    # paste_prob 0 gives exactly the samples of a config without pasting
    plain = AugmentConfig(max_points=500)
    off = AugmentConfig(max_points=500, paste_count=(3, 3), paste_classes=("c6",))
    a, b = TrainingSet(ds, plain, seed=2)[1], TrainingSet(ds, off, seed=2)[1]
    assert np.array_equal(a.xyz, b.xyz) and np.array_equal(a.sem, b.sem)
    with pytest.raises(ValueError, match="InstanceBank"):
        TrainingSet(ds, aug, seed=0)


def test_open_bank_errors_name_the_problem(tmp_path):
    ds = _Scans()
    assert open_bank(AugmentConfig(), ds) is None
    with pytest.raises(InputError, match="unknown class 'pedestrian'"):
        open_bank(_paste_cfg(paste_classes=("pedestrian",)), ds)
    with pytest.raises(InputError, match="'c9' is not a thing class; thing classes: c1, c6"):
        open_bank(_paste_cfg(paste_classes=("c9",)), ds)
    with pytest.raises(InputError, match="not a directory"):
        open_bank(_paste_cfg(paste_bank=str(tmp_path / "missing")), ds)
    (tmp_path / "sequences").mkdir()
    with pytest.raises(InputError, match="paste_bank: .*no sequence directories"):
        open_bank(_paste_cfg(paste_bank=str(tmp_path)), ds)


def test_open_bank_reads_a_synthetic_root(tmp_path):
    from panoptic_bench.datasets.synthetic.writers import generate_semantickitti

    generate_semantickitti(tmp_path, {"30": 1}, seed=0, progress=False)
    train = SemanticKittiDataset(tmp_path)
    names = train.class_map.class_names
    aug = _paste_cfg(paste_classes=("car", "person"), paste_bank=str(tmp_path))
    bank = open_bank(aug, train)
    assert set(bank.counts()) <= {names.index("car"), names.index("person")}
    assert len(bank) >= 1 and all(len(i.xyz) >= 20 for i in bank.instances)


@pytest.mark.parametrize(
    "bad",
    [
        {"paste_prob": 1.5},
        {"paste_count": [3, 1]},
        {"paste_count": [0, 99]},
        {"paste_prob": 0.5},  # no classes named
        {"paste_min_points": 0},
    ],
)
def test_config_rejects_bad_pasting(bad):
    with pytest.raises(InputError):
        DSNetConfig.from_dict({"augment": bad})
