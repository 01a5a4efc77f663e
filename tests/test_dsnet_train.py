"""DS-Net training and inference: resume bit-for-bit, DDP (gloo, 2 processes), train→infer→eval.

Everything runs on a tiny hand-made SemanticKITTI-format world (``dsnet_tiny_world``) with a
tiny network (init_size 4 on a 32 x 32 x 8 grid), so the module stays well under a minute.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from panoptic_bench.cli import main as cli
from panoptic_bench.dsnet.checkpoint import load_checkpoint
from panoptic_bench.dsnet.config import DatasetFormat, DSNetConfig, LRSchedule, save_config
from panoptic_bench.dsnet.training.platform import NUMERIC_KEYS, read_records
from panoptic_bench.dsnet.training.train import train

sys.path.insert(0, str(Path(__file__).parent))
from dsnet_tiny_world import write_tiny_world  # noqa: E402

TINY = {
    "grid": {"size": [32, 32, 8]},
    "model": {
        "init_size": 4,
        "point_hidden": [16],
        "point_feature_dim": 16,
        "voxel_feature_dim": 8,
        "offset_hidden": 8,
    },
    "optim": {"batch_size": 2, "epochs_semantic": 1, "epochs_offset": 1, "epochs_ds": 1},
    "dynamic_shift": {"max_seeds": 64, "iterations": 2, "bandwidths": [0.5, 2.0]},
    "loss": {"ds_iteration_weights": [1.0, 1.0]},
    "inference": {"min_points": 5, "ds_bandwidth": 1.0},
    "data": {"train_sequences": ["00"], "val_sequences": ["08"]},
}


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> Path:
    return write_tiny_world(tmp_path_factory.mktemp("tiny"), {"00": 4, "08": 2})


@pytest.fixture(scope="module")
def cfg() -> DSNetConfig:
    return DSNetConfig.from_dict(TINY)


def _rows(run: Path) -> list[dict]:
    with open(run / "metrics.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def _same_state(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_resume_is_bit_for_bit(world: Path, cfg: DSNetConfig, tmp_path: Path):
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    train(cfg, world, straight, stage="semantic", epochs=2, progress=False)
    train(cfg, world, resumed, stage="semantic", epochs=1, progress=False)
    assert load_checkpoint(resumed / "checkpoints" / "semantic.pt").epoch == 1
    train(cfg, world, resumed, stage="semantic", epochs=2, resume=True, progress=False)
    a = load_checkpoint(straight / "checkpoints" / "semantic.pt")
    b = load_checkpoint(resumed / "checkpoints" / "semantic.pt")
    assert a.epoch == b.epoch == 2
    assert _same_state(a.backbone, b.backbone)
    assert _same_state(a.optimizer["state"][0], b.optimizer["state"][0])
    drop = ("seconds",)
    assert [{k: v for k, v in r.items() if k not in drop} for r in _rows(straight)] == [
        {k: v for k, v in r.items() if k not in drop} for r in _rows(resumed)
    ]
    # every call recorded its machine (training/platform.py), the same one each time
    records = read_records(resumed)
    assert len(records) == 2
    assert [{k: r[k] for k in NUMERIC_KEYS} for r in records] == [
        {k: records[0][k] for k in NUMERIC_KEYS}
    ] * 2
    # and training did change the weights
    fresh = tmp_path / "zero"
    train(cfg, world, fresh, stage="semantic", epochs=0, progress=False)
    c = load_checkpoint(fresh / "checkpoints" / "semantic.pt")
    assert not _same_state(a.backbone, c.backbone)


def test_cosine_schedule_sets_the_optimizer_rate(world: Path, cfg: DSNetConfig, tmp_path: Path):
    sched = cfg.replace(optim={"lr_schedule": LRSchedule.COSINE, "lr_flat_epochs": 1})
    train(sched, world, tmp_path, stage="semantic", epochs=3, progress=False)
    rows = _rows(tmp_path)
    want = [sched.optim.lr_at(e, 3) for e in range(3)]
    assert want[0] == want[1] == sched.optim.lr > want[2] > 0
    assert [float(r["lr"]) for r in rows] == pytest.approx(want)
    ck = load_checkpoint(tmp_path / "checkpoints" / "semantic.pt")
    assert ck.optimizer["param_groups"][0]["lr"] == pytest.approx(want[2])


def test_checkpoint_contents(world: Path, cfg: DSNetConfig, tmp_path: Path):
    train(cfg, world, tmp_path, stage="semantic", epochs=1, progress=False)
    ck = load_checkpoint(tmp_path / "checkpoints" / "semantic.pt")
    assert ck.config == cfg
    assert ck.class_map.num_classes == 20 and ck.class_map.thing_ids == tuple(range(1, 9))
    assert ck.class_weights[0] == 0.0 and len(ck.class_weights) == 20
    assert ck.metrics[0]["epoch"] == 1 and 0.0 <= ck.metrics[0]["val_mIoU"] <= 1.0
    meta = json.loads((tmp_path / "run.json").read_text())
    assert set(meta) == {"method", "dataset", "data", "notes"}
    # release copy: no optimizer / RNG state, float16 weights, still loads for inference
    src = tmp_path / "checkpoints" / "semantic.pt"
    assert cli(["checkpoint", "export", str(src), "--out", str(tmp_path / "x.pt"), "--half"]) == 0
    small = load_checkpoint(tmp_path / "x.pt")
    assert small.optimizer is None and small.rng is None
    assert (tmp_path / "x.pt").stat().st_size < src.stat().st_size / 3
    key = next(k for k, v in ck.backbone.items() if v.is_floating_point() and v.numel() > 100)
    assert torch.allclose(small.backbone[key].float(), ck.backbone[key], atol=1e-2)
    assert cli(["checkpoint", "show", str(tmp_path / "x.pt")]) == 0


def _eval_scores(world: Path, pred: Path, out: Path) -> dict:
    args = ["eval", "semantickitti", "--dataset", str(world), "--predictions", str(pred)]
    args += ["--sequences", "08", "--min-inst-points", "5", "--output", str(out)]
    assert cli(args) == 0
    return json.loads((out / "scores.json").read_text())["all"]


def test_train_infer_eval_smoke(world: Path, cfg: DSNetConfig, tmp_path: Path):
    from panoptic_bench.baselines.centers import read_centers
    from panoptic_bench.datasets.semantickitti import list_scans, read_labels
    from panoptic_bench.dsnet.inference.predictor import evaluate_dataset
    from panoptic_bench.dsnet.inference.run import load_predictor

    cfg_path = tmp_path / "tiny.yaml"
    save_config(cfg, cfg_path)
    run = tmp_path / "run"
    args = ["train", "--config", str(cfg_path), "--data", str(world), "--out", str(run)]
    assert cli([*args, "--stage", "semantic", "--no-progress"]) == 0
    assert cli([*args, "--stage", "offset", "--no-progress"]) == 0
    ckpt = run / "checkpoints" / "offset.pt"
    pred = tmp_path / "pred"
    infer = ["infer", "--checkpoint", str(ckpt), "--data", str(world), "--split", "08"]
    assert cli([*infer, "--out", str(pred), "--no-progress"]) == 0
    for ref in list_scans(world, sequences=["08"]):
        n = len(read_labels(ref.label))
        assert (
            len(read_labels(pred / "sequences" / "08" / "predictions" / f"{ref.frame}.label")) == n
        )
        read_centers(pred / "sequences" / "08" / "centers" / f"{ref.frame}.npz", n_points=n)
    meta = json.loads((pred / "run.json").read_text())
    assert meta["method"] == "Backbone with Fusion"
    scores = _eval_scores(world, pred, tmp_path / "eval")
    # the written tree scores exactly as the in-memory evaluation used for validation
    predictor, ck = load_predictor(ckpt)
    from panoptic_bench.dsnet.inference.run import open_split

    mem = evaluate_dataset(predictor, open_split(ck.config, world, "08"), progress=False)
    for key in ("PQ", "PQ_th", "PQ_st", "mIoU"):
        assert scores[key] == pytest.approx(mem[key], abs=1e-9)
    assert float(_rows(run)[-1]["val_PQ"]) == pytest.approx(mem["PQ"], abs=1e-5)


def test_ds_stage_and_dynamic_shift_inference(world: Path, cfg: DSNetConfig, tmp_path: Path):
    cfg_path = tmp_path / "tiny.yaml"
    save_config(cfg, cfg_path)
    run = tmp_path / "run"
    args = ["train", "--config", str(cfg_path), "--data", str(world), "--out", str(run)]
    assert cli([*args, "--stage", "all", "--no-progress"]) == 0
    ckpt = run / "checkpoints" / "offset.pt"
    # stage ds ran on top with the backbone frozen; DS-Net inference writes the diagnostics
    ds_ckpt = load_checkpoint(run / "checkpoints" / "ds.pt")
    assert ds_ckpt.has_shift and _same_state(ds_ckpt.backbone, load_checkpoint(ckpt).backbone)
    ds_infer = ["infer", "--checkpoint", str(run / "checkpoints" / "ds.pt"), "--data", str(world)]
    ds_infer += ["--split", "08", "--no-progress"]
    assert cli([*ds_infer, "--out", str(tmp_path / "ds")]) == 0
    assert json.loads((tmp_path / "ds" / "run.json").read_text())["method"] == "DS-Net"
    diag = np.load(tmp_path / "ds" / "sequences" / "08" / "dynamic_shift" / "000000.npz")
    m = len(diag["seed_index"])
    assert 0 < m <= cfg.dynamic_shift.max_seeds
    assert diag["positions"].shape == (3, m, 3) and diag["weights"].shape == (2, m, 2)
    assert np.allclose(diag["weights"].sum(-1), 1.0, atol=1e-5)
    bw = diag["weights"] @ diag["candidates"]
    assert np.allclose(diag["bandwidths"], bw, atol=1e-5)
    _eval_scores(world, tmp_path / "ds", tmp_path / "ds_eval")
    # --clusterer on a DS-Net checkpoint: same regressed centres, another clustering
    assert cli([*ds_infer, "--out", str(tmp_path / "bfs"), "--clusterer", "bfs"]) == 0
    assert not (tmp_path / "bfs" / "sequences" / "08" / "dynamic_shift").exists()
    for name in ("000000.npz", "000001.npz"):
        a = np.load(tmp_path / "ds" / "sequences" / "08" / "centers" / name)
        b = np.load(tmp_path / "bfs" / "sequences" / "08" / "centers" / name)
        assert np.array_equal(a["offset"], b["offset"]) and np.array_equal(a["sem"], b["sem"])
    # --tta-views 2: averaged over two views, still a complete, scorable tree
    assert cli([*ds_infer, "--out", str(tmp_path / "tta"), "--tta-views", "2"]) == 0
    _eval_scores(world, tmp_path / "tta", tmp_path / "tta_eval")
    a = np.load(tmp_path / "ds" / "sequences" / "08" / "centers" / "000000.npz")
    b = np.load(tmp_path / "tta" / "sequences" / "08" / "centers" / "000000.npz")
    assert a["offset"].shape == b["offset"].shape and not np.array_equal(a["offset"], b["offset"])
    # --bn-stats scan: each scan's own BatchNorm statistics, another prediction, still scorable
    assert cli([*ds_infer, "--out", str(tmp_path / "bn"), "--bn-stats", "scan"]) == 0
    _eval_scores(world, tmp_path / "bn", tmp_path / "bn_eval")
    c = np.load(tmp_path / "bn" / "sequences" / "08" / "centers" / "000000.npz")
    assert a["offset"].shape == c["offset"].shape and not np.array_equal(a["offset"], c["offset"])
    # --orphans stuff: thing points left without an instance take a stuff class, nothing else moves
    assert cli([*ds_infer, "--out", str(tmp_path / "orph"), "--orphans", "stuff"]) == 0
    _check_orphans(tmp_path / "ds", tmp_path / "orph")


def _check_orphans(keep: Path, stuff: Path) -> None:
    from panoptic_bench.datasets.semantickitti import read_labels, split_label, to_train

    orphans = 0
    for a_path in sorted((keep / "sequences" / "08" / "predictions").glob("*.label")):
        sem_a, inst_a = split_label(read_labels(a_path))
        sem_b, inst_b = split_label(read_labels(stuff / a_path.relative_to(keep)))
        train_a, train_b = to_train(sem_a), to_train(sem_b)
        is_orphan = (train_a >= 1) & (train_a <= 8) & (inst_a == 0)
        orphans += int(is_orphan.sum())
        assert np.array_equal(inst_a, inst_b)
        assert np.array_equal(sem_a[~is_orphan], sem_b[~is_orphan])
        assert np.all(train_b[is_orphan] >= 9)  # a stuff class, never unlabelled
    assert orphans > 0  # the tiny model leaves some, so the option had work to do


def test_ddp_gloo_two_processes(world: Path, cfg: DSNetConfig, tmp_path: Path):
    from panoptic_bench.dsnet.inference.predictor import evaluate_dataset
    from panoptic_bench.dsnet.inference.run import load_predictor, open_split

    cfg_path = tmp_path / "tiny.yaml"
    save_config(cfg.replace(optim={"batch_size": 1}), cfg_path)
    run = tmp_path / "ddp"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2"]
    cmd += ["-m", "panoptic_bench", "train", "--config", str(cfg_path), "--data", str(world)]
    cmd += ["--out", str(run), "--stage", "semantic", "--device", "cpu", "--no-progress"]
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=240)
    assert res.returncode == 0, res.stderr[-3000:]
    ckpt = load_checkpoint(run / "checkpoints" / "semantic.pt")
    assert ckpt.epoch == 1
    # validation was split over the two ranks and all-reduced: equal to one process on all scans
    predictor, ck = load_predictor(ckpt)
    mem = evaluate_dataset(
        predictor, open_split(ck.config, world, "08"), panoptic=False, progress=False
    )
    assert ckpt.metrics[-1]["val_mIoU"] == pytest.approx(mem["mIoU"], abs=1e-12)


def test_shard_order_covers_every_sample_once_per_epoch():
    from panoptic_bench.dsnet.distributed import DistInfo, eval_shard, shard_order

    n = 7
    shards = [shard_order(n, 3, 0, DistInfo(rank=r, world_size=2), True) for r in range(2)]
    assert len(shards[0]) == len(shards[1]) == 4
    assert set(shards[0]) | set(shards[1]) == set(range(n))
    assert shard_order(n, 3, 0, DistInfo(), True) != shard_order(n, 4, 0, DistInfo(), True)
    ev = [eval_shard(n, DistInfo(rank=r, world_size=3)) for r in range(3)]
    assert sorted(sum(ev, [])) == list(range(n))


def test_training_set_augmentation_is_reproducible(world: Path, cfg: DSNetConfig):
    from panoptic_bench.dsnet.data.datasets import open_dataset
    from panoptic_bench.dsnet.data.training_set import TrainingSet

    ds = open_dataset(world, cfg.data, "train")
    a = TrainingSet(ds, cfg.augment.__class__(max_points=500), seed=1)
    b = TrainingSet(ds, cfg.augment.__class__(max_points=500), seed=1)
    a.set_epoch(2)
    b.set_epoch(2)
    assert np.array_equal(a[1].xyz, b[1].xyz) and len(a[1].xyz) == 500
    b.set_epoch(3)
    assert not np.array_equal(a[1].xyz, b[1].xyz)
    raw = ds.load(1)
    assert not np.array_equal(raw.xyz, TrainingSet(ds, cfg.augment, seed=1)[1].xyz)
    assert np.array_equal(raw.sem, TrainingSet(ds, cfg.augment, seed=1)[1].sem)


def test_dataset_instances_unique_and_errors(world: Path, cfg: DSNetConfig, tmp_path: Path):
    from panoptic_bench.dsnet.data.datasets import open_dataset
    from panoptic_bench.errors import InputError

    s = open_dataset(world, cfg.data, "train").load(0)
    assert s.inst.min() == 0 and set(np.unique(s.inst[s.inst > 0])) == set(
        range(1, s.inst.max() + 1)
    )
    assert (s.sem[s.inst > 0] == 1).all()  # only cars carry instances
    with pytest.raises(InputError, match="num_classes"):
        open_dataset(world, cfg.replace(data={"num_classes": 17}).data, "train")
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="checkpoint"):
        load_checkpoint(bad)


def test_nuscenes_root_train_infer_eval(cfg: DSNetConfig, tmp_path: Path):
    """A nuScenes-format root (synthetic, with panoptic labels) through the same interface."""
    from panoptic_bench.datasets.synthetic import generate_nuscenes
    from panoptic_bench.dsnet.data.datasets import open_dataset

    root = generate_nuscenes(tmp_path / "nus", scenes=10, samples=1, progress=False)
    assert cli(["nuscenes", "make-labels", "--dataroot", str(root), "--version", "v1.0-mini",
                "--out-dir", str(root)]) == 0  # fmt: skip
    nus = cfg.replace(
        data={"format": DatasetFormat.NUSCENES, "num_classes": 17, "train_split": "mini_train",
              "val_split": "mini_val", "nuscenes_version": "v1.0-mini"},
    )  # fmt: skip
    ds = open_dataset(root, nus.data, "val")
    s = ds.load(0)
    assert ds.class_map.thing_ids == tuple(range(1, 11)) and s.sem.max() <= 16
    assert (ds.class_map.thing_lut()[s.sem] | (s.inst == 0)).all()
    run = tmp_path / "run"
    paths = train(nus, root, run, stage="semantic", epochs=1, progress=False)
    pred = tmp_path / "pred"
    args = ["infer", "--checkpoint", str(paths["semantic"]), "--data", str(root)]
    assert cli([*args, "--split", "mini_val", "--out", str(pred), "--no-progress"]) == 0
    files = sorted((pred / "panoptic" / "mini_val").glob("*_panoptic.npz"))
    assert len(files) == len(ds) == 2
    assert cli(["eval", "nuscenes", "--dataroot", str(root), "--version", "v1.0-mini",
                "--result-path", str(pred), "--eval-set", "mini_val",
                "--output", str(tmp_path / "eval")]) == 0  # fmt: skip
    scores = json.loads((tmp_path / "eval" / "scores.json").read_text())["all"]
    assert 0.0 <= scores["mIoU"] <= 1.0


def test_training_with_instance_pasting_and_a_bad_bank(cfg: DSNetConfig, tmp_path: Path, capsys):
    """augment.paste_*: a run pastes its own cars; a bank root that is not there is exit 2."""
    world = write_tiny_world(tmp_path / "w", {"00": 3, "08": 1})
    paste = {"paste_prob": 1.0, "paste_count": [2, 2], "paste_classes": ["car"]}
    good = tmp_path / "paste.yaml"
    save_config(cfg.replace(augment={**paste, "paste_min_points": 5}), good)
    run = tmp_path / "run"
    args = ["train", "--data", str(world), "--stage", "semantic", "--epochs", "1", "--no-progress"]
    assert cli([*args, "--config", str(good), "--out", str(run)]) == 0
    assert (run / "checkpoints" / "semantic.pt").exists()
    bad = tmp_path / "bad.yaml"
    missing = tmp_path / "no-bank"
    save_config(cfg.replace(augment={**paste, "paste_bank": str(missing)}), bad)
    capsys.readouterr()
    assert cli([*args, "--config", str(bad), "--out", str(tmp_path / "bad_run")]) == 2
    err = capsys.readouterr().err
    assert "augment.paste_bank: not a directory" in err and str(missing) in err
    assert "Traceback" not in err and not (tmp_path / "bad_run" / "checkpoints").exists()
