"""The point-density policy, one code path for training and inference.

DS-Net on a CPU trains on a random subset of ``augment.max_points`` points per scan (a speed-up)
but, by default, predicts every point of a full scan, so it sees ~5x denser scans at test time
than it was trained on. With ``inference.match_training_density: true`` the predictor thins each
scan with the same :func:`thin` as the training set (same ``max_points``, a subset drawn from a
stream seeded by the scan), predicts the kept points and gives every dropped point the
prediction of its nearest kept point (:func:`nearest_kept`), so scores still cover every point.
Off by default: existing configs and checkpoints behave as before.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "DensityMatchedPredictor",
    "density_seed",
    "inference_max_points",
    "inference_subset",
    "nearest_kept",
    "predict_at_density",
    "thin",
    "thin_indices",
    "with_density_policy",
]


def thin_indices(n_points: int, max_points: int, rng: np.random.Generator) -> np.ndarray | None:
    """Sorted indices of a uniform random subset of ``max_points`` of ``n_points`` points.

    Returns None (keep everything, no random draw) when ``max_points`` is 0 or not smaller
    than ``n_points``.

    Returns
    -------
    ndarray of shape (max_points,), int64, or None
    """
    if not 0 < max_points < n_points:
        return None
    return np.sort(rng.choice(n_points, max_points, replace=False))


def thin(sample, max_points: int, rng: np.random.Generator):
    """``(thinned LidarSample, kept indices or None)`` under the policy of :func:`thin_indices`."""
    from panoptic_bench.dsnet.data.datasets import LidarSample

    keep = thin_indices(len(sample.xyz), max_points, rng)
    if keep is None:
        return sample, None
    return (
        LidarSample(
            sample.xyz[keep],
            sample.remission[keep],
            sample.sem[keep],
            sample.inst[keep],
            sample.key,
            None if sample.soft is None else sample.soft[keep],
        ),
        keep,
    )


def density_seed(key: tuple[str, ...]) -> list[int]:
    """A stable seed of a scan key (e.g. ``("08", "000123")``) for the inference subset."""
    return [int.from_bytes(part.encode()[:8].ljust(8, b"\0"), "little") for part in key] or [0]


def inference_max_points(cfg) -> int:
    """How many points inference feeds the network under ``cfg`` (a ``DSNetConfig``): the training
    density ``augment.max_points`` when ``inference.match_training_density`` is set, else 0
    (every point). The one statement of the density policy, shared by the predictor and by
    ``checkpoint recalibrate-bn``."""
    if cfg.inference.match_training_density and cfg.augment.max_points > 0:
        return int(cfg.augment.max_points)
    return 0


def inference_subset(sample, max_points: int):
    """``(thinned LidarSample, kept indices or None)``: the subset inference predicts, drawn by
    :func:`thin` from a stream seeded by the scan key (:func:`density_seed`), so it is the same
    subset on every call."""
    return thin(sample, max_points, np.random.default_rng(density_seed(sample.key)))


def nearest_kept(xyz: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """For every point, the position in ``keep`` of its nearest kept point (3-D, Euclidean).

    Parameters
    ----------
    xyz : ndarray of shape (n, 3), float
    keep : ndarray of shape (k,), int64
        Indices of the kept points.

    Returns
    -------
    ndarray of shape (n,), int64
        Kept points map to themselves.
    """
    from scipy.spatial import cKDTree

    out = cKDTree(xyz[keep]).query(xyz, k=1)[1].astype(np.int64)
    out[keep] = np.arange(keep.size)
    return out


def predict_at_density(predict, sample, max_points: int, panoptic: bool = True):
    """Predict ``sample`` at the training density and spread the prediction to every point.

    Parameters
    ----------
    predict : callable
        ``predict(sample, panoptic=...) -> ScanPrediction`` (e.g. ``Predictor.predict``).
    sample : LidarSample
    max_points : int
        ``augment.max_points`` of the checkpoint's config (0: predict every point).

    Returns
    -------
    ScanPrediction
        One entry per point of ``sample``; dropped points take the semantic class, instance id,
        offset, features and class probabilities of their nearest kept point.
    """
    import dataclasses

    small, keep = inference_subset(sample, max_points)
    pred = predict(small, panoptic=panoptic)
    if keep is None:
        return pred
    near = nearest_kept(sample.xyz, keep)
    spread = {
        name: getattr(pred, name)[near]
        for name in ("sem", "inst", "sem_raw", "offsets", "features", "probs")
        if getattr(pred, name, None) is not None
    }
    return dataclasses.replace(pred, **spread)


class DensityMatchedPredictor:
    """A predictor that applies ``inference.match_training_density`` (see the module docstring).

    Wraps any object with ``predict(sample, panoptic=True)`` and ``cfg``; every other attribute
    is the wrapped predictor's.
    """

    def __init__(self, predictor) -> None:
        self._inner = predictor

    def __getattr__(self, name: str):
        return getattr(self._inner, name)

    def predict(self, sample, panoptic: bool = True):
        """Predict at ``cfg.augment.max_points`` points, spread to every point of ``sample``."""
        return predict_at_density(
            self._inner.predict, sample, self._inner.cfg.augment.max_points, panoptic
        )


def with_density_policy(predictor):
    """``predictor`` itself, or wrapped when its config sets ``inference.match_training_density``."""
    if inference_max_points(predictor.cfg):
        return DensityMatchedPredictor(predictor)
    return predictor
