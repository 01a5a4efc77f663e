"""Vegetation texture (issue 13, session 28): the ``synth stats`` range-texture measure by hand and
the ``veg_rough`` world key (same draws, only vegetation returns move)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from synthetic_street_checks import by_beam, profile_changes

from panoptic_bench.datasets.synthetic import Sequence
from panoptic_bench.datasets.synthetic.profile import REALISTIC, WorldProfile
from panoptic_bench.datasets.synthetic.realism import MEASURES, scan_measures
from panoptic_bench.errors import InputError

REPO = Path(__file__).resolve().parents[1]
VEGETATION, BUILDING, ROAD = 70, 50, 40


def _ring(rng_m: np.ndarray, az: np.ndarray, z: float) -> np.ndarray:
    return np.column_stack([rng_m * np.cos(az), rng_m * np.sin(az), np.full(az.size, z)])


@pytest.mark.filterwarnings("ignore:All-NaN slice")  # no ground: the ego-hole rows are NaN
def test_texture_rows_by_hand():
    """A hedge ring with iid 1 cm range noise, a flat wall ring, and a far wall that is not counted.

    The second difference of iid N(0, s) ranges has std s * sqrt(1 + 1/4 + 1/4) = 12.25 mm for
    s = 1 cm; a circle around the sensor has constant range, so zero texture.
    """
    az = np.linspace(-1.0, 1.0, 4001)  # 0.0005 rad apart: ring neighbours
    noise = np.random.default_rng(0).normal(0.0, 0.01, az.size)
    hedge = _ring(10.0 + noise, az, 0.0)
    wall = _ring(np.full(az.size, 12.0), az + 2.5, 0.0)
    far = _ring(np.full(az.size, 25.0), az - 2.5, 0.0)  # beyond 20 m: not counted
    pts = np.vstack([hedge, wall, far])
    raw = np.concatenate(
        [np.full(az.size, VEGETATION), np.full(az.size, BUILDING), np.full(az.size, BUILDING)]
    )
    pts = np.column_stack([pts, np.full(len(pts), 0.3)]).astype(np.float32)
    m, _ = scan_measures(pts, raw.astype(np.uint32))
    assert "vegetation_texture_mm" in MEASURES and "building_texture_mm" in MEASURES
    assert m["vegetation_texture_mm"] == pytest.approx(10.0 * np.sqrt(1.5), rel=0.05)
    assert m["building_texture_mm"] == pytest.approx(0.0, abs=0.05)
    # a jump of more than 0.01 rad in azimuth ends a ring neighbourhood: every other point only
    m_sparse, _ = scan_measures(pts[::40], raw[::40].astype(np.uint32))
    assert np.isnan(m_sparse["vegetation_texture_mm"])
    # too few in-range triples: not a number, not a zero
    m_far, _ = scan_measures(pts[2 * az.size :], raw[2 * az.size :].astype(np.uint32))
    assert np.isnan(m_far["building_texture_mm"])


def test_veg_rough_moves_only_vegetation_returns_towards_the_sensor():
    prof = dataclasses.replace(REALISTIC, veg_rough=0.35)
    a = Sequence(2, 3, 1, profile=REALISTIC).frame(0).sweep
    b = Sequence(2, 3, 1, profile=prof).frame(0).sweep
    same = Sequence(2, 3, 1, profile=dataclasses.replace(REALISTIC, veg_rough=1.0)).frame(0).sweep
    np.testing.assert_array_equal(a.xyz, same.xyz)  # the default is every world bit for bit
    ia, ib = by_beam(a), by_beam(b)
    common = sorted(set(ia) & set(ib))
    assert len(common) > 0.99 * len(a)  # only returns at the range limits may come or go
    pa, pb = np.array([ia[k] for k in common]), np.array([ib[k] for k in common])
    np.testing.assert_array_equal(a.label[pa], b.label[pb])
    veg = a.label[pa] == VEGETATION
    assert veg.sum() > 1000
    np.testing.assert_array_equal(a.xyz[pa][~veg], b.xyz[pb][~veg])
    np.testing.assert_array_equal(a.remission[pa][~veg], b.remission[pb][~veg])
    ra = np.linalg.norm(a.xyz[pa][veg], axis=1)
    rb = np.linalg.norm(b.xyz[pb][veg], axis=1)
    # t_b - t_a = (0.35 - 1) x penetration <= 0; penetrations average 0.12-0.25 m
    assert np.all(rb <= ra + 1e-4)
    assert 0.65 * 0.08 < float((ra - rb).mean()) < 0.65 * 0.3
    # the measure sees it: the 0.35 world's vegetation is smoother
    ma, _ = scan_measures(np.column_stack([a.xyz, a.remission]), a.label.astype(np.uint32))
    mb, _ = scan_measures(np.column_stack([b.xyz, b.remission]), b.label.astype(np.uint32))
    assert mb["vegetation_texture_mm"] < 0.6 * ma["vegetation_texture_mm"]
    assert mb["building_texture_mm"] == pytest.approx(ma["building_texture_mm"], rel=0.05)


@pytest.mark.parametrize("value", [-0.1, 5.5])
def test_bad_veg_rough(value):
    with pytest.raises(InputError, match="veg_rough"):
        WorldProfile.from_dict({"veg_rough": value}, base=REALISTIC)


@pytest.mark.parametrize(
    "world", ["low_crowns_low_fences", "low_fences_tight_materials", "low_fences_raised_lots"]
)
def test_row_25_files_are_row_18a_worlds_plus_veg_rough(world):
    assert profile_changes(f"synth_vegtex_{world}", f"synth_realistic_{world}") == {
        "veg_rough": 0.35
    }
