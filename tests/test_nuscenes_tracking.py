"""`eval nuscenes --task tracking`: the devkit's ``NuScenesPanopticEval(task='tracking')`` numbers
on a synthetic v1.0-mini world with id switches between frames, plus the task selection and
bad inputs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from nuscenes_world import real_sweep, write_mini

from panoptic_bench.cli import main
from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar

VERSION = "v1.0-mini"


@pytest.fixture(scope="module")
def gt_root(tmp_path_factory, shared_data) -> Path:
    root = write_mini(tmp_path_factory.mktemp("nust") / "root", real_sweep(shared_data))
    args = ["nuscenes", "make-labels", "--dataroot", str(root), "--version", VERSION]
    assert main([*args, "--out-dir", str(root)]) == 0
    return root


@pytest.fixture(scope="module")
def truth(gt_root) -> dict[str, np.ndarray]:
    """sample_data token (scene order) -> ground truth in challenge classes, as a prediction."""
    from panoptic_bench.evaluation.nuscenes import ChallengeClasses

    reader = NuScenesLidar(gt_root, VERSION)
    lut = ChallengeClasses.from_nusc(reader.nusc).lut
    out = {}
    for tok in reader.sample_data_tokens("mini_val"):
        gt = reader.load_panoptic(tok).astype(np.int64)
        out[tok] = lut[gt // 1000] * 1000 + gt % 1000
    return out


def _perfect(preds, rng):
    return preds


def _id_switches(preds, rng):
    """From the second frame on, instance ids are swapped / renumbered: switches on every track."""
    out = {}
    for k, (tok, p) in enumerate(preds.items()):
        p = p.copy()
        inst = p % 1000
        thing = (inst > 0) & (p // 1000 <= 10)
        if k % 2:
            p[thing] = (p[thing] // 1000) * 1000 + (inst[thing] % 3) + 1  # merges + switches
        elif k % 3 == 2:
            p[thing] = p[thing] + 7
        out[tok] = p
    return out


def _noisy(preds, rng):
    out = {}
    for tok, p in _id_switches(preds, rng).items():
        p = p.copy()
        flip = rng.random(len(p)) < 0.12
        p[flip] = rng.integers(0, 17, flip.sum()) * 1000 + rng.integers(0, 4, flip.sum())
        out[tok] = p
    return out


def _write(res: Path, preds: dict, meta_task: str | None = None) -> Path:
    folder = res / "panoptic" / "mini_val"
    folder.mkdir(parents=True, exist_ok=True)
    for tok, pred in preds.items():
        np.savez_compressed(folder / f"{tok}_panoptic.npz", data=pred.astype(np.uint16))
    if meta_task is not None:
        (res / "mini_val").mkdir(exist_ok=True)
        meta = {"meta": {"task": meta_task, "use_lidar": True}}
        (res / "mini_val" / "submission.json").write_text(json.dumps(meta))
    return res


def _eval(gt_root: Path, res: Path, out: Path, *extra: str) -> int:
    args = ["eval", "nuscenes", "--dataroot", str(gt_root), "--version", VERSION]
    args += ["--result-path", str(res), "--eval-set", "mini_val", "--output", str(out)]
    return main([*args, *extra])


def _devkit(gt_root: Path, res: Path, out: Path, min_points: int) -> dict:
    from nuscenes import NuScenes
    from nuscenes.eval.panoptic.evaluate import NuScenesPanopticEval

    nusc = NuScenes(VERSION, str(gt_root), verbose=False)
    NuScenesPanopticEval(
        nusc, str(res), "mini_val", "tracking", min_points, out_dir=str(out)
    ).evaluate()
    return json.loads((out / "tracking-result.json").read_text())


def _close(a, b) -> None:
    if isinstance(a, dict):
        assert list(a) == list(b)
        for k in a:
            _close(a[k], b[k])
    elif isinstance(b, float) and np.isnan(b):
        assert np.isnan(a)
    else:
        assert a == pytest.approx(b, abs=1e-12, rel=0)


@pytest.mark.parametrize("make", [_perfect, _id_switches, _noisy])
@pytest.mark.parametrize("min_points", [15, 40])
def test_identical_to_devkit(gt_root, truth, tmp_path, make, min_points):
    rng = np.random.default_rng(min_points)
    res = _write(tmp_path / "res", make(truth, rng))
    expected = _devkit(gt_root, res, tmp_path / "dk", min_points)
    out = tmp_path / "ours"
    assert _eval(gt_root, res, out, "--task", "tracking", "--min-inst-points", str(min_points)) == 0
    ours = json.loads((out / "tracking-result.json").read_text())
    assert ours["segmentation"] == expected["segmentation"]  # to the last bit
    _close(ours["tracking"], expected["tracking"])
    assert json.dumps(list(ours["tracking"]["all"])) == json.dumps(
        list(expected["tracking"]["all"])
    )
    scores = json.loads((out / "scores.json").read_text())
    ids = sum(m["IDS"] for m in scores["tracking"]["classes"].values())
    if make is _perfect:
        t = scores["tracking"]["all"]
        assert (t["PTQ"], t["TQ"], t["S_assoc"], t["MOTSA"], ids) == (1.0, 1.0, 1.0, 1.0, 0)
        assert t["PAT"] < 1.0  # the devkit's PQ averages every class, absent ones included
    else:
        assert ids > 0 and scores["tracking"]["all"]["PTQ"] < 1.0


def test_submission_meta_task_wins(gt_root, truth, tmp_path, capsys):
    res = _write(tmp_path / "res", truth, meta_task="tracking")
    out = tmp_path / "out"
    assert _eval(gt_root, res, out) == 0  # --task defaults to segmentation
    assert "PAT" in capsys.readouterr().out
    assert (out / "tracking-result.json").is_file()
    assert not (out / "segmentation-result.json").exists()
    res2 = _write(tmp_path / "res2", truth, meta_task="segmentation")
    out2 = tmp_path / "out2"
    assert _eval(gt_root, res2, out2, "--task", "tracking") == 0
    assert (out2 / "segmentation-result.json").is_file()


def test_workers_give_the_same_numbers(gt_root, truth, tmp_path, monkeypatch):
    from panoptic_bench.evaluation import workers

    monkeypatch.setattr(workers, "MIN_ITEMS_PER_WORKER", 1)  # a real pool for 5 sweeps
    monkeypatch.setattr(workers, "free_cpus", lambda: (8, "test: 8 free"))
    res = _write(tmp_path / "res", _noisy(truth, np.random.default_rng(3)))
    got = []
    for w in ("1", "2"):
        out = tmp_path / f"w{w}"
        assert _eval(gt_root, res, out, "--task", "tracking", "--workers", w) == 0
        got.append(json.loads((out / "tracking-result.json").read_text()))
    _close(got[0], got[1])


@pytest.mark.parametrize("case", ["missing_sample", "int32_npz", "bad_meta"])
def test_bad_input(gt_root, truth, tmp_path, capsys, case):
    res = _write(tmp_path / "res", truth)
    tok = list(truth)[2]
    victim = res / "panoptic" / "mini_val" / f"{tok}_panoptic.npz"
    if case == "missing_sample":
        victim.unlink()
    elif case == "int32_npz":
        np.savez_compressed(victim, data=truth[tok].astype(np.int32))
    else:
        victim = _write(res, {}, meta_task="panoptic") / "mini_val" / "submission.json"
    out = tmp_path / "out"
    assert _eval(gt_root, res, out, "--task", "tracking") == 2
    err = capsys.readouterr().err
    assert str(victim) in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_kernel_rejects_a_label_with_two_classes():
    from panoptic_bench.metrics.tracking import tracking_frame

    labels = np.array([4001, 4001, 11000])
    kw = {"num_classes": 17, "n_things": 10}
    tracking_frame(labels // 1000, labels, labels // 1000, labels, **kw)  # consistent: fine
    with pytest.raises(ValueError, match="one class"):
        tracking_frame(np.array([4, 5, 11]), labels, labels // 1000, labels, **kw)
    with pytest.raises(ValueError, match="same length"):
        tracking_frame(labels[:2] // 1000, labels, labels // 1000, labels, **kw)
