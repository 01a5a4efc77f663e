"""Distillation from a teacher's class probabilities (``infer --save-probs``, ``loss.distill``):
the probability files, the soft cross-entropy against hand-worked values and F.cross_entropy,
the probabilities travelling with the points through thinning and pasting, the config rules, and
a tiny train run from the CLI (with a missing file as one clear error)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from panoptic_bench.cli import main as cli
from panoptic_bench.dsnet.checkpoint import load_checkpoint
from panoptic_bench.dsnet.config import DSNetConfig, save_config
from panoptic_bench.dsnet.data.bank import BankInstance, InstanceBank
from panoptic_bench.dsnet.data.datasets import LidarSample
from panoptic_bench.dsnet.data.density import thin
from panoptic_bench.dsnet.data.soft_labels import (
    one_hot,
    read_soft_labels,
    soft_label_path,
    write_soft_labels,
)
from panoptic_bench.dsnet.training.losses import semantic_loss, soft_cross_entropy
from panoptic_bench.errors import InputError

sys.path.insert(0, str(Path(__file__).parent))
from dsnet_tiny_checkpoints import write_tiny_checkpoint  # noqa: E402
from dsnet_tiny_world import write_tiny_world  # noqa: E402
from test_dsnet_train import TINY  # noqa: E402

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _probs(n: int, c: int, seed: int = 0) -> np.ndarray:
    p = np.random.default_rng(seed).random((n, c))
    p[:, 0] = 0
    return (p / p.sum(1, keepdims=True)).astype(np.float16)


def test_probability_files_round_trip_and_name_their_problems(tmp_path):
    path = soft_label_path(tmp_path, ("03", "000007"))
    assert path == tmp_path / "sequences" / "03" / "probs" / "000007.npy"
    assert soft_label_path(tmp_path, ("tok",)) == tmp_path / "probs" / "tok.npy"
    p = _probs(50, 4)
    path.parent.mkdir(parents=True)
    write_soft_labels(path, p)
    got = read_soft_labels(path, 50, 4)
    assert got.dtype == np.float16 and np.array_equal(got, p)
    with pytest.raises(InputError, match=r"shape \(50, 4\), expected \(51, 4\)") as e:
        read_soft_labels(path, 51, 4)
    assert str(path) in str(e.value)
    bad = p.astype(np.float32)
    bad[3] = [0.0, 0.5, 0.5, 0.5]
    write_soft_labels(path, bad)
    with pytest.raises(InputError, match="a row sums to 1.500, not 1"):
        read_soft_labels(path, 50, 4)
    bad[3] = [0.0, 1.5, -0.25, -0.25]
    write_soft_labels(path, bad)
    with pytest.raises(InputError, match=r"finite and within \[0, 1\]"):
        read_soft_labels(path, 50, 4)
    with pytest.raises(InputError, match="infer --save-probs"):
        read_soft_labels(tmp_path / "none.npy", 50, 4)
    path.write_bytes(b"not numpy")
    with pytest.raises(InputError, match="unreadable"):
        read_soft_labels(path, 50, 4)


def test_soft_cross_entropy_by_hand_and_against_torch():
    logits = torch.tensor([[0.0, 1.0], [2.0, 0.0]])
    target = torch.tensor([[0.25, 0.75], [1.0, 0.0]])
    w = torch.tensor([1.0, 3.0])
    ls = F.log_softmax(logits, 1)
    by_hand = -(0.25 * ls[0, 0] + 3 * 0.75 * ls[0, 1] + ls[1, 0]) / (0.25 + 2.25 + 1.0)
    assert torch.allclose(soft_cross_entropy(logits, target, w), by_hand)
    # one-hot rows: exactly the weighted mean of F.cross_entropy
    g = torch.Generator().manual_seed(0)
    z = torch.randn(40, 5, generator=g)
    y = torch.randint(0, 5, (40,), generator=g)
    w5 = torch.rand(5, generator=g) + 0.1
    hot = F.one_hot(y, 5).float()
    assert torch.allclose(soft_cross_entropy(z, hot, w5), F.cross_entropy(z, y, weight=w5))


def test_semantic_loss_mixes_labels_and_teacher_only_on_labelled_points():
    g = torch.Generator().manual_seed(1)
    z = torch.randn(30, 4, generator=g)
    y = torch.randint(0, 4, (30,), generator=g)  # 0 = ignored
    w = torch.tensor([0.0, 1.0, 2.0, 0.5])
    soft = torch.from_numpy(_probs(30, 4, seed=2).astype(np.float32))
    plain = semantic_loss(z, y, w, 0)
    assert torch.equal(semantic_loss(z, y, w, 0, soft=soft, distill=0.0), plain)
    # the teacher agreeing with the labels changes nothing
    agree = F.one_hot(y, 4).float()
    assert torch.allclose(semantic_loss(z, y, w, 0, soft=agree, distill=0.7), plain)
    half = semantic_loss(z, y, w, 0, ce_weight=1.0, lovasz_weight=0.0, soft=soft, distill=0.5)
    keep = y != 0
    target = 0.5 * F.one_hot(y[keep], 4).float() + 0.5 * soft[keep]
    assert torch.allclose(half, soft_cross_entropy(z[keep], target, w))
    assert not torch.allclose(half, semantic_loss(z, y, w, 0, lovasz_weight=0.0))


def _sample() -> LidarSample:
    """A dense ground ring (every 0.2 m, 4-16 m out) and some points above it."""
    rng = np.random.default_rng(5)
    g = np.arange(-16, 16, 0.2)
    gx, gy = np.meshgrid(g, g)
    ground = np.c_[gx.ravel(), gy.ravel(), np.full(gx.size, -1.73)]
    ground = ground[
        (np.hypot(ground[:, 0], ground[:, 1]) > 4) & (np.hypot(ground[:, 0], ground[:, 1]) < 16)
    ]
    above = rng.uniform([-15, -15, 0.5], [15, 15, 1.5], (200, 3))
    xyz = np.r_[ground, above].astype(np.float32)
    n = len(xyz)
    sem = rng.integers(1, 4, n)
    soft = _probs(n, 4, seed=6)
    return LidarSample(
        xyz, rng.random(n).astype(np.float32), sem, np.zeros(n, np.int64), ("00", "0"), soft
    )


def test_teacher_probabilities_follow_thinning_and_pasting():
    s = _sample()
    small, keep = thin(s, 100, np.random.default_rng(0))
    assert np.array_equal(small.soft, s.soft[keep]) and np.array_equal(small.sem, s.sem[keep])
    obj = BankInstance(
        xyz=np.array([[10.0, 0, -1.70], [10.2, 0.1, -1.4], [10.1, -0.1, -1.1]], np.float32),
        remission=np.full(3, 0.5, np.float32),
        sem=3,
    )
    bank = InstanceBank([obj])
    out = bank.paste(s, np.random.default_rng(1), count=1)
    assert len(out.soft) == len(out.xyz) == len(out.sem)
    pasted = out.inst == 1
    assert pasted.sum() == 3 and np.array_equal(out.soft[pasted], one_hot(np.full(3, 3), 4))
    # every kept scan point keeps its own row (matched by position: pasting does not move them)
    rows = {tuple(p): r for p, r in zip(s.xyz.tolist(), s.soft)}
    assert all(
        np.array_equal(rows[tuple(p)], r)
        for p, r in zip(out.xyz[~pasted].tolist(), out.soft[~pasted])
    )
    assert s.soft.shape == (len(s.xyz), 4)  # the input is not modified


@pytest.mark.parametrize(
    ("loss", "augment", "message"),
    [
        ({"distill": 1.5, "distill_probs": "x"}, {}, r"loss.distill must be in \[0, 1\]"),
        ({"distill": 0.5}, {}, "needs loss.distill_probs"),
        ({"distill": 0.5, "distill_probs": "x"}, {"mix_prob": 0.5}, "cannot be combined"),
    ],
)
def test_config_rules(loss, augment, message):
    raw = {**TINY, "loss": {**TINY["loss"], **loss}, "augment": augment}
    with pytest.raises(InputError, match=message):
        DSNetConfig.from_dict(raw)


def test_save_probs_then_train_a_student(tmp_path, capsys):
    """infer --save-probs writes one probability row per point (argmax = the backbone's class
    wherever that is not ignored); a student trains on them; a missing file is exit 2."""
    world = write_tiny_world(tmp_path / "w", {"00": 2, "08": 1})
    teacher = write_tiny_checkpoint(tmp_path / "t.pt", seed=0)
    probs = tmp_path / "teacher"
    args = ["infer", "--checkpoint", str(teacher), "--data", str(world), "--split", "00"]
    assert cli([*args, "--out", str(probs), "--save-probs", "--no-progress"]) == 0
    for frame in ("000000", "000001"):
        p = read_soft_labels(soft_label_path(probs, ("00", frame)), *_shape(world, frame))
        sem_raw = np.load(probs / "sequences" / "00" / "centers" / f"{frame}.npz")["sem"]
        assert np.all(p[:, 0] == 0)
        sure = sem_raw != 0
        assert np.array_equal(p.astype(np.float32).argmax(1)[sure], sem_raw[sure])
    cfg = DSNetConfig.from_dict(
        {**TINY, "loss": {**TINY["loss"], "distill": 0.5, "distill_probs": str(probs)}}
    )
    good = tmp_path / "distill.yaml"
    save_config(cfg, good)
    train = ["train", "--data", str(world), "--stage", "semantic", "--epochs", "1", "--no-progress"]
    assert cli([*train, "--config", str(good), "--out", str(tmp_path / "run")]) == 0
    assert (
        load_checkpoint(tmp_path / "run" / "checkpoints" / "semantic.pt").config.loss.distill == 0.5
    )
    (probs / "sequences" / "00" / "probs" / "000001.npy").unlink()
    capsys.readouterr()
    assert cli([*train, "--config", str(good), "--out", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err
    assert "000001.npy" in err and "--save-probs" in err and "Traceback" not in err
    nowhere = tmp_path / "no-teacher"
    save_config(cfg.replace(loss={"distill_probs": str(nowhere)}), good)
    assert cli([*train, "--config", str(good), "--out", str(tmp_path / "bad2")]) == 2
    err = capsys.readouterr().err
    assert "loss.distill_probs: no sequences/" in err and str(nowhere) in err
    assert not (tmp_path / "bad2" / "checkpoints").exists()


def _shape(world: Path, frame: str) -> tuple[int, int]:
    n = np.fromfile(world / "sequences" / "00" / "velodyne" / f"{frame}.bin", np.float32).size // 4
    return n, 20


def test_probabilities_are_spread_like_the_classes_at_training_density():
    from panoptic_bench.dsnet.data.density import predict_at_density
    from panoptic_bench.dsnet.inference.predictor import ScanPrediction

    s = _sample()

    def predict(small, panoptic=True):
        n = len(small.xyz)
        probs = _probs(n, 4, seed=n)
        sem = probs.astype(np.float32).argmax(1)
        return ScanPrediction(
            sem,
            np.zeros(n, np.int64),
            sem.astype(np.uint8),
            np.zeros((n, 3), np.float32),
            probs=probs,
        )

    p = predict_at_density(predict, s, 300)
    assert p.probs.shape == (len(s.xyz), 4)
    assert np.array_equal(p.probs.astype(np.float32).argmax(1), p.sem)
    assert len(np.unique(p.probs, axis=0)) == 300  # each point took one of the kept points' rows


def test_a_distilling_step_refuses_a_sample_without_teacher_probabilities():
    """No silent fall-back to the plain loss when a sample lost its probabilities."""
    from panoptic_bench.dsnet.data.datasets import ClassMap
    from panoptic_bench.dsnet.model.network import BackboneOutput
    from panoptic_bench.dsnet.training.steps import stage_loss

    cfg = DSNetConfig.from_dict(
        {**TINY, "loss": {**TINY["loss"], "distill": 0.5, "distill_probs": "x"}}
    )
    cmap = ClassMap("toy", ("unlabeled", "a", "b", "c"), (3,), (1, 2), (0,))
    s = _sample()
    z = torch.randn(len(s.xyz), 4)
    out = BackboneOutput(z, torch.zeros(len(s.xyz), 3), torch.zeros(len(s.xyz), 2), z[:1])
    weights = torch.ones(4)
    got = stage_loss("semantic", out, [s], cfg, cmap, weights).total
    assert torch.isfinite(got)
    bare = LidarSample(s.xyz, s.remission, s.sem, s.inst, s.key)
    with pytest.raises(ValueError, match="carries no teacher probabilities"):
        stage_loss("semantic", out, [bare], cfg, cmap, weights)
