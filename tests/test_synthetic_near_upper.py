"""Near-range dimming of the HDL-64E's upper block (issue 13, session 42): the ``rem_near_upper``
sensor key (only the remission of upper-block returns moves, never a position, label or other
draw), the kernel by hand, and the ``synth stats`` rows of upright stuff 4-8 m away, by hand."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from synthetic_street_checks import WORLDS, by_beam, profile_changes

from panoptic_bench.datasets.synthetic import Sequence
from panoptic_bench.datasets.synthetic.profile import REALISTIC, WorldProfile
from panoptic_bench.datasets.synthetic.realism import MEASURES, scan_measures
from panoptic_bench.datasets.synthetic.sensor_real import UPPER_BLOCK_DEG, near_upper
from panoptic_bench.errors import InputError

BUILDING, ROAD, POLE = 50, 40, 80


def test_near_upper_kernel_by_hand():
    """r0 = 4, k = 2: f = 1 / (1 + 16 / t^2); lower-block returns untouched; zero share z (1 - f)."""
    t = np.array([4.0, 8.0, 4.0, 40.0])
    up = np.array([True, True, False, True])
    rem = np.full(4, 0.5)
    out = near_upper(rem, t, up, (4.0, 2.0, 0.0), np.random.default_rng(0))
    np.testing.assert_allclose(out, [0.25, 0.5 / 1.25, 0.5, 0.5 / 1.01])
    n = 200_000
    t = np.full(n, 4.0)
    out = near_upper(
        np.full(n, 0.5), t, np.ones(n, bool), (4.0, 2.0, 0.6), np.random.default_rng(1)
    )
    zero = np.mean(out == 0)
    assert abs(zero - 0.6 * 0.5) < 4 * np.sqrt(0.3 * 0.7 / n)
    np.testing.assert_allclose(out[out > 0], 0.25)


def test_rem_near_upper_moves_only_upper_block_remission():
    prof = dataclasses.replace(REALISTIC, rem_near_upper=(5.0, 3.0, 0.8))
    a = Sequence(2, 3, 1, profile=REALISTIC).frame(0).sweep
    b = Sequence(2, 3, 1, profile=prof).frame(0).sweep
    # no draw moves: the same returns in the same order, the same positions and labels
    assert by_beam(a) == by_beam(b)
    np.testing.assert_array_equal(a.xyz, b.xyz)
    np.testing.assert_array_equal(a.label, b.label)
    upper = a.ring >= 32  # real elevations, ascending: the upper block is the top half
    np.testing.assert_array_equal(a.remission[~upper], b.remission[~upper])
    # dimmer, never brighter (a quantisation step aside); near far more than far
    assert np.all(b.remission[upper] <= a.remission[upper] + 1e-6)
    r = np.linalg.norm(a.xyz, axis=1)
    near, far = upper & (r < 7.0) & (a.remission > 0.1), upper & (r > 30.0) & (a.remission > 0.1)
    assert near.sum() > 100 and far.sum() > 100
    assert np.mean(b.remission[near] / a.remission[near]) < 0.7
    assert np.mean(b.remission[far] / a.remission[far]) > 0.95
    assert np.mean(b.remission[near] == 0) > 0.1


def test_upper_block_split_matches_the_hdl64e_rings():
    from panoptic_bench.datasets.synthetic.sensor_real import REAL_HDL64E_ELEVATIONS

    elev = np.asarray(REAL_HDL64E_ELEVATIONS)
    assert np.all(elev[:32] < UPPER_BLOCK_DEG) and np.all(elev[32:] > UPPER_BLOCK_DEG)


@pytest.mark.parametrize("value", [[4.0], [0.1, 3.0, 0.5], [4.0, 20.0, 0.5], [4.0, 3.0, 1.5]])
def test_bad_rem_near_upper(value):
    with pytest.raises(InputError, match="rem_near_upper"):
        WorldProfile.from_dict({"rem_near_upper": value}, base=REALISTIC)


@pytest.mark.filterwarnings("ignore:All-NaN slice", "ignore:Mean of empty slice")
def test_upper_near_rows_by_hand():
    """Building 6 m away at heights -0.5..0.5 m (elevation above -8.1 degrees: counted) and at
    -1.5 m (below: not counted), a pole 12 m away (out of 4-8 m: not counted), road: not upright."""
    az = np.linspace(-0.5, 0.5, 300)

    def ring(r, z, rem):
        return np.column_stack(
            [r * np.cos(az), r * np.sin(az), np.full(az.size, z), np.full(az.size, rem)]
        )

    rows = [
        (ring(6.0, 0.5, 0.0), BUILDING),
        (ring(6.0, -0.5, 0.2), BUILDING),
        (ring(6.0, 0.0, 0.3), BUILDING),
        (ring(6.0, -1.5, 0.9), BUILDING),  # -14 degrees: lower block
        (ring(12.0, 0.0, 0.9), POLE),
        (ring(6.0, -1.7, 0.0), ROAD),
    ]
    pts = np.vstack([p for p, _ in rows]).astype(np.float32)
    raw = np.concatenate([np.full(az.size, c) for _, c in rows]).astype(np.uint32)
    m, _ = scan_measures(pts, raw)
    assert "rem_upper_near_median" in MEASURES and "rem_upper_near_zero_pct" in MEASURES
    assert m["rem_upper_near_median"] == pytest.approx(0.2)
    assert m["rem_upper_near_zero_pct"] == pytest.approx(100 / 3)
    m, _ = scan_measures(pts[600:], raw[600:])  # 300 counted points (at least 200)
    assert m["rem_upper_near_median"] == pytest.approx(0.3)
    m, _ = scan_measures(pts[900:], raw[900:])
    assert np.isnan(m["rem_upper_near_median"]) and np.isnan(m["rem_upper_near_zero_pct"])


@pytest.mark.parametrize("world", WORLDS)
def test_row_59_files_are_row_56_worlds_plus_rem_near_upper(world):
    changed = profile_changes(f"synth_upper_{world}", f"synth_boards_{world}")
    assert changed == {"rem_near_upper": (4.0, 3.0, 0.5)}
