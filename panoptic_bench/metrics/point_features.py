"""Per-point quantities of a LiDAR scan for error breakdowns (``eval breakdown``).

Pure functions of the points (and, for the road plane, of a mask of road points):

- ``range``: distance from the sensor (m), :func:`~panoptic_bench.metrics.by_range.point_range`, as
  ``eval semantickitti --by-range`` bins it.
- ``height``: height above the scan's road plane (m), a least-squares plane ``z = a + b x + c y``
  fitted to the true road points less than ``plane_range`` metres away horizontally.
- ``roughness``: ``|z - (z_prev + z_next) / 2|`` (m) over the point's neighbours in recording
  order (the same laser ring) when both lie within 0.5 m horizontally: the second difference of
  height along the ring, what ``synth stats`` summarises as ground jitter.
- ``remission``: the recorded remission.

A point without a value (no neighbours close enough, too few road points for the plane) is NaN.
"""

from __future__ import annotations

import numpy as np

from panoptic_bench.metrics.by_range import point_range

__all__ = ["FEATURES", "DEFAULT_EDGES", "height_above_plane", "point_feature", "ring_roughness"]

#: bin edges used when none are given, per feature
DEFAULT_EDGES: dict[str, tuple[float, ...]] = {
    "range": (0.0, 5.0, 10.0, 15.0, 20.0, 30.0, 40.0, 50.0, 80.0),
    "height": (-1.0, -0.3, -0.1, -0.05, 0.05, 0.15, 0.3, 0.5, 1.0, 2.0, 5.0),
    "roughness": (0.0, 0.002, 0.004, 0.008, 0.016, 0.03, 0.06, 1.0),
    "remission": (0.0, 0.01, 0.1, 0.2, 0.3, 0.4, 0.5, 1.01),
}
FEATURES: tuple[str, ...] = tuple(DEFAULT_EDGES)

#: neighbours further apart than this (m, horizontally) do not give a roughness
RING_STEP = 0.5


def ring_roughness(points: np.ndarray, max_step: float = RING_STEP) -> np.ndarray:
    """Second difference of height along the recording order.

    Parameters
    ----------
    points : array of shape (n, >=3)
        ``x, y, z`` in recording order (a SemanticKITTI ``.bin`` lists each ring's points in turn).
    max_step : float
        Largest horizontal distance (m) to each neighbour.

    Returns
    -------
    numpy.ndarray of shape (n,), float64
        ``|z_i - (z_{i-1} + z_{i+1}) / 2|``; NaN for the first and last point and where a
        neighbour is further than ``max_step``.
    """
    p = np.asarray(points, dtype=np.float64)
    out = np.full(len(p), np.nan)
    if len(p) < 3:
        return out
    step = np.hypot(np.diff(p[:, 0]), np.diff(p[:, 1])) <= max_step
    ok = step[:-1] & step[1:]
    z = p[:, 2]
    d = np.abs(z[1:-1] - (z[:-2] + z[2:]) / 2)
    out[1:-1] = np.where(ok, d, np.nan)
    return out


def height_above_plane(
    points: np.ndarray, road: np.ndarray, plane_range: float = 20.0, min_points: int = 200
) -> np.ndarray:
    """Height of every point above a plane fitted to the road points.

    Parameters
    ----------
    points : array of shape (n, >=3)
    road : array of shape (n,), bool
        The road points (e.g. true class road).
    plane_range : float
        Only road points less than this far horizontally (m) fit the plane.
    min_points : int
        With fewer fitting points every height is NaN.

    Returns
    -------
    numpy.ndarray of shape (n,), float64
    """
    p = np.asarray(points, dtype=np.float64)
    road = np.asarray(road, dtype=bool)
    if road.shape != (len(p),):
        raise ValueError(f"road mask {road.shape} must be ({len(p)},)")
    fit = road & (np.hypot(p[:, 0], p[:, 1]) < plane_range)
    if fit.sum() < max(3, min_points):
        return np.full(len(p), np.nan)
    design = np.c_[np.ones(fit.sum()), p[fit, 0], p[fit, 1]]
    coef = np.linalg.lstsq(design, p[fit, 2], rcond=None)[0]
    return p[:, 2] - (coef[0] + coef[1] * p[:, 0] + coef[2] * p[:, 1])


def point_feature(name: str, points: np.ndarray, road: np.ndarray | None = None) -> np.ndarray:
    """The per-point quantity ``name`` (one of :data:`FEATURES`), shape (n,), float64.

    ``road`` (bool, shape (n,)) is needed for ``height`` only.
    """
    p = np.asarray(points)
    if name == "range":
        return point_range(p)
    if name == "height":
        if road is None:
            raise ValueError("height needs the road points")
        return height_above_plane(p, road)
    if name == "roughness":
        return ring_roughness(p)
    if name == "remission":
        return p[:, 3].astype(np.float64)
    raise ValueError(f"unknown feature {name!r}; choose one of {list(FEATURES)}")
