"""Vectorised ray casting of a spinning LiDAR against primitives and the ground plane.

The rays of one sweep form a grid of ``B`` beams (elevations) by ``C`` azimuth columns. Each
primitive is culled to the angular window its bounding cylinder can cover (a range of columns
and a range of beams, computed in closed form), so only the (ray, primitive) pairs inside that
window are intersected. All pairs are generated and intersected with numpy in one go; the
nearest hit per ray is a ``minimum.at`` reduction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from panoptic_bench.datasets.synthetic.shapes import BOX, ELLIPSOID, Primitives, intersect

__all__ = ["GROUND", "MISS", "RayHits", "cast", "ray_directions"]

GROUND = -2
MISS = -1


@dataclass(frozen=True)
class RayHits:
    """Nearest surface of every ray of a sweep.

    Attributes
    ----------
    t : ndarray of shape (B * C,), float64
        Range to the nearest surface, ``inf`` where nothing was hit. Ray ``b * C + c`` is beam
        ``b`` (ascending elevation order), column ``c``.
    prim : ndarray of shape (B * C,), int64
        Index of the primitive hit, :data:`GROUND` for the ground plane, :data:`MISS` for none.
    """

    t: np.ndarray
    prim: np.ndarray


def ray_directions(elevation: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    """Unit directions of the ray grid.

    Parameters
    ----------
    elevation : ndarray of shape (B,), float64
        Beam elevations in radians, ascending.
    azimuth : ndarray of shape (C,), float64
        Column azimuths in radians, ascending in ``[-pi, pi)``.

    Returns
    -------
    ndarray of shape (B * C, 3), float64
    """
    ce, se = np.cos(elevation)[:, None], np.sin(elevation)[:, None]
    ca, sa = np.cos(azimuth)[None, :], np.sin(azimuth)[None, :]
    d = np.stack([ce * ca, ce * sa, np.broadcast_to(se, (elevation.size, azimuth.size))], axis=-1)
    return d.reshape(-1, 3)


def _windows(
    prims: Primitives, elevation: np.ndarray, n_col: int, max_range: float, margin: float = 0.0
) -> tuple[np.ndarray, ...]:
    """Angular window of each primitive: first column, column count, first beam, beam count.

    ``margin`` (radians) widens every window on all sides (rays of a tilted sensor).
    """
    cx, cy = prims.center[:, 0], prims.center[:, 1]
    h = prims.half
    r_xy = np.where(
        prims.kind == BOX,
        np.hypot(h[:, 0], h[:, 1]),
        np.where(prims.kind == ELLIPSOID, np.maximum(h[:, 0], h[:, 1]), h[:, 0]),
    )
    d_xy = np.hypot(cx, cy)
    zmin, zmax = prims.center[:, 2] - h[:, 2], prims.center[:, 2] + h[:, 2]
    inside = d_xy <= r_xy + 1e-3
    half_w = np.where(inside, np.pi, np.arcsin(np.clip(r_xy / np.maximum(d_xy, 1e-9), 0.0, 1.0)))
    if margin:
        half_w = np.minimum(half_w + margin, np.pi)
    az = np.arctan2(cy, cx)
    step = 2.0 * np.pi / n_col
    c0 = np.floor((az - half_w + np.pi) / step).astype(np.int64)
    c1 = np.floor((az + half_w + np.pi) / step).astype(np.int64) + 1
    n_c = np.where(inside, n_col, np.minimum(c1 - c0 + 1, n_col))
    c0 = np.where(inside, 0, c0 % n_col)
    d_min = np.maximum(d_xy - r_xy, 0.05)
    d_max = d_xy + r_xy
    e_hi = np.arctan2(zmax, np.where(zmax > 0, d_min, d_max))
    e_lo = np.arctan2(zmin, np.where(zmin < 0, d_min, d_max))
    if margin:
        e_hi, e_lo = e_hi + margin, e_lo - margin
    b0 = np.searchsorted(elevation, e_lo - 1e-6, side="left")
    b1 = np.searchsorted(elevation, e_hi + 1e-6, side="right")
    n_b = b1 - b0
    n_b[d_xy - r_xy > max_range] = 0
    return c0, n_c, b0, n_b


def cast(
    prims: Primitives,
    elevation: np.ndarray,
    azimuth: np.ndarray,
    ground_z: float,
    max_range: float,
    rotation: np.ndarray | None = None,
) -> RayHits:
    """Cast every ray of one sweep from the origin.

    Parameters
    ----------
    prims : Primitives
        The world expressed in the sensor frame (sensor at the origin, z up).
    elevation : ndarray of shape (B,), float64
        Beam elevations in radians, ascending.
    azimuth : ndarray of shape (C,), float64
        Column azimuths in radians, evenly spaced over ``[-pi, pi)`` (column ``c`` centred at
        ``-pi + (c + 0.5) * 2 pi / C`` up to a small jitter).
    ground_z : float
        Height of the ground plane in the sensor frame (negative).
    max_range : float
        Returns beyond this range are dropped.
    rotation : ndarray of shape (3, 3), float64, optional
        Sensor-to-level rotation of a tilted sensor (small angles): the ray grid is defined in
        the sensor frame and rotated by it; the windows are widened by the tilt angle.

    Returns
    -------
    RayHits
    """
    n_b, n_c = elevation.size, azimuth.size
    dirs = ray_directions(elevation, azimuth)
    margin = 0.0
    if rotation is not None:
        dirs = dirs @ np.asarray(rotation).T
        tilt = float(np.arccos(np.clip(np.asarray(rotation)[2, 2], -1.0, 1.0)))
        margin = tilt * 1.5 + 2.0 * np.pi / n_c
    t_best = np.full(n_b * n_c, np.inf)
    prim = np.full(n_b * n_c, MISS, dtype=np.int64)
    with np.errstate(divide="ignore"):
        t_ground = np.where(dirs[:, 2] < 0, ground_z / dirs[:, 2], np.inf)
    if len(prims):
        c0, nc, b0, nb = _windows(prims, elevation, n_c, max_range, margin)
        keep = np.flatnonzero(nb * nc > 0)
        counts = (nb * nc)[keep]
        rows = np.repeat(keep, counts)
        start = np.cumsum(counts) - counts
        local = np.arange(rows.size) - np.repeat(start, counts)
        nb_r = nb[rows]
        col = (c0[rows] + local // nb_r) % n_c
        ray = (b0[rows] + local % nb_r) * n_c + col
        t = intersect(prims, rows, dirs[ray])
        hit = np.flatnonzero((t < max_range) & (t < t_ground[ray]))
        ray, rows, t = ray[hit], rows[hit], t[hit]
        np.minimum.at(t_best, ray, t)
        win = t == t_best[ray]
        prim[ray[win]] = rows[win]
    ground = (t_ground < t_best) & (t_ground < max_range)
    t_best[ground] = t_ground[ground]
    prim[ground] = GROUND
    t_best[prim == MISS] = np.inf
    return RayHits(t_best, prim)
