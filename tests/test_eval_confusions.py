"""``eval confusions``: the evaluator's confusion matrix read back from ``per_scan.npz`` (checked
against a direct count of the label files), hand-worked ranking, the A -> B change, bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from panoptic_bench.cli import main
from panoptic_bench.datasets import semantickitti as sk
from panoptic_bench.evaluation.confusion import confusion_rows, confusion_table, csv_text

RAW = np.array([0, 10, 30, 40, 48, 70])  # unlabeled, car, person, road, sidewalk, vegetation


def _tree(root: Path, noise: float, seed: int, scans: int = 3) -> tuple[Path, Path]:
    """Dataset ``root/data`` (with unlabelled points) and predictions ``root/pred``."""
    rng = np.random.default_rng(seed)
    data, pred = root / "data", root / "pred"
    for i in range(scans):
        sem = rng.choice(RAW, 500, p=[0.1, 0.2, 0.1, 0.3, 0.2, 0.1])
        inst = np.where(np.isin(sem, (10, 30)), rng.integers(1, 4, 500), 0)
        psem = np.where(rng.random(500) < noise, rng.choice(RAW, 500), sem)  # some predicted 0
        pts = rng.normal(0, 15, (500, 4)).astype(np.float32)
        sk.write_scan(data / "sequences/08/velodyne" / f"{i:06d}.bin", pts)
        sk.write_labels(data / "sequences/08/labels" / f"{i:06d}.label", sk.make_label(sem, inst))
        pinst = np.where(np.isin(psem, (10, 30)), inst, 0)
        path = pred / "sequences/08/predictions" / f"{i:06d}.label"
        sk.write_labels(path, sk.make_label(psem, pinst))
    return data, pred


def _count(data: Path, pred: Path) -> np.ndarray:
    """True x predicted train-id counts straight from the label files, unlabelled truth left out."""
    conf = np.zeros((20, 20), np.int64)
    for lab in sorted((data / "sequences/08/labels").iterdir()):
        t = sk.to_train(sk.read_labels(lab)).astype(np.int64)
        p = sk.to_train(sk.read_labels(pred / "sequences/08/predictions" / lab.name))
        conf += np.bincount(t * 20 + p, minlength=400).reshape(20, 20)
    conf[0] = 0
    return conf


def _scored(tmp_path: Path, name: str, noise: float) -> tuple[Path, np.ndarray]:
    data, pred = _tree(tmp_path / name, noise, seed=0)
    out = tmp_path / f"e{name}"
    argv = ["eval", "semantickitti", "--dataset", str(data), "--predictions", str(pred),
            "--sequences", "08", "--output", str(out)]  # fmt: skip
    assert main(argv) == 0
    return out, _count(data, pred)


def _read_csv(path: Path) -> tuple[list[str], np.ndarray]:
    lines = path.read_text().splitlines()
    names = lines[0].split(",")[1:]
    assert [r.split(",")[0] for r in lines[1:]] == names
    return names, np.array([[int(v) for v in r.split(",")[1:]] for r in lines[1:]])


def test_matrix_is_the_label_files_count_and_the_table_ranks_it(tmp_path: Path, capsys):
    out, truth = _scored(tmp_path, "a", noise=0.3)
    assert truth[:, 0].sum() > 0  # some points were predicted unlabelled: kept, as misses
    capsys.readouterr()
    fig = tmp_path / "conf.png"
    argv = ["eval", "confusions", str(out), "--top", "4", "--figure", str(fig)]
    assert main([*argv, "--output", str(tmp_path / "c")]) == 0
    text = capsys.readouterr().out
    names, got = _read_csv(tmp_path / "c" / "confusion.csv")
    assert names[:2] == ["unlabeled", "car"] and len(names) == 20
    np.testing.assert_array_equal(got, truth)
    assert fig.stat().st_size > 5000 and fig.read_bytes()[:4] == b"\x89PNG"
    # the printed rows are the four largest off-diagonal cells, in order
    off = np.where(~np.eye(20, dtype=bool), truth, -1)
    best = np.argsort(-off, axis=None, kind="stable")[:4]
    lines = text.splitlines()[2:6]
    for line, flat in zip(lines, best):
        t, p = divmod(int(flat), 20)
        cells = line.split()
        assert cells[:3] == [names[t], names[p], str(truth[t, p])]
        assert float(cells[3]) == pytest.approx(100 * truth[t, p] / truth[t].sum(), abs=0.05)
    assert text == (tmp_path / "c" / "confusions.txt").read_text()


def test_hand_worked_rows_and_change():
    names = ["unl", "a", "b", "c"]
    a = np.array([[0, 0, 0, 0], [5, 80, 10, 5], [0, 30, 60, 10], [0, 0, 2, 98]])
    rows = confusion_rows(a, names, top=3)
    assert [(r["true"], r["predicted"], r["points"]) for r in rows] == [
        ("b", "a", 30), ("a", "b", 10), ("b", "c", 10)]  # fmt: skip
    assert rows[0]["of_true"] == pytest.approx(0.3)
    assert rows[0]["of_predicted"] == pytest.approx(30 / 110)
    b = a.copy()
    b[2, 1], b[2, 2] = 5, 85  # B fixes most of b -> a
    changed = confusion_rows(a, names, top=5, other=b)
    assert len(changed) == 1  # only one off-diagonal cell moved
    assert changed[0] | {} == {
        "true": "b", "predicted": "a", "points": 30, "of_true": 0.3,
        "of_predicted": pytest.approx(30 / 110), "points_b": 5, "of_true_b": 0.05, "change": -25,
    }  # fmt: skip
    assert "-25" in confusion_table(changed) and "B - A" in confusion_table(changed)
    assert confusion_rows(np.diag([1, 2, 3, 4]), names) == []  # nothing confused
    assert csv_text(a, names).splitlines()[2] == "a,5,80,10,5"
    with pytest.raises(ValueError):
        confusion_rows(a[:3], names)


def test_change_between_two_outputs_and_bad_input(tmp_path: Path, capsys):
    ea, ta = _scored(tmp_path, "a", noise=0.3)
    eb, tb = _scored(tmp_path, "b", noise=0.05)
    capsys.readouterr()
    assert main(["eval", "confusions", str(ea), str(eb), "--top", "1"]) == 0
    line = capsys.readouterr().out.splitlines()[3]
    d = np.where(~np.eye(20, dtype=bool), np.abs(tb - ta), -1)
    t, p = divmod(int(np.argmax(d)), 20)
    assert line.split()[-1] == f"{tb[t, p] - ta[t, p]:+d}"
    # other scans: one clear error naming the second input, exit 2
    data, pred = _tree(tmp_path / "c", 0.1, seed=1, scans=2)
    argv = ["eval", "semantickitti", "--dataset", str(data), "--predictions", str(pred),
            "--sequences", "08", "--output", str(tmp_path / "ec")]  # fmt: skip
    assert main(argv) == 0
    capsys.readouterr()
    assert main(["eval", "confusions", str(ea), str(tmp_path / "ec")]) == 2
    err = capsys.readouterr().err
    assert "ec" in err and "same scans" in err and "Traceback" not in err
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["eval", "confusions", str(empty)]) == 2
    assert "no per_scan.npz here" in capsys.readouterr().err
