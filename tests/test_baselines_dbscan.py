"""Grid DBSCAN: labels and core points identical to sklearn.cluster.DBSCAN, then the noise policy."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.cluster import DBSCAN as SkDBSCAN

from panoptic_bench.baselines import dbscan as dbscan_mod
from panoptic_bench.baselines.clustering import DBSCAN, Noise
from panoptic_bench.baselines.dbscan import dbscan_labels
from panoptic_bench.baselines.meanshift import resolve_noise
from panoptic_bench.baselines.regression import RegressionNoise, simulate_offsets
from panoptic_bench.datasets.semantickitti import (
    LABELS,
    list_scans,
    read_labels,
    read_scan,
    to_train,
)


def assert_same_as_sklearn(X: np.ndarray, eps: float, min_samples: int, msg: str = "") -> None:
    ref = SkDBSCAN(eps=eps, min_samples=min_samples).fit(X)
    labels, core = dbscan_labels(X, eps, min_samples)
    assert labels.dtype == np.int64 and labels.shape == (len(X),)
    np.testing.assert_array_equal(labels, ref.labels_, err_msg=f"labels {msg}")
    np.testing.assert_array_equal(np.flatnonzero(core), ref.core_sample_indices_, err_msg=msg)
    model = DBSCAN(eps, min_samples).fit(X)
    np.testing.assert_array_equal(model.core_sample_indices_, ref.core_sample_indices_)
    np.testing.assert_array_equal(model.noise_mask_, ref.labels_ < 0)
    for noise in Noise:  # the project's noise policy on top of sklearn's labels
        got = DBSCAN(eps, min_samples, noise=noise).fit_predict(X)
        np.testing.assert_array_equal(got, resolve_noise(X, ref.labels_, noise), err_msg=msg)
        assert got.min() >= 0


def blobs(rng: np.random.Generator, n: int, dim: int) -> np.ndarray:
    centres = rng.uniform(-4, 4, (int(rng.integers(1, 6)), dim))
    pts = centres[rng.integers(0, len(centres), n)] + rng.normal(
        0, rng.uniform(0.05, 0.8), (n, dim)
    )
    return np.concatenate([pts, rng.uniform(-6, 6, (n // 10, dim))])


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_equals_sklearn_on_random_points(dim):
    rng = np.random.default_rng(dim)
    for t in range(60):
        X = blobs(rng, int(rng.integers(12, 300)), dim)
        if t % 3 == 0:
            X = np.round(X * 2) / 2  # many distances exactly equal to eps (0.5, 1.0)
        elif t % 3 == 1:
            X = np.round(X * 10) / 10  # near-exact eps distances for 0.3 / 0.2 (rounding both ways)
        if t % 4 == 0:
            X = np.repeat(X[: max(2, len(X) // 5)], 5, axis=0)  # duplicates
        eps = (0.5, 1.0, 0.3, 0.2)[t % 4]
        min_samples = (1, 2, 5, 12, 3)[t % 5]
        assert_same_as_sklearn(X, eps, min_samples, f"dim {dim} case {t}")


def test_border_point_shared_by_two_clusters():
    """A border point next to two clusters takes the one sklearn's index-order search reaches first."""
    left = [[-1.0, 0], [-1.2, 0], [-1.4, 0]]  # core points at distance <= 1 of the border point
    right = [[1.0, 0], [1.2, 0], [1.4, 0]]
    border = [[0.0, 0]]  # 2 neighbours of each side + itself = 3 < min_samples 4: not core
    pad = [[50.0 + 10 * i, 0] for i in range(10)]  # >= 12 points: sklearn's KD-tree route
    for rows in (left + right + border, right + left + border, border + right + left):
        X = np.array(rows + pad)
        assert_same_as_sklearn(X, 1.0, 4)
        labels, core = dbscan_labels(X, 1.0, 4)
        first = 0 if rows[0] in (left[0], right[0]) else 1
        b = rows.index(border[0])
        assert not core[b] and labels[b] == labels[first] == 0
    # two border points, interleaved indices, each between two clusters
    X = np.array(right + border + left + [[0.0, 5.0]] + [[-1.0, 5], [-1.2, 5], [-1.4, 5]] + pad)
    X = np.concatenate([X, [[1.0, 5], [1.2, 5], [1.4, 5]]])
    assert_same_as_sklearn(X, 1.0, 4)


def test_edge_cases_and_fallback_routes():
    # inclusive eps, self counted: min_samples 1 makes every point core and its own cluster
    line = np.array([[0.0, 0, 0], [0.5, 0, 0], [1.0, 0, 0], [1.5 + 1e-12, 0, 0]] * 4)
    assert_same_as_sklearn(line, 0.5, 1)
    assert_same_as_sklearn(line, 0.5, 9)
    assert_same_as_sklearn(np.zeros((30, 3)), 0.1, 30)  # all duplicates: one cluster
    assert_same_as_sklearn(np.zeros((30, 3)), 0.1, 31)  # all noise
    rng = np.random.default_rng(0)
    assert_same_as_sklearn(rng.normal(size=(8, 3)), 1.0, 2)  # < 12 points: sklearn's brute route
    assert_same_as_sklearn(rng.normal(size=(200, 4)), 1.5, 4)  # 4-D: sklearn itself
    far = np.concatenate([rng.normal(0, 1e-7, (20, 3)), 1e9 + rng.normal(0, 1e-7, (20, 3))])
    assert_same_as_sklearn(far, 1e-7, 3)  # keys would overflow
    huge = 1e8 + rng.normal(0, 1e-3, (40, 3))
    assert_same_as_sklearn(huge, 1e-3, 3)  # cells widened by rounding
    assert dbscan_labels(np.zeros((0, 2)), 0.5, 5)[0].shape == (0,)
    for eps, ms in ((0.0, 5), (-1.0, 5), (0.5, 0), (0.5, 2.5)):
        with pytest.raises(ValueError):
            DBSCAN(eps, ms).fit(line)


def test_tiny_inputs_follow_sklearns_brute_route():
    """Below 12 points sklearn's distances come from the dot-product expansion: for it 3.7 and 3.4
    are within 0.3 and -0.4 and -0.7 are not, the definition says the opposite; we follow sklearn."""
    X = np.array([[3.7], [-0.4], [-0.7], [3.4], [-3.8], [-0.9]])
    assert ((X[0] - X[3]) ** 2).sum() > 0.3**2  # the definition says apart
    assert_same_as_sklearn(X, 0.3, 2)
    assert dbscan_labels(X, 0.3, 2)[0].tolist() == [0, -1, 1, 0, -1, 1]
    # the same points, padded to >= 12: sklearn's KD-tree uses the definition, and so do we
    Xp = np.concatenate([X, 100 + 10 * np.arange(6)[:, None]])
    assert_same_as_sklearn(Xp, 0.3, 2)
    assert dbscan_labels(Xp, 0.3, 2)[0][:6].tolist() == [-1, 0, 0, -1, -1, 0]


def test_wide_cells_go_to_sklearn(monkeypatch):
    """If rounding ever made a cell wider than eps, its points would not all be neighbours: the
    guard sends such inputs to sklearn (forced here by widening the cells)."""
    calls = []
    real = dbscan_mod._sklearn_labels
    monkeypatch.setattr(dbscan_mod, "_SHRINK", 1.5)
    monkeypatch.setattr(dbscan_mod, "_sklearn_labels", lambda *a: calls.append(1) or real(*a))
    rng = np.random.default_rng(3)
    X = rng.uniform(0, 10, (200, 1))
    assert_same_as_sklearn(X, 0.3, 4)
    assert calls


def test_dense_collapsed_centres():
    """Thousands of points within a few cm (whole cells core at once) next to sparse strips."""
    rng = np.random.default_rng(7)
    spots = rng.uniform(-20, 20, (6, 3))
    X = np.concatenate(
        [s + rng.normal(0, 0.02, (400, 3)) for s in spots]
        + [s + np.outer(rng.uniform(-1.5, 1.5, 60), [1, 0.2, 0]) for s in spots]
        + [rng.uniform(-25, 25, (100, 3))]
    )
    X = X[rng.permutation(len(X))]
    for eps, min_samples in ((0.5, 5), (0.2, 10), (0.05, 50), (1.2, 50)):
        assert_same_as_sklearn(X, eps, min_samples, f"eps {eps}")


def test_equals_sklearn_on_simulated_centres_of_real_scans(kitti_root):
    """Noisy and exact simulated centres of the real scans' things points."""
    for k, ref in enumerate(list_scans(kitti_root)[:2]):
        points, labels = read_scan(ref.scan), read_labels(ref.label)
        sem = to_train(labels)
        things = np.isin(sem, LABELS.thing_ids)
        for noisy in (True, False):
            noise = RegressionNoise() if noisy else RegressionNoise.zero()
            offset = simulate_offsets(
                points, sem, labels >> 16, LABELS.thing_ids, noise=noise, seed=k
            )
            X = points[things, :3].astype(np.float64) + offset[things]
            for eps, min_samples in ((0.5, 5), (0.2, 10), (1.2, 50)):
                assert_same_as_sklearn(X, eps, min_samples, f"scan {k} noisy {noisy} eps {eps}")
            assert DBSCAN(0.5, 5).fit(X).labels_.max() >= 5  # several instances, not one blob
