"""Clustering estimators: exact toy labels, noise handling, MeanShift == sklearn (both seedings)."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.cluster import MeanShift as SkMeanShift

from panoptic_bench.baselines.clustering import (
    BFS,
    DBSCAN,
    HDBSCAN,
    MeanShift,
    Method,
    Noise,
    make_clusterer,
)
from panoptic_bench.baselines.meanshift import get_bin_seeds
from panoptic_bench.datasets.semantickitti import (
    LABELS,
    list_scans,
    read_labels,
    read_scan,
    to_train,
)

# three groups on a line: {0, 1, 2} (spacing 0.5), {3, 4} (spacing 0.5), {5} alone
LINE = np.array([[0, 0, 0], [0.5, 0, 0], [1, 0, 0], [5, 0, 0], [5.5, 0, 0], [20, 0, 0]], float)


def blobs(seed: int, n_blobs: int = 6, per: int = 50, outliers: int = 30) -> np.ndarray:
    rng = np.random.default_rng(seed)
    centers = rng.uniform(-8, 8, (n_blobs, 3))
    pts = centers[:, None, :] + rng.normal(0, 0.4, (n_blobs, per, 3))
    return np.concatenate([pts.reshape(-1, 3), rng.uniform(-10, 10, (outliers, 3))])


def test_bfs_toy_exact():
    assert BFS(0.6).fit_predict(LINE).tolist() == [0, 0, 0, 1, 1, 2]
    assert BFS(0.4).fit_predict(LINE).tolist() == [0, 1, 2, 3, 4, 5]
    assert BFS(0.5).fit_predict(LINE).tolist() == [0, 0, 0, 1, 1, 2]  # radius is inclusive
    assert BFS(100).fit_predict(LINE).tolist() == [0] * 6


def test_dbscan_noise_policies():
    model = DBSCAN(eps=0.6, min_samples=2).fit(LINE)
    assert model.labels_.tolist() == [0, 0, 0, 1, 1, 2]
    assert model.noise_mask_.tolist() == [False] * 5 + [True]
    nearest = DBSCAN(eps=0.6, min_samples=2, noise=Noise.NEAREST).fit_predict(LINE)
    assert nearest.tolist() == [0, 0, 0, 1, 1, 1]
    # min_samples 3: only the middle point of the first group is core; {3, 4} and {5} are noise
    model = DBSCAN(eps=0.6, min_samples=3).fit(LINE)
    assert model.labels_.tolist() == [0, 0, 0, 1, 2, 3]
    assert model.noise_mask_.tolist() == [False, False, False, True, True, True]
    assert DBSCAN(eps=0.1, min_samples=2, noise=Noise.NEAREST).fit_predict(LINE).tolist() == [
        0,
        1,
        2,
        3,
        4,
        5,
    ]  # all noise: nothing to join, singletons


def test_hdbscan_toy_exact():
    model = HDBSCAN(min_cluster_size=2, min_samples=1).fit(LINE)
    assert model.labels_.tolist() == [0, 0, 0, 1, 1, 2]
    assert model.noise_mask_.tolist() == [False] * 5 + [True]
    assert HDBSCAN(2, 1, noise=Noise.NEAREST).fit_predict(LINE).tolist() == [0, 0, 0, 1, 1, 1]
    # fewer points than min_cluster_size: all noise, still labels 0..K-1
    assert HDBSCAN(min_cluster_size=5).fit_predict(LINE[:3]).tolist() == [0, 1, 2]


def test_meanshift_toy_exact():
    X = np.array([[1, 1], [2, 1], [1, 0], [4, 7], [3, 5], [3, 6]])
    model = MeanShift(bandwidth=2).fit(X)
    assert model.labels_.tolist() == [1, 1, 1, 0, 0, 0]
    np.testing.assert_allclose(model.cluster_centers_, [[10 / 3, 6], [4 / 3, 2 / 3]])
    orphan = MeanShift(0.6, cluster_all=False).fit(LINE)
    assert orphan.labels_.min() >= 0


@pytest.mark.parametrize("cls", [BFS, DBSCAN, HDBSCAN, MeanShift])
def test_empty_and_nan(cls):
    model = cls(1.0) if cls is not HDBSCAN else cls(5)
    assert model.fit_predict(np.zeros((0, 3))).shape == (0,)
    with pytest.raises(ValueError, match="NaN"):
        model.fit(np.array([[0, 0, np.nan]]))


@pytest.mark.parametrize("cls", [BFS, DBSCAN, HDBSCAN, MeanShift])
def test_labels_are_compact_and_nonnegative(cls):
    X = blobs(3)
    labels = (cls(0.7) if cls is not HDBSCAN else cls(5)).fit_predict(X)
    assert labels.dtype == np.int64 and labels.min() == 0
    assert set(np.unique(labels)) == set(range(labels.max() + 1)) or cls is MeanShift


def test_make_clusterer():
    assert isinstance(make_clusterer(Method.BFS, radius=1.0), BFS)
    model = make_clusterer("meanshift", bandwidth=0.65, bin_seeding=True, max_iter=None)
    assert isinstance(model, MeanShift) and model.bin_seeding and model.max_iter == 300
    with pytest.raises(ValueError):
        make_clusterer("kmeans")


def assert_same_as_sklearn(X: np.ndarray, bandwidth: float, **kw) -> None:
    ours = MeanShift(bandwidth, **kw).fit(X)
    ref = SkMeanShift(bandwidth=bandwidth, **kw).fit(X)
    assert ours.labels_.tolist() == ref.labels_.tolist()
    np.testing.assert_allclose(ours.cluster_centers_, ref.cluster_centers_, atol=1e-9)
    assert ours.n_iter_ == ref.n_iter_


@pytest.mark.parametrize("bin_seeding", [False, True])
@pytest.mark.parametrize("seed", [0, 1])
def test_meanshift_matches_sklearn_on_blobs(seed, bin_seeding):
    assert_same_as_sklearn(blobs(seed), 1.2, bin_seeding=bin_seeding)


def test_meanshift_matches_sklearn_options():
    X = blobs(5, per=40)
    assert_same_as_sklearn(X, 0.8, bin_seeding=True, min_bin_freq=3)
    assert_same_as_sklearn(X, 1.0, max_iter=2)
    ours = MeanShift(1.0, cluster_all=False).fit(X)
    ref = SkMeanShift(bandwidth=1.0, cluster_all=False).fit(X)
    assert (ours.noise_mask_ == (ref.labels_ < 0)).all()
    kept = ~ours.noise_mask_
    assert ours.labels_[kept].tolist() == ref.labels_[kept].tolist()
    assert ours.labels_[~kept].min() >= len(ours.cluster_centers_)  # orphans: own clusters


def test_bin_seeds_match_sklearn():
    from sklearn.cluster import get_bin_seeds as sk_get_bin_seeds

    X = blobs(2).astype(np.float32)
    for freq in (1, 4):
        np.testing.assert_array_equal(get_bin_seeds(X, 1.2, freq), sk_get_bin_seeds(X, 1.2, freq))


def test_meanshift_matches_sklearn_on_real_things(kitti_root):
    ref = list_scans(kitti_root)[0]
    points = read_scan(ref.scan)
    sem = to_train(read_labels(ref.label))
    things = points[np.isin(sem, LABELS.thing_ids), :3].astype(np.float64)
    assert len(things) > 4000
    for bandwidth, bin_seeding in ((1.2, True), (0.65, True), (1.2, False)):
        X = things if bin_seeding else things[::8]  # sklearn all-seeds is slow: an eighth
        assert_same_as_sklearn(X, bandwidth, bin_seeding=bin_seeding)
