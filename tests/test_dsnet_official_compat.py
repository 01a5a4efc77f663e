"""Backward compatibility: the nominal network still gives bit-identical outputs.

The pins in ``tests/data/dsnet_nominal_pins.json`` are sha256 prefixes of the backbone outputs
and of the predictions on a small real scan (every 8th point of sequences/00 scan 0), computed
with the code of commit 9d30447, before ``model.variant`` existed; ``dsnet_nominal_pins.npz``
holds the leading rows of the same outputs and the full predictions. On the platform that made
them (same torch build and CPU kernels, ``_platform``) the shipped checkpoints and the CPU
configs (which name no variant) must reproduce every pin bit for bit; elsewhere float kernels
may round differently, so the arrays are compared to 1e-5 and the predictions to 99.9 %.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from panoptic_bench.dsnet.checkpoint import (
    build_backbone,
    build_grid,
    build_shift,
    is_official,
    load_checkpoint,
)
from panoptic_bench.dsnet.config import NetworkVariant, load_config
from panoptic_bench.dsnet.data.datasets import SemanticKittiDataset
from panoptic_bench.dsnet.inference.predictor import Predictor
from panoptic_bench.dsnet.model.forward import backbone_forward

REPO = Path(__file__).resolve().parents[1]
PINS = json.loads((REPO / "tests" / "data" / "dsnet_nominal_pins.json").read_text())
ARRAYS = np.load(REPO / "tests" / "data" / "dsnet_nominal_pins.npz")


def _platform() -> str:
    model = ""
    try:
        with open("/proc/cpuinfo") as fh:
            model = next(
                (ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name")), ""
            )
    except OSError:
        pass
    return f"torch {torch.__version__} | {torch.backends.cpu.get_cpu_capability()} | {model}"


SAME_PLATFORM = _platform() == PINS["_platform"]


def _check(name: str, key: str, got: np.ndarray) -> None:
    ref = ARRAYS[f"{name}.{key}"]
    part = got[: len(ref)]
    if SAME_PLATFORM:
        assert np.array_equal(part, ref), (name, key)
    else:
        np.testing.assert_allclose(part, ref, rtol=1e-5, atol=1e-5)


def _digest(a) -> str:
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()[:32]


@pytest.fixture(scope="module")
def small_scan(kitti_root):
    sample = SemanticKittiDataset(kitti_root, sequences=["00"]).load(0)
    n = len(sample.xyz)
    keep = np.arange(0, n, 8)
    arrays = {
        f.name: getattr(sample, f.name)[keep]
        for f in dataclasses.fields(sample)
        if isinstance(getattr(sample, f.name), np.ndarray) and len(getattr(sample, f.name)) == n
    }
    return dataclasses.replace(sample, **arrays)


@pytest.mark.parametrize("name", ["backbone_synthetic.pt", "dsnet_synthetic.pt"])
def test_shipped_checkpoints_bit_identical(name, small_scan, one_torch_thread):
    ck = load_checkpoint(REPO / "panoptic_bench" / "checkpoints" / name)
    assert ck.config.model.variant is NetworkVariant.NOMINAL and not is_official(ck.config)
    bb = build_backbone(ck.config, ck.class_map.num_classes)
    bb.load_state_dict(ck.backbone)
    bb.eval()
    shift = None
    if ck.shift is not None:
        shift = build_shift(ck.config, bb.instance_head.out_channels)
        shift.load_state_dict(ck.shift)
        shift.eval()
    with torch.no_grad():
        out = backbone_forward(bb, [small_scan], build_grid(ck.config), torch.device("cpu"))
    torch.manual_seed(0)
    pred = Predictor(bb, shift, ck.config, ck.class_map).predict(small_scan)
    pins, stem = PINS[name], name.removesuffix(".pt")
    assert len(small_scan.xyz) == PINS["n_points"]
    _check(stem, "sem_logits", out.sem_logits.numpy())
    _check(stem, "offsets", out.offsets.numpy())
    _check(stem, "point_features", out.point_features.numpy())
    if SAME_PLATFORM:  # bit for bit: every output of every point, and the predictions
        assert _digest(out.sem_logits.numpy()) == pins["sem_logits"]
        assert _digest(out.offsets.numpy()) == pins["offsets"]
        assert _digest(out.point_features.numpy()) == pins["point_features"]
        assert int(pred.inst.max()) == pins["n_instances"]
        assert _digest(pred.sem) == pins["sem"]
        assert _digest(pred.inst) == pins["inst"]
    assert np.mean(pred.sem == ARRAYS[f"{stem}.sem"]) >= (1.0 if SAME_PLATFORM else 0.999)


@pytest.mark.parametrize(
    "cfgname",
    [
        "dsnet_semantickitti_cpu.yaml",
        "dsnet_semantickitti_cpu_all.yaml",
        "dsnet_synthetic_cpu.yaml",
    ],
)
def test_cpu_configs_build_the_nominal_network(cfgname, small_scan, one_torch_thread):
    cfg = load_config(REPO / "configs" / cfgname)
    assert cfg.model.variant is NetworkVariant.NOMINAL
    torch.manual_seed(0)
    bb = build_backbone(cfg, 20)
    bb.eval()
    with torch.no_grad():
        out = backbone_forward(bb, [small_scan], build_grid(cfg), torch.device("cpu"))
    stem = cfgname.removesuffix(".yaml")
    _check(stem, "sem_logits", out.sem_logits.numpy())
    _check(stem, "offsets", out.offsets.numpy())
    if SAME_PLATFORM:
        assert _digest(out.sem_logits.numpy()) == PINS[cfgname]["sem_logits"]
        assert _digest(out.offsets.numpy()) == PINS[cfgname]["offsets"]
