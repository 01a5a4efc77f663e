"""``checkpoint import-dsnet`` end to end, ``infer`` on an imported checkpoint, bad inputs,
shipped checkpoint names and class-map mismatches."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from panoptic_bench.cli import main
from panoptic_bench.dsnet.checkpoint import (
    SHIPPED,
    load_checkpoint,
    resolve_checkpoint,
    shipped_checkpoints,
)
from panoptic_bench.dsnet.official.convert import convert_state
from panoptic_bench.errors import InputError

sys.path.insert(0, str(Path(__file__).parent))
from test_dsnet_official import random_official_state  # noqa: E402


@pytest.fixture(scope="module")
def official_step3(tmp_path_factory) -> Path:
    """A random official step-3 checkpoint as the official save_checkpoint writes it."""
    path = tmp_path_factory.mktemp("official") / "dsnet_pretrain_random.pth"
    state = random_official_state(3, seed=1)
    state["module.sem_loss.weight"] = torch.linspace(1, 2, 20)
    torch.save({"epoch": 7, "model_state": state, "optimizer_state": None}, path)
    return path


@pytest.fixture(scope="module")
def tiny_root(kitti_root, tmp_path_factory) -> Path:
    """A SemanticKITTI root holding every 40th point of one real scan (sequence 00)."""
    root = tmp_path_factory.mktemp("tiny") / "kitti"
    src = kitti_root / "sequences" / "00"
    pts = np.fromfile(src / "velodyne" / "000000.bin", np.float32).reshape(-1, 4)[::40]
    lab = np.fromfile(src / "labels" / "000000.label", np.uint32)[::40]
    for sub in ("velodyne", "labels"):
        (root / "sequences" / "00" / sub).mkdir(parents=True)
    pts.tofile(root / "sequences" / "00" / "velodyne" / "000000.bin")
    lab.tofile(root / "sequences" / "00" / "labels" / "000000.label")
    return root


@pytest.fixture(scope="module")
def imported(official_step3, tmp_path_factory) -> Path:
    dst = tmp_path_factory.mktemp("imported") / "dsnet_official.pt"
    assert main(["checkpoint", "import-dsnet", str(official_step3), "--out", str(dst)]) == 0
    return dst


def test_import_writes_a_strictly_loadable_official_checkpoint(imported, official_step3):
    ck = load_checkpoint(imported)
    assert ck.stage == "ds" and ck.epoch == 7 and ck.config.model.variant.value == "official"
    assert ck.class_map.num_classes == 20 and ck.class_map.thing_ids == tuple(range(1, 9))
    assert ck.class_weights == pytest.approx(np.linspace(1, 2, 20).tolist())
    raw = torch.load(official_step3, weights_only=True)["model_state"]
    w = raw["module.backbone.upBlock2.conv3.weight"]  # (3, 3, 3, 128, 128)
    assert torch.equal(ck.backbone["unet.up.2.refine.2.conv.weight"], w.reshape(27, 128, 128))
    lin = raw[f"module.pytorch_meanshift.learnable_bandwidth_weights_layer_list.{1}.3.weight"]
    assert torch.equal(ck.shift["mlps.1.3.weight"], lin)


def test_print_map_names_every_tensor(official_step3, tmp_path, capsys):
    dst = tmp_path / "x.pt"
    assert (
        main(["checkpoint", "import-dsnet", str(official_step3), "--out", str(dst), "--print-map"])
        == 0
    )
    out = capsys.readouterr().out
    assert "official DS-Net step 3 (ds): 337 rows" in out
    assert (
        "backbone.downCntx.conv1_2.weight [3, 1, 3, 32, 32] -> "
        "unet.context.branch_a.1.conv.weight [9, 32, 32] (spconv1 reshape)"
    ) in out
    assert len([line for line in out.splitlines() if " -> " in line]) == 337 + 1


def test_infer_eval_show_with_an_imported_checkpoint(imported, tiny_root, tmp_path, capsys):
    out = tmp_path / "pred"
    argv = ["infer", "--checkpoint", str(imported), "--data", str(tiny_root)]
    assert main([*argv, "--sequences", "00", "--out", str(out), "--no-progress"]) == 0
    assert "DS-Net: 1 scans" in capsys.readouterr().out
    label = out / "sequences" / "00" / "predictions" / "000000.label"
    centres = np.load(out / "sequences" / "00" / "centers" / "000000.npz")
    # the centres hold the official per-point argmax (all 20 classes) and offsets
    from panoptic_bench.dsnet.checkpoint import build_backbone, build_grid
    from panoptic_bench.dsnet.data.datasets import SemanticKittiDataset
    from panoptic_bench.dsnet.model.forward import backbone_forward

    ck = load_checkpoint(imported)
    bb = build_backbone(ck.config, 20)
    bb.load_state_dict(ck.backbone)
    bb.eval()
    sample = SemanticKittiDataset(tiny_root, sequences=["00"]).load(0)
    with torch.no_grad():
        o = backbone_forward(bb, [sample], build_grid(ck.config), torch.device("cpu"))
    sem_key = next(k for k in centres.files if k.startswith("sem"))
    off_key = next(k for k in centres.files if k.startswith("off"))
    assert np.array_equal(centres[sem_key], o.sem_logits.argmax(1).numpy())
    np.testing.assert_allclose(centres[off_key], o.offsets.numpy(), atol=1e-5)
    assert np.fromfile(label, np.uint32).shape == (len(sample.xyz),)
    scores = tmp_path / "scores"
    ev = ["eval", "semantickitti", "--dataset", str(tiny_root), "--predictions", str(out)]
    assert main([*ev, "--sequences", "00", "--output", str(scores)]) == 0
    assert (scores / "scores.json").is_file()
    assert main(["checkpoint", "show", str(imported)]) == 0
    assert "stage ds" in capsys.readouterr().out


def _run_import(tmp_path, capsys, src: Path) -> str:
    dst = tmp_path / "dst.pt"
    assert main(["checkpoint", "import-dsnet", str(src), "--out", str(dst)]) == 2
    assert not dst.exists()
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return err


def test_import_refuses_a_file_that_is_not_a_checkpoint(tmp_path, capsys):
    src = tmp_path / "notes.pth"
    src.write_text("not a checkpoint\n")
    err = _run_import(tmp_path, capsys, src)
    assert "cannot read as a PyTorch checkpoint" in err and "notes.pth" in err


def test_import_refuses_a_truncated_file(tmp_path, capsys):
    full = tmp_path / "full.pth"
    torch.save({"model_state": {"backbone.x.weight": torch.randn(1000)}}, full)
    src = tmp_path / "cut.pth"
    src.write_bytes(full.read_bytes()[: full.stat().st_size // 2])
    err = _run_import(tmp_path, capsys, src)
    assert "cannot read as a PyTorch checkpoint" in err and "truncated" in err


@pytest.mark.parametrize(
    ("state", "what"),
    [
        (
            {
                "cylinder_3d_generator.PPmodel.0.weight": torch.randn(9),
                "cylinder_3d_spconv_seg.downCntx.conv1.weight": torch.randn(1, 3, 3, 16, 32),
            },
            "a Cylinder3D checkpoint",
        ),
        (
            {
                "module.backbone.downCntx.conv1.weight": torch.randn(1, 3, 3, 16, 32),
                "module.tracking_head.conv1.weight": torch.randn(3, 3, 3, 128, 128),
            },
            "4D-DS-Net",
        ),
    ],
)
def test_import_names_foreign_models(tmp_path, capsys, state, what):
    src = tmp_path / "other.pth"
    torch.save({"epoch": 1, "model_state": state}, src)
    err = _run_import(tmp_path, capsys, src)
    assert what in err and "not supported" in err


def test_import_names_missing_keys(tmp_path, capsys):
    src = tmp_path / "partial.pth"
    torch.save({"backbone.downCntx.conv1.weight": torch.randn(1, 3, 3, 16, 32)}, src)
    err = _run_import(tmp_path, capsys, src)
    assert "missing key 'vfe_model.PPmodel.0.weight'" in err and "partial.pth" in err


@pytest.fixture(scope="module")
def step2_state() -> dict:
    return {k.removeprefix("module."): v for k, v in random_official_state(2, seed=2).items()}


def test_convert_names_wrong_shapes_and_unmapped_keys(step2_state):
    state = dict(step2_state)
    state["ins_head.conv2.weight"] = torch.randn(3, 3, 3, 128, 32)
    state["backbone.extra.weight"] = torch.randn(4)
    del state["sem_head.logits.bias"]
    with pytest.raises(InputError) as info:
        convert_state(state, "x.pth")
    text = str(info.value)
    assert "wrong shape for 'ins_head.conv2.weight': [3, 3, 3, 128, 32]" in text
    assert "unmapped key 'backbone.extra.weight'" in text
    assert "missing key 'sem_head.logits.bias'" in text
    assert convert_state(step2_state).step == 2


def test_step1_is_detected_and_gets_an_initialised_offset_head(step2_state, tmp_path, tiny_root):
    state = {k: v for k, v in step2_state.items() if not k.startswith("ins_head.")}
    src = tmp_path / "sem_pretrain_random.pth"
    torch.save(state, src)  # a bare state dict
    assert main(["checkpoint", "import-dsnet", str(src), "--out", str(tmp_path / "s1.pt")]) == 0
    ck = load_checkpoint(tmp_path / "s1.pt")
    assert ck.stage == "semantic" and ck.shift is None
    assert torch.equal(ck.backbone["semantic_head.logits.bias"], state["sem_head.logits.bias"])
    # as the official step-1 model: semantics only, no instances
    from panoptic_bench.dsnet.data.datasets import SemanticKittiDataset
    from panoptic_bench.dsnet.inference.run import load_predictor

    pred, _ = load_predictor(ck)
    assert pred.semantic_only
    out = pred.predict(SemanticKittiDataset(tiny_root, sequences=["00"]).load(0))
    assert out.inst.max() == 0 and np.array_equal(out.sem, out.sem_raw)


def test_shipped_names(tmp_path):
    assert set(SHIPPED) >= {
        "synthetic",
        "synthetic-backbone",
        "semantickitti-cpu",
        "semantickitti-cpu-backbone",
        "nuscenes-synthetic",
    }
    assert resolve_checkpoint("synthetic").name == "dsnet_synthetic.pt"
    assert resolve_checkpoint("synthetic-backbone").name == "backbone_synthetic.pt"
    assert {"synthetic", "synthetic-backbone"} <= set(shipped_checkpoints())
    from panoptic_bench.demo.steps import TRAINED_ON

    assert set(SHIPPED.values()) <= set(TRAINED_ON)  # every shipped file says what it learnt from
    for path in shipped_checkpoints().values():
        assert path.stat().st_size <= 30 * 2**20, path
    for name in set(SHIPPED) - set(shipped_checkpoints()):
        with pytest.raises(InputError, match="not shipped with this install; shipped: synthetic"):
            resolve_checkpoint(name)
    with pytest.raises(InputError, match="unknown checkpoint name 'synthtic'"):
        resolve_checkpoint("synthtic")
    assert resolve_checkpoint(tmp_path / "a.pt") == tmp_path / "a.pt"


def test_checkpoint_show_and_export_take_short_names(tmp_path, capsys):
    assert main(["checkpoint", "show", "synthetic"]) == 0
    assert capsys.readouterr().out.startswith("stage ds, epoch")
    dst = tmp_path / "copy.pt"
    assert main(["checkpoint", "export", "synthetic-backbone", "--out", str(dst)]) == 0
    copied, shipped = (
        load_checkpoint(dst),
        load_checkpoint(resolve_checkpoint("synthetic-backbone")),
    )
    assert copied.stage == shipped.stage and copied.backbone.keys() == shipped.backbone.keys()
    assert all(torch.equal(copied.backbone[k], v) for k, v in shipped.backbone.items())
    assert main(["checkpoint", "show", "synthtic"]) == 2
    assert "unknown checkpoint name 'synthtic'" in capsys.readouterr().err


def test_infer_refuses_a_class_map_that_does_not_fit(imported, tmp_path, capsys):
    from panoptic_bench.dsnet.checkpoint import save_checkpoint

    ck = load_checkpoint(resolve_checkpoint("synthetic"))
    ck.config = ck.config.replace(data={"format": ck.config.data.format.__class__("nuscenes")})
    ck.class_map = type(ck.class_map)("nuscenes", ck.class_map.class_names, (1,), (2,), (0,))
    nus = tmp_path / "nus.pt"
    save_checkpoint(ck, nus)
    kitti = tmp_path / "kitti"
    (kitti / "sequences" / "00" / "velodyne").mkdir(parents=True)
    argv = ["infer", "--checkpoint", str(nus), "--data", str(kitti), "--sequences", "00"]
    assert main([*argv, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "nuscenes model" in err and "semantickitti root" in err
    nus_root = tmp_path / "nusroot"
    (nus_root / "v1.0-mini").mkdir(parents=True)
    argv = ["infer", "--checkpoint", str(imported), "--data", str(nus_root), "--split", "mini_val"]
    assert main([*argv, "--out", str(tmp_path / "o2")]) == 2
    err = capsys.readouterr().err
    assert "semantickitti model" in err and "nuscenes root" in err
    assert not (tmp_path / "o").exists() and not (tmp_path / "o2").exists()
