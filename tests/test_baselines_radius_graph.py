"""Fast radius-graph components (BFS): exactly the naive definition, on toys, random and real data."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse.csgraph import connected_components

from panoptic_bench.baselines.clustering import BFS
from panoptic_bench.baselines.radius_graph import (
    _number_by_first_point,
    _pairs_components,
    radius_components,
)
from panoptic_bench.baselines.regression import RegressionNoise, simulate_offsets
from panoptic_bench.datasets.semantickitti import (
    LABELS,
    list_scans,
    read_labels,
    read_scan,
    to_train,
)


def naive(X: np.ndarray, radius: float) -> np.ndarray:
    """The definition: linked iff sum of squared differences <= radius**2; numbered by first point."""
    linked = ((X[:, None, :] - X[None, :, :]) ** 2).sum(-1) <= radius**2
    labels = connected_components(linked, directed=False)[1]
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first)] = np.arange(len(first))
    return rank[inverse]


@pytest.mark.parametrize("dim", [1, 2, 3, 4])
def test_equals_naive_on_random_points(dim):
    rng = np.random.default_rng(dim)
    for t in range(40):
        n = int(rng.integers(1, 300))
        X = rng.normal(0, rng.uniform(0.2, 4), (n, dim))
        if t % 3 == 0:
            X = np.round(X * 2) / 2  # many distances exactly equal to the radius
        if t % 4 == 0:
            X = np.repeat(X[: max(1, n // 6)], 6, axis=0)  # duplicates
        radius = (0.5, 1.0, 0.3, 1.2)[t % 4]
        got = radius_components(X, radius)
        assert got.dtype == np.int64
        np.testing.assert_array_equal(got, naive(X, radius), err_msg=f"dim {dim} case {t}")


def test_edge_cases():
    line = np.array([[0.0, 0, 0], [0.5, 0, 0], [1.0, 0, 0], [1.5 + 1e-12, 0, 0]])
    assert radius_components(line, 0.5).tolist() == [0, 0, 0, 1]  # inclusive, not beyond
    assert radius_components(np.zeros((0, 3)), 1.0).shape == (0,)
    assert radius_components(np.zeros((5, 3)), 1.0).tolist() == [0] * 5
    # coordinates so far apart that grid keys would overflow: the pair route answers
    far = np.array([[0.0, 0, 0], [1e9, 1e9, 1e9], [1e-7, 0, 0], [1e9, 1e9, 1e9 + 2e-7]])
    assert radius_components(far, 1e-6).tolist() == [0, 1, 0, 1]


def test_bfs_on_dense_regressed_centres_of_real_scans(kitti_root):
    """Noisy and exact simulated centres of the real scans: fast path == every-pair route."""
    for k, ref in enumerate(list_scans(kitti_root)[:2]):
        points, labels = read_scan(ref.scan), read_labels(ref.label)
        sem = to_train(labels)
        things = np.isin(sem, LABELS.thing_ids)
        for noise_seed in (k, None):
            noise = RegressionNoise() if noise_seed is not None else RegressionNoise.zero()
            offset = simulate_offsets(
                points, sem, labels >> 16, LABELS.thing_ids, noise=noise, seed=k
            )
            X = points[things, :3].astype(np.float64) + offset[things]
            ref_labels = _number_by_first_point(_pairs_components(X, 1.2))
            got = BFS(1.2).fit_predict(X)
            np.testing.assert_array_equal(got, ref_labels)
            assert got.max() >= 5  # several instances, not one blob
