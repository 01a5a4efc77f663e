"""Panoptic label generation: byte-identical to the devkit's generate_panoptic_labels."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from nuscenes_world import CAR, real_sweep, tree_bytes, tree_snapshot, write_mini

import panoptic_bench.datasets.nuscenes_boxes as boxes_mod
from panoptic_bench.cli import main
from panoptic_bench.datasets.nuscenes_boxes import BoxFrames, points_in_boxes

VERSION = "v1.0-mini"


@pytest.fixture(scope="module")
def mini(tmp_path_factory, shared_data) -> Path:
    return write_mini(tmp_path_factory.mktemp("nus") / "root", real_sweep(shared_data))


@pytest.fixture(scope="module")
def devkit_labels(mini, tmp_path_factory) -> Path:
    from nuscenes import NuScenes
    from nuscenes.panoptic.generate_panoptic_labels import generate_panoptic_labels

    out = tmp_path_factory.mktemp("devkit")
    generate_panoptic_labels(NuScenes(VERSION, str(mini), verbose=False), str(out))
    return out


def _make(mini: Path, out: Path, *extra: str) -> int:
    args = ["nuscenes", "make-labels", "--dataroot", str(mini), "--version", VERSION]
    return main([*args, "--out-dir", str(out), *extra])


@pytest.mark.parametrize("workers", [1, 2])
def test_byte_identical_to_devkit(mini, devkit_labels, tmp_path, workers, monkeypatch):
    calls = []
    original = boxes_mod._devkit_mask
    monkeypatch.setattr(boxes_mod, "_devkit_mask", lambda *a: calls.append(1) or original(*a))
    before = tree_snapshot(mini)
    assert _make(mini, tmp_path / "out", "--workers", str(workers)) == 0
    ours, theirs = tree_bytes(tmp_path / "out"), tree_bytes(devkit_labels)
    assert sorted(ours) == sorted(theirs) and len(ours) == 11 + 2
    assert ours == theirs  # every .npz, panoptic.json and category.json byte for byte
    assert tree_snapshot(mini) == before  # the dataroot is only read
    if workers == 1:
        assert calls  # points exactly on faces were decided by the devkit's own test


def test_fixture_has_every_rule(devkit_labels, mini):
    """The fixture exercises overlaps, thing points without box, recurring instance ids."""
    rows = json.loads((devkit_labels / VERSION / "panoptic.json").read_text())
    labels = [np.load(devkit_labels / r["filename"])["data"] for r in rows]
    segs = [
        np.fromfile(mini / "lidarseg" / VERSION / f"{r['token']}_lidarseg.bin", np.uint8)
        for r in rows
    ]
    zeroed_things = sum(int(((s == CAR) & (lab == 0)).sum()) for s, lab in zip(segs, labels))
    assert zeroed_things > 25 * len(rows)  # outside boxes and in overlaps
    # car-a of the first scene keeps id 1 in every sample
    for lab in labels[:2]:
        assert (lab == CAR * 1000 + 1).sum() > 0
    ids = {int(v) % 1000 for lab in labels for v in np.unique(lab)}
    assert max(ids) >= 5


def test_points_in_boxes_matches_devkit_on_random_boxes():
    from nuscenes.utils.data_classes import Box
    from nuscenes.utils.geometry_utils import points_in_box
    from pyquaternion import Quaternion

    rng = np.random.default_rng(3)
    pts = (rng.uniform(-20, 20, (20000, 3)) * [1, 1, 0.2]).astype(np.float32)
    n = 60
    q = rng.normal(size=(n, 4))
    frames = BoxFrames(
        translation=rng.uniform(-15, 15, (n, 3)) + [500.0, -300.0, 2.0],
        size=rng.uniform(0.3, 6, (n, 3)),
        rotation=q / np.linalg.norm(q, axis=1, keepdims=True),
        ego_translation=np.array([500.0, -300.0, 1.0]),
        ego_rotation=np.array(Quaternion(axis=[0.1, 0, 1], angle=2.0).elements),
        calib_translation=np.array([0.9, 0.0, 1.8]),
        calib_rotation=np.array(Quaternion(axis=[0, 0, 1], angle=-1.5).elements),
    )
    bi, pi = points_in_boxes(pts, frames)
    for b in range(n):
        box = Box(
            frames.translation[b].tolist(), frames.size[b].tolist(), Quaternion(frames.rotation[b])
        )
        box.translate(-frames.ego_translation)
        box.rotate(Quaternion(frames.ego_rotation).inverse)
        box.translate(-frames.calib_translation)
        box.rotate(Quaternion(frames.calib_rotation).inverse)
        assert np.array_equal(pi[bi == b], np.flatnonzero(points_in_box(box, pts.T)))
    assert len(pi) > 500


def test_points_in_boxes_non_finite_points_and_boxes_off_the_sweep():
    """NaN/inf points are in no box; boxes reaching past the points' extent still see them."""
    from nuscenes.utils.data_classes import Box
    from nuscenes.utils.geometry_utils import points_in_box
    from pyquaternion import Quaternion

    rng = np.random.default_rng(5)
    pts = rng.uniform(-3, 3, (3000, 3))  # float64 input as well
    pts[::97] = np.nan
    pts[5::101, 1] = np.inf
    pts[7] = [1e9, 0, 0]  # one far point: coarse grid, larger tolerance
    n = 12
    frames = BoxFrames(
        translation=np.c_[rng.uniform(-4, 4, (n, 2)), np.zeros(n)],
        size=rng.uniform(1, 4, (n, 3)),
        rotation=np.array([Quaternion(axis=[0, 0, 1], angle=a).elements for a in range(n)]),
        ego_translation=np.zeros(3),
        ego_rotation=np.array([1.0, 0, 0, 0]),
        calib_translation=np.zeros(3),
        calib_rotation=np.array([1.0, 0, 0, 0]),
    )
    bi, pi = points_in_boxes(pts, frames)
    with np.errstate(invalid="ignore"):
        for b in range(n):
            box = Box(frames.translation[b], frames.size[b], Quaternion(frames.rotation[b]))
            assert np.array_equal(pi[bi == b], np.flatnonzero(points_in_box(box, pts.T)))
    assert np.all(np.isfinite(pts[pi])) and len(pi) > 100
    assert np.all(np.diff(bi) >= 0)


def test_reuses_a_loaded_devkit_object(mini, devkit_labels, tmp_path):
    from nuscenes import NuScenes

    from panoptic_bench.datasets.nuscenes_panoptic import make_panoptic_labels

    nusc = NuScenes(VERSION, str(mini), verbose=False)
    make_panoptic_labels(mini, VERSION, tmp_path / "out", nusc=nusc, progress=False)
    assert tree_bytes(tmp_path / "out") == tree_bytes(devkit_labels)


def _corrupt_copy(mini: Path, tmp_path: Path) -> Path:
    root = tmp_path / "bad"
    shutil.copytree(mini, root)
    return root


def _lidarseg_rows(root: Path) -> list[dict]:
    return json.loads((root / VERSION / "lidarseg.json").read_text())


def _drop_lidarseg_table(root: Path) -> str:
    shutil.rmtree(root / "lidarseg")
    (root / VERSION / "lidarseg.json").unlink()
    return "lidarseg.json"


def _drop_lidarseg_file(root: Path) -> str:
    row = _lidarseg_rows(root)[4]
    (root / row["filename"]).unlink()
    return row["filename"]


def _short_lidarseg(root: Path) -> str:
    row = _lidarseg_rows(root)[2]
    path = root / row["filename"]
    path.write_bytes(path.read_bytes() + b"\x00")
    return row["sample_data_token"]


def _no_lidar_top(root: Path) -> str:
    table = root / VERSION / "sample_data.json"
    rows = json.loads(table.read_text())
    rows[5]["is_key_frame"] = False
    table.write_text(json.dumps(rows))
    return rows[5]["sample_token"]


@pytest.mark.parametrize(
    "corrupt, version, words",
    [
        (_drop_lidarseg_table, VERSION, "no nuScenes-lidarseg"),
        (_drop_lidarseg_file, VERSION, "is missing"),
        (_short_lidarseg, VERSION, "points"),
        (_no_lidar_top, VERSION, "has no keyframe LIDAR_TOP"),
        (lambda root: "v1.0-trainval", "v1.0-trainval", "unknown version folder"),
    ],
)
def test_bad_input(mini, tmp_path, capsys, corrupt, version, words):
    root = _corrupt_copy(mini, tmp_path)
    named = corrupt(root)
    out = tmp_path / "out"
    args = ["nuscenes", "make-labels", "--dataroot", str(root), "--version", version]
    assert main([*args, "--out-dir", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("panoptic-bench: error:") and len(err.strip().splitlines()) == 1
    assert words in err and named in err
    assert not out.exists()
