"""`eval nuscenes`: the devkit evaluator's numbers, plus the checks the devkit does not make."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from nuscenes_world import real_sweep, write_mini

from panoptic_bench.cli import main
from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar

VERSION = "v1.0-mini"


@pytest.fixture(scope="module")
def gt_root(tmp_path_factory, shared_data) -> Path:
    root = write_mini(tmp_path_factory.mktemp("nus") / "root", real_sweep(shared_data))
    args = ["nuscenes", "make-labels", "--dataroot", str(root), "--version", VERSION]
    assert main([*args, "--out-dir", str(root)]) == 0
    return root


@pytest.fixture(scope="module")
def truth(gt_root):
    """sample_data token -> (ground truth in challenge classes as a prediction, lut)."""
    from panoptic_bench.evaluation.nuscenes import ChallengeClasses

    reader = NuScenesLidar(gt_root, VERSION)
    lut = ChallengeClasses.from_nusc(reader.nusc).lut
    out = {}
    for tok in reader.sample_data_tokens("mini_val"):
        gt = reader.load_panoptic(tok).astype(np.int64)
        out[tok] = lut[gt // 1000] * 1000 + gt % 1000
    return out


def _perfect(pred, rng):
    return pred


def _perturbed(pred, rng):
    pred = pred.copy()
    flip = rng.random(len(pred)) < 0.15
    pred[flip] = rng.integers(1, 17, flip.sum()) * 1000 + rng.integers(0, 4, flip.sum())
    return pred


def _missing_instances(pred, rng):
    pred = pred.copy()
    ids = np.unique(pred[(pred % 1000) > 0])
    drop = np.isin(pred, ids[::2])
    pred[drop] = (pred[drop] // 1000) * 1000  # instance id 0: merged into one segment
    return pred


def _wrong_classes(pred, rng):
    sem = pred // 1000
    sem = np.where((sem >= 1) & (sem <= 10), (sem % 10) + 1, sem)  # things shifted by one
    return sem * 1000 + pred % 1000


def _write_predictions(res: Path, preds: dict, dtype=np.uint16) -> Path:
    folder = res / "panoptic" / "mini_val"
    folder.mkdir(parents=True, exist_ok=True)
    for tok, pred in preds.items():
        np.savez_compressed(folder / f"{tok}_panoptic.npz", data=pred.astype(dtype))
    return res


def _eval(gt_root: Path, res: Path, out: Path, *extra: str) -> int:
    args = ["eval", "nuscenes", "--dataroot", str(gt_root), "--version", VERSION]
    args += ["--result-path", str(res), "--eval-set", "mini_val", "--output", str(out)]
    return main([*args, *extra])


@pytest.mark.parametrize("make", [_perfect, _perturbed, _missing_instances, _wrong_classes])
@pytest.mark.parametrize("min_points", [15, 1])
def test_identical_to_devkit(gt_root, truth, tmp_path, make, min_points):
    from nuscenes import NuScenes
    from nuscenes.eval.panoptic.evaluate import NuScenesPanopticEval

    rng = np.random.default_rng(min_points)
    res = _write_predictions(tmp_path / "res", {t: make(p, rng) for t, p in truth.items()})
    nusc = NuScenes(VERSION, str(gt_root), verbose=False)
    NuScenesPanopticEval(
        nusc, str(res), "mini_val", "segmentation", min_points, out_dir=str(tmp_path / "dk")
    ).evaluate()
    expected = json.loads((tmp_path / "dk" / "segmentation-result.json").read_text())
    out = tmp_path / "ours"
    assert _eval(gt_root, res, out, "--min-inst-points", str(min_points)) == 0
    ours = json.loads((out / "segmentation-result.json").read_text())
    assert ours == expected  # every number, to the last bit
    assert json.dumps(ours) == json.dumps(expected)  # same keys in the same order
    gt_classes = {int(c) for p in truth.values() for c in np.unique(p // 1000)} - {0}
    assert len(gt_classes) >= 5
    names = list(expected["segmentation"])[2:]  # after "all" and "ignore"
    perfect = all(expected["segmentation"][names[c - 1]]["PQ"] == 1.0 for c in gt_classes)
    assert perfect == (make is _perfect)


def test_scores_and_by_range(gt_root, truth, tmp_path, monkeypatch):
    import panoptic_bench.evaluation.workers as workers

    monkeypatch.setattr(workers, "MIN_ITEMS_PER_WORKER", 1)  # a real 2-process pool
    monkeypatch.setattr(workers, "free_cpus", lambda: (8, "test: 8 free"))
    res = _write_predictions(tmp_path / "res", truth)
    out = tmp_path / "out"
    assert _eval(gt_root, res, out, "--by-range", "0,10,30,200", "--workers", "2") == 0
    scores = json.loads((out / "scores.json").read_text())
    present = [m for m in scores["classes"].values() if m["IoU"] > 0]
    assert present and all(m["PQ"] == 1.0 for m in present)
    assert scores["n_samples"] == 5
    bins = scores["by_range"]
    assert [b["range"] for b in bins] == [[0, 10], [10, 30], [30, 200]]
    assert sum(b["points"] for b in bins) > 0 and all(
        b["all"]["mIoU"] > 0 for b in bins if b["points"]
    )
    csv = (out / "per_class.csv").read_text().splitlines()
    assert csv[0] == "class,kind,PQ,SQ,RQ,IoU" and len(csv) == 17
    assert (out / "scores.txt").read_text().startswith("iou_mean:")


def _tok(truth, k=1):
    return list(truth)[k]


@pytest.mark.parametrize(
    "case, words",
    [
        ("no_data", "has no 'data'"),
        ("short", "points"),
        ("bad_class", "class ids must be 0..16"),
        ("missing", "is missing"),
        ("no_gt", "no panoptic ground truth"),
        ("eval_set", "absent from the dataroot"),
    ],
)
def test_bad_input(gt_root, truth, tmp_path, capsys, case, words):
    preds = dict(truth)
    tok = _tok(truth)
    root = gt_root
    eval_set = ["--eval-set", "mini_val"]
    res = _write_predictions(tmp_path / "res", preds)
    victim = res / "panoptic" / "mini_val" / f"{tok}_panoptic.npz"
    if case == "no_data":
        np.savez_compressed(victim, labels=preds[tok].astype(np.uint16))
    elif case == "short":
        np.savez_compressed(victim, data=preds[tok][:-3].astype(np.uint16))
    elif case == "bad_class":
        bad = preds[tok].copy()
        bad[7] = 17 * 1000 + 2
        np.savez_compressed(victim, data=bad.astype(np.uint16))
    elif case == "missing":
        victim.unlink()
    elif case == "no_gt":
        root = tmp_path / "nogt"
        shutil.copytree(gt_root, root)
        shutil.rmtree(root / "panoptic")
        (root / VERSION / "panoptic.json").unlink()
        victim = root / VERSION / "panoptic.json"
    elif case == "eval_set":
        (res / "panoptic" / "mini_train").mkdir()
        eval_set = ["--eval-set", "mini_train"]
        victim = root / VERSION / "scene.json"
    out = tmp_path / "out"
    args = ["eval", "nuscenes", "--dataroot", str(root), "--version", VERSION]
    args += ["--result-path", str(res), *eval_set, "--output", str(out)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("panoptic-bench: error:") and words in err
    assert str(victim) in err and len(err.strip().splitlines()) == 1
    assert not out.exists()
