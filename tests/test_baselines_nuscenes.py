"""nuScenes baselines: box-merge (devkit-identical, paper rule), simulated detector, centres →
cluster → eval, bad inputs exit 2 naming the file."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from nuscenes_world import real_sweep, write_mini

from panoptic_bench.baselines.box_merge import DetectorNoise, MergeMode
from panoptic_bench.baselines.box_merge_nuscenes import BoxTask, box_merge_nuscenes
from panoptic_bench.baselines.centers import write_centers
from panoptic_bench.baselines.simulated_detector_nuscenes import simulate_submission_nuscenes
from panoptic_bench.cli import main
from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar
from panoptic_bench.io import write_array, write_json

VERSION = "v1.0-mini"
EVAL_SET = "mini_val"
PRESENT_THINGS = ("barrier", "car", "pedestrian")  # the things classes of nuscenes_world


@pytest.fixture(scope="module")
def world(tmp_path_factory, shared_data) -> dict:
    """Dataroot with panoptic GT, GT lidarseg predictions and two perturbed ones, submissions."""
    from panoptic_bench.evaluation.nuscenes import ChallengeClasses

    base = tmp_path_factory.mktemp("nusbm")
    root = write_mini(base / "root", real_sweep(shared_data))
    assert main(["nuscenes", "make-labels", "--dataroot", str(root), "--version", VERSION,
                 "--out-dir", str(root)]) == 0  # fmt: skip
    reader = NuScenesLidar(root, VERSION)
    lut = ChallengeClasses.from_nusc(reader.nusc).lut
    rng = np.random.default_rng(0)
    tokens = reader.sample_data_tokens(EVAL_SET)
    for tok in tokens:
        seg = lut[reader.load_lidarseg(tok)].astype(np.uint8)
        write_array(base / "seg_gt/lidarseg/mini" / f"{tok}_lidarseg.bin", seg)
        flip = rng.random(len(seg)) < 0.2
        seg[flip] = rng.integers(0, 17, flip.sum())
        write_array(base / "seg_noisy/lidarseg/mini_val" / f"{tok}_lidarseg.bin", seg)
    subs = {}
    exact = DetectorNoise(0, 0, 0, 0, 0)
    for task in BoxTask:
        for name, noise in (("exact", exact), ("noisy", DetectorNoise(fp_rate=1.0))):
            sub = simulate_submission_nuscenes(root, VERSION, EVAL_SET, noise=noise, task=task)
            if name == "noisy":  # ties in score and a duplicated box: order and overlap rules
                first = next(b for b in sub["results"].values() if len(b) > 2)
                score = "tracking_score" if task is BoxTask.TRACKING else "detection_score"
                first[1][score] = first[0][score]
                first.append(dict(first[0]))
            subs[task, name] = base / f"{task}-{name}.json"
            write_json(subs[task, name], sub)
    return {"root": root, "base": base, "tokens": tokens, "subs": subs, "reader": reader}


def _arrays(folder: Path) -> dict[str, np.ndarray]:
    return {p.name: np.load(p)["data"] for p in sorted(folder.glob("*_panoptic.npz"))}


@pytest.mark.parametrize("task", list(BoxTask))
def test_devkit_mode_byte_identical_to_devkit(world, task, tmp_path):
    from nuscenes.eval.panoptic.get_panoptic_from_seg_det_or_track import generate_panoptic_labels

    nusc = world["reader"].nusc
    for seg in ("seg_gt", "seg_noisy"):
        for name in ("exact", "noisy"):
            sub = world["subs"][task, name]
            ours, ref = tmp_path / f"ours-{seg}-{name}", tmp_path / f"ref-{seg}-{name}"
            n = box_merge_nuscenes(world["root"], VERSION, EVAL_SET, world["base"] / seg, sub,
                                   ours, MergeMode.DEVKIT, task=task)  # fmt: skip
            assert n == len(world["tokens"]) == 5
            seg_root = world["base"] / seg
            if seg == "seg_noisy":  # the devkit reads only lidarseg/<version suffix>/
                (tmp_path / "devkit_seg/lidarseg").mkdir(parents=True, exist_ok=True)
                link = tmp_path / "devkit_seg/lidarseg/mini"
                if not link.exists():
                    link.symlink_to(seg_root / "lidarseg/mini_val")
                seg_root = tmp_path / "devkit_seg"
            generate_panoptic_labels(nusc, str(seg_root), str(sub), EVAL_SET,
                                     task="tracking" if task is BoxTask.TRACKING else "segmentation",
                                     out_dir=str(ref))  # fmt: skip
            a, b = _arrays(ours / "panoptic" / EVAL_SET), _arrays(ref / "panoptic" / EVAL_SET)
            assert a.keys() == b.keys() and len(a) == 5
            for key in a:
                assert a[key].dtype == b[key].dtype == np.uint16
                assert a[key].tobytes() == b[key].tobytes(), (seg, name, key)
            if name == "exact":  # the check can fail: instances were found
                assert max(int((v % 1000).max()) for v in a.values()) > 0


def _paper_reference(nusc, sd_token, seg, boxes, score_key):
    """Paper rule from the devkit's own transforms and points_in_box, one box at a time."""
    from nuscenes.eval.common.utils import boxes_to_sensor
    from nuscenes.eval.detection.data_classes import DetectionBox
    from nuscenes.eval.panoptic.utils import PanopticClassMapper
    from nuscenes.utils.data_classes import LidarPointCloud
    from nuscenes.utils.geometry_utils import points_in_box

    sd = nusc.get("sample_data", sd_token)
    points = LidarPointCloud.from_file(str(Path(nusc.dataroot) / sd["filename"])).points
    coarse2idx = PanopticClassMapper(nusc).get_coarse2idx()
    order = np.argsort([b[score_key] for b in boxes])[::-1]
    dboxes = [DetectionBox.deserialize(boxes[i]) for i in order]
    sensor = boxes_to_sensor(dboxes, nusc.get("ego_pose", sd["ego_pose_token"]),
                             nusc.get("calibrated_sensor", sd["calibrated_sensor_token"]))  # fmt: skip
    out = seg.astype(np.int64) * 1000
    taken = np.zeros(len(seg), bool)
    for rank, (box, dbox) in enumerate(zip(sensor, dboxes)):
        msk = points_in_box(box, points[:3]) & ~taken
        out[msk] = coarse2idx[dbox.detection_name] * 1000 + rank + 1
        taken |= msk
    return out.astype(np.uint16)


def test_paper_mode_matches_devkit_geometry_and_scores(world, tmp_path):
    reader, sub = world["reader"], world["subs"][BoxTask.DETECTION, "noisy"]
    out = tmp_path / "paper"
    argv = ["box-merge", "nuscenes", "--dataroot", str(world["root"]), "--version", VERSION,
            "--eval-set", EVAL_SET, "--semantic", str(world["base"] / "seg_noisy"), "--boxes",
            str(sub), "--mode", "paper", "--output", str(out)]  # fmt: skip
    assert main(argv) == 0
    results = json.loads(sub.read_text())["results"]
    meta = json.loads((out / "panoptic" / EVAL_SET / "submission.json").read_text())["meta"]
    assert "simulated detector" in meta["source"]
    seg_dir = world["base"] / "seg_noisy/lidarseg/mini_val"
    for tok in world["tokens"]:
        seg = np.fromfile(seg_dir / f"{tok}_lidarseg.bin", np.uint8)
        sample = reader.nusc.get("sample_data", tok)["sample_token"]
        ref = _paper_reference(reader.nusc, tok, seg, results[sample], "detection_score")
        got = np.load(out / "panoptic" / EVAL_SET / f"{tok}_panoptic.npz")["data"]
        np.testing.assert_array_equal(got, ref)
    # GT semantics + exact GT boxes: both rules find every instance; the devkit rule is perfect,
    # the paper rule also turns the stuff points inside boxes into things (lower IoU)
    for mode in ("paper", "devkit"):
        pred, scores = tmp_path / f"pred-{mode}", tmp_path / f"scores-{mode}"
        argv = ["box-merge", "nuscenes", "--dataset", str(world["root"]), "--version", VERSION,
                "--eval-set", EVAL_SET, "--semantic", str(world["base"] / "seg_gt"), "--boxes",
                str(world["subs"][BoxTask.DETECTION, "exact"]), "--mode", mode,
                "--output", str(pred)]  # fmt: skip
        assert main(argv) == 0
        classes = _eval(world["root"], pred, scores)["classes"]
        for name in PRESENT_THINGS:
            assert classes[name]["RQ"] == 1.0, (mode, name)
            if mode == "devkit":
                assert classes[name]["PQ"] == pytest.approx(1.0), name
        if mode == "paper":  # nuscenes_world puts a road point at the centre of car-a
            assert classes["car"]["SQ"] < 1.0


def _eval(root: Path, pred: Path, out: Path) -> dict:
    argv = ["eval", "nuscenes", "--dataroot", str(root), "--version", VERSION, "--result-path",
            str(pred), "--eval-set", EVAL_SET, "--min-inst-points", "1", "--output", str(out), "--overwrite"]  # fmt: skip
    assert main(argv) == 0
    return json.loads((out / "scores.json").read_text())


def test_simulated_detector_deterministic_and_labelled(world):
    root = world["root"]
    a = simulate_submission_nuscenes(root, VERSION, EVAL_SET, seed=3)
    assert a == simulate_submission_nuscenes(root, VERSION, EVAL_SET, seed=3)
    assert a["meta"]["source"] == "simulated detector" and a["meta"]["seed"] == 3
    exact = json.loads(world["subs"][BoxTask.DETECTION, "exact"].read_text())["results"]
    assert len(exact) == 5
    names = {b["detection_name"] for bs in exact.values() for b in bs}
    assert names == set(PRESENT_THINGS)  # the police car is a 'car' (panoptic class mapping)
    n_exact = sum(len(b) for b in exact.values())
    noisy = json.loads(world["subs"][BoxTask.DETECTION, "noisy"].read_text())["results"]
    assert sum(len(b) for b in noisy.values()) > n_exact  # fp_rate 1: false positives added
    track = json.loads(world["subs"][BoxTask.TRACKING, "exact"].read_text())["results"]
    assert {b["tracking_name"] for bs in track.values() for b in bs} <= {"car", "pedestrian"}


def test_centers_cluster_eval_nuscenes(world, tmp_path):
    root = str(world["root"])
    centers, pred, scores = tmp_path / "centers", tmp_path / "pred", tmp_path / "scores"
    assert main(["centers", "simulate", "--dataset", root, "--version", VERSION, "--eval-set",
                 EVAL_SET, "--zero-noise", "--output", str(centers)]) == 0  # fmt: skip
    assert len(list((centers / "centers").glob("*.npz"))) == 5
    assert json.loads((centers / "simulated.json").read_text())["source"] == "simulated regression"
    for method in (["bfs"], ["meanshift", "--bin-seeding", "--bandwidth", "0.65"]):
        argv = ["cluster", "nuscenes", "--dataset", root, "--version", VERSION, "--eval-set",
                EVAL_SET, "--centers", str(centers), "--method", *method, "--min-points", "1",
                "--output", str(pred), "--overwrite"]  # fmt: skip
        assert main(argv) == 0
        classes = _eval(world["root"], pred, scores)["classes"]
        for name in PRESENT_THINGS:  # exact centres: every instance found, nothing else
            assert classes[name]["PQ"] == pytest.approx(1.0), (method, name)
    # noisy simulated regression still runs end to end and scores below 1
    assert main(["centers", "simulate", "--dataset", root, "--version", VERSION, "--eval-set",
                 EVAL_SET, "--output", str(centers), "--overwrite"]) == 0  # fmt: skip
    assert main(argv) == 0
    classes = _eval(world["root"], pred, scores)["classes"]
    assert min(classes[name]["PQ"] for name in PRESENT_THINGS) < 1.0


def _merge_argv(world, out, seg="seg_gt", boxes=None):
    boxes = boxes or world["subs"][BoxTask.DETECTION, "exact"]
    return ["box-merge", "nuscenes", "--dataset", str(world["root"]), "--version", VERSION,
            "--eval-set", EVAL_SET, "--semantic", str(world["base"] / seg), "--boxes", str(boxes),
            "--mode", "devkit", "--output", str(out)]  # fmt: skip


def test_box_merge_bad_inputs_exit_2(world, tmp_path, capsys):
    out = tmp_path / "out"
    sub = json.loads(world["subs"][BoxTask.DETECTION, "exact"].read_text())
    cases = {}
    cases["missing.json"] = None
    bad = dict(sub, results=dict(sub["results"], **{"0" * 32: []}))
    cases["unknown-token.json"] = bad
    cases["not-json.json"] = "{"
    first = next(iter(sub["results"]))
    bad_name = json.loads(json.dumps(sub))
    bad_name["results"][first] = [dict(sub["results"][first][0], detection_name="plane")]
    cases["bad-name.json"] = bad_name
    cases["no-results.json"] = {"meta": sub["meta"]}
    for name, content in cases.items():
        path = tmp_path / name
        if isinstance(content, str):
            path.write_text(content)
        elif content is not None:
            write_json(path, content)
        assert main(_merge_argv(world, out, boxes=path)) == 2, name
        err = capsys.readouterr().err
        assert str(path) in err and "Traceback" not in err, (name, err)
    assert "not samples of v1.0-mini" in _last_err(world, out, tmp_path, capsys, "unknown-token")
    argv = _merge_argv(world, out) + ["--task", "tracking"]  # a detection JSON as tracking
    assert main(argv) == 2
    assert "pass --task detection" in capsys.readouterr().err
    # lidarseg predictions: one too short, one missing
    seg = tmp_path / "seg/lidarseg/mini"
    seg.mkdir(parents=True)
    tokens = world["tokens"]
    for tok in tokens[2:]:
        (seg / f"{tok}_lidarseg.bin").write_bytes(
            (world["base"] / "seg_gt/lidarseg/mini" / f"{tok}_lidarseg.bin").read_bytes()
        )
    short = seg / f"{tokens[0]}_lidarseg.bin"
    short.write_bytes(b"\x01" * 10)
    argv = _merge_argv(world, out)
    argv[argv.index("--semantic") + 1] = str(tmp_path / "seg")
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert str(short) in err and "10 lidarseg predictions" in err
    assert str(seg / f"{tokens[1]}_lidarseg.bin") in err and "missing" in err
    assert not (out / "panoptic").exists()  # nothing written before every input is checked


def _last_err(world, out, tmp_path, capsys, name):
    assert main(_merge_argv(world, out, boxes=tmp_path / f"{name}.json")) == 2
    return capsys.readouterr().err


def test_cluster_nuscenes_bad_centres_exit_2(world, tmp_path, capsys):
    tokens = world["tokens"]
    centers = tmp_path / "centers"
    for tok in tokens:
        write_centers(centers / "centers" / f"{tok}.npz", np.zeros(7, np.uint8), np.zeros((7, 3)))
    argv = ["cluster", "nuscenes", "--dataset", str(world["root"]), "--version", VERSION,
            "--eval-set", EVAL_SET, "--centers", str(centers), "--method", "bfs",
            "--output", str(tmp_path / "pred")]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"{tokens[0]}.npz" in err and "7 points" in err
    (centers / "centers" / f"{tokens[1]}.npz").unlink()
    assert main(argv) == 2
    assert f"{tokens[1]}.npz" in capsys.readouterr().err
