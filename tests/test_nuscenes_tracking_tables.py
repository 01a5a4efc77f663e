"""The devkit-free table reader used by scoring (``NuScenesTables``, ``devkit_splits``,
``ChallengeClasses.from_nusc``) against the devkit's own ``NuScenes``, ``create_splits_scenes``
and ``PanopticClassMapper``."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from nuscenes_world import write_mini

from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar
from panoptic_bench.datasets.nuscenes_tables import NuScenesTables, devkit_splits
from panoptic_bench.errors import InputError
from panoptic_bench.evaluation.nuscenes import ChallengeClasses

VERSION = "v1.0-mini"


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    return write_mini(tmp_path_factory.mktemp("nustab") / "root")


def test_splits_equal_the_devkit() -> None:
    from nuscenes.utils.splits import create_splits_scenes

    assert devkit_splits() == create_splits_scenes(verbose=False)


def test_tables_answer_like_the_devkit(root) -> None:
    from nuscenes import NuScenes

    dk = NuScenes(VERSION, str(root), verbose=False)
    ours = NuScenesTables(root, VERSION)
    assert [s["name"] for s in ours.scene] == [s["name"] for s in dk.scene]
    for rec in dk.sample:
        assert ours.get("sample", rec["token"])["data"] == rec["data"]
    for rec in dk.sample_data:
        assert ours.get("sample_data", rec["token"])["filename"] == rec["filename"]
    assert ours.lidarseg_name2idx_mapping == dk.lidarseg_name2idx_mapping
    a = NuScenesLidar(root, VERSION, nusc=dk)
    b = NuScenesLidar.tables_only(root, VERSION)
    assert a.sample_data_tokens("mini_val") == b.sample_data_tokens("mini_val")
    assert hasattr(b.nusc, "lidarseg") and not hasattr(b.nusc, "panoptic")
    with pytest.raises(KeyError):
        ours.get("sample", "no-such-token")


def test_challenge_classes_equal_the_devkit_mapper(root) -> None:
    from nuscenes import NuScenes
    from nuscenes.eval.panoptic.utils import PanopticClassMapper

    dk = NuScenes(VERSION, str(root), verbose=False)
    mapper = PanopticClassMapper(dk)
    ours = ChallengeClasses.from_nusc(NuScenesTables(root, VERSION))
    fine = mapper.fine_idx_2_coarse_idx_mapping
    assert ours.names[0] == "ignore" and len(ours.names) == 17
    assert all(ours.lut[f] == c for f, c in fine.items())
    assert ours.dagger_things == tuple(mapper.things.values())
    assert ours.dagger_stuff == tuple(mapper.stuff.values())


SCRIPT = """
from nuscenes.eval.panoptic.utils import PanopticClassMapper
from panoptic_bench.datasets.nuscenes_spec import CHALLENGE_CLASSES, devkit_set_order
m = PanopticClassMapper.__new__(PanopticClassMapper)
m.ignore_class = m.get_ignore_class()
assert list(m.get_things()) == devkit_set_order(CHALLENGE_CLASSES[1:11])
assert list(m.get_stuff()) == devkit_set_order(CHALLENGE_CLASSES[11:])
"""


@pytest.mark.parametrize("seed", ["1", "12345"])
def test_dagger_order_matches_under_any_hash_seed(seed: str) -> None:
    env = dict(os.environ, PYTHONHASHSEED=seed)
    subprocess.run([sys.executable, "-c", SCRIPT], env=env, check=True)


def test_bad_tables(tmp_path) -> None:
    (tmp_path / VERSION).mkdir()
    with pytest.raises(InputError, match="table missing"):
        NuScenesTables(tmp_path, VERSION)
