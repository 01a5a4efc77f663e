"""The CUDA paths against the CPU: sparse convolutions, the shipped network, training, DDP on nccl.

These tests need a CUDA device; on a machine without one (CI) each is reported as skipped with that
reason (``pytest -ra``). They ran on an H200 in session 24 (``docs/DEVELOPING.md``, *CUDA*). The CPU
is the reference: the CUDA path shares every line of the model with it except the kernel-map and
gather/scatter implementation (no numba, no tiled GEMM on a GPU), so the two must agree to rounding.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from panoptic_bench.cli import main as cli
from panoptic_bench.dsnet import sparse
from panoptic_bench.dsnet.config import DSNetConfig, save_config

sys.path.insert(0, str(Path(__file__).parent))
from dsnet_tiny_world import write_tiny_world  # noqa: E402
from test_dsnet_train import TINY  # noqa: E402
from test_sparse_conv import random_tensor  # noqa: E402

pytestmark = pytest.mark.skipif(
    not torch.cuda.is_available(), reason="needs a CUDA device (the CPU paths are tested elsewhere)"
)
CUDA = torch.device("cuda")


def _to(x: sparse.SparseTensor, device: torch.device) -> sparse.SparseTensor:
    feats = x.features.detach().to(device).requires_grad_(True)
    return sparse.SparseTensor(feats, x.coords.to(device), x.spatial_shape)


def _by_site(feats: torch.Tensor, coords: torch.Tensor) -> dict[tuple, np.ndarray]:
    f = feats.detach().cpu().numpy()
    return {tuple(c): f[i] for i, c in enumerate(coords.cpu().tolist())}


def _same_sites(a: sparse.SparseTensor, b: sparse.SparseTensor) -> None:
    fa, fb = _by_site(a.features, a.coords), _by_site(b.features, b.coords)
    assert fa.keys() == fb.keys()
    for k, v in fa.items():
        np.testing.assert_allclose(fb[k], v, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("kernel", [(3, 3, 3), (1, 3, 3), (3, 1, 3), (5, 3, 1)])
def test_submanifold_cuda_equals_cpu_with_gradients(kernel):
    x = random_tensor(11, channels=5, density=0.4)
    w = torch.randn(int(np.prod(kernel)), 5, 4, dtype=torch.float64)
    outs, grads = [], []
    for dev in ("cpu", "cuda"):
        xd = _to(x, torch.device(dev))
        wd = w.to(dev).requires_grad_(True)
        out = sparse.submanifold_conv3d(xd, wd, kernel)
        r = torch.linspace(-1, 1, out.features.numel(), dtype=torch.float64, device=dev)
        g = torch.autograd.grad((out.features.reshape(-1) * r).sum(), [xd.features, wd])
        outs.append(out)
        grads.append([t.cpu() for t in g])
    assert torch.equal(outs[0].coords, outs[1].coords.cpu())  # submanifold: the input sites
    torch.testing.assert_close(outs[1].features.cpu(), outs[0].features, rtol=1e-10, atol=1e-10)
    for a, b in zip(grads[0], grads[1]):
        torch.testing.assert_close(b, a, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("stride", [(2, 2, 2), (2, 2, 1)])
def test_strided_and_inverse_cuda_equal_cpu(stride):
    x = random_tensor(12, channels=3)
    w = torch.randn(27, 3, 4, dtype=torch.float64)
    w_inv = torch.randn(27, 4, 3, dtype=torch.float64)
    res = {}
    for dev in ("cpu", "cuda"):
        xd = _to(x, torch.device(dev))
        down = sparse.sparse_conv3d(xd, w.to(dev), 3, stride, 1)
        up = sparse.inverse_conv3d(down, w_inv.to(dev), 3, stride, 1)
        res[dev] = (down, up)
    for a, b in zip(res["cpu"], res["cuda"]):
        _same_sites(a, b)
        assert a.spatial_shape == b.spatial_shape


def test_shipped_real_model_cuda_equals_cpu(kitti_root: Path):
    """The shipped real-data DS-Net on a real scan: CUDA predicts what the CPU predicts."""
    from panoptic_bench.dsnet.checkpoint import resolve_checkpoint
    from panoptic_bench.dsnet.inference.run import load_predictor, open_split

    ckpt = resolve_checkpoint("semantickitti-cpu")
    cpu, ck = load_predictor(ckpt, device="cpu")
    gpu, _ = load_predictor(ckpt, device="cuda")
    sample = open_split(ck.config, kitti_root, "00").load(0)
    a, b = cpu.predict(sample), gpu.predict(sample)
    assert np.mean(a.sem == b.sem) > 0.995  # after fusion
    assert np.percentile(np.abs(a.offsets - b.offsets), 99) < 1e-3
    assert np.mean(a.sem_raw == b.sem_raw) > 0.999
    # the same instances up to renumbering: every CUDA instance maps to one CPU instance
    agree = [np.mean(a.inst[b.inst == i] == np.bincount(a.inst[b.inst == i]).argmax())
             for i in np.unique(b.inst[b.inst > 0])]  # fmt: skip
    assert len(agree) > 0 and np.median(agree) > 0.99


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> Path:
    return write_tiny_world(tmp_path_factory.mktemp("tiny"), {"00": 4, "08": 2})


def test_train_on_cuda_then_infer_on_both(world: Path, tmp_path: Path):
    """``train --device cuda`` writes a checkpoint the CPU loads; ``infer --device cuda`` agrees."""
    cfg_path = tmp_path / "tiny.yaml"
    save_config(DSNetConfig.from_dict(TINY), cfg_path)
    run = tmp_path / "run"
    args = ["train", "--config", str(cfg_path), "--data", str(world), "--out", str(run)]
    assert cli([*args, "--stage", "all", "--device", "cuda", "--no-progress"]) == 0
    rows = (run / "metrics.csv").read_text().splitlines()
    assert len(rows) >= 4 and "nan" not in (run / "metrics.csv").read_text()
    ckpt = run / "checkpoints" / "ds.pt"
    preds = {}
    for dev in ("cpu", "cuda"):
        out = tmp_path / f"pred_{dev}"
        infer = ["infer", "--checkpoint", str(ckpt), "--data", str(world), "--split", "08"]
        assert cli([*infer, "--out", str(out), "--device", dev, "--no-progress"]) == 0
        assert json.loads((out / "timing.json").read_text())["device"] == dev
        preds[dev] = np.fromfile(out / "sequences/08/predictions/000000.label", dtype=np.uint32)
    assert np.mean((preds["cpu"] & 0xFFFF) == (preds["cuda"] & 0xFFFF)) > 0.99


def test_ddp_nccl_one_process(world: Path, tmp_path: Path):
    """``torchrun`` on CUDA takes the nccl process group (one rank: the one GPU lent here)."""
    cfg_path = tmp_path / "tiny.yaml"
    save_config(DSNetConfig.from_dict(TINY), cfg_path)
    run = tmp_path / "ddp"
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=1"]
    cmd += ["-m", "panoptic_bench", "train", "--config", str(cfg_path), "--data", str(world)]
    cmd += ["--out", str(run), "--stage", "semantic", "--device", "cuda", "--no-progress"]
    res = subprocess.run(cmd, env=dict(os.environ), capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    assert (run / "checkpoints" / "semantic.pt").is_file()
