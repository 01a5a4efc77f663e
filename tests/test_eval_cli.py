"""``eval semantickitti``, ``validate semantickitti`` and ``semantickitti remap`` through the CLI:
numbers against the reference evaluator, output files, and every bad-input case (exit 2, one
message naming the file, no output written)."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from nuscenes.eval.panoptic.panoptic_seg_evaluator import PanopticEval

from panoptic_bench.cli import main
from panoptic_bench.datasets import semantickitti as sk
from panoptic_bench.evaluation.output import CODALAB_KEYS
from panoptic_bench.evaluation.semantickitti import label_stats

RAW_STUFF = [40, 44, 48, 49, 50, 51, 70, 71, 72, 80, 81, 0, 1, 60, 52]
RAW_THINGS = [10, 11, 15, 18, 20, 30, 31, 32, 252, 254]


def synthetic_scan(rng: np.random.Generator, n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    pts = rng.normal(0, 15, (n, 4)).astype(np.float32)
    sem = rng.choice(RAW_STUFF, n)
    things = rng.random(n) < 0.3
    sem[things] = rng.choice(RAW_THINGS, things.sum())
    inst = np.where(things, rng.integers(1, 5, n), 0)
    return pts, sk.make_label(sem, inst)


def make_tree(root: Path, seqs: dict[str, int], seed: int = 0) -> tuple[Path, Path]:
    """Dataset ``root/data`` and perfect predictions ``root/pred``."""
    rng = np.random.default_rng(seed)
    data, pred = root / "data", root / "pred"
    for seq, n_scans in seqs.items():
        for i in range(n_scans):
            pts, lab = synthetic_scan(rng)
            sk.write_scan(data / "sequences" / seq / "velodyne" / f"{i:06d}.bin", pts)
            sk.write_labels(data / "sequences" / seq / "labels" / f"{i:06d}.label", lab)
            sk.write_labels(pred / "sequences" / seq / "predictions" / f"{i:06d}.label", lab)
    return data, pred


def eval_args(data: Path, pred: Path, out: Path, *extra: str) -> list[str]:
    return ["eval", "semantickitti", "--dataset", str(data), "--predictions", str(pred),
            "--output", str(out), *extra]  # fmt: skip


def official_scores(scans, min_points: int = 50) -> dict[str, float]:
    """The numbers of semantic-kitti-api evaluate_panoptic.py, via the devkit's PanopticEval."""
    ev = PanopticEval(20, ignore=[0], min_points=min_points)
    for pred, gt in scans:
        ev.addBatch(sk.to_train(pred), pred.astype(np.int64), sk.to_train(gt), gt.astype(np.int64))
    _, _, _, pq, sq, rq = ev.getPQ()
    miou, iou = ev.getSemIoU()
    th, st = list(sk.LABELS.thing_ids), list(sk.LABELS.stuff_ids)
    tp, _, fn = ev.getSemIoUStats()
    present = [c for c in th + st if tp[c] + fn[c] > 0]
    return {
        "pq_mean": np.mean(pq[th + st]),
        "pq_dagger": np.mean(list(pq[th]) + list(iou[st])),
        "sq_mean": np.mean(sq[th + st]),
        "rq_mean": np.mean(rq[th + st]),
        "iou_mean": miou,
        "pq_stuff": np.mean(pq[st]),
        "rq_stuff": np.mean(rq[st]),
        "sq_stuff": np.mean(sq[st]),
        "pq_things": np.mean(pq[th]),
        "rq_things": np.mean(rq[th]),
        "sq_things": np.mean(sq[th]),
        "accuracy": ev.getSemAcc(),
        "car_pq": pq[1],
        "iou_present": np.mean(iou[present]),
        "n_present": len(present),
    }


@pytest.fixture(scope="module")
def real_pred(kitti_root: Path, tmp_path_factory) -> tuple[Path, list]:
    """Perturbed predictions of the 3 real scans: instance merges/splits and class changes."""
    root = tmp_path_factory.mktemp("realpred")
    rng = np.random.default_rng(5)
    scans = []
    for ref in sk.list_scans(kitti_root):
        gt = sk.read_labels(ref.label)
        sem, inst = sk.split_label(gt)
        n = len(gt)
        inst = np.where((inst % 2 == 1) & (rng.random(n) < 0.5), inst + 100, inst)
        sem = np.where((sem == 40) & (np.arange(n) % 5 == 0), 48, sem)
        sem = np.where(rng.random(n) < 0.05, rng.choice(RAW_STUFF, n), sem)
        pred = sk.make_label(sem, inst)
        sk.write_labels(sk.prediction_path(root, ref), pred)
        scans.append((pred, gt))
    return root, scans


def test_eval_real_scans_matches_official(
    kitti_root, real_pred, tmp_path, capsys, monkeypatch
) -> None:
    import panoptic_bench.evaluation.workers as workers

    monkeypatch.setattr(workers, "MIN_ITEMS_PER_WORKER", 1)  # a real 2-process pool
    monkeypatch.setattr(workers, "free_cpus", lambda: (8, "test: 8 free"))
    pred_root, scans = real_pred
    out1, out2 = tmp_path / "w1", tmp_path / "w2"
    assert main(eval_args(kitti_root, pred_root, out1, "--sequences", "00")) == 0
    args = eval_args(kitti_root, pred_root, out2, "--sequences", "0", "--workers", "2")
    assert main([*args, "--by-range", "0,10,20,40,80"]) == 0
    printed = capsys.readouterr().out
    assert "PQ_dagger" in printed and "10-20 m" in printed and "car" in printed

    ref = official_scores(scans)
    codalab = yaml.safe_load((out1 / "scores.txt").read_text())
    assert list(codalab) == sorted(CODALAB_KEYS)
    for key in CODALAB_KEYS:
        assert abs(codalab[key] - ref[key]) <= 1e-12, key
    scores = json.loads((out1 / "scores.json").read_text())
    assert abs(scores["all"]["accuracy"] - ref["accuracy"]) <= 1e-12
    assert abs(scores["classes"]["car"]["PQ"] - ref["car_pq"]) <= 1e-12
    # the mean over the classes with ground truth, from the official per-class IoU
    assert 0 < ref["n_present"] < 19
    assert abs(scores["all"]["mIoU_present"] - ref["iou_present"]) <= 1e-12
    assert scores["all"]["mIoU_present"] > scores["all"]["mIoU"]
    assert scores["n_scans"] == 3 and scores["by_range"] == []
    assert 0 < scores["all"]["PQ"] < 1
    scores2 = json.loads((out2 / "scores.json").read_text())
    assert scores2["all"] == scores["all"] and scores2["classes"] == scores["classes"]
    assert [b["range"] for b in scores2["by_range"]] == [[0, 10], [10, 20], [20, 40], [40, 80]]
    assert sum(b["points"] for b in scores2["by_range"]) > 0.9 * sum(len(g) for _, g in scans)
    rows = (out1 / "per_class.csv").read_text().splitlines()
    assert rows[0] == "class,kind,PQ,SQ,RQ,IoU" and len(rows) == 20
    assert rows[1].startswith("car,thing,") and rows[9].startswith("road,stuff,")


def test_real_scans_against_themselves_cli(kitti_root, tmp_path) -> None:
    pred = tmp_path / "pred" / "sequences" / "00" / "predictions"
    shutil.copytree(kitti_root / "sequences" / "00" / "labels", pred)
    assert main(eval_args(kitti_root, tmp_path / "pred", tmp_path / "o", "--sequences", "0")) == 0
    scores = json.loads((tmp_path / "o" / "scores.json").read_text())
    present = [n for n, m in scores["classes"].items() if m["IoU"] > 0]
    assert len(present) >= 10
    assert all(scores["classes"][n]["PQ"] == 1.0 for n in present)


def test_full_label_is_the_instance_id() -> None:
    # car (raw 10) and moving-car (raw 252) with the same instance bits: two gt segments
    gt = np.concatenate([sk.make_label(np.full(60, 10), np.full(60, 5)),
                         sk.make_label(np.full(60, 252), np.full(60, 5))])  # fmt: skip
    pred = sk.make_label(np.full(120, 10), np.full(120, 5))  # one predicted car
    stats, _ = label_stats(pred, gt, min_points=50)
    assert (stats.tp[1], stats.fp[1], stats.fn[1]) == (0, 1, 2)  # IoU 0.5 each: no match
    stats, _ = label_stats(gt, gt)
    assert (stats.tp[1], stats.fp[1], stats.fn[1]) == (2, 0, 0)


# --------------------------------------------------------------------------- bad input


def _missing(data, pred):
    path = pred / "sequences/08/predictions/000001.label"
    path.unlink()
    return path


def _extra(data, pred):
    path = pred / "sequences/08/predictions/000099.label"
    path.write_bytes(b"\0" * 16)
    return path


def _length(data, pred):
    path = pred / "sequences/08/predictions/000002.label"
    path.write_bytes(path.read_bytes()[:-8])
    return path


def _size4(data, pred):
    path = pred / "sequences/08/predictions/000000.label"
    path.write_bytes(path.read_bytes() + b"\0\0")
    return path


def _size16(data, pred):
    path = data / "sequences/08/velodyne/000001.bin"
    path.write_bytes(path.read_bytes()[:-4])
    return path


def _unknown_ids(data, pred):
    path = pred / "sequences/08/predictions/000001.label"
    lab = sk.read_labels(path)
    lab[3] = 7  # train-id style value, not a raw id
    sk.write_labels(path, lab)
    return path


def _empty_sequence(data, pred):
    path = data / "sequences/08/velodyne"
    for f in path.iterdir():
        f.unlink()
    return path


def _missing_sequence(data, pred):
    shutil.rmtree(data / "sequences/08")
    return data / "sequences/08"


def _unreadable_dir(data, pred):
    path = data / "sequences/08/velodyne"
    shutil.rmtree(path)
    path.write_text("not a directory")
    return path


BAD = {
    "missing prediction": (_missing, "missing"),
    "extra file": (_extra, "extra file"),
    "length mismatch": (_length, "labels but the scan has"),
    "size not multiple of 4": (_size4, "multiple of 4"),
    "bin not multiple of 16": (_size16, "multiple of 16"),
    "unknown raw ids": (_unknown_ids, "unknown raw label ids"),
    "empty sequence": (_empty_sequence, "empty sequence"),
    "missing sequence": (_missing_sequence, "not found"),
    "unreadable directory": (_unreadable_dir, "cannot read directory"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_eval_bad_input(case: str, tmp_path: Path, capsys) -> None:
    data, pred = make_tree(tmp_path, {"08": 3})
    breaker, text = BAD[case]
    path = breaker(data, pred)
    out = tmp_path / "out"
    assert main(eval_args(data, pred, out, "--split", "valid")) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert str(path) in err and text in err, err
    assert not out.exists()


def test_eval_unreadable_directory_permission(tmp_path: Path, capsys, monkeypatch) -> None:
    data, pred = make_tree(tmp_path, {"08": 1})
    velo = data / "sequences/08/velodyne"
    real = os.listdir

    def listdir(path):
        if Path(path) == velo:
            raise PermissionError(13, "Permission denied")
        return real(path)

    monkeypatch.setattr(os, "listdir", listdir)
    assert main(eval_args(data, pred, tmp_path / "out")) == 2
    err = capsys.readouterr().err
    assert f"{velo}: cannot read directory (Permission denied)" in err
    assert not (tmp_path / "out").exists()


def test_eval_bad_arguments(tmp_path: Path, capsys) -> None:
    data, pred = make_tree(tmp_path, {"08": 2})
    assert main(eval_args(data, pred, data / "scores")) == 2  # output inside the input
    assert "inside the input tree" in capsys.readouterr().err
    assert main(eval_args(data, pred, tmp_path / "o", "--by-range", "10,5")) == 2
    assert "--by-range" in capsys.readouterr().err
    assert main(eval_args(data, pred, tmp_path / "o", "--workers", "0")) == 2
    assert main(eval_args(data, pred, tmp_path / "o", "--split", "test")) == 2
    assert "sequences/11" in capsys.readouterr().err
    assert not (tmp_path / "o").exists() and not (data / "scores").exists()


def test_eval_synthetic_split_workers(tmp_path: Path, monkeypatch) -> None:
    import panoptic_bench.evaluation.workers as workers

    monkeypatch.setattr(workers, "MIN_ITEMS_PER_WORKER", 1)  # a real 2-process pool
    monkeypatch.setattr(workers, "free_cpus", lambda: (8, "test: 8 free"))
    data, pred = make_tree(tmp_path, {"08": 4})
    assert main(eval_args(data, pred, tmp_path / "o", "--workers", "2")) == 0
    scores = json.loads((tmp_path / "o" / "scores.json").read_text())
    assert scores["sequences"] == ["08"] and scores["n_scans"] == 4
    assert scores["all"]["mIoU"] == 1.0 and scores["all"]["accuracy"] == 1.0


def test_validate_lists_every_problem(tmp_path: Path, capsys) -> None:
    data, pred = make_tree(tmp_path, {"08": 6})
    broken = [f(data, pred) for f in (_missing, _extra, _length, _size4, _size16)]
    path = pred / "sequences/08/predictions/000003.label"
    lab = sk.read_labels(path)
    lab[0] = 9
    sk.write_labels(path, lab)
    broken.append(path)
    args = ["validate", "semantickitti", "--dataset", str(data), "--predictions", str(pred)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "validation of 6 scans found problems (6)" in err
    for p in broken:
        assert str(p) in err
    shutil.rmtree(tmp_path)
    data, pred = make_tree(tmp_path, {"08": 2})
    assert main(args) == 0
    assert "OK: 2 scans" in capsys.readouterr().out


def test_validate_empty_sequence_and_unreadable(tmp_path: Path, capsys) -> None:
    data, pred = make_tree(tmp_path, {"08": 1, "09": 1})
    _empty_sequence(data, pred)
    args = ["validate", "semantickitti", "--dataset", str(data), "--predictions", str(pred)]
    assert main([*args, "--sequences", "08,09,10"]) == 2
    err = capsys.readouterr().err
    assert "empty sequence" in err and "sequences/10: sequence directory not found" in err
    assert "validation of 1 scans found problems (2)" in err


# --------------------------------------------------------------------------- remap


def test_remap_round_trip_keeps_instances(kitti_root: Path, tmp_path: Path, capsys) -> None:
    src = kitti_root / "sequences"
    train, raw = tmp_path / "train", tmp_path / "raw"
    assert main(["semantickitti", "remap", "--input", str(src), "--output", str(train)]) == 0
    args = ["semantickitti", "remap", "--input", str(train), "--output", str(raw), "--inverse"]
    assert main(args) == 0
    for ref in sk.list_scans(kitti_root):
        gt = sk.read_labels(ref.label)
        rel = ref.label.relative_to(src)
        t = sk.read_labels(train / rel)
        np.testing.assert_array_equal(t >> 16, gt >> 16)
        np.testing.assert_array_equal(t & 0xFFFF, sk.to_train(gt))
        back = sk.read_labels(raw / rel)
        np.testing.assert_array_equal(back, sk.make_label(sk.to_raw(sk.to_train(gt)), gt >> 16))
    assert not list(train.rglob("*.bin"))
    capsys.readouterr()
    # raw files given to --inverse, output inside input, bad file: exit 2 and nothing written
    bad = ["semantickitti", "remap", "--input", str(src), "--output", str(tmp_path / "x")]
    assert main([*bad, "--inverse"]) == 2
    err = capsys.readouterr().err
    assert "000000.label" in err and "drop --inverse" in err and not (tmp_path / "x").exists()
    assert (
        main(["semantickitti", "remap", "--input", str(train), "--output", str(train / "a")]) == 2
    )
    assert "inside the input tree" in capsys.readouterr().err
    (raw / "00" / "labels" / "000001.label").write_bytes(b"\0" * 5)
    out = tmp_path / "y"
    assert main(["semantickitti", "remap", "--input", str(raw), "--output", str(out)]) == 2
    assert "000001.label" in capsys.readouterr().err and not out.exists()
