"""``eval semantickitti-4d`` through the CLI: the real sequences of ../shared/data/semantickitti-train
against 4D-PLS ``Panoptic4DEval`` (both reference-mode rules and the output files), the corrected
mode on ground truth, workers, and every bad-input case (exit 2, one message naming the file,
nothing written)."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest
from test_eval_4d_metrics import reference_eval

from panoptic_bench.cli import main
from panoptic_bench.datasets import semantickitti as sk

SEQS = ("00", "06")


def args4d(data: Path, pred: Path, out: Path, *extra: str) -> list[str]:
    return ["eval", "semantickitti-4d", "--dataset", str(data), "--predictions", str(pred),
            "--output", str(out), *extra]  # fmt: skip


def perturb(label: np.ndarray, frame: int, rng: np.random.Generator) -> np.ndarray:
    """A 4D prediction: class noise (class 0 included), an id switch, a merge and new ids."""
    sem, inst = label & 0xFFFF, (label >> 16).astype(np.int64)
    ids = np.unique(inst[inst > 0])
    out_inst = inst * 3 + 11 * (inst > 0)  # consistent renumbering along the sequence
    if len(ids) >= 3:
        if frame >= 4:  # id switch of the first object half-way
            out_inst[inst == ids[0]] = 999
        out_inst[inst == ids[2]] = out_inst[inst == ids[1]][0]  # merge of two objects
    noise = rng.random(len(label)) < 0.05
    sem = sem.copy()
    sem[noise] = rng.choice([0, 10, 40, 48, 70, 30], int(noise.sum()))  # class 0 = "unlabeled"
    return sk.make_label(sem, out_inst)


@pytest.fixture(scope="module")
def real_4d(shared_data: Path, tmp_path_factory) -> tuple[Path, Path, list]:
    root = shared_data / "semantickitti-train"
    pred_root = tmp_path_factory.mktemp("pred4d")
    rng = np.random.default_rng(4)
    frames = []
    for seq in SEQS:
        for ref in sk.list_sequence(root / "sequences" / seq):
            gt = sk.read_labels(ref.label)
            pred = perturb(gt, int(ref.frame), rng)
            sk.write_labels(sk.prediction_path(pred_root, ref), pred)
            frames.append((seq, pred, gt))
    return root, pred_root, frames


def reference_numbers(frames, min_points: int = 50):
    """What 4D-PLS evaluate_4dpanoptic.py computes (its loop, in process)."""
    ev = reference_eval(min_points)
    with contextlib.redirect_stdout(io.StringIO()):
        for seq, pred, gt in frames:
            lut = sk.LABELS.train_lut.astype(np.int32)
            ev.addBatch(seq, lut[pred & 0xFFFF], pred >> 16, lut[gt & 0xFFFF], gt >> 16)
        return ev.getPQ4D()


def test_real_sequences_match_4d_pls(real_4d, tmp_path, capsys) -> None:
    root, pred, frames = real_4d
    out = tmp_path / "out"
    assert main(args4d(root, pred, out, "--sequences", ",".join(SEQS))) == 0
    printed = capsys.readouterr().out
    assert "LSTQ" in printed and "15 scans" in printed
    scores = json.loads((out / "scores.json").read_text())
    lstq, s_assoc, aq, _, _, iou, s_cls = reference_numbers(frames)[:7]
    assert scores["mode"] == "reference"
    assert scores["all"]["LSTQ"] == pytest.approx(lstq, abs=1e-12)
    assert scores["all"]["S_assoc"] == pytest.approx(s_assoc, abs=1e-12)
    assert scores["all"]["S_cls"] == pytest.approx(s_cls, abs=1e-12)
    assert scores["all"]["phantom_class_0"] is True
    assert 0 < lstq < 1
    for c in (*sk.LABELS.thing_ids, *sk.LABELS.stuff_ids):
        m = scores["classes"][sk.LABELS.class_names[c]]
        assert m["IoU"] == pytest.approx(iou[c], abs=1e-12)
        assert m["AQ"] == pytest.approx(aq[c], abs=1e-12)
    csv = (out / "per_class.csv").read_text().splitlines()
    assert csv[0] == "class,kind,IoU,AQ,tubes" and len(csv) == 20
    assert "LSTQ:" in (out / "scores.txt").read_text()


def test_pool_size_rule(monkeypatch) -> None:
    from panoptic_bench.evaluation import workers

    monkeypatch.setattr(workers, "free_cpus", lambda: (8, "test: 8 free"))
    assert workers.pool_size(4, 10) == 1  # too little work for a pool
    assert workers.pool_size(2, 10 * workers.MIN_ITEMS_PER_WORKER) == 2
    assert workers.pool_size(8, 10 * workers.MIN_ITEMS_PER_WORKER, n_jobs=3) == 3
    monkeypatch.setattr(workers, "MIN_ITEMS_PER_WORKER", 1)
    assert workers.pool_size(2, 15) == 2


def test_workers_and_min_points_option(real_4d, tmp_path, monkeypatch) -> None:
    from panoptic_bench.evaluation import workers

    monkeypatch.setattr(workers, "MIN_ITEMS_PER_WORKER", 1)  # a real pool for 15 frames
    monkeypatch.setattr(workers, "free_cpus", lambda: (8, "test: 8 free"))
    root, pred, frames = real_4d
    outs = []
    for w in ("1", "2"):
        out = tmp_path / f"w{w}"
        extra = ("--sequences", "00,06", "--workers", w, "--min-inst-points", "100")
        assert main(args4d(root, pred, out, *extra)) == 0
        outs.append(json.loads((out / "scores.json").read_text()))
    assert outs[0] == outs[1]
    assert outs[0]["all"]["LSTQ"] == pytest.approx(reference_numbers(frames, 100)[0], abs=1e-12)


def test_ground_truth_scores_one_only_when_corrected(shared_data, tmp_path) -> None:
    root = shared_data / "semantickitti-train"
    pred = tmp_path / "gt"
    for ref in sk.list_sequence(root / "sequences" / "06"):
        sk.write_labels(sk.prediction_path(pred, ref), sk.read_labels(ref.label))
    got = {}
    for mode in ("reference", "corrected"):
        out = tmp_path / mode
        extra = ("--sequences", "06", "--mode", mode, "--by-range", "0,20,80")
        assert main(args4d(root, pred, out, *extra)) == 0
        got[mode] = json.loads((out / "scores.json").read_text())
    assert got["corrected"]["all"]["LSTQ"] == 1.0
    assert [r["all"]["LSTQ"] for r in got["corrected"]["by_range"]] == [1.0, 1.0]
    assert got["reference"]["all"]["LSTQ"] < 0.99  # 4D-PLS issue 14


# ------------------------------------------------------------------ bad input


def tiny_tree(root: Path, n_frames: int = 3) -> tuple[Path, Path]:
    rng = np.random.default_rng(1)
    data, pred = root / "data", root / "pred"
    for i in range(n_frames):
        pts = rng.normal(0, 10, (200, 4)).astype(np.float32)
        lab = sk.make_label(rng.choice([10, 40, 30], 200), rng.integers(0, 3, 200))
        sk.write_scan(data / "sequences" / "08" / "velodyne" / f"{i:06d}.bin", pts)
        sk.write_labels(data / "sequences" / "08" / "labels" / f"{i:06d}.label", lab)
        sk.write_labels(pred / "sequences" / "08" / "predictions" / f"{i:06d}.label", lab)
    return data, pred


@pytest.mark.parametrize("case", ["missing_frame", "extra_frame", "uint64_ids", "bad_raw_id"])
def test_bad_input_names_the_file(case: str, tmp_path: Path, capsys) -> None:
    data, pred = tiny_tree(tmp_path)
    pdir = pred / "sequences" / "08" / "predictions"
    bad = pdir / "000001.label"
    if case == "missing_frame":
        bad.unlink()
    elif case == "extra_frame":
        bad = pdir / "000003.label"
        sk.write_labels(bad, np.zeros(200, np.uint32))
    elif case == "uint64_ids":
        (np.arange(200, dtype=np.uint64) << np.uint64(20)).tofile(bad)  # ids >= 2**16
    else:
        sk.write_labels(bad, np.full(200, 7, np.uint32))
    out = tmp_path / "out"
    assert main(args4d(data, pred, out)) == 2
    err = capsys.readouterr().err.strip()
    assert str(bad) in err and "Traceback" not in err
    assert len(err.splitlines()) == 1
    assert not out.exists()


def test_bad_options(tmp_path: Path, capsys) -> None:
    data, pred = tiny_tree(tmp_path, 1)
    assert main(args4d(data, pred, data / "o")) == 2
    assert "inside the input tree" in capsys.readouterr().err
    assert main(args4d(data, pred, tmp_path / "o", "--by-range", "5,1")) == 2
    assert "--by-range" in capsys.readouterr().err
    assert main(args4d(data, pred, tmp_path / "o", "--workers", "0")) == 2
    assert main(args4d(data, pred, tmp_path / "o", "--min-inst-points", "-1")) == 2
    assert not (tmp_path / "o").exists()
