"""Geometric primitives of the synthetic world and their vectorised ray intersections.

Every solid of the world is one of three primitives, stored together as a struct of arrays
(:class:`Primitives`):

- ``BOX``: an oriented box (rotation about z only), ``half`` = half extents ``(hx, hy, hz)``;
- ``CYLINDER``: a vertical cylinder, ``half`` = ``(r, r, hz)``;
- ``ELLIPSOID``: an ellipsoid rotated about z, ``half`` = radii ``(rx, ry, rz)``.

The ground is the plane ``z = 0`` and is handled by the ray caster, not here. The intersection
kernels take rays starting at the origin of the frame the primitives are expressed in (the
sensor), one ray direction and one primitive per row, and return the entry distance ``t`` (``inf``
for a miss or when the origin lies inside the primitive).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

__all__ = [
    "BOX",
    "CYLINDER",
    "ELLIPSOID",
    "Primitives",
    "intersect",
    "normals",
]

BOX, CYLINDER, ELLIPSOID = 0, 1, 2

_EPS = 1e-6


@dataclass
class Primitives:
    """A set of primitives (struct of arrays, ``M`` rows).

    Attributes
    ----------
    kind : ndarray of shape (M,), int8
        ``BOX``, ``CYLINDER`` or ``ELLIPSOID``.
    center : ndarray of shape (M, 3), float64
        Centre in the frame of the set (world or object frame), metres.
    half : ndarray of shape (M, 3), float64
        Half extents (box), ``(r, r, half height)`` (cylinder) or radii (ellipsoid).
    yaw : ndarray of shape (M,), float64
        Rotation about z, radians.
    label : ndarray of shape (M,), uint16
        SemanticKITTI raw semantic id of the surface.
    owner : ndarray of shape (M,), int32
        Index of the owning thing in the scene, ``-1`` for stuff.
    reflect : ndarray of shape (M,), float32
        Base reflectivity in ``[0, 1]`` (remission at normal incidence).
    rough : ndarray of shape (M,), float32
        Surface roughness in metres: ray penetration depth of stochastic surfaces (vegetation).
    """

    kind: np.ndarray
    center: np.ndarray
    half: np.ndarray
    yaw: np.ndarray
    label: np.ndarray
    owner: np.ndarray
    reflect: np.ndarray
    rough: np.ndarray

    def __len__(self) -> int:
        return int(self.kind.shape[0])

    @classmethod
    def empty(cls) -> Primitives:
        """A set with no primitive."""
        return cls(
            np.zeros(0, np.int8),
            np.zeros((0, 3)),
            np.zeros((0, 3)),
            np.zeros(0),
            np.zeros(0, np.uint16),
            np.zeros(0, np.int32),
            np.zeros(0, np.float32),
            np.zeros(0, np.float32),
        )

    @classmethod
    def concat(cls, parts: list[Primitives]) -> Primitives:
        """Concatenate several sets (in order)."""
        if not parts:
            return cls.empty()
        return cls(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)))

    def take(self, index: np.ndarray) -> Primitives:
        """The rows ``index`` (boolean mask or integer indices)."""
        return Primitives(*(getattr(self, f.name)[index] for f in fields(self)))

    def placed(self, xy: np.ndarray, yaw: np.ndarray, row_pose: np.ndarray) -> Primitives:
        """Move object-frame primitives into the world.

        Parameters
        ----------
        xy : ndarray of shape (K, 2), float64
            Position of each pose on the ground.
        yaw : ndarray of shape (K,), float64
            Heading of each pose.
        row_pose : ndarray of shape (M,), int
            Which pose moves each primitive.
        """
        c, s = np.cos(yaw[row_pose]), np.sin(yaw[row_pose])
        x, y = self.center[:, 0], self.center[:, 1]
        center = np.stack(
            [c * x - s * y + xy[row_pose, 0], s * x + c * y + xy[row_pose, 1], self.center[:, 2]],
            axis=1,
        )
        return Primitives(
            self.kind,
            center,
            self.half,
            self.yaw + yaw[row_pose],
            self.label,
            self.owner,
            self.reflect,
            self.rough,
        )


def _to_local(d: np.ndarray, center: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ray origin (the frame origin) and direction in each primitive's local frame."""
    c, s = np.cos(yaw), np.sin(yaw)
    o = -center
    ol = np.stack([c * o[:, 0] + s * o[:, 1], -s * o[:, 0] + c * o[:, 1], o[:, 2]], axis=1)
    dl = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]], axis=1)
    return ol, dl


def _box(o: np.ndarray, d: np.ndarray, h: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t1 = (-h - o) * inv
        t2 = (h - o) * inv
    tn = np.nanmax(np.minimum(t1, t2), axis=1)
    tf = np.nanmin(np.maximum(t1, t2), axis=1)
    hit = (tn <= tf) & (tn > _EPS)
    return np.where(hit, tn, np.inf)


def _cylinder(o: np.ndarray, d: np.ndarray, h: np.ndarray) -> np.ndarray:
    r, hz = h[:, 0], h[:, 2]
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = o[:, 0] * d[:, 0] + o[:, 1] * d[:, 1]
    c = o[:, 0] ** 2 + o[:, 1] ** 2 - r**2
    disc = b * b - a * c
    with np.errstate(divide="ignore", invalid="ignore"):
        ts = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
        zs = o[:, 2] + ts * d[:, 2]
        side = np.where((disc > 0) & (ts > _EPS) & (np.abs(zs) <= hz), ts, np.inf)
        cap_z = np.where(o[:, 2] > 0, hz, -hz)
        tc = (cap_z - o[:, 2]) / d[:, 2]
        xc, yc = o[:, 0] + tc * d[:, 0], o[:, 1] + tc * d[:, 1]
        cap = np.where(
            (np.abs(o[:, 2]) > hz) & (tc > _EPS) & (xc * xc + yc * yc <= r * r), tc, np.inf
        )
    return np.minimum(side, cap)


def _ellipsoid(o: np.ndarray, d: np.ndarray, h: np.ndarray) -> np.ndarray:
    os_, ds = o / h, d / h
    a = np.einsum("ij,ij->i", ds, ds)
    b = np.einsum("ij,ij->i", os_, ds)
    c = np.einsum("ij,ij->i", os_, os_) - 1.0
    disc = b * b - a * c
    t = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
    return np.where((disc > 0) & (t > _EPS) & (c > 0), t, np.inf)


_KERNELS = {BOX: _box, CYLINDER: _cylinder, ELLIPSOID: _ellipsoid}


def intersect(prims: Primitives, rows: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Entry distance of rays from the origin into primitives, one pair per row.

    Parameters
    ----------
    prims : Primitives
        Primitives expressed in the ray frame (rays start at its origin).
    rows : ndarray of shape (P,), int
        Primitive index of each pair.
    dirs : ndarray of shape (P, 3), float64
        Unit ray direction of each pair.

    Returns
    -------
    ndarray of shape (P,), float64
        Distance along the ray to the first surface hit, ``inf`` for a miss.
    """
    t = np.full(rows.shape[0], np.inf)
    kinds = prims.kind[rows]
    for kind, kernel in _KERNELS.items():
        sel = np.flatnonzero(kinds == kind)
        if sel.size == 0:
            continue
        r = rows[sel]
        o, d = _to_local(dirs[sel], prims.center[r], prims.yaw[r])
        t[sel] = kernel(o, d, prims.half[r])
    return t


def normals(prims: Primitives, rows: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Outward unit surface normals at points lying on primitives.

    Parameters
    ----------
    prims : Primitives
        Primitives in the frame of ``points``.
    rows : ndarray of shape (N,), int
        Primitive hit by each point.
    points : ndarray of shape (N, 3), float64
        Points on the primitives' surfaces.

    Returns
    -------
    ndarray of shape (N, 3), float64
    """
    center, half, yaw = prims.center[rows], prims.half[rows], prims.yaw[rows]
    c, s = np.cos(yaw), np.sin(yaw)
    p = points - center
    lx, ly = c * p[:, 0] + s * p[:, 1], -s * p[:, 0] + c * p[:, 1]
    local = np.stack([lx, ly, p[:, 2]], axis=1)
    kind = prims.kind[rows]
    n = np.zeros_like(local)
    box = kind == BOX
    if box.any():
        q = np.abs(local[box]) / half[box]
        axis = np.argmax(q, axis=1)
        nb = np.zeros((axis.size, 3))
        nb[np.arange(axis.size), axis] = np.sign(local[box][np.arange(axis.size), axis])
        n[box] = nb
    cyl = kind == CYLINDER
    if cyl.any():
        lc, hc = local[cyl], half[cyl]
        top = np.abs(lc[:, 2]) >= hc[:, 2] - 1e-6
        nc = np.stack([lc[:, 0], lc[:, 1], np.zeros(lc.shape[0])], axis=1)
        nc[top] = np.stack([np.zeros(top.sum()), np.zeros(top.sum()), np.sign(lc[top, 2])], axis=1)
        n[cyl] = nc
    ell = kind == ELLIPSOID
    if ell.any():
        n[ell] = local[ell] / half[ell] ** 2
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return np.stack([c * n[:, 0] - s * n[:, 1], s * n[:, 0] + c * n[:, 1], n[:, 2]], axis=1)
