"""DS-Net config: YAML round trip, unknown keys and bad values rejected with the file named."""

from __future__ import annotations

from pathlib import Path

import pytest

from panoptic_bench.dsnet.config import (
    Clusterer,
    DatasetFormat,
    DSNetConfig,
    LRSchedule,
    OptimConfig,
    ShiftKernel,
    load_config,
    save_config,
)
from panoptic_bench.errors import InputError

CONFIGS = sorted((Path(__file__).resolve().parents[1] / "configs").glob("dsnet_*.yaml"))


def test_shipped_configs_exist():
    names = {p.name for p in CONFIGS}
    assert {"dsnet_semantickitti.yaml", "dsnet_nuscenes.yaml", "dsnet_synthetic_cpu.yaml"} <= names


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.stem)
def test_round_trip(path: Path, tmp_path: Path):
    cfg = load_config(path)
    assert DSNetConfig.from_dict(cfg.to_dict()) == cfg
    save_config(cfg, tmp_path / "c.yaml")
    assert load_config(tmp_path / "c.yaml") == cfg


def test_paper_values():
    kitti = load_config(CONFIGS[0].parent / "dsnet_semantickitti.yaml")
    assert kitti.grid.size == (480, 360, 32)
    assert kitti.model.init_size == 32
    assert kitti.optim.lr == 0.002
    assert kitti.inference.clusterer is Clusterer.MEANSHIFT and kitti.inference.bandwidth == 1.2
    assert kitti.dynamic_shift.bandwidths == (0.2, 1.7, 3.2)
    assert kitti.dynamic_shift.iterations == 4 and kitti.dynamic_shift.kernel is ShiftKernel.FLAT
    assert kitti.inference.ds_bandwidth == 0.65 and kitti.inference.min_points == 50
    nus = load_config(CONFIGS[0].parent / "dsnet_nuscenes.yaml")
    assert nus.data.format is DatasetFormat.NUSCENES and nus.data.num_classes == 17
    assert nus.inference.ds_clusterer is Clusterer.BFS and nus.inference.ds_bandwidth == 1.2
    assert nus.inference.min_points == 5


def test_defaults_round_trip_and_types():
    cfg = DSNetConfig()
    d = cfg.to_dict()
    assert d["inference"]["clusterer"] == "meanshift"
    assert d["grid"]["size"] == [480, 360, 32]
    again = DSNetConfig.from_dict(d)
    assert again == cfg and isinstance(again.grid.size, tuple)
    assert cfg.grid.max_bound[1] == pytest.approx(3.141592653589793)


@pytest.mark.parametrize(
    "mapping, needle",
    [
        ({"optim": {"learning_rate": 0.1}}, "optim.learning_rate"),
        ({"optimiser": {}}, "optimiser"),
        ({"optim": {"lr": "0.002"}}, "optim.lr"),
        ({"grid": {"size": [1, 2]}}, "grid.size"),
        ({"inference": {"clusterer": "kmeans"}}, "inference.clusterer"),
        ({"augment": {"flip": 1}}, "augment.flip"),
        ({"optim": {"lr": -1.0}}, "optim.lr"),
        ({"data": {"train_sequences": [0]}}, "data.train_sequences"),
        ({"optim": {"lr_schedule": "step"}}, "optim.lr_schedule"),
        ({"optim": {"lr_min": 0.1}}, "optim.lr_min"),
        ({"optim": {"lr_flat_epochs": -1}}, "optim.lr_flat_epochs"),
        ({"model": {"remission_input": "no"}}, "model.remission_input"),
    ],
)
def test_rejects_bad_input_naming_key_and_file(tmp_path: Path, mapping, needle):
    import yaml

    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(mapping))
    with pytest.raises(InputError) as err:
        load_config(path)
    assert needle in str(err.value) and "bad.yaml" in str(err.value)


def test_replace_and_frozen():
    cfg = DSNetConfig().replace(optim={"lr": 0.5})
    assert cfg.optim.lr == 0.5
    with pytest.raises(AttributeError):
        cfg.optim.lr = 1.0  # type: ignore[misc]


def test_lr_schedule_hand_worked():
    const = OptimConfig(lr=0.002)
    assert [const.lr_at(e, 10) for e in (0, 5, 9)] == [0.002] * 3
    cos = OptimConfig(lr=0.002, lr_schedule=LRSchedule.COSINE, lr_min=0.0002, lr_flat_epochs=2)
    # flat for epochs 0 and 1, then a half cosine over the remaining 4 epochs of 6
    assert cos.lr_at(0, 6) == cos.lr_at(1, 6) == cos.lr_at(2, 6) == 0.002
    assert cos.lr_at(4, 6) == pytest.approx(0.0011)  # half-way: (lr + lr_min) / 2
    assert cos.lr_at(3, 6) > cos.lr_at(4, 6) > cos.lr_at(5, 6) > 0.0002
    assert cos.lr_at(6, 6) == pytest.approx(0.0002)


def test_remission_input_reaches_the_network():
    from panoptic_bench.dsnet.checkpoint import build_backbone

    cfg = DSNetConfig()
    assert cfg.model.remission_input is True
    assert build_backbone(cfg, 20).remission_input is True
    off = cfg.replace(model={"remission_input": False})
    assert DSNetConfig.from_dict(off.to_dict()) == off
    assert build_backbone(off, 20).remission_input is False


@pytest.mark.parametrize(
    "name", ["dsnet_synthetic_buildings_start_cpu.yaml", "dsnet_synthetic_mixed_start_cpu.yaml"]
)
def test_new_start_recipe_equals_the_old_starts(name):
    # realism rows 71, 72: each header says its start is the old start's recipe, only the data differ
    root = Path(__file__).resolve().parents[1] / "configs"
    assert load_config(root / name) == load_config(root / "dsnet_synthetic_realistic_cpu.yaml")
