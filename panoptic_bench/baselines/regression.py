"""Simulated centre regression from ground truth ("simulated regression", never a network result).

Stands in for a trained instance branch so that clustering studies (paper Fig. 3b, 4b) can run
on the real scans in ``../shared/data`` and on synthetic data before DS-Net is trained.

Model, per ground-truth instance (things points sharing one instance id):

- target centre ``c`` = centre of the instance's axis-aligned tight box (paper appendix §4);
- ``size`` = diagonal of that box, ``range`` = horizontal distance of ``c`` from the sensor;
- each point's regressed centre is ``c + e``: ``e`` has a Gaussian component along the viewing
  ray (unit vector from the sensor to the point) with standard deviation
  ``sigma = base_sigma + size_gain * size + range_gain * range`` and components across the ray with
  standard deviation ``across_ratio * sigma``: strips elongated along the ray, growing with
  instance size and range, as observed in the paper (Fig. 3);
- with probability ``outlier_rate`` a point is an outlier: its centre lies at a uniform fraction
  ``u ~ U(0, 1)`` of the way from the point to ``c`` (under-shot regression);
- stuff points (and things points without an instance id) get a zero offset.

``RegressionNoise.zero()`` gives exact ground-truth centres. Results are deterministic given the
seed (one ``numpy.random.Generator``, points visited in file order).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

__all__ = ["SIMULATED", "RegressionNoise", "gt_box_centers", "simulate_offsets"]

SIMULATED = "simulated regression"


@dataclass(frozen=True)
class RegressionNoise:
    """Parameters of the simulated regression error (metres; see module docstring)."""

    base_sigma: float = 0.05
    size_gain: float = 0.03
    range_gain: float = 0.002
    across_ratio: float = 0.3
    outlier_rate: float = 0.02

    def __post_init__(self) -> None:
        for f in fields(self):
            if getattr(self, f.name) < 0:
                raise ValueError(f"{f.name} must be >= 0")
        if self.outlier_rate > 1:
            raise ValueError("outlier_rate must be <= 1")

    @classmethod
    def zero(cls) -> RegressionNoise:
        """No noise and no outliers: regressed centres are the ground-truth centres."""
        return cls(0.0, 0.0, 0.0, 0.0, 0.0)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RegressionNoise:
        """Build from a mapping; unknown keys are an error."""
        unknown = set(data) - {f.name for f in fields(cls)}
        if unknown:
            raise ValueError(f"unknown regression-noise keys: {sorted(unknown)}")
        return cls(**{k: float(v) for k, v in data.items()})

    def to_dict(self) -> dict[str, float]:
        """Plain mapping of the parameters."""
        return asdict(self)


def gt_box_centers(xyz: np.ndarray, instance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centres and diagonals of the axis-aligned tight boxes of the instances.

    Parameters
    ----------
    xyz : array of shape (m, 3), float
        Points of the instances.
    instance : array of shape (m,), integer
        Instance key per point (any integers; e.g. the full uint32 label).

    Returns
    -------
    centers : ndarray of shape (m, 3), float64
        Box centre of each point's instance.
    diagonal : ndarray of shape (m,), float64
        Box diagonal of each point's instance.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    _, inv = np.unique(np.asarray(instance), return_inverse=True)
    inv = inv.reshape(-1)
    k = int(inv.max()) + 1 if inv.size else 0
    lo = np.full((k, 3), np.inf)
    hi = np.full((k, 3), -np.inf)
    np.minimum.at(lo, inv, xyz)
    np.maximum.at(hi, inv, xyz)
    centers = (lo + hi) / 2
    return centers[inv], np.linalg.norm(hi - lo, axis=1)[inv]


def simulate_offsets(
    points: np.ndarray,
    sem: np.ndarray,
    instance: np.ndarray,
    thing_ids: Sequence[int],
    *,
    noise: RegressionNoise | None = None,
    seed: int = 0,
) -> np.ndarray:
    """Simulated point → centre offsets from ground truth.

    Parameters
    ----------
    points : array of shape (n, >=3), float
        Scan points (sensor at the origin).
    sem : array of shape (n,), integer
        Ground-truth semantic train ids.
    instance : array of shape (n,), integer
        Ground-truth instance id per point (0 = none); points are grouped by ``(sem, instance)``.
    thing_ids : sequence of int
        Things train ids.
    noise : RegressionNoise, optional
        Error model (default ``RegressionNoise()``; ``RegressionNoise.zero()`` for exact centres).
    seed : int
        Seed of the random generator.

    Returns
    -------
    ndarray of shape (n, 3), float32
        Offsets; zero on stuff points and on things points with instance 0.
    """
    noise = RegressionNoise() if noise is None else noise
    xyz = np.asarray(points, dtype=np.float64)[:, :3]
    sem = np.asarray(sem).astype(np.int64)
    instance = np.asarray(instance).astype(np.int64)
    offset = np.zeros((len(xyz), 3))
    sel = np.flatnonzero(np.isin(sem, np.asarray(thing_ids)) & (instance > 0))
    if not sel.size:
        return offset.astype(np.float32)
    key = sem[sel] * (1 << 32) + instance[sel]
    center, diagonal = gt_box_centers(xyz[sel], key)
    rng = np.random.default_rng(seed)
    p = xyz[sel]
    radial = np.linalg.norm(center[:, :2], axis=1)
    sigma = noise.base_sigma + noise.size_gain * diagonal + noise.range_gain * radial
    ray = p / np.maximum(np.linalg.norm(p, axis=1, keepdims=True), 1e-9)
    # two unit vectors across the ray
    up = np.where(np.abs(ray[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    across1 = np.cross(ray, up)
    across1 /= np.linalg.norm(across1, axis=1, keepdims=True)
    across2 = np.cross(ray, across1)
    g = rng.standard_normal((len(sel), 3))
    err = sigma[:, None] * (
        g[:, :1] * ray + noise.across_ratio * (g[:, 1:2] * across1 + g[:, 2:3] * across2)
    )
    predicted = center + err
    outlier = rng.random(len(sel)) < noise.outlier_rate
    u = rng.random(len(sel))[:, None]
    predicted[outlier] = p[outlier] + u[outlier] * (center[outlier] - p[outlier])
    offset[sel] = predicted - p
    return offset.astype(np.float32)
