"""Ground levelling (``model.level_ground``): the plane fit, the rotation, and the one code path.

Hand-made scenes with a known tilt: the fit must find it, the levelled ground must be flat, a scan
without enough ground must be left alone, and a levelling model must give exactly what a plain
model gives on the levelled scan, with its offsets turned back into the scan's frame.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from panoptic_bench.dsnet.config import DSNetConfig
from panoptic_bench.dsnet.data.datasets import LidarSample
from panoptic_bench.dsnet.data.level import (
    GroundPlane,
    fit_ground_plane,
    level_points,
    levelling_rotation,
)
from panoptic_bench.dsnet.model.forward import backbone_forward
from panoptic_bench.dsnet.model.network import PanopticBackbone
from panoptic_bench.dsnet.model.voxelize import CylinderGrid

sys.path.insert(0, str(Path(__file__).parent))
from dsnet_tiny_world import tiny_model  # noqa: E402

GRID = CylinderGrid(size=(32, 32, 8), rho_range=(1, 30), z_range=(-3, 2))


def street(pitch_deg: float, roll_deg: float, height: float = -1.75, seed: int = 0) -> np.ndarray:
    """Tilted ground (2 cm noise, a few points 0.4 m below it), a wall, two boxes; (n, 3) float32."""
    rng = np.random.default_rng(seed)
    a, b = math.tan(math.radians(pitch_deg)), math.tan(math.radians(roll_deg))
    xy = rng.uniform(-35, 35, size=(20000, 2))
    ground = np.c_[xy, height + a * xy[:, 0] + b * xy[:, 1] + rng.normal(0, 0.02, len(xy))]
    ground[:40, 2] -= 0.4  # multipath returns under the road
    wall = np.c_[rng.uniform(-30, 30, 4000), np.full(4000, 9.0), rng.uniform(-1.7, 3.0, 4000)]
    box = np.c_[rng.uniform(4, 8, 2000), rng.uniform(-4, -2, 2000), rng.uniform(-1.7, -0.2, 2000)]
    return np.concatenate([ground, wall, box]).astype(np.float32)


@pytest.mark.parametrize("pitch, roll", [(0.0, 0.0), (0.5, -1.6), (-1.2, 2.4), (3.0, 0.7)])
def test_fit_finds_the_tilt_and_levelling_flattens_the_ground(pitch: float, roll: float):
    pts = street(pitch, roll)
    plane = fit_ground_plane(pts)
    assert plane is not None
    assert plane.pitch_deg == pytest.approx(pitch, abs=0.05)
    assert plane.roll_deg == pytest.approx(roll, abs=0.05)
    assert plane.height == pytest.approx(-1.75 - 0.005, abs=0.02)  # lowest of noisy points
    flat, rot = level_points(pts)
    assert flat.dtype == np.float32 and flat.shape == pts.shape
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rot) == pytest.approx(1.0)
    again = fit_ground_plane(flat)
    assert abs(again.pitch_deg) < 0.02 and abs(again.roll_deg) < 0.02
    # the sensor stays at the origin and distances are kept
    np.testing.assert_allclose(np.linalg.norm(flat, axis=1), np.linalg.norm(pts, axis=1), rtol=1e-5)


def test_rotation_hand_worked():
    # a pure 2-degree roll: the x axis (heading) stays, the plane normal becomes +z
    b = math.tan(math.radians(2.0))
    rot = levelling_rotation(GroundPlane(0.0, b, -1.7, 100))
    np.testing.assert_allclose(rot @ [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], atol=1e-12)
    normal = np.array([0.0, -b, 1.0]) / math.hypot(b, 1.0)
    np.testing.assert_allclose(rot @ normal, [0.0, 0.0, 1.0], atol=1e-12)
    # a ground point 10 m to the left: y' = 10 / cos - 1.7 sin, z' = -1.7 cos (the plane's height)
    c, s = math.cos(math.radians(2.0)), math.sin(math.radians(2.0))
    np.testing.assert_allclose(
        rot @ [0.0, 10.0, 10 * b - 1.7], [0, 10 / c - 1.7 * s, -1.7 * c], atol=1e-9
    )
    np.testing.assert_array_equal(levelling_rotation(None), np.eye(3))


def test_no_plane_means_no_rotation():
    rng = np.random.default_rng(1)
    assert fit_ground_plane(np.zeros((0, 3), np.float32)) is None
    close = rng.uniform(-2, 2, size=(5000, 3)).astype(np.float32)  # nothing beyond 3 m
    assert fit_ground_plane(close) is None
    steep = street(15.0, 0.0)  # a wall-like "ground" is not levelled
    assert fit_ground_plane(steep) is None
    for pts in (close, steep):
        out, rot = level_points(pts)
        np.testing.assert_array_equal(rot, np.eye(3))
        np.testing.assert_array_equal(out, pts)
        assert out is not pts


def _model(level: bool) -> PanopticBackbone:
    torch.manual_seed(0)
    return tiny_model(5, GRID, level_ground=level).eval()


def _sample(pts: np.ndarray, key: str) -> LidarSample:
    n = len(pts)
    rem = np.linspace(0, 1, n, dtype=np.float32)
    return LidarSample(pts, rem, np.ones(n, np.int64), np.zeros(n, np.int64), ("00", key))


def test_levelling_model_equals_plain_model_on_levelled_scans():
    scans = [
        _sample(street(0.4, -1.8, seed=2)[::4], "a"),
        _sample(street(-0.8, 2.2, seed=3)[::4], "b"),
    ]
    before = [s.xyz.copy() for s in scans]
    plain, level = _model(False), _model(True)
    level.load_state_dict(plain.state_dict())
    assert "level_ground=True" in repr(level)
    with torch.no_grad():
        out = backbone_forward(level, scans, GRID, torch.device("cpu"))
        turned = [level_points(s.xyz) for s in scans]
        ref = backbone_forward(
            plain, [_sample(x, s.key[1]) for (x, _), s in zip(turned, scans)], GRID, "cpu"
        )
    for s, x in zip(scans, before):  # inputs untouched
        np.testing.assert_array_equal(s.xyz, x)
    torch.testing.assert_close(out.sem_logits, ref.sem_logits, rtol=0, atol=0)
    n0 = len(scans[0].xyz)
    for part, ref_part, (_, rot) in (
        (out.offsets[:n0], ref.offsets[:n0], turned[0]),
        (out.offsets[n0:], ref.offsets[n0:], turned[1]),
    ):
        # offsets come back in the scan's frame: turning them forward gives the levelled ones
        torch.testing.assert_close(part @ torch.as_tensor(rot, dtype=part.dtype).T, ref_part)
    # and a plain model ignores the tilt correction entirely
    with torch.no_grad():
        raw = backbone_forward(plain, scans, GRID, "cpu")
    assert not torch.equal(raw.sem_logits, out.sem_logits)


def test_config_key_reaches_the_network_and_round_trips(tmp_path: Path):
    from panoptic_bench.dsnet.checkpoint import build_backbone
    from panoptic_bench.dsnet.config import load_config

    cfg = DSNetConfig()
    assert cfg.model.level_ground is False and build_backbone(cfg, 20).level_ground is False
    on = cfg.replace(model={"level_ground": True})
    assert DSNetConfig.from_dict(on.to_dict()) == on
    assert build_backbone(on, 20).level_ground is True
    shipped = Path(__file__).parents[1] / "configs" / "dsnet_semantickitti_cpu_paste_level.yaml"
    assert load_config(shipped).model.level_ground is True
