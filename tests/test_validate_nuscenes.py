"""`validate nuscenes`: a valid submission passes; every kind of problem is listed in one run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from nuscenes_world import write_mini

from panoptic_bench.cli import main
from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar

VERSION = "v1.0-mini"
META = {"task": "segmentation", "use_camera": False, "use_lidar": True, "use_radar": False,
        "use_map": False, "use_external": False}  # fmt: skip


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    return write_mini(tmp_path_factory.mktemp("nusv") / "root")


@pytest.fixture(scope="module")
def counts(root) -> dict[str, int]:
    reader = NuScenesLidar(root, VERSION)
    return {t: reader.num_points(t) for t in reader.sample_data_tokens("mini_val")}


def submission(res: Path, counts: dict[str, int], meta: dict | None = None) -> Path:
    folder = res / "panoptic" / "mini_val"
    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for tok, n in counts.items():
        sem = rng.integers(0, 17, n)
        inst = np.where((sem >= 1) & (sem <= 10), rng.integers(0, 999, n), 0)
        np.savez_compressed(
            folder / f"{tok}_panoptic.npz", data=(sem * 1000 + inst).astype(np.uint16)
        )
    (res / "mini_val").mkdir()
    (res / "mini_val" / "submission.json").write_text(json.dumps({"meta": meta or META}))
    return res


def run(root: Path, res: Path) -> int:
    return main(["validate", "nuscenes", "--dataroot", str(root), "--version", VERSION,
                 "--result-path", str(res), "--eval-set", "mini_val"])  # fmt: skip


def test_valid_submission_passes(root, counts, tmp_path, capsys) -> None:
    res = submission(tmp_path / "res", counts)
    assert run(root, res) == 0
    assert f"OK: {len(counts)} samples" in capsys.readouterr().out


def test_every_problem_listed_at_once(root, counts, tmp_path, capsys) -> None:
    meta = dict(META, use_map="no")
    del meta["use_external"]
    res = submission(tmp_path / "res", counts, meta)
    folder = res / "panoptic" / "mini_val"
    toks = list(counts)
    bad = {}
    (folder / f"{toks[0]}_panoptic.npz").unlink()
    bad["missing"] = folder / f"{toks[0]}_panoptic.npz"
    n1 = counts[toks[1]]
    np.savez_compressed(folder / f"{toks[1]}_panoptic.npz", data=np.zeros(n1, np.int32))
    bad["dtype"] = folder / f"{toks[1]}_panoptic.npz"
    np.savez_compressed(folder / f"{toks[2]}_panoptic.npz", data=np.zeros(5, np.uint16))
    bad["count"] = folder / f"{toks[2]}_panoptic.npz"
    lab = np.full(counts[toks[3]], 11000, np.uint16)
    lab[:3] = 17001  # class 17
    lab[3:5] = 12005  # stuff class with an instance id
    np.savez_compressed(folder / f"{toks[3]}_panoptic.npz", data=lab)
    np.savez_compressed(folder / f"{toks[4]}_panoptic.npz", labels=lab)
    (folder / "stray.npz").write_bytes(b"x")
    assert run(root, res) == 2
    err = capsys.readouterr().err
    assert "found problems (9)" in err
    for words in ("missing", "must be uint16, got int32", "5 labels but the sweep has",
                  "class ids outside 0..16", "carry an instance id", "no 'data' array",
                  "stray.npz: extra file", "meta lacks use_external",
                  "meta.use_map must be true or false"):  # fmt: skip
        assert words in err, words
    for path in bad.values():
        assert str(path) in err


def test_submission_json_and_folder_missing(root, counts, tmp_path, capsys) -> None:
    res = tmp_path / "empty"
    res.mkdir()
    assert run(root, res) == 2
    err = capsys.readouterr().err
    assert "submission.json missing" in err and "prediction folder missing" in err


def test_bad_task_in_meta(root, counts, tmp_path, capsys) -> None:
    res = submission(tmp_path / "res", counts, dict(META, task="detection"))
    assert run(root, res) == 2
    assert "meta.task must be 'segmentation' or 'tracking'" in capsys.readouterr().err
