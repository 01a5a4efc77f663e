"""`panoptic-bench view`: the page's content, its numbers against the evaluator, bad input, reports."""

from __future__ import annotations

import base64
import gzip
import hashlib
import re
from pathlib import Path

import numpy as np
import pytest
from nuscenes_world import real_sweep, write_mini

from panoptic_bench.baselines.centers import write_centers
from panoptic_bench.cli import main
from panoptic_bench.datasets import semantickitti as sk
from panoptic_bench.metrics.panoptic import panoptic_stats
from panoptic_bench.viewer.matching import match_segments
from panoptic_bench.viewer.page import plotly_bundle_gz
from panoptic_bench.viewer.payload import decode_payload, encode_payload
from panoptic_bench.viewer.report import REPORT_MAX_POINTS, VIEWER_FILE, write_best_and_worst

BLOB = re.compile(r'(<script id="pb-\w+" type="application/octet-stream">)(.*?)(</script>)', re.S)
NUS = "v1.0-mini"


def page_payload(text: str) -> tuple[dict, dict]:
    """The (meta, arrays) payload embedded in a viewer page."""
    blobs = {m.group(1): m.group(2) for m in BLOB.finditer(text)}
    (data,) = [v for k, v in blobs.items() if 'id="pb-data"' in k]
    return decode_payload(gzip.decompress(base64.b64decode(re.sub(r"\s+", "", data))))


def markup(text: str) -> str:
    """The page without its two base64 blobs (library and payload)."""
    return BLOB.sub(r"\1\3", text)


def damaged(gt: np.ndarray, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    inst = gt >> 16
    pred = gt.copy()
    pred[np.isin(inst, np.unique(inst[inst > 0])[seed % 3 :: 3])] = 10  # merged into one car
    pred[rng.random(len(gt)) < 0.03 * (seed + 1)] = 40  # road
    return pred


@pytest.fixture(scope="module")
def kitti_run(tmp_path_factory, kitti_root):
    """Damaged predictions and regressed centres for the 3 real scans."""
    root = tmp_path_factory.mktemp("kitti")
    for k, ref in enumerate(sk.list_scans(kitti_root, sequences=["00"])):
        gt = sk.read_labels(ref.label)
        sk.write_labels(sk.prediction_path(root / "pred", ref), damaged(gt, k))
        xyz = sk.read_scan(ref.scan)[:, :3]
        offset = np.where((sk.to_train(gt) <= 8)[:, None], -xyz * 0.01, 0.0)
        path = root / "centres" / "sequences" / "00" / "centers" / f"{ref.frame}.npz"
        write_centers(path, sk.to_train(gt), offset)
    return root


def _view(kitti_root, run, out, *extra):
    args = ["view", "semantickitti", "--dataset", str(kitti_root), "--scan", "00/000001"]
    return main([*args, "--predictions", str(run / "pred"), "--out", str(out), *extra])


def test_semantickitti_page_carries_the_evaluators_matching(kitti_root, kitti_run, tmp_path):
    out = tmp_path / "view.html"
    assert _view(kitti_root, kitti_run, out, "--centers", str(kitti_run / "centres")) == 0
    text = out.read_text()
    page = markup(text)
    assert "prediction" in page and "ground truth" in page
    assert not re.search(r"https?://|(src|href)\s*=|url\(|@import", page, re.I)
    meta, arr = page_payload(text)
    gt = sk.read_labels(kitti_root / "sequences/00/labels/000001.label")
    pred = sk.read_labels(kitti_run / "pred/sequences/00/predictions/000001.label")
    xyz = sk.read_scan(kitti_root / "sequences/00/velodyne/000001.bin")[:, :3]
    (scan,) = meta["scans"]
    assert scan["name"] == "00/000001" and scan["n_points"] == scan["n_shown"] == len(gt)
    assert meta["classes"]["names"][1] == "car" and meta["classes"]["colours"][1] == "#6496f5"
    # every point, its class and segment status as the evaluator matches them
    np.testing.assert_allclose(
        arr["s0_xyz"].reshape(-1, 3) * scan["scale"], xyz, atol=scan["scale"]
    )
    np.testing.assert_array_equal(arr["s0_pred_sem"], sk.to_train(pred))
    np.testing.assert_array_equal(arr["s0_gt_sem"], sk.to_train(gt))
    kw = {"num_classes": 20, "ignore": (0,), "min_points": 50}
    m = match_segments(sk.to_train(pred), pred, sk.to_train(gt), gt, **kw)
    np.testing.assert_array_equal(arr["s0_pred_seg"], m.pred_segment)
    np.testing.assert_array_equal(arr["s0_gt_status"], m.gt.status)
    np.testing.assert_array_equal(arr["s0_pred_inst"], m.pred.inst >> 16)
    stats = panoptic_stats(sk.to_train(pred), pred, sk.to_train(gt), gt, **kw)
    assert (scan["tp"], scan["fp"], scan["fn"]) == (stats.tp.sum(), stats.fp.sum(), stats.fn.sum())
    assert scan["fp"] + scan["fn"] > 0
    # matched instances share a palette colour; the centres layer holds the things points
    matched = m.pred.match >= 0
    things = np.isin(m.pred.cls, range(1, 9)) & matched
    p_col, g_col = arr["s0_pred_colour"], arr["s0_gt_colour"]
    np.testing.assert_array_equal(p_col[things], g_col[m.pred.match[things]])
    gt_things = (sk.to_train(gt) >= 1) & (sk.to_train(gt) <= 8)  # the centre file's semantics
    assert len(arr["s0_centres"]) == 3 * int(gt_things.sum()) > 0


def test_max_points_subsamples_but_scores_all(kitti_root, kitti_run, tmp_path):
    out = tmp_path / "small.html"
    assert _view(kitti_root, kitti_run, out, "--max-points", "5000") == 0
    meta, arr = page_payload(out.read_text())
    (scan,) = meta["scans"]
    assert scan["n_shown"] == 5000 == len(arr["s0_gt_sem"]) and scan["n_points"] > 100_000
    full = tmp_path / "full.html"
    assert _view(kitti_root, kitti_run, full) == 0
    assert page_payload(full.read_text())[0]["scans"][0]["tp"] == scan["tp"]
    assert out.stat().st_size < full.stat().st_size


def test_without_predictions_both_sides_show_ground_truth(kitti_root, tmp_path):
    out = tmp_path / "gt.html"
    args = ["view", "semantickitti", "--dataset", str(kitti_root), "--scan", "0/0"]
    assert main([*args, "--out", str(out)]) == 0
    text = out.read_text()
    assert "No predictions given" in text
    meta, arr = page_payload(text)
    assert meta["scans"][0]["pq"] == 1.0 and meta["scans"][0]["fp"] == 0
    np.testing.assert_array_equal(arr["s0_pred_sem"], arr["s0_gt_sem"])


def test_payload_round_trip_and_alignment():
    rng = np.random.default_rng(0)
    arrays = {
        f"a_{dt}": rng.integers(0, 100, 7).astype(dt)
        for dt in ("int8", "uint8", "int16", "uint16", "int32", "uint32", "float32", "float64")
    }
    data = encode_payload({"x": [1, "two"]}, arrays)
    meta, back = decode_payload(data)
    assert meta == {"x": [1, "two"]}
    for name, arr in arrays.items():
        np.testing.assert_array_equal(back[name], arr)
        assert back[name].dtype == arr.dtype
    n = int.from_bytes(data[4:8], "little")
    assert (8 + n) % 8 == 0
    with pytest.raises(ValueError, match="dtype"):
        encode_payload({}, {"b": np.zeros(2, bool)})


def test_vendored_plotly_bundle_is_the_documented_one():
    import plotly.offline

    js = gzip.decompress(plotly_bundle_gz())
    readme = (Path(__file__).parents[1] / "panoptic_bench/viewer/vendor/README.md").read_text()
    assert hashlib.sha256(js).hexdigest() in readme
    version = plotly.offline.get_plotlyjs_version()
    assert f"(gl3d - minified) v{version}" in js[:200].decode()
    assert f"v{version}" in readme


def _kitti_args(kitti_root, run, out, scan="00/000001", pred=None, centres=None):
    args = ["view", "semantickitti", "--dataset", str(kitti_root), "--scan", scan]
    args += ["--predictions", str(pred or run / "pred"), "--out", str(out)]
    return args + (["--centers", str(centres)] if centres else [])


@pytest.mark.parametrize(
    "case, words",
    [
        ("missing_scan", "scan 00/000099 is not in the dataset"),
        ("missing_sequence", "scan 05/000000 is not in the dataset (sequence not found)"),
        ("bad_scan_text", "--scan '00-000001': expected SEQUENCE/FRAME"),
        ("short_prediction", "prediction has 1000 labels but the scan has"),
        ("missing_prediction", "no prediction for scan 00/000001"),
        ("short_centres", "holds 10 points but the scan has"),
        ("out_is_dir", "--out is a directory"),
    ],
)
def test_bad_semantickitti_input(kitti_root, kitti_run, tmp_path, capsys, case, words):
    out = tmp_path / "view.html"
    kw = {}
    if case == "missing_scan":
        kw["scan"] = "00/000099"
    elif case == "missing_sequence":
        kw["scan"] = "05/000000"
    elif case == "bad_scan_text":
        kw["scan"] = "00-000001"
    elif case == "short_prediction":
        pred = tmp_path / "pred"
        sk.write_labels(pred / "sequences/00/predictions/000001.label", np.zeros(1000, np.uint32))
        kw["pred"] = pred
    elif case == "missing_prediction":
        kw["pred"] = tmp_path / "nothing"
    elif case == "short_centres":
        cen = tmp_path / "cen"
        write_centers(cen / "sequences/00/centers/000001.npz", np.zeros(10, int), np.zeros((10, 3)))
        kw["centres"] = cen
    elif case == "out_is_dir":
        out.mkdir()
    assert main(_kitti_args(kitti_root, kitti_run, out, **kw)) == 2
    err = capsys.readouterr().err
    assert words in err and len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err
    assert out.is_dir() if case == "out_is_dir" else not out.exists()
    assert not [p for p in tmp_path.rglob("*.html") if p.is_file()]
    assert not list(tmp_path.rglob("*.tmp"))


def test_existing_out_needs_overwrite(kitti_run, tmp_path, capsys, kitti_root):
    out = tmp_path / "view.html"
    out.write_text("keep me")
    assert main(_kitti_args(kitti_root, kitti_run, out)) == 2
    assert "--out exists; pass --overwrite" in capsys.readouterr().err
    assert out.read_text() == "keep me"
    assert main([*_kitti_args(kitti_root, kitti_run, out), "--overwrite"]) == 0
    assert out.read_text().startswith("<!DOCTYPE html>") or "plotly" in out.read_text()[:5000]


def test_out_inside_an_input_tree_is_refused(kitti_run, tmp_path, capsys, kitti_root):
    out = kitti_run / "pred" / "view.html"
    assert main(_kitti_args(kitti_root, kitti_run, out)) == 2
    assert "--out lies inside the input tree" in capsys.readouterr().err
    assert not out.exists()


@pytest.fixture(scope="module")
def nus_root(tmp_path_factory, shared_data):
    root = write_mini(tmp_path_factory.mktemp("nus") / "root", real_sweep(shared_data))
    args = ["nuscenes", "make-labels", "--dataroot", str(root), "--version", NUS]
    assert main([*args, "--out-dir", str(root)]) == 0
    return root


def _nus_truth(root):
    from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar
    from panoptic_bench.evaluation.nuscenes import ChallengeClasses

    reader = NuScenesLidar(root, NUS)
    lut = ChallengeClasses.from_nusc(reader.nusc).lut
    tok = reader.sample_data_tokens("mini_val")[0]
    gt = reader.load_panoptic(tok).astype(np.int64)
    return tok, lut[gt // 1000] * 1000 + gt % 1000


def _gt_ids(root, tok):
    from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar

    return NuScenesLidar(root, NUS).load_panoptic(tok).astype(np.int64)


def test_nuscenes_page_and_bad_input(nus_root, tmp_path, capsys):
    tok, truth = _nus_truth(nus_root)
    pred = truth.copy()
    pred[::7] = 11 * 1000  # some points to one stuff class
    things = (pred // 1000 >= 1) & (pred // 1000 <= 10)
    pred[things] = (pred[things] // 1000) * 1000 + 1 + np.arange(things.sum()) % 2  # split, merge
    folder = tmp_path / "res" / "panoptic" / "mini_val"
    folder.mkdir(parents=True)
    np.savez_compressed(folder / f"{tok}_panoptic.npz", data=pred.astype(np.uint16))
    args = ["view", "nuscenes", "--dataroot", str(nus_root), "--version", NUS]
    out = tmp_path / "nus.html"
    ok = [*args, "--result-path", str(tmp_path / "res"), "--sample-data-token", tok]
    assert main([*ok, "--out", str(out)]) == 0
    meta, arr = page_payload(out.read_text())
    assert meta["classes"]["dataset"] == "nuscenes" and meta["classes"]["names"][0] == "ignore"
    assert meta["classes"]["colours"][meta["classes"]["names"].index("car")] == "#ff9e00"
    (scan,) = meta["scans"]
    assert scan["name"] == tok and scan["n_points"] == len(truth)
    np.testing.assert_array_equal(arr["s0_pred_sem"], pred // 1000)
    kw = {"num_classes": 17, "ignore": (0,), "min_points": 15}
    stats = panoptic_stats(pred // 1000, pred, truth // 1000, _gt_ids(nus_root, tok), **kw)
    assert (scan["tp"], scan["fp"], scan["fn"]) == (stats.tp.sum(), stats.fp.sum(), stats.fn.sum())
    assert scan["fp"] + scan["fn"] > 0
    # errors: unknown token, prediction of another point count; nothing written
    bad = tmp_path / "bad.html"
    assert main([*args, "--sample-data-token", "nope", "--out", str(bad)]) == 2
    assert "sample_data token 'nope' is not in nuScenes v1.0-mini" in capsys.readouterr().err
    np.savez_compressed(folder / f"{tok}_panoptic.npz", data=pred[:-5].astype(np.uint16))
    assert main([*ok, "--out", str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"prediction has {len(pred) - 5} labels" in err and tok in err
    assert not bad.exists()


def test_report_links_best_and_worst_pages(kitti_root, kitti_run, tmp_path):
    from panoptic_bench.reports.index import build_report

    run = tmp_path / "run"
    args = ["eval", "semantickitti", "--dataset", str(kitti_root), "--sequences", "00"]
    assert main([*args, "--predictions", str(kitti_run / "pred"), "--output", str(run)]) == 0
    write_best_and_worst(run, kitti_root, kitti_run / "pred", ["00"], centers=kitti_run / "centres")
    assert (run / VIEWER_FILE).is_file()
    index = build_report([run], tmp_path / "report")
    text = index.read_text()
    assert "## Viewer" in text
    links = re.findall(r"\]\((viewer/[^)]+\.html)\)", text)
    assert links == ["viewer/run-best.html", "viewer/run-worst.html"]
    pq = [float(v) for v in re.findall(r"PQ ([\d.]+) %\]", text)]
    assert len(pq) == 2 and pq[0] > pq[1]
    for link, anchor in zip(links, ("best", "worst")):
        meta, arr = page_payload((tmp_path / "report" / link).read_text())
        (scan,) = meta["scans"]
        assert scan["anchor"] == anchor and scan["n_shown"] == REPORT_MAX_POINTS
        assert "s0_centres" in arr


@pytest.mark.parametrize("network", [True, False])
def test_demo_viewer_picks_the_headline_run(kitti_root, kitti_run, tmp_path, network):
    import shutil

    from panoptic_bench.demo.kitti import KittiTarget
    from panoptic_bench.demo.pipeline import prepare_workspace
    from panoptic_bench.demo.viewer import write_demo_viewer
    from panoptic_bench.viewer.report import read_viewer_scans

    ws = prepare_workspace(tmp_path / "report", tmp_path / "work")
    target = KittiTarget(kitti_root, ("00",), "real scans", "real")
    name = "real-dsnet" if network else "real-meanshift"
    shutil.copytree(kitti_run / "pred", ws.predictions(name))
    centres = ws.predictions(name) if network else ws.centres("real-simulated")
    shutil.copytree(kitti_run / "centres", centres, dirs_exist_ok=True)
    runs = [ws.runs / "real-bfs", ws.runs / name]
    path = write_demo_viewer(ws, target, runs)
    assert path == ws.runs / name / VIEWER_FILE
    scans, classes, entries = read_viewer_scans(path)
    assert [e["anchor"] for e in entries] == ["best", "worst"]
    assert all(s.centres is not None for s in scans) and classes.dataset == "semantickitti"
    assert write_demo_viewer(ws, target, [ws.runs / "real-bfs"]) is None
