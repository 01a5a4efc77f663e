"""Scene mixing (PolarMix-style) of training scans: hand-worked cases and properties."""

from __future__ import annotations

import math

import numpy as np
import pytest

from panoptic_bench.dsnet.config import AugmentConfig, DSNetConfig
from panoptic_bench.dsnet.data.datasets import LidarSample
from panoptic_bench.dsnet.data.mix import (
    azimuth_in_sector,
    mix_pair,
    paste_instances,
    swap_sector,
)
from panoptic_bench.dsnet.data.training_set import TrainingSet
from panoptic_bench.errors import InputError


def _ring(n: int, radius: float, sem: int, inst_every: int = 0, key=("00", "000000"), z=0.0):
    phi = np.linspace(-math.pi, math.pi, n, endpoint=False) + 1e-3
    xyz = np.stack([radius * np.cos(phi), radius * np.sin(phi), np.full(n, z)], 1)
    inst = np.zeros(n, dtype=np.int64)
    if inst_every:
        inst = (np.arange(n) // inst_every + 1).astype(np.int64)
    return LidarSample(
        xyz.astype(np.float32),
        np.full(n, 0.1 * sem, dtype=np.float32),
        np.full(n, sem, dtype=np.int64),
        inst,
        key,
    )


def test_azimuth_sector_hand_worked():
    xyz = np.array([[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]], dtype=np.float32)
    # sector [45, 135) degrees holds only +y; [315, 45) wraps through 0 and holds +x
    assert azimuth_in_sector(xyz, math.radians(45), math.radians(90)).tolist() == [0, 1, 0, 0]
    assert azimuth_in_sector(xyz, math.radians(-45), math.radians(90)).tolist() == [1, 0, 0, 0]
    assert azimuth_in_sector(xyz, 0.0, 0.0).sum() == 0
    assert azimuth_in_sector(xyz, 1.234, 2 * math.pi).all()


def test_swap_sector_replaces_exactly_the_sector():
    a = _ring(360, 10.0, sem=9)  # road ring, stuff
    b = _ring(720, 20.0, sem=1, inst_every=60)  # car ring, 12 instances
    out = swap_sector(a, b, 0.0, math.pi / 2)
    in_a = azimuth_in_sector(a.xyz, 0.0, math.pi / 2).sum()
    in_b = azimuth_in_sector(b.xyz, 0.0, math.pi / 2).sum()
    assert len(out.xyz) == 360 - in_a + in_b
    inside = azimuth_in_sector(out.xyz, 0.0, math.pi / 2)
    # inside the sector only b's points (radius 20, class 1); outside only a's
    assert np.allclose(np.hypot(*out.xyz[inside, :2].T), 20.0, atol=1e-4)
    assert (out.sem[inside] == 1).all() and (out.sem[~inside] == 9).all()
    assert (out.inst[~inside] == 0).all() and (out.inst[inside] > 0).all()
    assert out.key == a.key


def test_swap_keeps_ids_unique_across_scans():
    a = _ring(100, 10.0, sem=1, inst_every=10)  # ids 1..10
    b = _ring(100, 20.0, sem=1, inst_every=10)
    out = swap_sector(a, b, 0.0, math.pi)
    from_a = np.hypot(*out.xyz[:, :2].T) < 15
    assert not set(out.inst[from_a]) & set(out.inst[~from_a])


def test_paste_rotates_about_the_sensor_and_renumbers():
    a = _ring(50, 10.0, sem=9)
    b = _ring(40, 15.0, sem=1, inst_every=20, z=-1.0)  # two instances
    b.inst[:5] = 0  # a few stuff points of b are never pasted
    out = paste_instances(a, b, np.array([0.5, 2.0]))
    pasted = slice(50, None)
    assert len(out.xyz) == 50 + 2 * 35
    assert np.allclose(np.hypot(*out.xyz[pasted, :2].T), 15.0, atol=1e-4)  # range kept
    assert np.allclose(out.xyz[pasted, 2], -1.0)  # height kept
    first = out.xyz[50:85]
    phi_b = np.arctan2(b.xyz[5:, 1], b.xyz[5:, 0])
    phi_1 = np.arctan2(first[:, 1], first[:, 0])
    assert np.allclose(np.mod(phi_1 - phi_b, 2 * math.pi), 0.5, atol=1e-5)
    ids = out.inst[pasted]
    assert len(np.unique(ids)) == 4 and ids.min() > 0
    assert paste_instances(a, b, np.array([])).xyz.shape == a.xyz.shape


def test_mix_pair_is_deterministic_per_generator():
    a = _ring(300, 10.0, sem=9)
    b = _ring(300, 20.0, sem=1, inst_every=30)
    x = mix_pair(a, b, np.random.default_rng(3), (90.0, 180.0), 2)
    y = mix_pair(a, b, np.random.default_rng(3), (90.0, 180.0), 2)
    z = mix_pair(a, b, np.random.default_rng(4), (90.0, 180.0), 2)
    assert np.array_equal(x.xyz, y.xyz) and np.array_equal(x.inst, y.inst)
    assert not np.array_equal(x.xyz, z.xyz)


class _Toy:
    """A dataset of four rings in two sequences."""

    def __init__(self):
        self._keys = [("00", "0"), ("00", "1"), ("05", "0"), ("05", "1")]

    def __len__(self):
        return 4

    def keys(self):
        return list(self._keys)

    def load(self, index):
        seq = self._keys[index][0]
        return _ring(
            400, 10.0 if seq == "00" else 20.0, 9 if seq == "00" else 1, 0, self._keys[index]
        )


def test_training_set_mixes_with_another_sequence_only():
    aug = AugmentConfig(
        rotate=False,
        flip=False,
        scale_range=(1.0, 1.0),
        translate_std=(0, 0, 0),
        mix_prob=1.0,
        mix_sector_deg=(90.0, 90.0),
    )
    ts = TrainingSet(_Toy(), aug, seed=0)
    assert ts.partners(0) == [2, 3] and ts.partners(3) == [0, 1]
    s = ts[0]
    radius = np.hypot(*s.xyz[:, :2].T)
    share = np.mean(np.isclose(radius, 20.0, atol=1e-3))
    assert 0.2 < share < 0.3  # a 90-degree sector of the other sequence's scan
    again = ts[0]
    assert np.array_equal(s.xyz, again.xyz)


def test_training_set_without_mixing_is_unchanged_by_the_mix_stream():
    base = AugmentConfig(max_points=100)
    with_zero = AugmentConfig(max_points=100, mix_prob=0.0, mix_paste_copies=3)
    a, b = TrainingSet(_Toy(), base, seed=1)[2], TrainingSet(_Toy(), with_zero, seed=1)[2]
    assert np.array_equal(a.xyz, b.xyz) and np.array_equal(a.sem, b.sem)


@pytest.mark.parametrize(
    "bad",
    [{"mix_prob": 1.5}, {"mix_sector_deg": [200.0, 100.0]}, {"mix_paste_copies": 99}],
)
def test_config_rejects_bad_mixing(bad):
    with pytest.raises(InputError):
        DSNetConfig.from_dict({"augment": bad})
