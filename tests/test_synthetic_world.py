"""Synthetic world: ray-primitive intersections, sensors, determinism, stable instance ids."""

from __future__ import annotations

import numpy as np
import pytest

from panoptic_bench.datasets.synthetic import HDL32E, HDL64E, Sequence
from panoptic_bench.datasets.synthetic.raycast import GROUND, cast
from panoptic_bench.datasets.synthetic.scene import generate_scene
from panoptic_bench.datasets.synthetic.shapes import BOX, CYLINDER, ELLIPSOID, Primitives, intersect
from panoptic_bench.datasets.synthetic.things import MOVING_LABEL, STATIC_LABEL

ALLOWED_RAW = {10, 11, 13, 15, 18, 20, 30, 31, 32, 40, 44, 48, 49, 50, 51, 70, 71, 72, 80, 81}
ALLOWED_RAW |= set(range(252, 260))


def _one(kind: int, center, half, yaw: float = 0.0) -> Primitives:
    return Primitives(
        np.array([kind], np.int8),
        np.array([center], float),
        np.array([half], float),
        np.array([yaw]),
        np.array([10], np.uint16),
        np.array([-1], np.int32),
        np.array([0.5], np.float32),
        np.array([0.0], np.float32),
    )


@pytest.mark.parametrize(
    ("kind", "half", "expected"),
    [
        (BOX, (1.0, 2.0, 1.0), 4.0),
        (CYLINDER, (1.0, 1.0, 1.0), 4.0),
        (ELLIPSOID, (1.5, 1.0, 1.0), 3.5),
    ],
)
def test_intersections_on_axis(kind, half, expected):
    prims = _one(kind, (5.0, 0.0, 0.0), half)
    d = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    t = intersect(prims, np.zeros(3, np.int64), d)
    assert t[0] == pytest.approx(expected)
    assert np.isinf(t[1]) and np.isinf(t[2])


def test_rotated_box_and_origin_inside():
    # a 2 x 2 box rotated 45 deg: its corner faces the ray at distance 5 - sqrt(2)
    prims = _one(BOX, (5.0, 0.0, 0.0), (1.0, 1.0, 1.0), yaw=np.pi / 4)
    t = intersect(prims, np.zeros(1, np.int64), np.array([[1.0, 0.0, 0.0]]))
    assert t[0] == pytest.approx(5.0 - np.sqrt(2.0))
    inside = _one(BOX, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    assert np.isinf(intersect(inside, np.zeros(1, np.int64), np.array([[1.0, 0.0, 0.0]])))[0]


def test_cast_culling_matches_brute_force():
    rng = np.random.default_rng(3)
    n = 60
    prims = Primitives(
        rng.integers(0, 3, n).astype(np.int8),
        np.column_stack([rng.uniform(-30, 30, (n, 2)), rng.uniform(-1.5, 3.0, n)]),
        rng.uniform(0.2, 3.0, (n, 3)),
        rng.uniform(-np.pi, np.pi, n),
        np.full(n, 50, np.uint16),
        np.full(n, -1, np.int32),
        np.full(n, 0.4, np.float32),
        np.zeros(n, np.float32),
    )
    elev = np.radians(np.linspace(-25.0, 5.0, 16))
    az = -np.pi + (np.arange(180) + 0.5) * 2 * np.pi / 180
    hits = cast(prims, elev, az, -1.73, 80.0)
    from panoptic_bench.datasets.synthetic.raycast import ray_directions

    d = ray_directions(elev, az)
    rows = np.repeat(np.arange(n), d.shape[0])
    t_all = intersect(prims, rows, np.tile(d, (n, 1))).reshape(n, -1).min(axis=0)
    with np.errstate(divide="ignore"):
        t_ground = np.where(d[:, 2] < 0, -1.73 / d[:, 2], np.inf)
    brute = np.minimum(t_all, t_ground)
    brute[brute > 80.0] = np.inf
    np.testing.assert_allclose(hits.t, brute)
    assert ((hits.prim == GROUND) == (np.isfinite(brute) & (t_ground <= t_all))).all()


def test_sequence_is_deterministic_and_instances_are_stable():
    a = Sequence(seed=7, key=1, n_frames=3)
    b = Sequence(seed=7, key=1, n_frames=3)
    fa, fb = a.frame(2), b.frame(2)
    np.testing.assert_array_equal(fa.sweep.xyz, fb.sweep.xyz)
    np.testing.assert_array_equal(fa.sweep.label, fb.sweep.label)
    np.testing.assert_array_equal(fa.pose, fb.pose)
    other = Sequence(seed=8, key=1, n_frames=3).frame(2)
    assert len(other.sweep) != len(fa.sweep) or not np.array_equal(other.sweep.xyz, fa.sweep.xyz)
    f0 = a.frame(0).sweep
    # an instance keeps its id and its class between frames
    for f in (f0, fa.sweep):
        assert set(np.unique(f.label).tolist()) <= ALLOWED_RAW
        thing = f.instance > 0
        thing_labels = list(STATIC_LABEL.values()) + list(MOVING_LABEL.values())
        assert np.isin(f.label[thing], thing_labels).all()
        assert (
            f.instance[np.isin(f.label, [40, 44, 48, 49, 50, 51, 70, 71, 72, 80, 81])] == 0
        ).all()
    common = np.intersect1d(np.unique(f0.instance[f0.instance > 0]), np.unique(fa.sweep.instance))
    assert common.size >= 5
    for k in common:
        assert (
            np.unique(f0.label[f0.instance == k]).tolist()
            == np.unique(fa.sweep.label[fa.sweep.instance == k]).tolist()
        )
    # the ego moves forward at 10 Hz
    assert 0.5 < fa.pose[0, 3] - a.frame(0).pose[0, 3] < 2.5


def test_sensors_point_counts_and_value_ranges():
    seq = Sequence(seed=0, key=0, n_frames=1)
    sw = seq.frame(0).sweep
    assert 100_000 < len(sw) < 131_072  # 64 x 2048 rays, most return
    assert sw.xyz.dtype == np.float32 and sw.remission.dtype == np.float32
    assert 0.0 <= sw.remission.min() and sw.remission.max() <= 1.0
    r = np.linalg.norm(sw.xyz, axis=1)
    assert r.min() >= HDL64E.min_range - 0.1 and r.max() <= HDL64E.max_range + 0.1
    elev = np.degrees(np.arcsin(sw.xyz[:, 2] / r))
    assert elev.min() > -25.5 and elev.max() < 2.5
    assert sw.ring.max() == 63
    # things are made of several primitives, so several classes of thing are present
    assert (sw.instance > 0).sum() > 1000
    nus = Sequence(seed=0, key=1000, n_frames=1, model=HDL32E, rate=2.0).frame(0).sweep
    assert 25_000 < len(nus) < 32 * 1084 + 1
    assert nus.ring.max() == 31


def test_scene_has_all_structures():
    scene = generate_scene(5, duration=4.0)
    labels = set(scene.static.label.tolist()) | set(np.unique(scene.ground.label).tolist())
    assert {40, 48, 50, 70, 71, 80, 81} <= labels
    cats = [t.category for t in scene.things]
    assert cats.count("car") >= 10 and "person" in cats
    # parked rows: some neighbouring parked cars nearly touch
    cars = sorted(
        (t.xyz[0], t.size[0], t.xyz[1])
        for t in scene.things
        if t.category == "car" and not t.moving
    )
    gaps = [
        b[0] - b[1] / 2 - (a[0] + a[1] / 2)
        for a, b in zip(cars, cars[1:])
        if abs(a[2] - b[2]) < 1.0
    ]
    assert min(gaps) < 0.6
