"""Scene mixing of two labelled scans (PolarMix-style), for training on few real scans.

Two operations on :class:`~panoptic_bench.dsnet.data.datasets.LidarSample` pairs, both in the
sensor frame (before the usual augmentation), both deterministic for a given generator:

* :func:`swap_sector` — the points of scan ``a`` inside an azimuth sector are replaced by the
  points of scan ``b`` in the same sector (PolarMix's scene-level swap). A street seen from one
  place is joined with another street at the same range and ring pattern, so a network sees new
  layouts without any point leaving the sensor's geometry.
* :func:`paste_instances` — every thing instance of ``b`` is copied into ``a`` rotated about the
  sensor's vertical axis (PolarMix's instance-level rotate-pasting): range, height and ring
  pattern of each copy stay those of a real return.

Instance ids stay unique in the mixed scan: the ids of ``b`` (and of each pasted copy) are
offset past the largest id already present; stuff points keep id 0.
"""

from __future__ import annotations

import math

import numpy as np

from panoptic_bench.dsnet.data.bank import rotate_z

__all__ = ["azimuth_in_sector", "mix_pair", "paste_instances", "swap_sector"]


def azimuth_in_sector(xyz: np.ndarray, start: float, width: float) -> np.ndarray:
    """Boolean mask of the points whose azimuth lies in ``[start, start + width)`` (radians).

    Parameters
    ----------
    xyz : ndarray of shape (n, 3), float
    start : float
        Sector start, any real number (taken modulo 2 pi).
    width : float
        Sector width in [0, 2 pi].

    Returns
    -------
    ndarray of shape (n,), bool
    """
    phi = np.arctan2(xyz[:, 1], xyz[:, 0])
    return np.mod(phi - start, 2 * math.pi) < width


def _concat(parts, key):
    from panoptic_bench.dsnet.data.datasets import LidarSample

    return LidarSample(
        xyz=np.concatenate([p[0] for p in parts]).astype(np.float32, copy=False),
        remission=np.concatenate([p[1] for p in parts]).astype(np.float32, copy=False),
        sem=np.concatenate([p[2] for p in parts]).astype(np.int64, copy=False),
        inst=np.concatenate([p[3] for p in parts]).astype(np.int64, copy=False),
        key=key,
    )


def _offset_ids(inst: np.ndarray, offset: int) -> np.ndarray:
    return np.where(inst > 0, inst + offset, 0)


def swap_sector(a, b, start: float, width: float):
    """Scan ``a`` with its points in the azimuth sector replaced by the points of ``b`` there.

    Parameters
    ----------
    a, b : LidarSample
        Labelled scans in their sensor frames.
    start, width : float
        Sector in radians (see :func:`azimuth_in_sector`).

    Returns
    -------
    LidarSample
        Key of ``a``; ids of ``b`` offset past the largest id of ``a``.
    """
    keep_a = ~azimuth_in_sector(a.xyz, start, width)
    take_b = azimuth_in_sector(b.xyz, start, width)
    offset = int(a.inst.max(initial=0))
    return _concat(
        [
            (a.xyz[keep_a], a.remission[keep_a], a.sem[keep_a], a.inst[keep_a]),
            (
                b.xyz[take_b],
                b.remission[take_b],
                b.sem[take_b],
                _offset_ids(b.inst[take_b], offset),
            ),
        ],
        a.key,
    )


def paste_instances(a, b, angles: np.ndarray):
    """Scan ``a`` plus every thing instance of ``b`` rotated about z by each angle.

    Parameters
    ----------
    a, b : LidarSample
    angles : ndarray of shape (k,), float
        Rotation angles (radians); each gives one copy of every instance of ``b``.

    Returns
    -------
    LidarSample
        ``a`` followed by the copies (key of ``a``); every copy gets new instance ids.
    """
    things = b.inst > 0
    parts = [(a.xyz, a.remission, a.sem, a.inst)]
    if not things.any() or len(angles) == 0:
        return _concat(parts, a.key)
    xyz, rem, sem, inst = b.xyz[things], b.remission[things], b.sem[things], b.inst[things]
    span = int(inst.max())
    offset = int(a.inst.max(initial=0))
    for angle in angles:
        parts.append((rotate_z(xyz, float(angle)), rem, sem, _offset_ids(inst, offset)))
        offset += span
    return _concat(parts, a.key)


def mix_pair(
    a,
    b,
    rng: np.random.Generator,
    sector_deg: tuple[float, float] = (90.0, 180.0),
    paste_copies: int = 0,
):
    """One PolarMix draw: swap a random sector of ``a`` with ``b``, then paste ``b``'s things.

    The sector starts at U[0, 360) degrees and is U[sector_deg] wide; ``paste_copies`` rotated
    copies of every thing instance of ``b`` at angles U[0, 360) degrees (none when 0).

    Returns
    -------
    LidarSample
    """
    start = rng.uniform(0.0, 2 * math.pi)
    width = math.radians(rng.uniform(*sector_deg))
    mixed = swap_sector(a, b, start, width)
    if paste_copies > 0:
        mixed = paste_instances(mixed, b, rng.uniform(0.0, 2 * math.pi, paste_copies))
    return mixed
