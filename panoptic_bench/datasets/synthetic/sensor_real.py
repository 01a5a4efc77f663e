"""The realistic sensor model of a :class:`~.profile.WorldProfile` (``physical_remission`` etc.).

One :class:`SensorState` per sequence (drawn from ``default_rng([seed, key, 2])``): sensor height,
pitch and roll, the gentle undulation of the ground, a gain and dark flag per primitive (the
material of each surface, constant along the sequence) and, with ``ground_rough_corr > 0``, the
smooth roughness field of the ground (drawn last, so the other draws do not depend on it). :func:`sweep_realistic` then casts the
tilted beam grid (real HDL-64E elevations when asked), hides rays that hit the ego vehicle,
moves ground returns onto the rough, cambered, undulating ground, records remission with range
and incidence falloff (quantised to 0.01, exactly 0 below the detection floor: far road, dark
paint, glass, grazing angles; with ``rem_near_upper`` the upper block's near returns dimmed) and
applies dropout, thinner low rings and the range cap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from panoptic_bench.datasets.synthetic.profile import WorldProfile
from panoptic_bench.datasets.synthetic.raw_ids import (
    CAR,
    MOVING_CAR,
    OTHER_VEHICLES,
    PARKING,
    PEOPLE,
    POLE,
    SIDEWALK,
    SIGN,
    TERRAIN,
    VEGETATION,
)
from panoptic_bench.datasets.synthetic.raycast import GROUND, cast, ray_directions
from panoptic_bench.datasets.synthetic.scene import Scene
from panoptic_bench.datasets.synthetic.shapes import normals

__all__ = [
    "REAL_HDL64E_ELEVATIONS",
    "SensorState",
    "rough_field",
    "sensor_state",
    "sweep_realistic",
    "tilt_matrix",
]

#: Median elevation (degrees) of each ring of the 55 real HDL-64E scans, lowest first.
REAL_HDL64E_ELEVATIONS = (
    -23.673, -23.157, -22.677, -22.047, -21.619, -21.192, -20.721, -20.093, -19.602, -19.041,
    -18.606, -18.189, -17.689, -17.232, -16.67, -16.145, -15.512, -15.146, -14.65, -14.215,
    -13.64, -13.12, -12.596, -12.171, -11.72, -11.291, -10.799, -10.198, -9.738, -9.354, -8.898,
    -8.382, -7.771, -7.396, -7.173, -6.834, -6.467, -6.202, -5.897, -5.589, -5.255, -4.939,
    -4.626, -4.305, -4.008, -3.634, -3.352, -2.962, -2.647, -2.312, -1.993, -1.656, -1.289,
    -0.96, -0.662, -0.265, 0.087, 0.453, 0.725, 1.129, 1.415, 1.874, 2.131, 2.495,
)  # fmt: skip

#: Raw ids whose primitives are vehicle bodies / glass (dark paint is common).
_VEHICLES = (CAR, MOVING_CAR, *OTHER_VEHICLES)
#: Raw ids scaled by ``rem_gain_pole`` and ``rem_gain_sign`` (people: ``raw_ids.PEOPLE``).
_POLE, _SIGN = (POLE,), (SIGN,)


@dataclass(frozen=True)
class SensorState:
    """Per-sequence draw of the realistic sensor.

    Attributes
    ----------
    height : float
        Sensor height above the road, metres.
    rotation : ndarray of shape (3, 3), float64
        Sensor-to-level rotation (pitch about y, roll about x).
    wave : ndarray of shape (3, 3), float64
        Ground undulation terms ``(amplitude m, wavenumber rad/m, phase)`` along x.
    gain : ndarray of shape (M,), float32
        Reflectivity factor of every primitive of the scene (static first, then things).
    rough : ndarray of shape (K, 4), float64, or None
        Smooth ground roughness field ``sum_k a_k cos(kx_k x + ky_k y + phase_k)``, one row
        ``(kx rad/m, ky rad/m, phase, a m)`` per term (world frame); None: iid roughness.
    """

    height: float
    rotation: np.ndarray
    wave: np.ndarray
    gain: np.ndarray
    rough: np.ndarray | None = None


def tilt_matrix(pitch_deg: float, roll_deg: float) -> np.ndarray:
    """Sensor-to-level rotation, ndarray (3, 3) float64.

    Positive pitch points the sensor's x axis down (the road then rises ahead in the sensor
    frame); positive roll lowers its left (+y) side.
    """
    p, r = np.radians(pitch_deg), -np.radians(roll_deg)
    ry = np.array([[np.cos(p), 0.0, np.sin(p)], [0.0, 1.0, 0.0], [-np.sin(p), 0.0, np.cos(p)]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(r), -np.sin(r)], [0.0, np.sin(r), np.cos(r)]])
    return ry @ rx


def sensor_state(profile: WorldProfile, scene: Scene, rng: np.random.Generator) -> SensorState:
    """Draw the sensor pose, ground undulation and surface materials of one sequence."""
    h = rng.normal(*profile.height_shift)
    pitch, roll = rng.normal(*profile.pitch_deg), rng.normal(*profile.roll_deg)
    wave = np.column_stack(
        [
            profile.ground_wave * rng.uniform(0.3, 1.0, 3) / np.sqrt(3.0),
            2 * np.pi / rng.uniform(30.0, 80.0, 3),
            rng.uniform(0.0, 2 * np.pi, 3),
        ]
    )
    labels = np.concatenate([scene.static.label, scene._local.label])
    late = sum(len(t.prims) for t in scene.things[len(scene.things) - scene.late_things :])
    gain = _materials(profile, labels[: labels.size - late], rng)
    if late:  # things added by a late key: their own stream, the others' draws unchanged
        gain = np.concatenate([gain, _materials(profile, labels[-late:], rng.spawn(1)[0])])
    rough = None
    if profile.ground_rough and profile.ground_rough_corr > 0:
        rough = rough_field(rng, profile.ground_rough, profile.ground_rough_corr)
    return SensorState(float(h), tilt_matrix(pitch, roll), wave, gain.astype(np.float32), rough)


def _materials(profile: WorldProfile, labels: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Reflectivity factor (n,) float64 of primitives with raw ids ``labels`` (n,): material
    spread, dark paint / glass, the per-class gains."""
    vehicle = np.isin(labels, _VEHICLES)
    if profile.rem_stuff_spread:  # same draws, another spread for the stuff primitives
        stuff = ~vehicle & ~np.isin(labels, PEOPLE)
        sigma = np.where(stuff, profile.rem_stuff_spread[0], profile.rem_material_spread)
        gain = np.exp(sigma * rng.standard_normal(labels.size))
    else:
        gain = rng.lognormal(0.0, profile.rem_material_spread, labels.size)
    p_dark = np.where(vehicle, profile.rem_dark_prob, profile.rem_dark_stuff)
    if profile.rem_dark_other:
        p_dark = np.where(np.isin(labels, OTHER_VEHICLES), profile.rem_dark_other[0], p_dark)
    gain = np.where(rng.random(labels.size) < p_dark, 0.1 * gain, gain)
    for ids, factor in (
        (PEOPLE, profile.rem_gain_people),
        (_POLE, profile.rem_gain_pole),
        (_SIGN, profile.rem_gain_sign),
        ((VEGETATION,), profile.rem_gain_vegetation),
    ):
        if factor != 1.0:
            gain = np.where(np.isin(labels, ids), factor * gain, gain)
    return gain


#: Number of random cosines of a smooth roughness field.
ROUGH_TERMS = 48


def rough_field(rng: np.random.Generator, std: float, corr: float) -> np.ndarray:
    """Draw a smooth random height field (random Fourier features of a Gaussian covariance).

    Wave vectors ~ N(0, I / corr^2), phases ~ U[0, 2 pi), equal amplitudes: the field has
    standard deviation ``std`` and covariance ``std^2 exp(-d^2 / (2 corr^2))`` between points
    ``d`` apart (in expectation over draws).

    Returns
    -------
    ndarray of shape (ROUGH_TERMS, 4), float64
        Rows ``(kx rad/m, ky rad/m, phase, amplitude m)``.
    """
    k = rng.normal(0.0, 1.0 / corr, (ROUGH_TERMS, 2))
    phase = rng.uniform(0.0, 2 * np.pi, ROUGH_TERMS)
    amp = np.full(ROUGH_TERMS, std * np.sqrt(2.0 / ROUGH_TERMS))
    return np.column_stack([k, phase, amp])


#: Cosine of the grazing cutoff of every surface unless ``rem_grazing`` says otherwise.
GRAZING_COS = 0.06


def _grazing(profile: WorldProfile, label: np.ndarray) -> float | np.ndarray:
    """Grazing cutoff cosine per return: (n,) float64, or the scalar 0.06 without ``rem_grazing``."""
    if not profile.rem_grazing:
        return GRAZING_COS
    c = np.full(label.shape, GRAZING_COS)
    c[label == TERRAIN] = profile.rem_grazing[0]
    c[np.isin(label, (SIDEWALK, PARKING))] = profile.rem_grazing[1]
    return c


def _ego_hidden(dirs: np.ndarray, box: tuple[float, ...]) -> np.ndarray:
    """Rays (sensor frame) that hit the top of the ego body ``(xb, xf, yr, yl, z_top)``."""
    xb, xf, yr, yl, zt = box
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(dirs[:, 2] < 0, zt / dirs[:, 2], np.inf)
    x, y = dirs[:, 0] * t, dirs[:, 1] * t
    return np.isfinite(t) & (x >= xb) & (x <= xf) & (y >= yr) & (y <= yl)


def _ground_height(scene: Scene, state: SensorState, profile: WorldProfile, wx, wy, n, rng):
    """Height of the ground surface at world ``(wx, wy)``: waves + camber + roughness."""
    h = np.zeros(n)
    for amp, k, ph in state.wave:
        h += amp * np.sin(k * wx + ph)
    road_half = scene.plan.road_half
    h -= profile.camber * np.minimum(np.abs(wy), road_half)
    if state.rough is not None:
        kx, ky, ph, amp = state.rough.T
        h += np.cos(np.multiply.outer(wx, kx) + np.multiply.outer(wy, ky) + ph) @ amp
    elif profile.ground_rough:
        h += rng.normal(0.0, profile.ground_rough, n)
    return h


#: Beams above this elevation (degrees) belong to the HDL-64E's upper block (32 of 64 real rings).
UPPER_BLOCK_DEG = -8.1


def near_upper(
    rem: np.ndarray,
    t: np.ndarray,
    upper: np.ndarray,
    params: tuple[float, ...],
    rng: np.random.Generator,
) -> np.ndarray:
    """Near-range dimming of the upper block (``rem_near_upper``).

    On the 55 real scans the stuff returns of the upper block's beams are dim near the sensor
    (median remission 0.23-0.24 and 18-22 % exactly 0 at 4-6 m, 0.29 / 10 % at 6-8 m, 0.31 /
    6 % at 8-9 m, 0.36-0.40 / 1-2 % beyond 9 m), those of the lower block at the same range are
    not (0.34-0.36, 0-2 % zero).

    Parameters
    ----------
    rem : ndarray of shape (N,), float64
        Remission before quantisation.
    t : ndarray of shape (N,), float64
        Range along the ray (m).
    upper : ndarray of shape (N,), bool
        Return of an upper-block beam.
    params : tuple of float
        ``(r0, k, z)``: factor ``f = 1 / (1 + (r0 / t)^k)``, zero with probability ``z (1 - f)``.
    rng : numpy.random.Generator
        One uniform draw per return.

    Returns
    -------
    ndarray of shape (N,), float64
    """
    r0, k, z = params
    f = np.where(upper, 1.0 / (1.0 + (r0 / np.maximum(t, 1e-3)) ** k), 1.0)
    zero = rng.random(rem.size) < z * (1.0 - f)
    return np.where(zero, 0.0, rem * f)


def sweep_realistic(
    scene: Scene,
    time: float,
    model,
    rng: np.random.Generator,
    sensor_xy_offset: tuple[float, float],
    profile: WorldProfile,
    state: SensorState,
):
    """One sweep with the realistic sensor; same contract as :func:`.sensor.sweep`."""
    from panoptic_bench.datasets.synthetic.sensor import Sweep, sensor_frame

    height = model.mount_height + state.height
    max_range = profile.max_range or model.max_range
    local, sx, sy, c, s = sensor_frame(scene, time, sensor_xy_offset, height)
    elev_deg = model.elevation_deg
    if profile.real_elevations and model.n_beams == len(REAL_HDL64E_ELEVATIONS):
        elev_deg = REAL_HDL64E_ELEVATIONS
    elevation = np.radians(np.asarray(elev_deg))
    n_c = model.n_azimuth
    step = 2 * np.pi / n_c
    azimuth = -np.pi + (np.arange(n_c) + 0.5) * step + rng.uniform(-0.1, 0.1) * step
    hits = cast(local, elevation, azimuth, -height, max_range, rotation=state.rotation)
    dirs_s = ray_directions(elevation, azimuth)
    dirs = dirs_s @ state.rotation.T
    ok = np.isfinite(hits.t)
    if profile.ego_box:
        ok &= ~_ego_hidden(dirs_s, profile.ego_box)
    idx = np.flatnonzero(ok)
    prim, t = hits.prim[idx], hits.t[idx]
    on_ground = prim == GROUND
    obj = np.flatnonzero(~on_ground)
    d = dirs[idx]
    pts = d * t[:, None]
    nrm = np.zeros_like(pts)
    nrm[on_ground, 2] = 1.0
    nrm[obj] = normals(local, prim[obj], pts[obj])
    label = np.zeros(idx.size, np.uint16)
    reflect = np.zeros(idx.size, np.float32)
    gain = np.ones(idx.size, np.float32)
    instance = np.zeros(idx.size, np.uint32)
    rough = np.zeros(idx.size, np.float32)
    g = np.flatnonzero(on_ground)
    wx = sx + c * pts[g, 0] - s * pts[g, 1]
    wy = sy + s * pts[g, 0] + c * pts[g, 1]
    label[g], reflect[g] = scene.ground.lookup(wx, wy)
    # rough, cambered, undulating ground: two fixed-point steps of the ray / height-field hit
    dh = _ground_height(scene, state, profile, wx, wy, g.size, rng)
    h0 = dh - _ground_height(scene, state, profile, np.array([sx]), np.array([sy]), 1, rng)[0]
    t[g] = (-height + h0) / np.minimum(d[g, 2], -1e-3)
    p = prim[obj]
    label[obj] = local.label[p]
    reflect[obj] = local.reflect[p]
    gain[obj] = state.gain[p]
    rough[obj] = local.rough[p]
    if profile.veg_rough != 1.0:
        rough = np.where(label == VEGETATION, profile.veg_rough * rough, rough).astype(np.float32)
    owner = local.owner[p]
    instance[obj] = np.where(owner >= 0, owner + 1, 0).astype(np.uint32)

    cos_inc = np.clip(np.abs(np.einsum("ij,ij->i", nrm, d)), 1e-4, 1.0)
    noise = profile.range_noise or model.range_noise
    t = (
        t
        + rough * rng.exponential(1.0, idx.size)
        + np.clip(rng.normal(0.0, noise, idx.size), -2.5 * noise, 2.5 * noise)
    )
    fall_r = 1.0 / (1.0 + (t / profile.rem_range_m) ** 4)
    fall_i = cos_inc**profile.rem_incidence_exp / (1.0 + (_grazing(profile, label) / cos_inc) ** 8)
    rem = reflect * gain * fall_r * fall_i * rng.lognormal(0.0, profile.rem_spread, idx.size)
    if profile.rem_near_upper:  # its own stream: every other draw of the sweep unchanged
        up = np.asarray(elev_deg)[idx // n_c] > UPPER_BLOCK_DEG
        rem = near_upper(rem, t, up, profile.rem_near_upper, rng.spawn(1)[0])
    rem = np.floor(np.clip(rem, 0.0, 0.99) * 100.0) / 100.0
    rem[rem < profile.rem_zero_below] = 0.0
    keep_p = np.full(idx.size, 1.0 - model.dropout)
    ring_all = idx // n_c
    if profile.low_ring_keep:
        table = np.ones(elevation.size)
        table[: len(profile.low_ring_keep)] = profile.low_ring_keep
        keep_p *= table[ring_all]
    keep = (rng.random(idx.size) < keep_p) & (t >= model.min_range) & (t <= max_range)
    xyz = (dirs_s[idx] * t[:, None])[keep].astype(np.float32)
    ring, column = np.divmod(idx[keep], n_c)
    return Sweep(
        xyz,
        rem[keep].astype(np.float32),
        ring.astype(np.uint8),
        column.astype(np.int32),
        label[keep],
        instance[keep],
    )
