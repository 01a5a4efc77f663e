"""Which points lie in which nuScenes boxes: all boxes of a sweep at once, devkit-exact.

The devkit moves each annotation box to the sensor frame (``NuScenes.get_sample_data``) and tests
every point against it (``geometry_utils.points_in_box``: inclusive bounds, corners from
``Box.corners`` with w along y, l along x). Here all boxes of a sweep are moved to the sensor frame
in one batch and only the points of the grid cells around each box are tested. A point farther
than a tolerance from every face is decided by our arithmetic; a box with any point within the
tolerance of a face is re-tested with the devkit's own ``points_in_box`` on the devkit's box, so
the result equals the devkit's bit for bit, including points exactly on faces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_GRID = 256  # cells per axis of the candidate grid (keys fit in uint16: radix sort)


@dataclass(frozen=True)
class BoxFrames:
    """Annotation boxes of one sweep with the poses that move them to the sensor frame.

    Attributes
    ----------
    translation, size : arrays of shape (n_boxes, 3), float64
        Global centre and (w, l, h) as stored in ``sample_annotation``.
    rotation : array of shape (n_boxes, 4), float64
        Global orientation quaternion (w, x, y, z).
    ego_translation, calib_translation : arrays of shape (3,), float64
    ego_rotation, calib_rotation : arrays of shape (4,), float64
        Ego pose (global frame) and LIDAR_TOP calibration (ego frame).
    """

    translation: np.ndarray
    size: np.ndarray
    rotation: np.ndarray
    ego_translation: np.ndarray
    ego_rotation: np.ndarray
    calib_translation: np.ndarray
    calib_rotation: np.ndarray

    def __len__(self) -> int:
        return len(self.translation)


def _quat_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of shape (..., 3, 3) from quaternions (..., 4) (w, x, y, z), normalised."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def boxes_in_sensor_frame(frames: BoxFrames) -> tuple[np.ndarray, np.ndarray]:
    """Centres (n_boxes, 3) and rotation matrices (n_boxes, 3, 3) of the boxes in the sensor frame."""
    r_ego = _quat_matrix(frames.ego_rotation)
    r_cal = _quat_matrix(frames.calib_rotation)
    to_sensor = r_cal.T @ r_ego.T
    centres = (frames.translation - frames.ego_translation) @ r_ego
    centres = (centres - frames.calib_translation) @ r_cal
    return centres, to_sensor @ _quat_matrix(frames.rotation)


def _devkit_mask(frames: BoxFrames, b: int, points_t: np.ndarray) -> np.ndarray:
    """The devkit's own result for box ``b``: ``get_sample_data`` transforms + ``points_in_box``."""
    from nuscenes.utils.data_classes import Box
    from nuscenes.utils.geometry_utils import points_in_box
    from pyquaternion import Quaternion

    box = Box(
        frames.translation[b].tolist(), frames.size[b].tolist(), Quaternion(frames.rotation[b])
    )
    box.translate(-np.array(frames.ego_translation))
    box.rotate(Quaternion(frames.ego_rotation).inverse)
    box.translate(-np.array(frames.calib_translation))
    box.rotate(Quaternion(frames.calib_rotation).inverse)
    return points_in_box(box, points_t)


def _grid_candidates(
    x: np.ndarray, y: np.ndarray, idx: np.ndarray | None, centres: np.ndarray, radius: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(box, point) pairs whose point lies in the grid cells covering each box's bounding square.

    ``x``, ``y``: float64 coordinates of the finite points, ``idx`` their indices (None: all).
    Pairs come grouped by box.
    """
    if len(x) == 0 or len(centres) == 0:
        return np.empty(0, np.intp), np.empty(0, np.intp)
    lo = np.array([x.min(), y.min()])
    cell = max(max(x.max() - lo[0], y.max() - lo[1]) / _GRID, 1e-3)

    def cell_of(v: np.ndarray, axis: int) -> np.ndarray:
        return np.clip(np.floor((v - lo[axis]) / cell), 0, _GRID - 1).astype(np.intp)

    key = (cell_of(x, 0) * _GRID + cell_of(y, 1)).astype(np.uint16)
    order = np.argsort(key, kind="stable")
    if idx is not None:
        order = idx[order]
    starts = np.concatenate([[0], np.cumsum(np.bincount(key, minlength=_GRID * _GRID))])
    x0, x1 = cell_of(centres[:, 0] - radius, 0), cell_of(centres[:, 0] + radius, 0)
    y0, y1 = cell_of(centres[:, 1] - radius, 1), cell_of(centres[:, 1] + radius, 1)
    rows = x1 - x0 + 1
    row_box = np.repeat(np.arange(len(centres)), rows)
    row_x = x0[row_box] + np.arange(len(row_box)) - np.repeat(np.cumsum(rows) - rows, rows)
    begin = starts[row_x * _GRID + y0[row_box]]
    length = starts[row_x * _GRID + y1[row_box] + 1] - begin
    offsets = np.arange(length.sum()) - np.repeat(np.cumsum(length) - length, length)
    return np.repeat(row_box, length), order[np.repeat(begin, length) + offsets]


def points_in_boxes(
    points: np.ndarray, frames: BoxFrames, tol: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """All (box, point) memberships of one sweep, equal to the devkit's ``points_in_box``.

    Parameters
    ----------
    points : array of shape (n_points, >=3), float32
        The sweep in the LIDAR_TOP frame (as ``LidarPointCloud.from_file`` reads it).
    frames : BoxFrames
        The sweep's boxes, ego pose and calibration.
    tol : float, optional
        Distance (m) from a face under which the devkit itself decides; default
        ``1e-6 * max(1, largest coordinate / 1000)``, far above any rounding difference.

    Returns
    -------
    box_index, point_index : arrays of shape (n_pairs,), intp
        Pairs sorted by box, then by point.
    """
    n_boxes = len(frames)
    if n_boxes == 0 or len(points) == 0:
        return np.empty(0, np.intp), np.empty(0, np.intp)
    cols = [np.ascontiguousarray(points[:, k], dtype=np.float64) for k in range(3)]
    finite = np.isfinite(cols[0]) & np.isfinite(cols[1]) & np.isfinite(cols[2])
    idx = None if finite.all() else np.flatnonzero(finite)
    if idx is not None:
        cols = [col[idx] for col in cols]
    centres, rot = boxes_in_sensor_frame(frames)
    half = np.abs(frames.size[:, [1, 0, 2]]) / 2  # local x: l, y: w, z: h
    if tol is None:
        scale = max([np.abs(frames.translation).max()] + [np.abs(c).max(initial=0.0) for c in cols])
        tol = 1e-6 * max(1.0, scale / 1000.0)
    radius = np.linalg.norm(half, axis=1) + 2 * tol
    bi, pi = _grid_candidates(cols[0], cols[1], idx, centres, radius)
    # candidates come grouped by box: expand per-box values with repeat, not fancy indexing
    per_box = np.bincount(bi, minlength=n_boxes)
    local_pi = pi if idx is None else np.searchsorted(idx, pi)
    d = [cols[k][local_pi] - np.repeat(centres[:, k], per_box) for k in range(3)]
    worst = None
    for j in range(3):  # |local_j| - half_j, local = R^T d (columns of R are the box axes)
        r = [np.repeat(rot[:, i, j], per_box) for i in range(3)]
        e = np.abs(d[0] * r[0] + d[1] * r[1] + d[2] * r[2]) - np.repeat(half[:, j], per_box)
        worst = e if worst is None else np.maximum(worst, e)
    sure_in = worst <= -tol
    unsure = ~sure_in & (worst <= tol)
    exact_boxes = np.unique(bi[unsure])
    keep = sure_in & ~np.isin(bi, exact_boxes)
    bi, pi = bi[keep], pi[keep]
    if len(exact_boxes):
        points_t = points[:, :3].T
        extra = [np.flatnonzero(_devkit_mask(frames, int(b), points_t)) for b in exact_boxes]
        bi = np.concatenate([bi, np.repeat(exact_boxes, [len(e) for e in extra])])
        pi = np.concatenate([pi, *extra])
    order = np.argsort(bi.astype(np.int64) * len(points) + pi)
    return bi[order], pi[order]
