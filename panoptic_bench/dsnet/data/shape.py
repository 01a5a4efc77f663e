"""Local shape features: how linear, planar, scattered and vertical the surface around a point is.

The held-out errors of the real-data models are mostly between vertical surfaces — fence called
vegetation, building called vegetation and the reverse — which differ less in height or remission
than in the *shape* of the surface: a wall or a fence panel is a vertical plane, a bush scatters in
every direction, a pole is a vertical line. :func:`shape_features` hands the network the classic
covariance descriptors (Weinmann et al., ISPRS 2015) of the points in each point's ``cell`` m cube:
with the eigenvalues ``l1 >= l2 >= l3`` of their 3 x 3 covariance,

- linearity ``(l1 - l2) / l1``, planarity ``(l2 - l3) / l1``, scattering ``l3 / l1``;
- verticality ``1 - |n_z|``, ``n`` the eigenvector of ``l3`` (the surface normal): 1 on a wall,
  0 on the ground.

A cube with fewer than ``min_points`` points gets zeros. The covariance of a uniform random subset
of a cube's points is an unbiased estimate of the cube's, but its noise grows as points are
dropped, so a model trained on thinned scans (``augment.max_points``) would see noisier features
than it is given on a full scan. ``max_points`` removes that mismatch (the one point-density policy
of :mod:`panoptic_bench.dsnet.data.density`): the cubes are measured on a random subset of at most
``max_points`` points (:func:`~panoptic_bench.dsnet.data.density.thin_indices`, the training
scans' own subset rule, from a stream seeded by the scan's size), and every point takes the
features of its cube (zeros where no kept point fell in it). Without ``max_points`` the features
do not depend on the point order; they hardly change under rotations about the vertical axis
(only the cube boundaries move). A model built with ``model.shape_features: true`` computes them for every scan it sees
(:func:`panoptic_bench.dsnet.model.forward.backbone_forward`) in the frame it voxelizes (levelled
when ``model.level_ground`` is on) and appends them to its 9 point features.

Example
-------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> wall = np.c_[rng.uniform(0, 4, 4000), rng.normal(0, 0.01, 4000), rng.uniform(0, 2, 4000)]
>>> f = shape_features(wall)
>>> f.shape, bool(np.median(f[:, 1]) > 0.5), bool(np.median(f[:, 3]) > 0.95)
((4000, 4), True, True)
"""

from __future__ import annotations

import numpy as np

from panoptic_bench.dsnet.data.density import thin_indices

__all__ = ["N_SHAPE_FEATURES", "SHAPE_FEATURE_NAMES", "shape_features"]

SHAPE_FEATURE_NAMES = ("linearity", "planarity", "scattering", "verticality")
N_SHAPE_FEATURES = len(SHAPE_FEATURE_NAMES)
CELL_M = 0.5  # cube size (m)
MIN_POINTS = 4  # fewer points in a cube: no shape (zeros)


def shape_features(
    xyz: np.ndarray, cell: float = CELL_M, max_points: int = 0, min_points: int = MIN_POINTS
) -> np.ndarray:
    """Linearity, planarity, scattering and verticality of the points in each point's cube.

    Parameters
    ----------
    xyz : np.ndarray of shape (n, 3), float
        Points in metres; z up.
    cell : float
        Cube size (m).
    max_points : int
        Measure the cubes on a random subset of this many points (0: every point); see the
        module docstring.
    min_points : int
        Cubes with fewer (measured) points get zeros.

    Returns
    -------
    np.ndarray of shape (n, 4), float32
        Columns in :data:`SHAPE_FEATURE_NAMES` order, each in [0, 1].
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"xyz must have shape (n, 3), got {xyz.shape}")
    if cell <= 0 or max_points < 0 or min_points < 2:
        raise ValueError(
            f"need cell > 0, max_points >= 0, min_points >= 2; got {cell}, "
            f"{max_points}, {min_points}"
        )
    n = len(xyz)
    if n == 0:
        return np.zeros((0, N_SHAPE_FEATURES), dtype=np.float32)
    keys = np.floor(xyz / cell).astype(np.int64)
    uniq, cube = np.unique(keys, axis=0, return_inverse=True)
    cube = cube.reshape(-1)
    m = len(uniq)
    kept = thin_indices(n, max_points, np.random.default_rng(n))  # the training subset rule
    if kept is None:
        kept = np.arange(n)
    local = xyz[kept] - (keys[kept] + 0.5) * cell  # small numbers: stable second moments
    c = cube[kept]
    counts = np.bincount(c, minlength=m).astype(np.float64)
    safe_n = np.maximum(counts, 1.0)
    mean = np.stack([np.bincount(c, local[:, i], m) for i in range(3)], axis=1) / safe_n[:, None]
    cov = np.empty((m, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            moment = np.bincount(c, local[:, i] * local[:, j], m) / safe_n
            cov[:, i, j] = cov[:, j, i] = moment - mean[:, i] * mean[:, j]
    vals, vecs = np.linalg.eigh(cov)  # ascending: l3, l2, l1
    l3, l2, l1 = (np.maximum(vals[:, i], 0.0) for i in range(3))
    safe = np.where(l1 > 0, l1, 1.0)
    feats = np.stack(
        [(l1 - l2) / safe, (l2 - l3) / safe, l3 / safe, 1.0 - np.abs(vecs[:, 2, 0])], axis=1
    )
    feats[(counts < min_points) | (l1 <= 0)] = 0.0
    return np.clip(feats, 0.0, 1.0).astype(np.float32)[cube]
