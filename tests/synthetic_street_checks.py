"""Shared checks of the world-key tests: profile files that add one key to a world, sweeps compared
ray by ray, and raised boxes turned into painted ground."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from panoptic_bench.datasets.synthetic.profile_files import load_profile

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
#: The three worlds every realism row since 18a mixes street by street.
WORLDS = ("low_crowns_low_fences", "low_fences_tight_materials", "low_fences_raised_lots")


def profile_changes(new: str, base: str) -> dict:
    """Keys (other than ``name``, which must differ) in which ``configs/<new>.yaml`` differs
    from ``configs/<base>.yaml``, with the new values (tuples as tuples)."""
    a, b = load_profile(str(CONFIGS / f"{new}.yaml")), load_profile(str(CONFIGS / f"{base}.yaml"))
    assert a.name != b.name
    da, db = a.to_dict(), b.to_dict()
    return {k: getattr(a, k) for k in da if k != "name" and da[k] != db[k]}


def by_beam(sweep) -> dict[int, int]:
    """Index of each return of ``sweep`` by its beam (ring, column)."""
    return {int(k): i for i, k in enumerate(sweep.ring.astype(np.int64) * 100_000 + sweep.column)}


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
