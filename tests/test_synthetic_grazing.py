"""Far ground remission by material (issue 13, session 36): the ``rem_grazing`` world key (only the
remission of terrain, sidewalk and parking moves, never a position, label or draw) and the
``synth stats`` rows of far sidewalk / terrain remission, by hand."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from synthetic_street_checks import WORLDS, by_beam, profile_changes

from panoptic_bench.datasets.synthetic import Sequence
from panoptic_bench.datasets.synthetic.profile import REALISTIC, WorldProfile
from panoptic_bench.datasets.synthetic.realism import MEASURES, scan_measures
from panoptic_bench.datasets.synthetic.sensor_real import GRAZING_COS, _grazing
from panoptic_bench.errors import InputError

REPO = Path(__file__).resolve().parents[1]
ROAD, PARKING, SIDEWALK, TERRAIN, VEGETATION = 40, 44, 48, 72, 70


@pytest.mark.filterwarnings("ignore:All-NaN slice", "ignore:Mean of empty slice")
def test_far_remission_rows_by_hand():
    """Medians over the points of each class and range band; other bands and classes do not count."""
    az = np.linspace(-0.5, 0.5, 101)

    def ring(r, z, rem):
        return np.column_stack(
            [r * np.cos(az), r * np.sin(az), np.full(az.size, z), np.full(az.size, rem)]
        )

    rows = [
        (ring(25.0, -1.7, 0.20), SIDEWALK),
        (ring(35.0, -1.7, 0.10), SIDEWALK),  # sidewalk 20-40 m: 202 points, half 0.2, half 0.1
        (ring(10.0, -1.7, 0.90), SIDEWALK),  # under 20 m: not counted
        (ring(30.0, -1.5, 0.31), TERRAIN),
        (ring(50.0, -1.5, 0.12), TERRAIN),
        (ring(60.0, -1.5, 0.14), TERRAIN),
        (ring(30.0, -1.7, 0.05), ROAD),
    ]
    pts = np.vstack([p for p, _ in rows]).astype(np.float32)
    raw = np.concatenate([np.full(az.size, c) for _, c in rows]).astype(np.uint32)
    m, _ = scan_measures(pts, raw)
    for key in ("rem_sidewalk_20_40", "rem_terrain_20_40", "rem_terrain_gt40"):
        assert key in MEASURES
    assert m["rem_sidewalk_20_40"] == pytest.approx(0.15)  # even count: mean of 0.1 and 0.2
    assert m["rem_terrain_20_40"] == pytest.approx(0.31)
    assert m["rem_terrain_gt40"] == pytest.approx(0.13)
    assert m["rem_road_20_40"] == pytest.approx(0.05)


def test_grazing_cosine_per_return():
    labels = np.array([ROAD, TERRAIN, SIDEWALK, PARKING, VEGETATION], np.uint16)
    assert _grazing(REALISTIC, labels) == GRAZING_COS == 0.06  # empty key: one scalar
    prof = dataclasses.replace(REALISTIC, rem_grazing=(0.025, 0.045))
    np.testing.assert_array_equal(_grazing(prof, labels), [0.06, 0.025, 0.045, 0.045, 0.06])


def test_rem_grazing_moves_only_far_ground_remission_of_its_classes():
    prof = dataclasses.replace(REALISTIC, rem_grazing=(0.025, 0.045))
    a = Sequence(2, 3, 1, profile=REALISTIC).frame(0).sweep
    b = Sequence(2, 3, 1, profile=prof).frame(0).sweep
    # no draw moves: the same returns in the same order, the same positions and labels
    assert by_beam(a) == by_beam(b)
    np.testing.assert_array_equal(a.xyz, b.xyz)
    np.testing.assert_array_equal(a.label, b.label)
    mine = np.isin(a.label, (TERRAIN, SIDEWALK, PARKING))
    np.testing.assert_array_equal(a.remission[~mine], b.remission[~mine])
    # a smaller cutoff cosine only raises the falloff factor (quantisation aside)
    assert np.all(b.remission[mine] >= a.remission[mine] - 1e-6)
    r = np.hypot(a.xyz[:, 0], a.xyz[:, 1])
    near, far = mine & (r < 12.0), mine & (r > 28.0)
    assert near.sum() > 100 and far.sum() > 50
    # near the sensor the cutoff is far from grazing: at most a quantisation step moves
    assert np.abs(b.remission[near] - a.remission[near]).max() <= 0.0100001
    assert np.median(a.remission[far]) < 0.05 < 0.1 < np.median(b.remission[far])


@pytest.mark.parametrize("value", [[0.1], [0.02, 0.4], [-0.01, 0.05], [0.02, 0.03, 0.04]])
def test_bad_rem_grazing(value):
    with pytest.raises(InputError, match="rem_grazing"):
        WorldProfile.from_dict({"rem_grazing": value}, base=REALISTIC)


@pytest.mark.parametrize("world", WORLDS)
def test_row_43_files_are_row_38_worlds_plus_rem_grazing(world):
    changed = profile_changes(f"synth_graze_{world}", f"synth_kerb_{world}")
    assert changed == {"rem_grazing": (0.025, 0.045)}
