"""Ground levelling: rotate a scan so that its ground plane is horizontal.

Real streets tilt against the sensor (the road's cross slope plus the car's roll: -2.1 to +2.4
degrees across the ten SemanticKITTI training sequences), and a network that reads absolute
heights then sees the high side of the road as a raised sidewalk (session 16, README "Ground
levelling"). :func:`level_points` removes that nuisance before voxelization: it fits a plane to
the lowest point of each 1 m column around the sensor and rotates the scan about the sensor
origin so that the plane's normal points up. A model built with ``level_ground=True`` does this
for every scan it sees, in training and inference alike (:func:`panoptic_bench.dsnet.model.
forward.backbone_forward`), and returns its offsets in the scan's own frame.

Example
-------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> xy = rng.uniform(-20, 20, size=(4000, 2))
>>> ground = np.c_[xy, -1.7 + 0.03 * xy[:, 1]]          # a 1.7 degree cross slope
>>> plane = fit_ground_plane(ground)
>>> round(plane.roll_deg, 2), round(plane.height, 2)
(1.72, -1.7)
>>> flat, rot = level_points(ground)
>>> float(np.ptp(flat[:, 2])) < 1e-3
True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["GroundPlane", "fit_ground_plane", "level_points", "levelling_rotation"]

CELL_M = 1.0  # column size of the lowest-point search (m)
RANGE_M = (3.0, 25.0)  # horizontal distances whose columns are fitted (m)
MIN_COLUMNS = 30  # fewer ground columns than this: no plane, no rotation
MAX_TILT_DEG = 10.0  # a fitted plane steeper than this is not a ground plane: no rotation
TOLERANCES_M = (1.0, 0.5, 0.25, 0.15)  # residual cut of each refit (inliers shrink to the ground)


@dataclass(frozen=True)
class GroundPlane:
    """``z = a x + b y + c`` in the scan's frame (metres)."""

    a: float
    b: float
    c: float
    inliers: int

    @property
    def pitch_deg(self) -> float:
        """Slope along x in degrees (positive: the ground rises ahead)."""
        return float(np.degrees(np.arctan(self.a)))

    @property
    def roll_deg(self) -> float:
        """Slope along y in degrees (positive: the ground rises to the left)."""
        return float(np.degrees(np.arctan(self.b)))

    @property
    def height(self) -> float:
        """Height of the plane under the sensor (m)."""
        return float(self.c)


def _column_minima(xyz: np.ndarray) -> np.ndarray:
    """Lowest point of every ``CELL_M`` column at ``RANGE_M`` distance; shape (m, 3), float64."""
    r = np.hypot(xyz[:, 0], xyz[:, 1])
    pts = xyz[(r >= RANGE_M[0]) & (r <= RANGE_M[1])].astype(np.float64)
    if len(pts) == 0:
        return pts.reshape(0, 3)
    cell = np.floor(pts[:, :2] / CELL_M).astype(np.int64)
    cell -= cell.min(axis=0)
    key = cell[:, 0] * (int(cell[:, 1].max()) + 1) + cell[:, 1]
    order = np.lexsort((pts[:, 2], key))
    k = key[order]
    first = np.r_[True, k[1:] != k[:-1]]
    return pts[order][first]


def fit_ground_plane(xyz: np.ndarray) -> GroundPlane | None:
    """Fit the ground plane of a scan, or None when the scan shows too little ground.

    The lowest point of each 1 m column between 3 and 25 m from the sensor is a ground
    candidate; a least-squares plane is refitted to the candidates within 1.0, 0.5, 0.25 and
    0.15 m of the previous fit (the first fit uses every candidate), which leaves the dominant
    low surface. Deterministic; no random draw.

    Parameters
    ----------
    xyz : ndarray of shape (n, 3), float
        Points in the sensor frame (metres, z up).

    Returns
    -------
    GroundPlane or None
        None when fewer than ``MIN_COLUMNS`` columns support the plane or it is steeper than
        ``MAX_TILT_DEG`` in either direction.
    """
    cand = _column_minima(np.asarray(xyz)[:, :3])
    if len(cand) < MIN_COLUMNS:
        return None
    design = np.c_[cand[:, 0], cand[:, 1], np.ones(len(cand))]
    use = np.ones(len(cand), dtype=bool)
    coef = np.zeros(3)
    for tol in (None, *TOLERANCES_M):
        if tol is not None:
            use = np.abs(cand[:, 2] - design @ coef) < tol
        if use.sum() < MIN_COLUMNS:
            return None
        coef = np.linalg.lstsq(design[use], cand[use, 2], rcond=None)[0]
    plane = GroundPlane(float(coef[0]), float(coef[1]), float(coef[2]), int(use.sum()))
    if max(abs(plane.pitch_deg), abs(plane.roll_deg)) > MAX_TILT_DEG:
        return None
    return plane


def levelling_rotation(plane: GroundPlane | None) -> np.ndarray:
    """Rotation about the origin that turns the plane's upward normal to +z.

    Returns
    -------
    ndarray of shape (3, 3), float64
        ``R`` with ``levelled = xyz @ R.T``; the identity for None. The smallest such rotation
        (about the axis normal to both), so the heading of the scan is kept.
    """
    if plane is None:
        return np.eye(3)
    n = np.array([-plane.a, -plane.b, 1.0])
    n /= np.linalg.norm(n)
    axis = np.cross(n, [0.0, 0.0, 1.0])
    s, c = float(np.linalg.norm(axis)), float(n[2])
    if s < 1e-12:
        return np.eye(3)
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + k + k @ k * ((1.0 - c) / s**2)


def level_points(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Level one scan: ``(xyz @ R.T, R)`` with ``R`` of :func:`levelling_rotation`.

    Parameters
    ----------
    xyz : ndarray of shape (n, 3), float

    Returns
    -------
    levelled : ndarray of shape (n, 3), same dtype as ``xyz`` (a new array)
    rotation : ndarray of shape (3, 3), float64
        A vector ``v`` of the levelled frame is ``v @ R`` in the scan's frame.
    """
    xyz = np.asarray(xyz)
    rot = levelling_rotation(fit_ground_plane(xyz))
    return (xyz @ rot.T).astype(xyz.dtype, copy=False), rot
