"""Remission / pose augmentation and the shared point-density policy (issue 13, training side)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from panoptic_bench.datasets import semantickitti as sk
from panoptic_bench.dsnet.config import AugmentConfig, DSNetConfig
from panoptic_bench.dsnet.data.augment import (
    augment_remission,
    class_ids,
    class_remission_gain,
    tilt_points,
)
from panoptic_bench.dsnet.data.datasets import ClassMap, LidarSample
from panoptic_bench.dsnet.data.density import (
    DensityMatchedPredictor,
    density_seed,
    inference_max_points,
    nearest_kept,
    predict_at_density,
    thin_indices,
    with_density_policy,
)
from panoptic_bench.dsnet.data.training_set import TrainingSet
from panoptic_bench.errors import InputError


def _state(rng: np.random.Generator) -> dict:
    return rng.bit_generator.state


def test_disabled_augmentations_draw_nothing_and_change_nothing():
    rng = np.random.default_rng(3)
    before = _state(rng)
    rem = np.linspace(0, 1, 11, dtype=np.float32)
    np.testing.assert_array_equal(augment_remission(rem, rng), rem)
    xyz = np.random.default_rng(0).normal(size=(20, 3)).astype(np.float32)
    assert tilt_points(xyz, rng) is xyz
    assert thin_indices(100, 0, rng) is None and thin_indices(100, 100, rng) is None
    assert _state(rng) == before


def test_remission_gain_gamma_zeroing():
    rem = np.full(10_000, 0.25, np.float32)
    out = augment_remission(rem, np.random.default_rng(1), gamma=(0.5, 0.5))
    np.testing.assert_allclose(out, 0.5, rtol=1e-6)
    out = augment_remission(rem, np.random.default_rng(1), gain=(2.0, 2.0))
    np.testing.assert_allclose(out, 0.5, rtol=1e-6)
    out = augment_remission(np.full(10, 0.8, np.float32), np.random.default_rng(1), gain=(2.0, 2.0))
    assert out.max() == 1.0
    out = augment_remission(rem, np.random.default_rng(1), zero_prob=0.3)
    assert 0.27 < (out == 0).mean() < 0.33 and set(np.unique(out)) == {0.0, 0.25}
    assert out.dtype == np.float32


def test_tilt_is_a_rotation_and_tilts():
    xyz = np.random.default_rng(0).normal(size=(500, 3)) * 10
    out = tilt_points(xyz, np.random.default_rng(4), pitch_std_deg=2.0, roll_std_deg=2.0)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), np.linalg.norm(xyz, axis=1))
    assert not np.allclose(out[:, 2], xyz[:, 2])
    # a flat ground plane becomes a tilted plane
    plane = np.column_stack([xyz[:, 0], xyz[:, 1], np.full(500, -1.7)])
    tilted = tilt_points(plane, np.random.default_rng(4), pitch_std_deg=2.0)
    a = np.linalg.lstsq(np.column_stack([tilted[:, :2], np.ones(500)]), tilted[:, 2], rcond=None)[0]
    assert abs(a[0]) > 1e-3 and abs(a[1]) < 1e-9


def test_config_keys_round_trip_and_validate():
    cfg = DSNetConfig.from_dict(
        {
            "augment": {
                "remission_gain": [0.8, 1.2],
                "remission_gamma": [0.7, 1.4],
                "remission_zero_prob": 0.05,
                "pitch_std_deg": 1.0,
                "roll_std_deg": 1.5,
                "remission_class_gain": [0.7, 1.4],
            },
            "inference": {"match_training_density": True},
        }
    )
    assert DSNetConfig.from_dict(cfg.to_dict()) == cfg
    assert DSNetConfig().augment.remission_zero_prob == 0.0
    assert DSNetConfig().inference.match_training_density is False
    for bad, key in (
        ({"remission_gain": [1.2, 0.8]}, "remission_gain"),
        ({"remission_zero_prob": 1.0}, "remission_zero_prob"),
        ({"pitch_std_deg": -1.0}, "pitch_std_deg"),
        ({"remission_class_gain": [0.0, 1.5]}, "remission_class_gain"),
    ):
        with pytest.raises(InputError, match=key):
            DSNetConfig.from_dict({"augment": bad})


class _Data:
    def __init__(self, n: int = 3000) -> None:
        rng = np.random.default_rng(0)
        self.sample = LidarSample(
            rng.normal(size=(n, 3)).astype(np.float32) * 10,
            rng.random(n).astype(np.float32),
            rng.integers(1, 5, n),
            np.zeros(n, np.int64),
            ("00", "000000"),
        )
        lab = sk.LABELS
        self.class_map = ClassMap(
            "semantickitti", lab.class_names, lab.thing_ids, lab.stuff_ids, lab.ignore_ids
        )

    def __len__(self) -> int:
        return 1

    def load(self, index: int) -> LidarSample:
        s = self.sample
        return LidarSample(s.xyz.copy(), s.remission.copy(), s.sem.copy(), s.inst.copy(), s.key)


def test_training_set_remission_augmentation_leaves_geometry_stream_alone():
    base = AugmentConfig(max_points=1000)
    rem_aug = dataclasses.replace(base, remission_gain=(0.5, 1.5), remission_zero_prob=0.1)
    a, b = TrainingSet(_Data(), base, seed=2)[0], TrainingSet(_Data(), rem_aug, seed=2)[0]
    np.testing.assert_array_equal(a.xyz, b.xyz)
    np.testing.assert_array_equal(a.sem, b.sem)
    assert len(a.xyz) == 1000 and not np.array_equal(a.remission, b.remission)
    assert (b.remission == 0).mean() > 0.05


def test_class_remission_gain_one_factor_per_class():
    rem = np.array([0.2, 0.4, 0.2, 0.9, 0.5, 0.1], np.float32)
    sem = np.array([9, 11, 9, 11, 0, 9])
    rng = np.random.default_rng(5)
    before = _state(rng)
    np.testing.assert_array_equal(class_remission_gain(rem, sem, rng), rem)
    assert _state(rng) == before  # (1, 1) draws nothing
    # a fixed range is a fixed gain, clipped at 1: hand-worked
    np.testing.assert_allclose(
        class_remission_gain(rem, sem, rng, (2.0, 2.0)), [0.4, 0.8, 0.4, 1.0, 1.0, 0.2], rtol=1e-6
    )
    # property: within one class the ratio of any two points is kept; gains stay in range
    big_rem = np.random.default_rng(1).uniform(0.01, 0.4, 5000).astype(np.float32)
    big_sem = np.random.default_rng(2).integers(0, 20, 5000)
    out = class_remission_gain(big_rem, big_sem, np.random.default_rng(3), (0.6, 1.6))
    ratios = out / big_rem
    for c in np.unique(big_sem):
        r = ratios[big_sem == c]
        assert np.ptp(r) < 1e-5 and 0.6 - 1e-6 <= r[0] <= 1.6 + 1e-6
    assert np.unique(np.round(ratios, 4)).size == 20  # twenty classes, twenty gains
    assert out.dtype == np.float32 and big_rem.max() <= 0.4  # input untouched


def test_training_set_class_gain_has_its_own_stream():
    base = AugmentConfig(max_points=1000, remission_gain=(0.8, 1.2))
    cls_aug = dataclasses.replace(base, remission_class_gain=(0.5, 2.0))
    a, b = TrainingSet(_Data(), base, seed=2)[0], TrainingSet(_Data(), cls_aug, seed=2)[0]
    np.testing.assert_array_equal(a.xyz, b.xyz)
    np.testing.assert_array_equal(a.sem, b.sem)
    ratio = b.remission / np.maximum(a.remission, 1e-6)
    keep = (a.remission > 0.05) & (a.remission < 0.999) & (b.remission < 0.999)
    for c in np.unique(a.sem):  # the global gain is shared: one ratio per class
        r = ratio[keep & (a.sem == c)]
        assert np.ptp(r) < 1e-4
    assert np.unique(np.round(ratio[keep], 3)).size == np.unique(a.sem).size


def test_class_gain_on_listed_classes_only():
    rem = np.random.default_rng(1).uniform(0.01, 0.4, 3000).astype(np.float32)
    sem = np.random.default_rng(2).integers(0, 20, 3000)
    every = class_remission_gain(rem, sem, np.random.default_rng(3), (0.6, 1.6))
    only = class_remission_gain(rem, sem, np.random.default_rng(3), (0.6, 1.6), np.array([9, 10]))
    listed = np.isin(sem, [9, 10])
    np.testing.assert_array_equal(only[listed], every[listed])  # the same draws as for every class
    np.testing.assert_array_equal(only[~listed], rem[~listed])  # the rest untouched
    assert not np.array_equal(only[listed], rem[listed])
    # names -> train ids; an unknown name is one error naming the key
    names = ("unlabeled", "car", "road", "parking")
    np.testing.assert_array_equal(class_ids(names, ["road", "parking"], "k"), [2, 3])
    assert class_ids(names, [], "k") is None
    with pytest.raises(
        InputError, match="augment.remission_class_gain_classes: unknown class 'lawn'"
    ):
        class_ids(names, ["lawn"], "augment.remission_class_gain_classes")


def test_training_set_class_gain_on_named_classes():
    base = AugmentConfig(max_points=1000, remission_class_gain=(0.5, 2.0))
    data = _Data()
    names = data.class_map.class_names
    pick = names[int(np.unique(data.sample.sem)[1])]
    only = dataclasses.replace(base, remission_class_gain_classes=(pick,))
    a, b = TrainingSet(data, base, seed=2)[0], TrainingSet(_Data(), only, seed=2)[0]
    plain = TrainingSet(_Data(), AugmentConfig(max_points=1000), seed=2)[0]
    hit = b.sem == names.index(pick)
    np.testing.assert_array_equal(b.remission[hit], a.remission[hit])
    np.testing.assert_array_equal(b.remission[~hit], plain.remission[~hit])
    bad = dataclasses.replace(base, remission_class_gain_classes=("lawn",))
    with pytest.raises(InputError, match="remission_class_gain_classes"):
        TrainingSet(_Data(), bad, seed=2)


def test_inference_max_points_is_the_one_density_policy():
    def cfg(match: bool, n: int) -> DSNetConfig:
        return DSNetConfig.from_dict(
            {"augment": {"max_points": n}, "inference": {"match_training_density": match}}
        )

    assert inference_max_points(cfg(False, 25000)) == 0  # policy off: every point
    assert inference_max_points(cfg(True, 25000)) == 25000  # training density
    assert inference_max_points(cfg(True, 0)) == 0  # training kept every point too


def test_density_policy_spreads_to_nearest_kept_point():
    data = _Data()
    sample = data.load(0)
    keep = thin_indices(len(sample.xyz), 500, np.random.default_rng(0))
    near = nearest_kept(sample.xyz, keep)
    np.testing.assert_array_equal(near[keep], np.arange(500))
    d_near = np.linalg.norm(sample.xyz - sample.xyz[keep][near], axis=1)
    d_brute = np.linalg.norm(sample.xyz[:, None] - sample.xyz[keep][None], axis=2).min(1)
    np.testing.assert_allclose(d_near, d_brute, rtol=1e-6)

    @dataclasses.dataclass
    class Pred:
        sem: np.ndarray
        inst: np.ndarray
        sem_raw: np.ndarray
        offsets: np.ndarray
        features: np.ndarray | None = None

    seen = []

    def predict(s, panoptic=True):
        seen.append(len(s.xyz))
        idx = np.arange(len(s.xyz))
        return Pred(idx, idx % 7, (idx % 3).astype(np.uint8), s.xyz.copy())

    out = predict_at_density(predict, sample, 500)
    assert seen == [500] and len(out.sem) == len(sample.xyz)
    used = thin_indices(len(sample.xyz), 500, np.random.default_rng(density_seed(sample.key)))
    d_brute = np.linalg.norm(sample.xyz[:, None] - sample.xyz[used][None], axis=2).min(1)
    # every point carries the prediction (here: the offsets = xyz) of its nearest kept point
    np.testing.assert_allclose(
        np.linalg.norm(out.offsets - sample.xyz, axis=1), d_brute, rtol=1e-5, atol=1e-6
    )
    again = predict_at_density(predict, data.load(0), 500)
    np.testing.assert_array_equal(again.sem, out.sem)  # the subset is seeded by the scan key

    class Host:
        cfg = DSNetConfig.from_dict(
            {"augment": {"max_points": 500}, "inference": {"match_training_density": True}}
        )

        def predict(self, s, panoptic=True):
            return predict(s, panoptic)

    wrapped = with_density_policy(Host())
    assert isinstance(wrapped, DensityMatchedPredictor) and wrapped.cfg is Host.cfg
    assert len(wrapped.predict(sample).sem) == len(sample.xyz)
    plain = Host()
    plain.cfg = DSNetConfig()
    assert with_density_policy(plain) is plain


@pytest.mark.parametrize("match", [False, True])
def test_infer_and_validation_apply_the_density_policy(tmp_path, match):
    """``load_predictor`` (infer, demo) wraps the predictor exactly when the config asks."""
    import torch

    from panoptic_bench.datasets.semantickitti import LABELS
    from panoptic_bench.dsnet.checkpoint import (
        Checkpoint,
        build_backbone,
        save_checkpoint,
    )
    from panoptic_bench.dsnet.data.datasets import ClassMap
    from panoptic_bench.dsnet.inference.predictor import Predictor
    from panoptic_bench.dsnet.inference.run import load_predictor

    cfg = DSNetConfig.from_dict(
        {
            "grid": {"size": [16, 16, 4]},
            "model": {"init_size": 4, "point_hidden": [8], "point_feature_dim": 8},
            "augment": {"max_points": 300},
            "inference": {"match_training_density": match},
        }
    )
    lab = LABELS
    cmap = ClassMap("semantickitti", lab.class_names, lab.thing_ids, lab.stuff_ids, lab.ignore_ids)
    torch.manual_seed(0)
    backbone = build_backbone(cfg, cmap.num_classes)
    path = tmp_path / "c.pt"
    save_checkpoint(Checkpoint("offset", 1, cfg, cmap, backbone.state_dict(), None), path)
    pred, _ = load_predictor(path)
    assert isinstance(pred, DensityMatchedPredictor) is match
    if not match:
        assert isinstance(pred, Predictor)
    sample = _Data().load(0)
    out = pred.predict(sample)
    assert len(out.sem) == len(sample.xyz)
