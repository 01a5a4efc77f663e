"""Random tiny DS-Net checkpoints (SemanticKITTI class map, 32 x 32 x 8 grid) for tests that
only need loadable networks, not trained ones (weight averaging, ensembles)."""

from __future__ import annotations

from pathlib import Path

import torch

from panoptic_bench.dsnet.checkpoint import Checkpoint, build_backbone, build_shift, save_checkpoint
from panoptic_bench.dsnet.config import DSNetConfig, load_config
from panoptic_bench.dsnet.data.datasets import ClassMap

REPO = Path(__file__).resolve().parents[1]


def tiny_config(init_size: int = 4, grid: tuple[int, int, int] = (32, 32, 8)) -> DSNetConfig:
    """The SemanticKITTI paper config shrunk to a tiny network on a ``grid`` of cells."""
    raw = load_config(REPO / "configs" / "dsnet_semantickitti.yaml").to_dict()
    raw["grid"]["size"] = list(grid)
    raw["model"].update(init_size=init_size, point_hidden=[8], point_feature_dim=8, offset_hidden=8)
    raw["dynamic_shift"]["max_seeds"] = 200
    return DSNetConfig.from_dict(raw)


def kitti_class_map() -> ClassMap:
    """The SemanticKITTI class map (20 train ids)."""
    from panoptic_bench.datasets.semantickitti import LABELS as lab

    return ClassMap("semantickitti", lab.class_names, lab.thing_ids, lab.stuff_ids, lab.ignore_ids)


def write_tiny_checkpoint(
    path: Path,
    seed: int,
    stage: str = "ds",
    init_size: int = 4,
    grid: tuple[int, int, int] = (32, 32, 8),
    class_map: ClassMap | None = None,
) -> Path:
    """A random tiny checkpoint at ``path``; BatchNorm running statistics are randomised too."""
    cfg = tiny_config(init_size, grid)
    cmap = class_map or kitti_class_map()
    torch.manual_seed(seed)
    backbone = build_backbone(cfg, cmap.num_classes)
    state = backbone.state_dict()
    for key, value in state.items():
        if "running_mean" in key:
            value.normal_()
        elif "running_var" in key:
            value.uniform_(0.5, 2.0)
        elif key.endswith("num_batches_tracked"):
            value.fill_(10 + seed)
    shift = build_shift(cfg, cfg.model.init_size).state_dict() if stage == "ds" else None
    save_checkpoint(Checkpoint(stage, 3, cfg, cmap, state, shift), path)
    return path
