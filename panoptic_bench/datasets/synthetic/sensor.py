"""Spinning LiDAR models (HDL-64E as in KITTI, HDL-32E as in nuScenes) and one sweep of a scene.

A sweep casts a grid of beams x azimuth columns from the sensor (see
:mod:`~panoptic_bench.datasets.synthetic.raycast`), then applies the sensor's imperfections:
range noise (about 2 cm), penetration into stochastic surfaces (vegetation), random dropout
(more likely for far, dark returns), and a remission that depends on the material and on the
angle of incidence.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from panoptic_bench.datasets.synthetic.raycast import GROUND, cast, ray_directions
from panoptic_bench.datasets.synthetic.scene import Scene
from panoptic_bench.datasets.synthetic.shapes import Primitives, normals

__all__ = ["HDL32E", "HDL64E", "LidarModel", "Sweep", "sensor_frame", "sweep"]


@dataclass(frozen=True)
class LidarModel:
    """A spinning multi-beam LiDAR.

    Attributes
    ----------
    name : str
    elevation_deg : tuple of float
        Beam elevations in degrees, ascending (ring 0 = lowest beam).
    n_azimuth : int
        Firings per revolution (azimuth columns).
    mount_height : float
        Sensor height above the ground, metres.
    max_range, min_range : float
        Returns outside ``[min_range, max_range]`` are dropped, metres.
    range_noise : float
        Standard deviation of the range noise, metres.
    dropout : float
        Probability that a return is lost (before the range/darkness term).
    """

    name: str
    elevation_deg: tuple[float, ...]
    n_azimuth: int
    mount_height: float
    max_range: float = 120.0
    min_range: float = 2.5
    range_noise: float = 0.02
    dropout: float = 0.02

    @property
    def n_beams(self) -> int:
        """Number of beams."""
        return len(self.elevation_deg)


#: HDL-64E as mounted on the KITTI car: 64 beams from +2 deg to -24.8 deg (denser upper block).
HDL64E = LidarModel(
    name="HDL-64E",
    elevation_deg=tuple(
        sorted(
            np.concatenate([np.linspace(2.0, -8.33, 32), np.linspace(-8.83, -24.8, 32)]).tolist()
        )
    ),
    n_azimuth=2048,
    mount_height=1.73,
)

#: HDL-32E as on the nuScenes car: 32 beams from +10.67 deg to -30.67 deg, 1084 firings.
HDL32E = LidarModel(
    name="HDL-32E",
    elevation_deg=tuple(np.linspace(-30.67, 10.67, 32).tolist()),
    n_azimuth=1084,
    mount_height=1.84,
    max_range=100.0,
    min_range=1.0,
)


@dataclass(frozen=True)
class Sweep:
    """The returns of one sweep, in the sensor frame (x forward, y left, z up).

    Attributes
    ----------
    xyz : ndarray of shape (N, 3), float32
    remission : ndarray of shape (N,), float32
        In ``[0, 1]``.
    ring : ndarray of shape (N,), uint8
        Beam index, 0 = lowest.
    column : ndarray of shape (N,), int32
        Azimuth firing index.
    label : ndarray of shape (N,), uint16
        Raw SemanticKITTI id.
    instance : ndarray of shape (N,), uint32
        Instance id (``thing index + 1``), 0 for stuff.
    """

    xyz: np.ndarray
    remission: np.ndarray
    ring: np.ndarray
    column: np.ndarray
    label: np.ndarray
    instance: np.ndarray

    def __len__(self) -> int:
        return int(self.xyz.shape[0])


def sensor_frame(
    scene: Scene, time: float, offset: tuple[float, float], height: float
) -> tuple[Primitives, float, float, float, float]:
    """The scene's primitives in the level sensor frame at ``time``.

    Returns
    -------
    local : Primitives
        Every primitive, sensor at the origin (x forward, y left, z up), ground at ``-height``.
    sx, sy : float
        Sensor position in the world.
    c, s : float
        Cosine and sine of the ego heading.
    """
    ex, ey, eyaw = scene.ego_pose(time)
    c, s = np.cos(eyaw), np.sin(eyaw)
    sx = ex + c * offset[0] - s * offset[1]
    sy = ey + s * offset[0] + c * offset[1]
    world = scene.primitives_at(time)
    local = world.take(slice(None))
    dx, dy = world.center[:, 0] - sx, world.center[:, 1] - sy
    local.center = np.stack(
        [c * dx + s * dy, -s * dx + c * dy, world.center[:, 2] - height], axis=1
    )
    local.yaw = world.yaw - eyaw
    return local, sx, sy, c, s


def sweep(
    scene: Scene,
    time: float,
    model: LidarModel,
    rng: np.random.Generator,
    sensor_xy_offset: tuple[float, float] = (0.0, 0.0),
) -> Sweep:
    """Simulate one sweep of ``model`` mounted on the ego vehicle at ``time``.

    Parameters
    ----------
    scene : Scene
    time : float
        Seconds since the start of the sequence (the whole sweep is taken at this instant).
    model : LidarModel
    rng : numpy.random.Generator
        Noise source (azimuth jitter, range noise, dropout, remission noise).
    sensor_xy_offset : tuple of float
        Sensor position in the ego frame (forward, left), metres.

    Returns
    -------
    Sweep
        Returns ordered ring by ring (lowest ring first), each ring by azimuth.
    """
    local, sx, sy, c, s = sensor_frame(scene, time, sensor_xy_offset, model.mount_height)
    elevation = np.radians(np.asarray(model.elevation_deg))
    n_c = model.n_azimuth
    step = 2 * np.pi / n_c
    azimuth = -np.pi + (np.arange(n_c) + 0.5) * step + rng.uniform(-0.1, 0.1) * step
    hits = cast(local, elevation, azimuth, -model.mount_height, model.max_range)

    dirs = ray_directions(elevation, azimuth)
    idx = np.flatnonzero(np.isfinite(hits.t))
    prim = hits.prim[idx]
    t = hits.t[idx]
    on_ground = prim == GROUND
    obj = np.flatnonzero(~on_ground)
    # surface normals and material, before noise moves the point off the surface
    pts = dirs[idx] * t[:, None]
    nrm = np.zeros_like(pts)
    nrm[on_ground, 2] = 1.0
    nrm[obj] = normals(local, prim[obj], pts[obj])
    label = np.zeros(idx.size, np.uint16)
    reflect = np.zeros(idx.size, np.float32)
    instance = np.zeros(idx.size, np.uint32)
    rough = np.zeros(idx.size, np.float32)
    wx = sx + c * pts[on_ground, 0] - s * pts[on_ground, 1]
    wy = sy + s * pts[on_ground, 0] + c * pts[on_ground, 1]
    label[on_ground], reflect[on_ground] = scene.ground.lookup(wx, wy)
    p = prim[obj]
    label[obj] = local.label[p]
    reflect[obj] = local.reflect[p]
    rough[obj] = local.rough[p]
    owner = local.owner[p]
    instance[obj] = np.where(owner >= 0, owner + 1, 0).astype(np.uint32)

    cos_inc = np.abs(np.einsum("ij,ij->i", nrm, dirs[idx]))
    remission = reflect * (0.7 + 0.3 * cos_inc) * rng.normal(1.0, 0.08, idx.size)
    remission = np.clip(remission, 0.0, 0.99).astype(np.float32)

    t = (
        t
        + rough * rng.exponential(1.0, idx.size)
        + np.clip(
            rng.normal(0.0, model.range_noise, idx.size),
            -2.5 * model.range_noise,
            2.5 * model.range_noise,
        )
    )
    p_drop = model.dropout + 0.4 * np.clip(t / model.max_range, 0, 1) ** 2 * (remission < 0.1)
    keep = (rng.random(idx.size) >= p_drop) & (t >= model.min_range) & (t <= model.max_range)
    xyz = (dirs[idx] * t[:, None])[keep].astype(np.float32)
    ring, column = np.divmod(idx[keep], n_c)
    return Sweep(
        xyz,
        remission[keep],
        ring.astype(np.uint8),
        column.astype(np.int32),
        label[keep],
        instance[keep],
    )
