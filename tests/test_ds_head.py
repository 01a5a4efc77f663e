"""DSNetHead / shift_instances / shift_training_loss on small synthetic scans."""

from __future__ import annotations

import numpy as np
import torch
from sklearn.metrics import adjusted_rand_score

from panoptic_bench.baselines.clustering import BFS
from panoptic_bench.dsnet.model.ds_head import DSNetHead, shift_instances, shift_training_loss
from panoptic_bench.dsnet.model.dynamic_shift import DynamicShift

THINGS = (1, 2)


def scan(rng: np.random.Generator):
    """Two well separated objects (class 1 and 2) with perfect offsets, plus stuff points."""
    a = rng.normal(0, 0.5, (120, 3)) + [5, 0, 0]
    b = rng.normal(0, 0.3, (60, 3)) + [-5, 2, 0]
    stuff = rng.uniform(-20, 20, (200, 3))
    xyz = np.concatenate([a, b, stuff])
    sem = np.repeat([1, 2, 0], [120, 60, 200])
    inst = np.repeat([1, 2, 0], [120, 60, 200])
    centre = np.zeros_like(xyz)
    centre[:120], centre[120:180] = [5, 0, 0], [-5, 2, 0]
    offsets = np.where(sem[:, None] > 0, centre - xyz, 0.0)
    logits = np.eye(3)[sem] * 5.0
    return xyz, sem, inst, offsets, logits


def test_head_recovers_instances_and_reports_diagnostics():
    torch.manual_seed(0)
    xyz, sem, inst, offsets, logits = scan(np.random.default_rng(0))
    module = DynamicShift(8, iterations=3, hidden=8)
    feats = torch.randn(len(xyz), 8)
    head = DSNetHead(module, THINGS, max_seeds=100)
    sem_p, inst_p, diag = head(torch.from_numpy(logits), torch.from_numpy(offsets), feats, xyz)
    np.testing.assert_array_equal(sem_p, sem)
    assert (inst_p[sem == 0] == 0).all()
    assert adjusted_rand_score(inst[sem > 0], inst_p[sem > 0]) == 1.0
    assert set(np.unique(inst_p)) == {0, 1, 2}
    assert diag.seed_index.shape == (100,)
    assert diag.positions.shape == (4, 100, 3)
    assert diag.weights.shape == (3, 100, 3) and diag.bandwidths.shape == (3, 100)
    assert set(diag.as_arrays()) == {
        "seed_index",
        "positions",
        "weights",
        "bandwidths",
        "seed_labels",
    }


def test_head_without_things_and_with_bfs_by_xyz():
    xyz, sem, inst, offsets, logits = scan(np.random.default_rng(1))
    module = DynamicShift(4, iterations=2, hidden=4)
    feats = torch.randn(len(xyz), 4)
    stuff_logits = torch.from_numpy(np.eye(3)[np.zeros(len(xyz), int)])
    _, inst_p, diag = DSNetHead(module, THINGS)(stuff_logits, torch.zeros(len(xyz), 3), feats, xyz)
    assert diag is None and (inst_p == 0).all()
    head = DSNetHead(module, THINGS, clusterer=BFS(radius=1.2), assign_by_xyz=True)
    _, inst_p, _ = head(torch.from_numpy(logits), torch.from_numpy(offsets), feats, xyz)
    assert adjusted_rand_score(inst[sem > 0], inst_p[sem > 0]) == 1.0


def test_shift_instances_empty_and_training_loss_backpropagates():
    module = DynamicShift(4, iterations=2, hidden=4)
    labels, diag = shift_instances(module, np.zeros((0, 3)), torch.zeros(0, 4))
    assert labels.shape == (0,) and diag.positions.shape == (3, 0, 3)
    centers = torch.randn(50, 3)
    loss = shift_training_loss(module, centers, torch.randn(50, 4), centers * 0, max_seeds=20)
    loss.backward()
    assert torch.isfinite(loss) and loss > 0
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in module.parameters())
    empty = shift_training_loss(module, torch.zeros(0, 3), torch.zeros(0, 4), torch.zeros(0, 3))
    assert empty.item() == 0.0
