"""Driving sequences: the ego vehicle drives along a generated street and the LiDAR sweeps it.

One sequence is one :class:`~panoptic_bench.datasets.synthetic.scene.Scene`, so instance ids
(``thing index + 1``) are stable along the sequence and unique in it. Everything is a pure
function of ``(seed, key)``: the scene from ``default_rng([seed, key])``, the sensor noise of
frame ``i`` from ``default_rng([seed, key, i, 1])``, and with a realistic sensor
(:mod:`~panoptic_bench.datasets.synthetic.sensor_real`) its per-sequence pose and materials
from ``default_rng([seed, key, 2])``, and the per-street draws of the world profile
(:func:`~panoptic_bench.datasets.synthetic.scene.street_profile`, e.g. ``road_reflect_range``)
from ``default_rng([seed, key, 3])``.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from panoptic_bench.datasets.synthetic.profile import WorldProfile
from panoptic_bench.datasets.synthetic.profile_files import load_profile
from panoptic_bench.datasets.synthetic.scene import Scene, generate_scene
from panoptic_bench.datasets.synthetic.sensor import HDL64E, LidarModel, Sweep, sweep
from panoptic_bench.datasets.synthetic.sensor_real import SensorState, sensor_state, sweep_realistic

__all__ = ["Frame", "Sequence", "sensor_pose"]


@dataclass(frozen=True)
class Frame:
    """One sweep of a sequence.

    Attributes
    ----------
    index : int
        Frame number in the sequence.
    time : float
        Seconds since the first frame.
    pose : ndarray of shape (4, 4), float64
        Sensor-to-world transform (the sensor frame is x forward, y left, z up).
    sweep : Sweep
        The returns, in the sensor frame.
    """

    index: int
    time: float
    pose: np.ndarray
    sweep: Sweep


def sensor_pose(
    scene: Scene,
    time: float,
    model: LidarModel,
    offset: tuple[float, float] = (0.0, 0.0),
    state: SensorState | None = None,
) -> np.ndarray:
    """Sensor-to-world transform, ndarray of shape (4, 4), float64, at ``time``.

    With a realistic ``state`` the sensor height and tilt of the sequence are included.
    """
    x, y, yaw = scene.ego_pose(time)
    c, s = np.cos(yaw), np.sin(yaw)
    pose = np.eye(4)
    pose[:2, :2] = [[c, -s], [s, c]]
    pose[:3, 3] = [
        x + c * offset[0] - s * offset[1],
        y + s * offset[0] + c * offset[1],
        model.mount_height,
    ]
    if state is not None:
        pose[:3, :3] = pose[:3, :3] @ state.rotation
        pose[2, 3] += state.height
    return pose


class Sequence:
    """A synthetic driving sequence of ``n_frames`` sweeps at ``rate`` Hz.

    Parameters
    ----------
    seed : int
        Global seed.
    key : int
        Which sequence of that seed (e.g. the SemanticKITTI sequence number).
    n_frames : int
        Number of sweeps.
    model : LidarModel
        The sensor (HDL-64E by default).
    rate : float
        Sweeps per second (10 Hz by default).
    sensor_offset : tuple of float
        Sensor position in the ego frame (forward, left), metres.
    profile : WorldProfile or str, optional
        World and sensor profile (``classic`` by default: the original world, bit for bit).

    Examples
    --------
    >>> seq = Sequence(seed=0, key=8, n_frames=2)
    >>> frames = list(seq)  # doctest: +SKIP
    """

    def __init__(
        self,
        seed: int,
        key: int,
        n_frames: int,
        model: LidarModel = HDL64E,
        rate: float = 10.0,
        sensor_offset: tuple[float, float] = (0.0, 0.0),
        profile: WorldProfile | str | None = None,
    ) -> None:
        if n_frames < 1:
            raise ValueError("n_frames must be at least 1")
        self.seed, self.key, self.n_frames = int(seed), int(key), int(n_frames)
        self.model, self.rate, self.sensor_offset = model, float(rate), sensor_offset
        self.profile = load_profile(profile)
        self.scene = generate_scene(
            [self.seed, self.key],
            duration=(n_frames - 1) / self.rate + 1.0,
            profile=self.profile,
        )
        self.state: SensorState | None = None
        if self.profile.sensor_model:
            rng = np.random.default_rng([self.seed, self.key, 2])
            self.state = sensor_state(self.profile, self.scene, rng)

    def __len__(self) -> int:
        return self.n_frames

    def frame(self, index: int) -> Frame:
        """Simulate frame ``index`` (independent of the other frames)."""
        time = index / self.rate
        rng = np.random.default_rng([self.seed, self.key, index, 1])
        if self.state is None:
            sw = sweep(self.scene, time, self.model, rng, self.sensor_offset)
        else:
            sw = sweep_realistic(
                self.scene, time, self.model, rng, self.sensor_offset, self.profile, self.state
            )
        pose = sensor_pose(self.scene, time, self.model, self.sensor_offset, self.state)
        return Frame(index, time, pose, sw)

    def __iter__(self) -> Iterator[Frame]:
        for i in range(self.n_frames):
            yield self.frame(i)
