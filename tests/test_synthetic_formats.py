"""Synthetic datasets on disk: SemanticKITTI layout, nuScenes dataroot, CLI behaviour."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from panoptic_bench.cli import main
from panoptic_bench.datasets import semantickitti as sk
from panoptic_bench.datasets.synthetic.writers import (
    CALIB_TR,
    generate_semantickitti,
    nuscenes_order,
    nuscenes_sequence,
    parse_sequences,
)
from panoptic_bench.errors import InputError

ALLOWED_RAW = {10, 11, 13, 15, 18, 20, 30, 31, 32, 40, 44, 48, 49, 50, 51, 70, 71, 72, 80, 81}
ALLOWED_RAW |= set(range(252, 260))


@pytest.fixture(scope="module")
def kitti_tree(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("synth") / "kitti"
    generate_semantickitti(root, {"00": 3, "08": 2}, seed=0, progress=False)
    return root


def test_semantickitti_layout(kitti_tree: Path):
    refs = sk.list_scans(kitti_tree)
    assert [(r.sequence, r.frame) for r in refs] == [
        ("00", "000000"), ("00", "000001"), ("00", "000002"), ("08", "000000"), ("08", "000001")
    ]  # fmt: skip
    seen: dict[int, int] = {}
    for ref in refs:
        pts = sk.read_scan(ref.scan)
        labels = sk.read_labels(ref.label)
        assert pts.shape[0] == labels.shape[0] and 100_000 < pts.shape[0] < 131_072
        sem, inst = sk.split_label(labels)
        assert set(np.unique(sem).tolist()) <= ALLOWED_RAW
        thing = np.isin(sk.to_train(sem), sk.LABELS.thing_ids)
        assert (inst[~thing] == 0).all() and (inst[thing] > 0).all()
        if ref.sequence == "00":
            for k in np.unique(inst[inst > 0]):
                raw = int(np.unique(sem[inst == k])[0])
                assert seen.setdefault(int(k), raw) == raw  # stable id, stable class
    for seq, n in (("00", 3), ("08", 2)):
        d = kitti_tree / "sequences" / seq
        poses = np.loadtxt(d / "poses.txt").reshape(-1, 3, 4)
        times = np.loadtxt(d / "times.txt")
        assert poses.shape[0] == n and times.shape == (n,)
        np.testing.assert_allclose(np.diff(times), 0.1)
        np.testing.assert_allclose(poses[0], np.eye(4)[:3], atol=1e-9)
        # the camera moves forward (+z in KITTI camera axes) between frames
        assert 0.4 < poses[-1, 2, 3] < 2.5 * (n - 1)
        calib = dict(line.split(":", 1) for line in (d / "calib.txt").read_text().splitlines())
        assert {"P0", "P1", "P2", "P3", "Tr"} <= set(calib)
        tr = np.array(calib["Tr"].split(), float).reshape(3, 4)
        np.testing.assert_allclose(tr, CALIB_TR[:3])


def test_semantickitti_deterministic_and_validates(kitti_tree: Path, tmp_path: Path):
    again = tmp_path / "again"
    generate_semantickitti(again, {"08": 2}, seed=0, progress=False)
    for name in ("velodyne/000001.bin", "labels/000001.label", "poses.txt"):
        a = (kitti_tree / "sequences/08" / name).read_bytes()
        assert a == (again / "sequences/08" / name).read_bytes()
    from panoptic_bench.evaluation.semantickitti import evaluate_semantickitti
    from panoptic_bench.evaluation.semantickitti_tools import validate_semantickitti

    preds = tmp_path / "preds"
    shutil.copytree(kitti_tree / "sequences/08/labels", preds / "sequences/08/predictions")
    n, problems = validate_semantickitti(
        kitti_tree, preds, split=None, sequences=["08"], progress=False
    )
    assert n == 2 and problems == []
    ev = evaluate_semantickitti(kitti_tree, preds, split=None, sequences=["08"], progress=False)
    res = ev.result()
    present = res.iou[1:] > 0  # classes absent from both trees score 0
    assert present.sum() >= 12 and np.all(res.pq[1:][present] == 1.0)


def test_cli_refuses_non_empty_output(tmp_path: Path, capsys):
    out = tmp_path / "busy"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    assert main(["synth", "semantickitti", "--out", str(out), "--sequences", "00:1"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert main(["synth", "nuscenes", "--out", str(out), "--scenes", "1", "--samples", "1"]) == 2
    assert (out / "keep.txt").read_text() == "x"
    with pytest.raises(InputError):
        parse_sequences("00-40")
    assert parse_sequences("0:4, 8:2") == {"00": 4, "08": 2}


def test_nuscenes_loads_and_devkit_panoptic_agrees(tmp_path: Path):
    from nuscenes import NuScenes

    from panoptic_bench.datasets.nuscenes_panoptic import make_panoptic_labels

    root = tmp_path / "nus"
    assert main(["synth", "nuscenes", "--out", str(root), "--scenes", "2", "--samples", "2"]) == 0
    nus = NuScenes("v1.0-mini", str(root), verbose=False)
    assert len(nus.scene) == 2 and len(nus.sample) == 4 and len(nus.sample_annotation) > 20
    cats = {
        nus.get("instance", a["instance_token"])["category_token"] for a in nus.sample_annotation
    }
    names = {c["name"] for c in nus.category if c["token"] in cats}
    assert {"vehicle.car", "human.pedestrian.adult"} <= names
    make_panoptic_labels(root, "v1.0-mini", root, progress=False)
    for si, scene in enumerate(nus.scene):
        seq = nuscenes_sequence(0, si, 2)
        tok, fi = scene["first_sample_token"], 0
        while tok:
            sample = nus.get("sample", tok)
            sd = sample["data"]["LIDAR_TOP"]
            pts = np.fromfile(root / nus.get("sample_data", sd)["filename"], np.float32).reshape(
                -1, 5
            )
            assert 0 <= pts[:, 3].min() and pts[:, 3].max() <= 255 and pts[:, 4].max() <= 31
            pan = np.load(root / "panoptic/v1.0-mini" / f"{sd}_panoptic.npz")["data"].astype(
                np.int64
            )
            sweep = seq.frame(fi).sweep
            ours = sweep.instance[nuscenes_order(sweep)].astype(np.int64)
            assert pan.shape == ours.shape
            cls, pid = pan // 1000, pan % 1000
            both = (ours > 0) & (pid > 0)
            # one-to-one correspondence of instances; devkit 0 only on a handful of points
            pairs = set(zip(ours[both].tolist(), pid[both].tolist()))
            assert len({a for a, _ in pairs}) == len(pairs) == len({b for _, b in pairs})
            assert ((ours > 0) & (pid == 0)).sum() <= 0.01 * max((ours > 0).sum(), 1)
            assert ((ours == 0) & (pid > 0)).sum() == 0
            assert ((cls >= 24) == (ours == 0)).mean() > 0.99
            tok, fi = sample["next"], fi + 1


def test_mixed_worlds_take_each_sequence_from_its_profile(tmp_path: Path, capsys):
    """``--profile a,b``: the k-th listed sequence is exactly what profile k mod 2 writes alone."""
    mixed, real_only, classic_only = tmp_path / "mixed", tmp_path / "r", tmp_path / "c"
    seqs = "03:1,01:1,02:1"  # order of the list, not of the ids, assigns the worlds
    assert main(["synth", "semantickitti", "--out", str(mixed), "--sequences", seqs,
                 "--profile", "realistic,classic"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert "world realistic (realistic): sequences 03, 02" in out
    assert "world classic (classic): sequences 01" in out
    generate_semantickitti(real_only, {"03": 1, "02": 1}, profile="realistic", progress=False)
    generate_semantickitti(classic_only, {"01": 1}, profile="classic", progress=False)
    for seq, alone in (("03", real_only), ("02", real_only), ("01", classic_only)):
        for name in ("velodyne/000000.bin", "labels/000000.label", "poses.txt"):
            got = (mixed / "sequences" / seq / name).read_bytes()
            assert got == (alone / "sequences" / seq / name).read_bytes()
    # the two worlds differ, so the test would see a swapped assignment
    other = generate_semantickitti(tmp_path / "c3", {"03": 1}, progress=False)
    a = (other / "sequences/03/velodyne/000000.bin").read_bytes()
    assert a != (mixed / "sequences/03/velodyne/000000.bin").read_bytes()


def test_mixed_worlds_bad_profile_is_one_error(tmp_path: Path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("lot_raise: [0.1]\n")
    out = tmp_path / "never"
    code = main(["synth", "semantickitti", "--out", str(out), "--sequences", "00:1,01:1",
                 "--profile", f"realistic,{bad}"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "bad.yaml" in err and "lot_raise" in err and "Traceback" not in err
    assert not out.exists()
    assert main(["synth", "semantickitti", "--out", str(out), "--sequences", "00:1",
                 "--profile", "realistic,"]) == 2  # fmt: skip
    assert "unknown profile ''" in capsys.readouterr().err and not out.exists()
