"""Scan-level bootstrap: hand-worked cases, properties, and the eval / compare command line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from panoptic_bench.cli import main
from panoptic_bench.datasets import semantickitti as sk
from panoptic_bench.evaluation.per_scan import read_per_scan
from panoptic_bench.metrics.accumulator import PanopticStats
from panoptic_bench.metrics.bootstrap import (
    _replicates,
    bootstrap,
    paired_bootstrap,
    resample_counts,
)
from panoptic_bench.metrics.panoptic import panoptic_stats

THINGS, STUFF = (1,), (2, 3)


def _scan(rng: np.random.Generator, n: int = 300, noise: float = 0.2) -> PanopticStats:
    gt = rng.integers(1, 4, n)
    gi = np.where(gt == 1, rng.integers(1, 4, n), 0)
    flip = rng.random(n) < noise
    pred = np.where(flip, rng.integers(0, 4, n), gt)
    pi = np.where(pred == 1, gi + flip, 0)
    return panoptic_stats(pred, pi, gt, gi, num_classes=4, ignore=(0,), min_points=1)


def _scans(seed: int, k: int, noise: float = 0.2) -> list[PanopticStats]:
    rng = np.random.default_rng(seed)
    return [_scan(rng, noise=noise) for _ in range(k)]


def test_resample_counts_rows_are_draws_of_all_scans():
    c = resample_counts(7, 500, seed=3)
    assert c.shape == (500, 7) and (c.sum(1) == 7).all() and c.min() >= 0
    assert np.array_equal(c, resample_counts(7, 500, seed=3))
    assert not np.array_equal(c, resample_counts(7, 500, seed=4))
    # each scan is drawn once per replicate on average
    assert c.mean() == pytest.approx(1.0) and abs(c.mean(0) - 1).max() < 0.2
    with pytest.raises(ValueError):
        resample_counts(0, 10)


def test_a_replicate_of_every_scan_once_is_the_dataset_score():
    scans = _scans(0, 6)
    total = sum(scans, PanopticStats.zeros(4)).compute().summary(THINGS, STUFF)
    reps = _replicates(scans, np.ones((1, 6), np.int64), THINGS, STUFF)
    got = {k: float(v[0]) for k, v in reps.items()}
    assert got == pytest.approx(total, abs=1e-12)  # same formulas; IoU sums to round-off
    assert {k: got[k] for k in ("RQ", "mIoU")} == {
        k: total[k] for k in ("RQ", "mIoU")
    }  # counts only
    # a replicate drawing scan 2 three times equals adding its counts three times
    w = np.array([[1, 0, 3, 0, 1, 1]])
    by_hand = scans[0] + scans[2] + scans[2] + scans[2] + scans[4] + scans[5]
    got = {k: float(v[0]) for k, v in _replicates(scans, w, THINGS, STUFF).items()}
    assert got == pytest.approx(by_hand.compute().summary(THINGS, STUFF), abs=1e-12)


def test_identical_scans_give_a_zero_width_interval():
    one = _scans(1, 1)[0]
    got = bootstrap([one] * 5, THINGS, STUFF, n_boot=200)
    for k, v in got.estimate.items():
        assert got.low[k] == pytest.approx(v, abs=1e-12) == got.high[k]


def test_interval_contains_the_estimate_and_narrows_with_more_scans():
    few = bootstrap(_scans(2, 4, noise=0.4), THINGS, STUFF, n_boot=400)
    many = bootstrap(_scans(2, 64, noise=0.4), THINGS, STUFF, n_boot=400)
    for k in ("PQ", "mIoU"):
        assert few.low[k] <= few.estimate[k] <= few.high[k]
        assert many.high[k] - many.low[k] < few.high[k] - few.low[k]
    d = few.to_dict()
    assert d["unit"] == "scan" and "correlated" in d["caveat"]
    with pytest.raises(ValueError, match="level"):
        bootstrap(_scans(2, 3), THINGS, STUFF, level=1.0)


def test_paired_bootstrap_sees_a_consistent_improvement():
    rng = np.random.default_rng(5)
    gts = [
        (rng.integers(1, 4, 300), None) for _ in range(8)
    ]  # shared scans, two predictors: B makes fewer semantic errors on every scan
    a, b = [], []
    for gt, _ in gts:
        gi = np.where(gt == 1, 1 + (np.arange(300) % 3), 0)
        for noise, out in ((0.3, a), (0.1, b)):
            flip = rng.random(300) < noise
            pred = np.where(flip, rng.integers(1, 4, 300), gt)
            out.append(panoptic_stats(pred, gi, gt, gi, num_classes=4, ignore=(0,), min_points=1))
    got = paired_bootstrap(a, b, THINGS, STUFF, n_boot=500)
    assert got.b["mIoU"] > got.a["mIoU"] and got.low["mIoU"] > 0 and got.p_b_greater["mIoU"] == 1
    same = paired_bootstrap(a, a, THINGS, STUFF, n_boot=100)
    assert same.low["PQ"] == same.high["PQ"] == 0 and same.p_b_greater["PQ"] == 0
    with pytest.raises(ValueError, match="scans"):
        paired_bootstrap(a, b[:-1], THINGS, STUFF)


def _tree(root: Path, seq_scans: dict[str, int], noise: float, seed: int) -> tuple[Path, Path]:
    """Dataset ``root/data`` and predictions ``root/pred`` with ``noise`` wrong classes."""
    rng = np.random.default_rng(seed)
    data, pred = root / "data", root / "pred"
    stuff_raw, thing_raw = np.array([40, 48, 70]), np.array([10, 30])
    for seq, n in seq_scans.items():
        for i in range(n):
            m = 400
            sem = rng.choice(stuff_raw, m)
            things = rng.random(m) < 0.3
            sem[things] = rng.choice(thing_raw, things.sum())
            inst = np.where(things, rng.integers(1, 4, m), 0)
            psem = np.where(rng.random(m) < noise, rng.choice(stuff_raw, m), sem)
            pts = rng.normal(0, 15, (m, 4)).astype(np.float32)
            sk.write_scan(data / "sequences" / seq / "velodyne" / f"{i:06d}.bin", pts)
            sk.write_labels(data / "sequences" / seq / "labels" / f"{i:06d}.label",
                            sk.make_label(sem, inst))  # fmt: skip
            path = pred / "sequences" / seq / "predictions" / f"{i:06d}.label"
            sk.write_labels(path, sk.make_label(psem, np.where(np.isin(psem, thing_raw), inst, 0)))
    return data, pred


def _eval(data: Path, pred: Path, out: Path, *extra: str) -> list[str]:
    return ["eval", "semantickitti", "--dataset", str(data), "--predictions", str(pred),
            "--sequences", "08,09", "--output", str(out), *extra]  # fmt: skip


def test_eval_writes_per_scan_counts_and_intervals_and_compare(tmp_path: Path, capsys):
    data, pred_a = _tree(tmp_path / "a", {"08": 4, "09": 3}, noise=0.3, seed=0)
    _, pred_b = _tree(tmp_path / "b", {"08": 4, "09": 3}, noise=0.05, seed=0)
    data_b = tmp_path / "b" / "data"
    assert main(_eval(data, pred_a, tmp_path / "ea", "--bootstrap", "300")) == 0
    assert main(_eval(data_b, pred_b, tmp_path / "eb")) == 0
    out = capsys.readouterr().out
    assert "95 % intervals, 300 bootstrap replicates of 7 scans" in out
    scores = json.loads((tmp_path / "ea" / "scores.json").read_text())
    per = read_per_scan(tmp_path / "ea")
    assert per.scans == (*(f"08/{i:06d}" for i in range(4)), *(f"09/{i:06d}" for i in range(3)))
    total = sum(per.stats, PanopticStats.zeros(20)).compute().summary(per.things, per.stuff)
    for key, value in scores["all"].items():  # the per-scan counts add up to the scores
        assert total[key] == pytest.approx(value, abs=1e-12)
        b = scores["bootstrap"]["metrics"][key]
        assert b["estimate"] == pytest.approx(value, abs=1e-12) and b["low"] <= b["high"]
    assert "bootstrap" not in json.loads((tmp_path / "eb" / "scores.json").read_text())
    # paired comparison: B (fewer errors) is better on every resample
    args = ["eval", "compare", str(tmp_path / "ea"), str(tmp_path / "eb"), "--bootstrap", "300"]
    assert main([*args, "--output", str(tmp_path / "cmp")]) == 0
    cmp = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    m = cmp["metrics"]["mIoU"]
    assert m["diff"] > 0 and m["low"] > 0 and m["p_b_greater"] == 1.0
    assert m["a"] == pytest.approx(scores["all"]["mIoU"], abs=1e-12)
    assert "P(B > A)" in (tmp_path / "cmp" / "compare.txt").read_text()
    # five of the 19 classes have ground truth and none other is predicted: the present mean is
    # the official mean times 19 / 5, in both sets and so in their difference
    p = cmp["metrics"]["mIoU_present"]
    assert p["a"] == pytest.approx(m["a"] * 19 / 5, abs=1e-12)
    assert p["diff"] == pytest.approx(m["diff"] * 19 / 5, abs=1e-12) and p["low"] > 0


def test_compare_bad_inputs(tmp_path: Path, capsys):
    data, pred = _tree(tmp_path / "a", {"08": 3, "09": 1}, noise=0.2, seed=1)
    assert main(_eval(data, pred, tmp_path / "e1")) == 0
    one = ["eval", "semantickitti", "--dataset", str(data), "--predictions", str(pred),
           "--sequences", "08", "--output", str(tmp_path / "e2")]  # fmt: skip
    assert main(one) == 0
    capsys.readouterr()
    assert main(["eval", "compare", str(tmp_path / "e1"), str(tmp_path / "e2")]) == 2
    err = capsys.readouterr().err
    assert "hold different scans" in err and "09/000000" in err and "Traceback" not in err
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["eval", "compare", str(empty), str(tmp_path / "e1")]) == 2
    assert "no per_scan.npz here" in capsys.readouterr().err
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not an archive")
    assert main(["eval", "compare", str(bad), str(tmp_path / "e1")]) == 2
    assert "bad.npz" in capsys.readouterr().err
    assert (
        main(["eval", "compare", str(tmp_path / "e1"), str(tmp_path / "e1"), "--level", "1"]) == 2
    )


def test_sequence_unit_resamples_whole_sequences(tmp_path: Path, capsys):
    from panoptic_bench.evaluation.per_scan import by_sequence

    data, pred_a = _tree(tmp_path / "a", {"08": 4, "09": 3}, noise=0.3, seed=0)
    _, pred_b = _tree(tmp_path / "b", {"08": 4, "09": 3}, noise=0.05, seed=0)
    argv = _eval(
        data, pred_a, tmp_path / "ea", "--bootstrap", "200", "--bootstrap-unit", "sequence"
    )
    assert main(argv) == 0
    assert "200 bootstrap replicates of 2 sequences" in capsys.readouterr().out
    boot = json.loads((tmp_path / "ea" / "scores.json").read_text())["bootstrap"]
    assert boot["unit"] == "sequence" and boot["n_units"] == 2 and "places" in boot["caveat"]
    per = read_per_scan(tmp_path / "ea")
    seqs = by_sequence(per)
    assert seqs.scans == ("08", "09")
    by_hand = per.stats[4] + per.stats[5] + per.stats[6]
    assert np.array_equal(seqs.stats[1].confusion, by_hand.confusion)
    assert np.array_equal(seqs.stats[1].tp, by_hand.tp)
    # with two sequences, a replicate holds 08 twice, 09 twice or one of each: few distinct values
    assert main(_eval(tmp_path / "b" / "data", pred_b, tmp_path / "eb")) == 0
    cmp = ["eval", "compare", str(tmp_path / "ea"), str(tmp_path / "eb"), "--unit", "sequence",
           "--bootstrap", "200", "--output", str(tmp_path / "c")]  # fmt: skip
    assert main(cmp) == 0
    got = json.loads((tmp_path / "c" / "compare.json").read_text())
    assert got["unit"] == "sequence" and got["n_units"] == 2
    assert got["metrics"]["mIoU"]["low"] > 0


def test_report_shows_intervals_of_runs_with_per_scan_counts(tmp_path: Path):
    import shutil

    from panoptic_bench.metrics.bootstrap import bootstrap as boot
    from panoptic_bench.reports.index import build_report

    runs = Path(__file__).resolve().parents[1] / "reports/real-scans-heldout/runs"
    with_counts = tmp_path / "dsnet"
    shutil.copytree(runs / "real-dsnet", with_counts)
    without = tmp_path / "bfs"
    shutil.copytree(runs / "real-bfs", without)
    (without / "per_scan.npz").unlink()
    index = build_report([with_counts, without], tmp_path / "rep").read_text()
    assert "## How sure: bootstrap intervals" in index
    section = index.split("## How sure")[1].split("## Figures")[0]
    rows = [line for line in section.splitlines() if line.startswith(f"| `{with_counts}`")]
    assert len(rows) == 1 and "| scan | 10 |" in rows[0]  # two sequences: no sequence row
    per = read_per_scan(with_counts)
    b = boot(per.stats, per.things, per.stuff, n_boot=1000)
    assert (
        f"{100 * b.estimate['PQ']:.1f} [{100 * b.low['PQ']:.1f}, {100 * b.high['PQ']:.1f}]"
        in rows[0]
    )
    assert f"| `{without}`" not in section
    # no run with counts: no section
    index = build_report([without], tmp_path / "rep2").read_text()
    assert "How sure" not in index
