"""Ensemble files (``checkpoint ensemble``, ``dsnet/inference/ensemble_file.py``): one file used
as ``--checkpoint`` predicts exactly as the members and views given on the command line, it
travels with its folder, the command line overrides it, and every bad file is one clear error."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from panoptic_bench.cli import main
from panoptic_bench.dsnet.checkpoint import load_checkpoint
from panoptic_bench.dsnet.data.datasets import ClassMap
from panoptic_bench.dsnet.inference.ensemble_file import (
    FORMAT,
    read_ensemble_file,
    write_ensemble_file,
)
from panoptic_bench.errors import InputError

sys.path.insert(0, str(Path(__file__).parent))
from dsnet_tiny_checkpoints import write_tiny_checkpoint  # noqa: E402
from dsnet_tiny_world import write_tiny_world  # noqa: E402

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def ckpts(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("ensemble_file")
    other = ClassMap("other", ("unlabeled", "a", "b"), (1,), (2,), (0,))
    return {
        "a": write_tiny_checkpoint(d / "a.pt", seed=0),
        "b": write_tiny_checkpoint(d / "b.pt", seed=1),
        "c": write_tiny_checkpoint(d / "c.pt", seed=2),
        "classes": write_tiny_checkpoint(d / "classes.pt", seed=4, class_map=other),
    }


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> Path:
    return write_tiny_world(tmp_path_factory.mktemp("ensemble_world") / "w", {"08": 1})


def _infer(world: Path, out: Path, *extra: str) -> int:
    args = ["infer", "--data", str(world), "--split", "08", "--out", str(out), "--no-progress"]
    return main([*args, *extra])


def _tree(out: Path) -> dict[str, bytes]:
    """Every prediction and centre file of a tree, by relative path."""
    files = sorted(out.glob("sequences/08/*/*"))
    return {f.relative_to(out).as_posix(): f.read_bytes() for f in files if f.is_file()}


def test_round_trip_stores_members_relative_to_the_file(ckpts, tmp_path):
    folder = tmp_path / "models"
    folder.mkdir()
    for name in ("a", "b"):
        shutil.copy(ckpts[name], folder / f"{name}.pt")
    spec = write_ensemble_file(folder / "e.json", [folder / "a.pt", folder / "b.pt"], 3, "two")
    raw = json.loads((folder / "e.json").read_text())
    assert raw == {"format": FORMAT, "members": ["a.pt", "b.pt"], "tta_views": 3, "notes": "two"}
    assert spec.members == (folder / "a.pt", folder / "b.pt") and spec.tta_views == 3
    moved = tmp_path / "elsewhere"
    shutil.move(folder, moved)
    again = read_ensemble_file(moved / "e.json")
    assert again.members == (moved / "a.pt", moved / "b.pt")


def test_a_file_predicts_as_its_members_and_views_on_the_command_line(
    ckpts, world, tmp_path, capsys
):
    e = write_ensemble_file(tmp_path / "e.json", [ckpts["a"], ckpts["b"]], tta_views=2).path
    assert _infer(world, tmp_path / "file", "--checkpoint", str(e)) == 0
    given = ["--checkpoint", str(ckpts["a"]), "--ensemble", str(ckpts["b"]), "--tta-views", "2"]
    assert _infer(world, tmp_path / "flags", *given) == 0
    assert "DS-Net (ensemble of 2): 1 scans" in capsys.readouterr().out
    a, b = _tree(tmp_path / "file"), _tree(tmp_path / "flags")
    assert len(a) >= 2 and a == b
    # without the file's views the prediction changes: the views are part of the file
    assert _infer(world, tmp_path / "one_view", *given[:4]) == 0
    assert _tree(tmp_path / "one_view") != a


def test_the_command_line_overrides_views_and_adds_members(ckpts, world, tmp_path, capsys):
    e = write_ensemble_file(tmp_path / "e.json", [ckpts["a"], ckpts["b"]], tta_views=2).path
    assert _infer(world, tmp_path / "v1", "--checkpoint", str(e), "--tta-views", "1") == 0
    flags = ["--checkpoint", str(ckpts["a"]), "--ensemble", str(ckpts["b"])]
    assert _infer(world, tmp_path / "flags", *flags) == 0
    assert _tree(tmp_path / "v1") == _tree(tmp_path / "flags")
    capsys.readouterr()
    assert (
        _infer(world, tmp_path / "three", "--checkpoint", str(e), "--ensemble", str(ckpts["c"]))
        == 0
    )
    assert "DS-Net (ensemble of 3)" in capsys.readouterr().out
    meta = json.loads((tmp_path / "three" / "run.json").read_text())
    assert f"checkpoint {ckpts['a']}" in meta["notes"] and str(ckpts["c"]) in meta["notes"]
    assert f"from the ensemble file {e} (2 views each)" in meta["notes"]


def test_checkpoint_ensemble_command_checks_members_before_writing(ckpts, tmp_path, capsys):
    out = tmp_path / "e.json"
    cmd = ["checkpoint", "ensemble", str(ckpts["a"]), str(ckpts["b"]), "--out", str(out)]
    assert main([*cmd, "--tta-views", "4", "--notes", "n"]) == 0
    assert "2 members, 4 view(s) each" in capsys.readouterr().out
    assert read_ensemble_file(out).tta_views == 4
    assert main([*cmd, "--tta-views", "4"]) == 2  # exists: refused without --overwrite
    assert "exists" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    assert (
        main(["checkpoint", "ensemble", str(ckpts["a"]), str(ckpts["classes"]), "--out", str(bad)])
        == 2
    )
    err = capsys.readouterr().err
    assert "predicts other classes" in err and "Traceback" not in err
    assert not bad.exists()


def _write(path: Path, doc) -> Path:
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return path


@pytest.mark.parametrize(
    ("doc", "message"),
    [
        ("{not json", "cannot read ensemble file"),
        ({"format": "other/1", "members": ["a.pt"]}, "not a panoptic-bench ensemble file"),
        ({"format": FORMAT, "members": ["a.pt"], "views": 2}, "unknown keys ['views']"),
        ({"format": FORMAT, "members": []}, "'members' must be a non-empty list"),
        (
            {"format": FORMAT, "members": ["a.pt"], "tta_views": 0},
            "'tta_views' must be an integer in 1..16",
        ),
        ({"format": FORMAT, "members": ["a.pt"], "tta_views": 17}, "in 1..16, got 17"),
        ({"format": FORMAT, "members": ["a.pt"], "tta_views": True}, "in 1..16, got True"),
        (
            {"format": FORMAT, "members": ["a.pt", "gone.pt"]},
            "member checkpoint 'gone.pt' not found",
        ),
        ({"format": FORMAT, "members": ["a.pt", "inner.json"]}, "is itself an ensemble file"),
        ({"format": FORMAT, "members": ["a.pt"], "notes": 3}, "'notes' must be a string"),
    ],
)
def test_bad_files_are_one_clear_error(ckpts, world, tmp_path, capsys, doc, message):
    shutil.copy(ckpts["a"], tmp_path / "a.pt")
    _write(tmp_path / "inner.json", {"format": FORMAT, "members": ["a.pt"]})
    path = _write(tmp_path / "e.json", doc)
    with pytest.raises(InputError, match=r"e\.json") as info:
        read_ensemble_file(path)
    assert message in str(info.value)
    out = tmp_path / "out"
    assert _infer(world, out, "--checkpoint", str(path)) == 2
    err = capsys.readouterr().err
    assert message in err and str(path) in err and "Traceback" not in err
    assert not out.exists()


def test_an_ensemble_file_is_not_one_checkpoint(ckpts, tmp_path, capsys):
    e = write_ensemble_file(tmp_path / "e.json", [ckpts["a"], ckpts["b"]]).path
    with pytest.raises(InputError, match="an ensemble file, not one checkpoint"):
        load_checkpoint(e)
    assert main(["checkpoint", "show", str(e)]) == 2
    assert "an ensemble file, not one checkpoint" in capsys.readouterr().err


def test_the_demo_note_names_each_members_training(ckpts, tmp_path):
    from panoptic_bench.demo.steps import training_overlap_note

    e = write_ensemble_file(tmp_path / "e.json", [ckpts["a"], ckpts["b"]]).path
    note = training_overlap_note(e, ("08",))
    single = training_overlap_note(ckpts["a"], ("08",)).removeprefix("; ")
    assert note == f"; member 1: {single} | member 2: {single}"


def test_checkpoint_list_names_every_shipped_name(capsys):
    from panoptic_bench.dsnet.checkpoint import SHIPPED

    assert main(["checkpoint", "list"]) == 0
    out = capsys.readouterr().out
    for name, file in SHIPPED.items():
        assert f"{name} " in out and file in out
    assert np.all([line.split()[0] in SHIPPED for line in out.splitlines()])


def test_shipped_ensembles_name_shipped_members(world, tmp_path, capsys):
    from panoptic_bench.demo.steps import TRAINED_ON
    from panoptic_bench.dsnet.checkpoint import SHIPPED, shipped_checkpoints
    from panoptic_bench.dsnet.inference.ensemble_file import is_ensemble_file

    shipped = shipped_checkpoints()
    files = {n: p for n, p in shipped.items() if is_ensemble_file(p)}
    assert "synthetic-ensemble" in files
    for path in files.values():
        spec = read_ensemble_file(path)
        assert len(spec.members) >= 2 and 1 <= spec.tta_views <= 16
        for member in spec.members:
            assert member.parent == path.parent and member.name in SHIPPED.values()
            assert member.name in TRAINED_ON
    out = tmp_path / "out"
    assert _infer(world, out, "--checkpoint", "synthetic-ensemble", "--max-scans", "1") == 0
    assert "DS-Net (ensemble of 3): 1 scans" in capsys.readouterr().out
    meta = json.loads((out / "run.json").read_text())
    assert "from the ensemble file" in meta["notes"] and "(4 views each)" in meta["notes"]
