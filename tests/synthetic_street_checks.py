"""Shared checks of the world-key tests that turn raised boxes into painted ground."""

from __future__ import annotations

import numpy as np


def check_boxes_painted(
    raised, flat, gm_flat, label: int, heights: tuple[float, float]
) -> np.ndarray:
    """Assert that ``flat`` is ``raised`` without its boxes of ``label``, painted on the ground.

    Every other primitive is still there, in order, with its place (x, y), size and label; what
    stood on such a box stands lower by that box's height, within ``heights`` (m); the boxes'
    footprints carry ``label`` in ``gm_flat``. Returns the mask of the boxes in ``raised``.
    """
    boxes = raised.label == label
    assert boxes.sum() >= 4 and not (flat.label == label).any()
    np.testing.assert_array_equal(flat.center[:, :2], raised.center[~boxes, :2])
    np.testing.assert_array_equal(flat.half, raised.half[~boxes])
    np.testing.assert_array_equal(flat.label, raised.label[~boxes])
    dz = raised.center[~boxes, 2] - flat.center[:, 2]
    lo, hi = heights
    assert np.all((np.abs(dz) < 1e-9) | ((dz >= lo - 1e-9) & (dz <= hi + 1e-9)))
    assert (dz > 0.05).any()
    xy = raised.center[boxes, :2]
    painted, _ = gm_flat.lookup(xy[:, 0], xy[:, 1])
    assert np.all(painted == label)
    return boxes
