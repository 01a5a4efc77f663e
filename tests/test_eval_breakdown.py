"""``eval breakdown``: the binning kernel by hand and as a sum over scans, the point quantities by
hand, the command against the evaluator's own confusion matrix and against a hand count, bad input."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from panoptic_bench.cli import main
from panoptic_bench.datasets import semantickitti as sk
from panoptic_bench.metrics.breakdown import BinnedCounts, binned_counts
from panoptic_bench.metrics.point_features import height_above_plane, point_feature, ring_roughness

# raw ids: unlabeled, car, road, sidewalk, vegetation, terrain
RAW = np.array([0, 10, 40, 48, 70, 72])


def test_binned_counts_by_hand():
    values = np.array([0.5, 1.5, 1.5, 2.5, np.nan, -1.0, 3.0, 1.0])
    pred = np.array([1, 2, 1, 0, 1, 1, 2, 2])
    got = binned_counts(values, pred, [0, 1, 2, 3], num_classes=3)
    # bin [0,1): 0.5 -> 1; [1,2): 1.5 -> 2, 1.5 -> 1, 1.0 -> 2; [2,3): 2.5 -> 0; NaN, -1, 3 dropped
    np.testing.assert_array_equal(got, [[0, 1, 0], [0, 1, 2], [1, 0, 0]])
    b = BinnedCounts.of_scan(values, pred, [0, 1, 2, 3], 3)
    assert b.unbinned == 3
    np.testing.assert_array_equal(b.points(), [1, 3, 1])
    np.testing.assert_allclose(b.shares()[1], [0, 1 / 3, 2 / 3])
    assert np.isnan(BinnedCounts.of_scan(values[:1], pred[:1], [0, 1, 2], 3).shares()[1]).all()
    with pytest.raises(ValueError):
        binned_counts(values, pred, [0, 2, 1], 3)  # edges not increasing
    with pytest.raises(ValueError):
        binned_counts(values, pred + 1, [0, 1], 3)  # class 3 out of range
    with pytest.raises(ValueError):
        b + BinnedCounts.of_scan(values, pred, [0, 1, 2, 4], 3)


def test_counts_over_scans_add_up_to_the_counts_of_all_points():
    rng = np.random.default_rng(3)
    values = rng.normal(0, 1, 3000)
    values[rng.random(3000) < 0.05] = np.nan
    pred = rng.integers(0, 5, 3000)
    edges = [-1.5, -0.5, 0, 0.3, 2]
    whole = BinnedCounts.of_scan(values, pred, edges, 5)
    parts = [
        BinnedCounts.of_scan(values[s], pred[s], edges, 5)
        for s in np.split(np.arange(3000), [700, 701, 2100])
    ]
    total = parts[0] + parts[1] + parts[2] + parts[3]
    np.testing.assert_array_equal(total.counts, whole.counts)
    assert total.unbinned == whole.unbinned
    inside = np.isfinite(values) & (values >= -1.5) & (values < 2)
    assert whole.counts.sum() == inside.sum() and whole.unbinned == 3000 - inside.sum()


def test_ring_roughness_by_hand():
    x = np.array([0.0, 0.1, 0.2, 0.3, 0.4, 2.0, 2.1, 2.2])
    z = np.array([0.0, 0.01, 0.0, 0.03, 0.0, 0.0, 0.5, 0.0])
    got = ring_roughness(np.c_[x, np.zeros(8), z])
    # point 1: |0.01 - 0| ; point 2: |0 - 0.02| ; point 3: |0.03 - 0| ; point 4: next is 1.6 m away
    np.testing.assert_allclose(got[1:4], [0.01, 0.02, 0.03])
    assert np.isnan(got[[0, 4, 5, 7]]).all()
    assert got[6] == pytest.approx(0.5)
    assert np.isnan(ring_roughness(np.zeros((2, 3)))).all()


def test_height_above_a_tilted_road_plane_by_hand():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-15, 15, (600, 2))
    plane = -1.7 + 0.01 * xy[:, 0] - 0.02 * xy[:, 1]
    lift = np.where(np.arange(600) < 400, 0.0, rng.uniform(-0.5, 2, 600))
    pts = np.c_[xy, plane + lift, np.zeros(600)]
    road = np.arange(600) < 400
    far = np.array([[30.0, 0.0, 5.0, 0.0]])  # a road point beyond 20 m, far off the plane: unused
    got = height_above_plane(np.r_[pts, far], np.r_[road, True])
    np.testing.assert_allclose(got[:600], lift, atol=1e-9)
    assert np.isnan(height_above_plane(pts, np.arange(600) < 100)).all()  # under 200 road points
    np.testing.assert_allclose(point_feature("remission", np.c_[pts[:, :3], lift]), lift)
    with pytest.raises(ValueError):
        point_feature("height", pts)
    with pytest.raises(ValueError):
        point_feature("colour", pts)


def _tree(root: Path, seed: int, scans: int = 3) -> tuple[Path, Path]:
    """A flat road at z = -1.7 and classes spread over it; predictions with 30 % wrong classes."""
    rng = np.random.default_rng(seed)
    data, pred = root / "data", root / "pred"
    for i in range(scans):
        n = 800
        sem = rng.choice(RAW, n, p=[0.05, 0.1, 0.4, 0.15, 0.15, 0.15])
        xy = rng.uniform(-18, 18, (n, 2))
        z = -1.7 + np.where(sem == 40, 0.0, rng.uniform(-0.4, 1.5, n))
        pts = np.c_[xy, z, rng.uniform(0, 1, n)].astype(np.float32)
        inst = np.where(sem == 10, rng.integers(1, 4, n), 0)
        psem = np.where(rng.random(n) < 0.3, rng.choice(RAW, n), sem)
        sk.write_scan(data / "sequences/08/velodyne" / f"{i:06d}.bin", pts)
        sk.write_labels(data / "sequences/08/labels" / f"{i:06d}.label", sk.make_label(sem, inst))
        path = pred / "sequences/08/predictions" / f"{i:06d}.label"
        sk.write_labels(path, sk.make_label(psem, np.where(psem == 10, inst, 0)))
    return data, pred


def _digest(root: Path) -> str:
    h = hashlib.sha256()
    for f in sorted(root.rglob("*")):
        if f.is_file():
            h.update(str(f.relative_to(root)).encode() + f.read_bytes())
    return h.hexdigest()


def _argv(data: Path, pred: Path, out: Path, *extra: str) -> list[str]:
    return ["eval", "breakdown", "--dataset", str(data), "--predictions", str(pred),
            "--sequences", "08", "--output", str(out), "--no-progress", *extra]  # fmt: skip


def _csv(path: Path) -> tuple[list[str], np.ndarray]:
    lines = path.read_text().splitlines()
    head = lines[0].split(",")
    return head, np.array([[float(v) for v in r.split(",")] for r in lines[1:]])


def test_all_bins_together_are_the_evaluators_confusion_row(tmp_path: Path, capsys):
    data, pred = _tree(tmp_path, seed=1)
    before = {p: _digest(tmp_path / p) for p in ("data", "pred")}
    argv = ["eval", "semantickitti", "--dataset", str(data), "--predictions", str(pred),
            "--sequences", "08", "--output", str(tmp_path / "e")]  # fmt: skip
    assert main(argv) == 0
    assert main(["eval", "confusions", str(tmp_path / "e"), "--output", str(tmp_path / "c")]) == 0
    rows = (tmp_path / "c" / "confusion.csv").read_text().splitlines()
    conf = {r.split(",")[0]: [int(v) for v in r.split(",")[1:]] for r in rows[1:]}
    for cls in ("terrain", "road", "car"):
        out = tmp_path / f"b_{cls}"
        assert (
            main(_argv(data, pred, out, "--class", cls, "--by", "range", "--edges", "0,1000")) == 0
        )
        head, got = _csv(out / "breakdown.csv")
        assert head[:3] == ["bin_lo", "bin_hi", "points"] and head[3:5] == ["unlabeled", "car"]
        assert got.shape == (1, 3 + 20)
        assert got[0, 3:].astype(int).tolist() == conf[cls]
        assert got[0, 2] == sum(conf[cls])
    text = capsys.readouterr().out
    assert "true car by range, 3 scans" in text
    png = (tmp_path / "b_car" / "breakdown.png").read_bytes()
    assert png[:4] == b"\x89PNG" and len(png) > 5000
    assert (tmp_path / "b_car" / "breakdown.txt").read_text() in text
    assert {p: _digest(tmp_path / p) for p in ("data", "pred")} == before  # inputs unchanged


def test_height_bins_match_a_hand_count(tmp_path: Path, capsys):
    data, pred = _tree(tmp_path, seed=2, scans=2)
    edges = [-0.5, 0.0, 0.25, 1.0, 2.0]
    out = tmp_path / "h"
    argv = _argv(data, pred, out, "--class", "vegetation", "--by", "height",
                 "--edges=" + ",".join(map(str, edges)), "--within", "5,20", "--top", "3")  # fmt: skip
    assert main(argv) == 0
    expect = np.zeros((4, 20), int)
    for f in sorted((data / "sequences/08/labels").iterdir()):
        pts = sk.read_scan(data / "sequences/08/velodyne" / f"{f.stem}.bin").astype(np.float64)
        t = sk.to_train(sk.read_labels(f))
        p = sk.to_train(sk.read_labels(pred / "sequences/08/predictions" / f.name))
        h = pts[:, 2] + 1.7  # the road is the plane z = -1.7
        r = np.linalg.norm(pts[:, :3], axis=1)
        m = (t == sk.LABELS.class_names.index("vegetation")) & (r >= 5) & (r < 20)
        for b in range(4):
            s = m & (h >= edges[b]) & (h < edges[b + 1])
            expect[b] += np.bincount(p[s], minlength=20)
    head, got = _csv(out / "breakdown.csv")
    np.testing.assert_array_equal(got[:, 3:].astype(int), expect)
    np.testing.assert_allclose(got[:, :2], [[-0.5, 0], [0, 0.25], [0.25, 1], [1, 2]])
    lines = capsys.readouterr().out.splitlines()
    assert "range [5, 20) m" in lines[0]
    assert lines[1].split()[2] == "vegetation" and len(lines) == 2 + 4  # true class first, 4 bins
    share = 100 * expect[2, sk.LABELS.class_names.index("vegetation")] / expect[2].sum()
    assert float(lines[4].split()[-4]) == pytest.approx(share, abs=0.05)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--class", "grass", "--by", "range"], "unknown class 'grass'"),
        (["--class", "unlabeled", "--by", "range"], "ignored by the evaluator"),
        (["--class", "road", "--by", "range", "--edges", "3,2"], "increasing"),
        (["--class", "road", "--by", "colour"], "invalid choice"),
        (["--class", "road", "--by", "range", "--within", "5,2"], "MIN,MAX"),
    ],
)
def test_bad_options_exit_2(tmp_path: Path, capsys, extra, message):
    data, pred = _tree(tmp_path, seed=3, scans=1)
    assert main(_argv(data, pred, tmp_path / "o", *extra)) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_bad_files_exit_2_naming_the_file(tmp_path: Path, capsys):
    data, pred = _tree(tmp_path, seed=4, scans=2)
    missing = pred / "sequences/08/predictions/000001.label"
    missing.unlink()
    assert main(_argv(data, pred, tmp_path / "o", "--class", "road", "--by", "height")) == 2
    assert "000001.label" in capsys.readouterr().err
    sk.write_labels(missing, np.full(5, 40, np.uint32))  # wrong point count
    assert main(_argv(data, pred, tmp_path / "o", "--class", "road", "--by", "height")) == 2
    err = capsys.readouterr().err
    assert "000001.label" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()  # nothing half written
    inside = pred / "out"  # an output inside the inputs is refused
    assert main(_argv(data, pred, inside, "--class", "road", "--by", "range")) == 2
