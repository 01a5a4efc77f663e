"""Weight averaging of checkpoints (``checkpoint average``, ``dsnet/soup.py``): hand-worked means,
properties of the average, the averaged network's outputs, and bad inputs."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from panoptic_bench.cli import main
from panoptic_bench.dsnet.checkpoint import build_backbone, load_checkpoint, save_checkpoint
from panoptic_bench.dsnet.soup import average_checkpoints, average_states
from panoptic_bench.errors import InputError

sys.path.insert(0, str(Path(__file__).parent))
from dsnet_tiny_checkpoints import write_tiny_checkpoint  # noqa: E402

_write = write_tiny_checkpoint


@pytest.fixture(scope="module")
def three(tmp_path_factory) -> list[Path]:
    d = tmp_path_factory.mktemp("soup")
    return [_write(d / f"s{i}.pt", seed=i) for i in range(3)]


def test_uniform_and_weighted_means_by_hand(three):
    cks = [load_checkpoint(p) for p in three]
    soup = average_checkpoints(three)
    weighted = average_checkpoints(three[:2], [3.0, 1.0])
    checked = 0
    for part in ("backbone", "shift"):
        for key, value in getattr(soup, part).items():
            parts = [getattr(ck, part)[key] for ck in cks]
            if not value.is_floating_point():
                assert torch.equal(value, parts[0])  # num_batches_tracked of the first
                continue
            torch.testing.assert_close(value, (parts[0] + parts[1] + parts[2]) / 3)
            torch.testing.assert_close(
                getattr(weighted, part)[key], 0.75 * parts[0] + 0.25 * parts[1]
            )
            checked += 1
    assert checked > 20
    key = next(k for k in soup.backbone if k.endswith("num_batches_tracked"))
    assert int(soup.backbone[key]) == 10
    assert soup.stage == "ds" and soup.epoch == 3 and soup.optimizer is None
    assert (
        "s0.pt" in soup.metrics[0]["averaged_from"] and "s2.pt" in soup.metrics[0]["averaged_from"]
    )


def test_average_states_properties():
    gen = torch.Generator().manual_seed(0)
    states = [{"w": torch.randn(5, 3, generator=gen), "n": torch.tensor(4)} for _ in range(4)]
    same = average_states([states[0]] * 3, [0.2, 0.3, 0.5])
    torch.testing.assert_close(same["w"], states[0]["w"], rtol=0, atol=1e-7)
    a = average_states(states, [0.25] * 4)
    b = average_states(states[::-1], [0.25] * 4)
    torch.testing.assert_close(a["w"], b["w"], rtol=0, atol=1e-7)  # order does not matter
    lo, hi = torch.stack([s["w"] for s in states]).aminmax(dim=0)
    assert bool(((a["w"] >= lo - 1e-7) & (a["w"] <= hi + 1e-7)).all())  # a convex combination


def test_soup_of_one_network_predicts_like_it(three, tmp_path):
    """Averaging copies of one checkpoint gives that network back: same logits and offsets."""
    from panoptic_bench.dsnet.checkpoint import build_grid
    from panoptic_bench.dsnet.data.datasets import LidarSample
    from panoptic_bench.dsnet.model.forward import backbone_forward

    soup = average_checkpoints([three[1], three[1]])
    save_checkpoint(soup, tmp_path / "soup.pt")
    ck, own = load_checkpoint(tmp_path / "soup.pt"), load_checkpoint(three[1])
    rng = np.random.default_rng(1)
    xyz = rng.uniform([-20, -20, -2], [20, 20, 1], size=(400, 3)).astype(np.float32)
    rem = rng.uniform(0, 1, 400).astype(np.float32)
    zeros = np.zeros(400, np.int64)
    sample = LidarSample(xyz=xyz, remission=rem, sem=zeros, inst=zeros, key=("00", "000000"))
    outs = []
    for c in (ck, own):
        bb = build_backbone(c.config, c.class_map.num_classes)
        bb.load_state_dict(c.backbone)
        bb.eval()
        with torch.no_grad():
            outs.append(backbone_forward(bb, [sample], build_grid(c.config), torch.device("cpu")))
    torch.testing.assert_close(outs[0].sem_logits, outs[1].sem_logits, rtol=0, atol=1e-5)
    torch.testing.assert_close(outs[0].offsets, outs[1].offsets, rtol=0, atol=1e-5)


def test_cli_writes_a_loadable_soup_and_refuses_to_overwrite(three, tmp_path, capsys):
    out = tmp_path / "soup.pt"
    assert main(["checkpoint", "average", *map(str, three), "--out", str(out)]) == 0
    assert "average of 3 checkpoints" in capsys.readouterr().out
    ck = load_checkpoint(out)
    ref = average_checkpoints(three)
    for key, value in ref.backbone.items():
        assert torch.equal(ck.backbone[key], value)
    assert main(["checkpoint", "show", str(out)]) == 0
    assert "averaged_from=" in capsys.readouterr().out
    assert main(["checkpoint", "average", *map(str, three), "--out", str(out)]) == 2
    assert "output file exists" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("one", "at least two checkpoints"),
        ("weights", "2 weights for 3 checkpoints"),
        ("negative", "weights must be positive"),
        ("stage", "stage 'offset'"),
        ("network", "config model.init_size differs"),
    ],
)
def test_bad_inputs_are_one_clear_error(three, tmp_path, capsys, case, message):
    paths = list(three)
    extra: list[str] = []
    if case == "one":
        paths = paths[:1]
    elif case == "weights":
        extra = ["--weights", "1", "2"]
    elif case == "negative":
        extra = ["--weights", "1", "-1", "1"]
    elif case == "stage":
        paths.append(_write(tmp_path / "offset.pt", seed=5, stage="offset"))
    elif case == "network":
        paths.append(_write(tmp_path / "wide.pt", seed=5, init_size=8))
    with pytest.raises(InputError, match=message.replace("(", r"\(")):
        average_checkpoints(paths, [float(w) for w in extra[1:]] or None)
    before = {p: p.read_bytes() for p in paths}
    out = tmp_path / "out.pt"
    assert main(["checkpoint", "average", *map(str, paths), "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    if case in ("stage", "network"):
        assert paths[-1].name in err  # names the file that does not fit
    assert not out.exists()
    assert all(p.read_bytes() == before[p] for p in paths)  # inputs untouched
