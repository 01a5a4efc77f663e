"""Building frontages (``frontage_p``) and realism row 62's worlds (issue 13, session 44)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from synthetic_street_checks import WORLDS, profile_changes

from panoptic_bench.datasets.synthetic.profile import REALISTIC, WorldProfile
from panoptic_bench.datasets.synthetic.raw_ids import BUILDING
from panoptic_bench.datasets.synthetic.street import build_street, curb_at
from panoptic_bench.errors import InputError


def _buildings(seed: int, frontage_p):
    prof = dataclasses.replace(REALISTIC, frontage_p=frontage_p)
    prims, _, plan = build_street(np.random.default_rng(seed), (-150.0, 150.0), prof)
    k = prims.label == BUILDING
    return prims.center[k], prims.half[k], plan


@pytest.mark.parametrize("seed", range(3))
def test_facades_stand_behind_the_sidewalk(seed):
    center, half, plan = _buildings(seed, (1.0, 0.0, 0.0, 0.0))
    assert len(center) >= 40  # every segment a building frontage
    near_face = np.abs(center[:, 1]) - half[:, 1]
    front = [curb_at(plan, int(np.sign(y)), x) + plan.sidewalk_width for x, y in center[:, :2]]
    assert np.all(near_face >= np.array(front) - 1e-9)


def test_more_building_frontages_build_more_and_nearer_buildings():
    def count_and_near(fp):
        parts = [_buildings(seed, fp) for seed in range(4)]
        count = sum(len(c) for c, _, _ in parts)
        near = sum(int(np.sum(np.abs(c[:, 1]) - h[:, 1] < 12.0)) for c, h, _ in parts)
        return count, near

    (n0, near0), (n1, near1) = (
        count_and_near((0.12, 0.5, 0.28, 0.1)),
        count_and_near((0.25, 0.37, 0.28, 0.1)),
    )
    assert n1 > n0 and near1 > near0


def test_frontage_shares_must_sum_to_one():
    with pytest.raises(InputError, match="frontage_p"):
        WorldProfile(frontage_p=(0.5, 0.5, 0.5, 0.5))


@pytest.mark.parametrize("world", WORLDS)
def test_row_62_files_are_row_56_worlds_with_more_building_frontages(world):
    changed = profile_changes(f"synth_buildings_{world}", f"synth_boards_{world}")
    assert changed == {"frontage_p": (0.25, 0.37, 0.28, 0.10)}


@pytest.mark.parametrize("world", WORLDS)
def test_row_63_files_are_row_56_worlds_with_building_frontages_at_0_30(world):
    changed = profile_changes(f"synth_more_buildings_{world}", f"synth_boards_{world}")
    assert changed == {"frontage_p": (0.30, 0.32, 0.28, 0.10)}
