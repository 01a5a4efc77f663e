"""DS-Net training: which sequences of a SemanticKITTI root a run reads (--train-sequences /
--val-sequences, resume and seed checks, the note naming labelled sequences left unread).

Runs on the tiny hand-made world of ``dsnet_tiny_world`` with ``test_dsnet_train``'s tiny network.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from panoptic_bench.cli import main as cli
from panoptic_bench.dsnet.checkpoint import load_checkpoint
from panoptic_bench.dsnet.config import DatasetFormat, DSNetConfig, save_config

sys.path.insert(0, str(Path(__file__).parent))
from dsnet_tiny_world import write_tiny_world  # noqa: E402
from test_dsnet_train import TINY  # noqa: E402

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def cfg() -> DSNetConfig:
    return DSNetConfig.from_dict(TINY)


def test_split_by_sequence_from_the_command_line(cfg: DSNetConfig, tmp_path: Path, capsys):
    """--train-sequences / --val-sequences override the config, are stored, never overlap."""
    world = write_tiny_world(tmp_path / "w", {"00": 2, "01": 3, "08": 1})
    cfg_path = tmp_path / "tiny.yaml"
    save_config(cfg, cfg_path)  # config: train 00, validate 08
    run = tmp_path / "run"
    args = ["train", "--config", str(cfg_path), "--data", str(world), "--out", str(run)]
    fold = ["--train-sequences", "1,8", "--val-sequences", "00", "--no-progress"]
    assert cli([*args, "--stage", "semantic", "--epochs", "1", *fold]) == 0
    stored = load_checkpoint(run / "checkpoints" / "semantic.pt").config.data
    assert (stored.train_sequences, stored.val_sequences) == (("01", "08"), ("00",))
    assert json.loads((run / "run.json").read_text())["notes"] == "4 train / 2 val samples"
    assert "val_sequences:\n  - '00'" in (run / "config.yaml").read_text()
    capsys.readouterr()
    # a sequence both trained on and validated on: exit 2, the sequence named, nothing trained
    leak = tmp_path / "leak"
    bad = ["train", "--config", str(cfg_path), "--data", str(world), "--out", str(leak)]
    assert cli([*bad, "--val-sequences", "00", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "00 both trained on and validated on" in err and "Traceback" not in err
    assert not (leak / "checkpoints").exists()
    # resuming the fold without its options would switch the data: refused, checkpoint kept
    before = (run / "checkpoints" / "semantic.pt").read_bytes()
    resume = [*args, "--stage", "semantic", "--epochs", "2", "--resume", "--no-progress"]
    assert cli(resume) == 2
    err = capsys.readouterr().err
    assert "cannot resume with a different config" in err and "data.train_sequences" in err
    assert (run / "checkpoints" / "semantic.pt").read_bytes() == before
    assert cli([*resume, *fold[:4]]) == 0
    assert load_checkpoint(run / "checkpoints" / "semantic.pt").epoch == 2
    # --seed overrides optim.seed, is stored, and a resume must repeat it
    seeded = tmp_path / "seeded"
    sargs = ["train", "--config", str(cfg_path), "--data", str(world), "--out", str(seeded)]
    assert (
        cli([*sargs, "--stage", "semantic", "--epochs", "1", "--seed", "7", "--no-progress"]) == 0
    )
    assert load_checkpoint(seeded / "checkpoints" / "semantic.pt").config.optim.seed == 7
    assert "seed: 7" in (seeded / "config.yaml").read_text()
    capsys.readouterr()
    sresume = [*sargs, "--stage", "semantic", "--epochs", "2", "--resume", "--no-progress"]
    assert cli(sresume) == 2
    assert "optim.seed" in capsys.readouterr().err
    assert cli([*sresume, "--seed", "7"]) == 0
    # nuScenes configs have no sequences
    nus = tmp_path / "nus.yaml"
    save_config(cfg.replace(data={"format": DatasetFormat.NUSCENES}), nus)
    argv = ["train", "--config", str(nus), "--data", str(world), "--out", str(tmp_path / "n")]
    assert cli([*argv, "--val-sequences", "08"]) == 2
    assert "need a SemanticKITTI config" in capsys.readouterr().err


def test_train_names_labelled_sequences_it_will_not_read(cfg: DSNetConfig, tmp_path: Path, capsys):
    """A labelled sequence in neither list is named on stderr; unlabelled ones are not."""
    from panoptic_bench.dsnet.data.datasets import unread_sequences

    world = write_tiny_world(tmp_path / "w", {"00": 2, "05": 1, "08": 1, "22": 1})
    (world / "sequences" / "30" / "velodyne").mkdir(parents=True)  # no labels: a test sequence
    assert unread_sequences(world, cfg.data) == ["05", "22"]  # config: train 00, validate 08
    official = cfg.replace(data={"train_sequences": [], "val_sequences": []}).data
    assert unread_sequences(world, official) == ["22"]  # 00 and 05 train, 08 valid
    nus = cfg.replace(data={"format": DatasetFormat.NUSCENES}).data
    assert unread_sequences(world, nus) == []
    cfg_path = tmp_path / "tiny.yaml"
    save_config(cfg, cfg_path)
    args = ["train", "--config", str(cfg_path), "--data", str(world), "--no-progress"]
    assert cli([*args, "--out", str(tmp_path / "a"), "--stage", "semantic", "--epochs", "0"]) == 0
    err = capsys.readouterr().err
    assert "2 labelled sequence(s)" in err and "not read: 05, 22" in err
    every = ["--train-sequences", "0,5,22"]
    assert (
        cli([*args, "--out", str(tmp_path / "b"), "--stage", "semantic", "--epochs", "0", *every])
        == 0
    )
    assert "not read" not in capsys.readouterr().err
