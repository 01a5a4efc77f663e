"""Losses: Lovász-softmax vs brute-force Jaccard, tight-box centres, class weights, offsets."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch

from panoptic_bench.dsnet.data.augment import augment_points
from panoptic_bench.dsnet.training.losses import (
    class_weights,
    instance_centers,
    label_counts,
    lovasz_softmax,
    offset_loss,
    semantic_loss,
)


def jaccard_loss_of_set(fg: np.ndarray, mispredicted: np.ndarray) -> float:
    """Delta_J(M) = |M| / |fg u M| by set operations."""
    union = np.logical_or(fg, mispredicted).sum()
    return float(mispredicted.sum() / union) if union else 0.0


def lovasz_extension_brute(fg: np.ndarray, errors: np.ndarray) -> float:
    """Choquet integral: integral over t in [0, 1] of Delta_J({i: errors_i > t}) dt."""
    ts = np.concatenate([[0.0], np.unique(errors), [1.0]])
    total = 0.0
    for lo, hi in itertools.pairwise(np.unique(ts)):
        total += (hi - lo) * jaccard_loss_of_set(fg, errors > lo)
    return total


@pytest.mark.parametrize("seed", range(6))
def test_lovasz_equals_brute_force_extension(seed):
    rng = np.random.default_rng(seed)
    n, c = 7, 3
    probs = torch.softmax(torch.tensor(rng.normal(size=(n, c))), 1)
    labels = torch.tensor(rng.integers(0, c, n))
    got = lovasz_softmax(probs, labels, ignore_index=None).item()
    per_class = []
    for k in range(c):
        fg = (labels == k).numpy()
        if fg.any():
            per_class.append(lovasz_extension_brute(fg, np.abs(fg - probs[:, k].numpy())))
    assert got == pytest.approx(np.mean(per_class), abs=1e-9)


def test_lovasz_on_hard_predictions_is_one_minus_iou():
    labels = torch.tensor([1, 1, 1, 2, 2, 0, 3])
    pred = torch.tensor([1, 1, 2, 2, 2, 1, 3])
    probs = torch.nn.functional.one_hot(pred, 4).double()
    # class 1: I=2, U=4 (point 5 has label 0 -> ignored, so U=3); class 2: I=2 U=3; class 3: 1
    got = lovasz_softmax(probs, labels, ignore_index=0).item()
    assert got == pytest.approx(np.mean([1 - 2 / 3, 1 - 2 / 3, 0.0]))
    assert lovasz_softmax(torch.nn.functional.one_hot(labels, 4).double(), labels).item() == 0.0


def test_semantic_loss_has_gradients_and_ignores_class_zero():
    logits = torch.randn(20, 4, requires_grad=True)
    labels = torch.randint(0, 4, (20,))
    loss = semantic_loss(logits, labels, class_weights(label_counts([labels], 4)))
    loss.backward()
    assert torch.isfinite(loss) and logits.grad[labels == 0].abs().sum() == 0


def test_class_weights():
    w = class_weights(np.array([1000, 100, 10, 0]), power=1.0)
    assert w[0] == 0 and w[3] == 0
    assert w[2] > w[1] > 0 and w[1:3].mean().item() == pytest.approx(1.0)
    assert torch.allclose(class_weights(np.array([5, 3, 3]), power=0.0), torch.tensor([0, 1.0, 1]))
    with pytest.raises(ValueError, match="remap"):
        label_counts([np.array([0, 5])], 4)


def test_tight_box_centres_not_mass_centres():
    xyz = torch.tensor([[0.0, 0, 0], [1, 0, 0], [1, 0, 0], [1, 2, 4], [10, 10, 10], [12, 10, 10]])
    ids = torch.tensor([7, 7, 7, 7, 3, 3])
    c = instance_centers(xyz, ids)
    assert c[0].tolist() == [0.5, 1.0, 2.0] and torch.equal(c[0], c[3])
    assert c[4].tolist() == [11.0, 10.0, 10.0]
    # same id in two scans = two instances
    c2 = instance_centers(xyz, torch.zeros(6, dtype=torch.long), torch.tensor([0, 0, 0, 0, 1, 1]))
    assert c2[0].tolist() == [0.5, 1.0, 2.0] and c2[5].tolist() == [11.0, 10.0, 10.0]


def test_offset_loss_is_mean_l1_over_things():
    xyz = torch.zeros(3, 3)
    centers = torch.tensor([[1.0, 2, 3], [0, 0, 0], [5, 5, 5]])
    offsets = torch.zeros(3, 3, requires_grad=True)
    loss = offset_loss(offsets, xyz, centers, torch.tensor([True, True, False]))
    assert loss.item() == pytest.approx(3.0, rel=1e-5)  # (6 + 0) / 2
    loss.backward()
    assert offsets.grad[2].abs().sum() == 0
    assert offset_loss(offsets, xyz, centers, torch.zeros(3, dtype=torch.bool)).item() == 0


@pytest.mark.parametrize("make_gen", [np.random.default_rng, torch.Generator().manual_seed])
def test_augmentation_deterministic_and_rigid_in_z(make_gen):
    xyz = np.random.default_rng(1).normal(size=(100, 3)).astype(np.float32)
    a = augment_points(xyz, make_gen(5))
    b = augment_points(xyz, make_gen(5))
    assert np.array_equal(a, b) and a.dtype == np.float32
    assert not np.allclose(a, augment_points(xyz, make_gen(6)))
    t = augment_points(torch.from_numpy(xyz), make_gen(5))
    np.testing.assert_allclose(t.numpy(), a, atol=1e-5)
    # z only translated; xy radii scaled by one factor in [0.95, 1.05]
    dz = a[:, 2] - xyz[:, 2]
    assert np.ptp(dz) < 1e-5
    ratio = (
        np.linalg.norm(a[:, :2] - a[:1, :2], axis=1)[1:]
        / np.linalg.norm(xyz[:, :2] - xyz[:1, :2], axis=1)[1:]
    )
    assert np.ptp(ratio) < 1e-4 and 0.95 <= ratio.mean() <= 1.05
    ident = augment_points(
        xyz, make_gen(0), rotate=False, flip=False, scale_range=(1, 1), translate_std=(0, 0, 0)
    )
    assert np.array_equal(ident, xyz)
