"""Ensembles of checkpoints (``infer --ensemble``, ``dsnet/inference/ensemble.py``): hand-worked
averages, an ensemble of copies predicts like its member, mixed widths / grids, the CLI and bad
members."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from panoptic_bench.cli import main
from panoptic_bench.dsnet.data.datasets import ClassMap, LidarSample
from panoptic_bench.dsnet.inference.ensemble import ensemble_forward
from panoptic_bench.dsnet.inference.run import load_predictor
from panoptic_bench.dsnet.inference.tta import tta_forward
from panoptic_bench.dsnet.model.network import BackboneOutput
from panoptic_bench.dsnet.model.voxelize import CylinderGrid
from panoptic_bench.errors import InputError

sys.path.insert(0, str(Path(__file__).parent))
from dsnet_tiny_checkpoints import write_tiny_checkpoint  # noqa: E402
from dsnet_tiny_world import write_tiny_world  # noqa: E402

pytestmark = pytest.mark.usefixtures("one_torch_thread")
CPU = torch.device("cpu")
GRID = CylinderGrid(size=(40, 36, 8))


class _Fixed(nn.Module):
    """Logits ``[0, a * x, b]`` and offsets ``c * xyz`` per point; features = xyz[:, :2] * c."""

    def __init__(self, a: float, b: float, c: float) -> None:
        super().__init__()
        self.a, self.b, self.c = a, b, c

    def forward(self, batch):
        xyz = batch.xyz
        logits = torch.stack(
            [torch.zeros(len(xyz)), self.a * xyz[:, 0], torch.full((len(xyz),), self.b)], 1
        )
        return BackboneOutput(logits, self.c * xyz, self.c * xyz[:, :2], logits[:1])


def _sample(n: int = 400, seed: int = 0) -> LidarSample:
    rng = np.random.default_rng(seed)
    xyz = rng.uniform([-20, -20, -2], [20, 20, 1], size=(n, 3)).astype(np.float32)
    zeros = np.zeros(n, np.int64)
    rem = rng.uniform(0, 1, n).astype(np.float32)
    return LidarSample(xyz=xyz, remission=rem, sem=zeros, inst=zeros, key=("08", "000000"))


def _softmax(z: np.ndarray) -> np.ndarray:
    e = np.exp(z - z.max(1, keepdims=True))
    return e / e.sum(1, keepdims=True)


def test_one_member_is_the_plain_pass():
    model, s = _Fixed(0.3, 1.0, -1.0), _sample()
    a = ensemble_forward([(model, GRID)], s, CPU)
    b = tta_forward(model, s, GRID, CPU, 1)
    assert torch.equal(a.sem_logits, b.sem_logits) and torch.equal(a.offsets, b.offsets)
    with pytest.raises(ValueError):
        ensemble_forward([], s, CPU)


def test_probabilities_and_offsets_are_averaged_by_hand():
    s = _sample(seed=1)
    members = [
        (_Fixed(0.3, 1.0, -1.0), GRID),
        (_Fixed(-0.2, 0.0, 0.5), GRID),
        (_Fixed(0, 2, 0), GRID),
    ]
    out = ensemble_forward(members, s, CPU)
    x = s.xyz[:, 0].astype(np.float64)
    expected = np.zeros((len(x), 3))
    for a, b, _ in ((0.3, 1.0, -1.0), (-0.2, 0.0, 0.5), (0, 2, 0)):
        expected += _softmax(np.stack([np.zeros_like(x), a * x, np.full_like(x, b)], 1)) / 3
    assert np.allclose(np.exp(out.sem_logits.numpy()), expected, atol=1e-6)
    # offsets: mean of -1, 0.5 and 0 times xyz; features are the first member's
    assert np.allclose(out.offsets.numpy(), (-1.0 + 0.5 + 0.0) / 3 * s.xyz, atol=1e-6)
    assert np.allclose(out.point_features.numpy(), -s.xyz[:, :2])


def test_views_are_taken_per_member():
    """With K views each member is test-time augmented, then the members are averaged."""
    s = _sample(seed=2)
    m1, m2 = _Fixed(0.3, 1.0, -1.0), _Fixed(-0.2, 0.0, 0.5)
    out = ensemble_forward([(m1, GRID), (m2, GRID)], s, CPU, n_views=4)
    parts = [tta_forward(m, s, GRID, CPU, 4) for m in (m1, m2)]
    probs = sum(torch.exp(p.sem_logits) for p in parts) / 2
    assert torch.allclose(torch.exp(out.sem_logits), probs, atol=1e-6)
    assert torch.allclose(out.offsets, (parts[0].offsets + parts[1].offsets) / 2, atol=1e-6)


@pytest.fixture(scope="module")
def ckpts(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("ensemble")
    other = ClassMap("other", ("unlabeled", "a", "b"), (1,), (2,), (0,))
    return {
        "a": write_tiny_checkpoint(d / "a.pt", seed=0),
        "b": write_tiny_checkpoint(d / "b.pt", seed=1),
        "wide": write_tiny_checkpoint(d / "wide.pt", seed=2, init_size=8, grid=(24, 40, 6)),
        "semantic": write_tiny_checkpoint(d / "semantic.pt", seed=3, stage="semantic"),
        "classes": write_tiny_checkpoint(d / "classes.pt", seed=4, class_map=other),
    }


def test_an_ensemble_of_copies_predicts_like_its_member(ckpts):
    plain, _ = load_predictor(ckpts["a"])
    twice, _ = load_predictor(ckpts["a"], ensemble=(ckpts["a"],))
    s = _sample(n=600, seed=3)
    p, q = plain.predict(s), twice.predict(s)
    assert np.array_equal(p.sem, q.sem) and np.array_equal(p.inst, q.inst)
    assert np.allclose(p.offsets, q.offsets, atol=1e-6)


def test_members_may_differ_in_width_and_grid(ckpts):
    """A width-8 member on its own 24 x 40 x 6 grid joins a width-4 one on 32 x 32 x 8: the
    ensemble's class probabilities are the mean of each network's own."""
    from panoptic_bench.dsnet.model.forward import backbone_forward

    pred, _ = load_predictor(ckpts["a"], ensemble=(ckpts["wide"],))
    s = _sample(n=500, seed=4)
    ((model, grid),) = pred.members
    assert grid.size == (24, 40, 6)
    with torch.no_grad():
        out = ensemble_forward([(pred.backbone, pred.grid), (model, grid)], s, CPU)
        own = [
            backbone_forward(m, [s], g, CPU) for m, g in ((pred.backbone, pred.grid), (model, grid))
        ]
    mean = sum(torch.softmax(o.sem_logits, 1) for o in own) / 2
    assert torch.allclose(torch.exp(out.sem_logits), mean, atol=1e-5)
    assert not torch.allclose(torch.softmax(own[0].sem_logits, 1), mean, atol=1e-3)
    got = pred.predict(s).sem_raw
    # the predictor takes the ensemble's argmax (over every class: this is the official variant)
    assert pred.official
    logits = out.sem_logits
    assert np.array_equal(got, logits.argmax(1).numpy().astype(np.uint8))


def test_cli_writes_an_ensemble_tree(ckpts, tmp_path, capsys):
    world = write_tiny_world(tmp_path / "world", {"08": 2})
    base = ["infer", "--checkpoint", str(ckpts["a"]), "--data", str(world), "--split", "08"]
    base += ["--no-progress"]
    assert main([*base, "--out", str(tmp_path / "one")]) == 0
    assert main([*base, "--out", str(tmp_path / "two"), "--ensemble", str(ckpts["b"])]) == 0
    assert "DS-Net (ensemble of 2): 2 scans" in capsys.readouterr().out
    meta = json.loads((tmp_path / "two" / "run.json").read_text())
    assert meta["method"] == "DS-Net (ensemble of 2)"
    assert f"checkpoint {ckpts['a']}" in meta["notes"]
    assert f"averaged with {ckpts['b']} (ensemble)" in meta["notes"]
    for name in ("000000", "000001"):
        assert (tmp_path / "two" / "sequences" / "08" / "predictions" / f"{name}.label").is_file()
    a = np.load(tmp_path / "one" / "sequences" / "08" / "centers" / "000000.npz")
    b = np.load(tmp_path / "two" / "sequences" / "08" / "centers" / "000000.npz")
    assert a["offset"].shape == b["offset"].shape and not np.array_equal(a["offset"], b["offset"])


@pytest.mark.parametrize(
    ("member", "message"),
    [
        ("classes", "predicts other classes (other, 3 train ids)"),
        ("semantic", "stage-1 (semantic) checkpoint"),
        ("missing", "missing.pt"),
    ],
)
def test_bad_members_are_one_clear_error(ckpts, tmp_path, capsys, member, message):
    path = ckpts.get(member, tmp_path / "missing.pt")
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")):
        load_predictor(ckpts["a"], ensemble=(path,))
    world = write_tiny_world(tmp_path / "world", {"08": 1})
    out = tmp_path / "out"
    args = ["infer", "--checkpoint", str(ckpts["a"]), "--data", str(world), "--split", "08"]
    assert main([*args, "--out", str(out), "--ensemble", str(path), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert message in err and str(path) in err and "Traceback" not in err
    assert not out.exists()
