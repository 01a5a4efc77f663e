"""`synth nuscenes --scenes K`: every K writes at least one complete devkit split (usable by the
devkit's ``get_samples_in_panoptic_eval_set`` and the tracking evaluator) and prints which."""

from __future__ import annotations

import pytest
from nuscenes.utils.splits import create_splits_scenes

from panoptic_bench.cli import main
from panoptic_bench.datasets.nuscenes_spec import synthetic_scene_plan
from panoptic_bench.errors import InputError


@pytest.mark.parametrize("k", range(2, 11))
def test_every_mini_k_completes_a_split(k: int) -> None:
    names, complete = synthetic_scene_plan("v1.0-mini", k)
    splits = create_splits_scenes(verbose=False)
    assert len(names) == len(set(names)) == k
    assert complete and "mini_val" in complete
    for split in complete:
        assert set(splits[split]) <= set(names)
    assert ("mini_train" in complete) == (k == 10)


def test_trainval_and_test_need_their_smallest_split() -> None:
    assert synthetic_scene_plan("v1.0-trainval", 150)[1] == ["val"]
    assert synthetic_scene_plan("v1.0-test", 150)[1] == ["test"]
    with pytest.raises(InputError, match="val with 150 scenes"):
        synthetic_scene_plan("v1.0-trainval", 149)
    with pytest.raises(InputError, match="exceeds"):
        synthetic_scene_plan("v1.0-mini", 11)


def test_synth_two_scenes_usable_by_the_devkit(tmp_path, capsys) -> None:
    from nuscenes import NuScenes
    from nuscenes.eval.panoptic.utils import get_samples_in_panoptic_eval_set

    root = tmp_path / "nus"
    assert main(["synth", "nuscenes", "--out", str(root), "--scenes", "2", "--samples", "1"]) == 0
    assert "complete devkit split(s): mini_val" in capsys.readouterr().out
    nusc = NuScenes("v1.0-mini", str(root), verbose=False)
    assert len(get_samples_in_panoptic_eval_set(nusc, "mini_val")) == 2
    out = tmp_path / "one"
    assert main(["synth", "nuscenes", "--out", str(out), "--scenes", "1", "--samples", "1"]) == 2
    assert "--scenes >= 2" in capsys.readouterr().err
    assert not out.exists()
