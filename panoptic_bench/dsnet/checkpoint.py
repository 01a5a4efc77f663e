"""DS-Net checkpoints: build the networks from a config, save and load training state.

A checkpoint is one ``torch.save`` file holding only builtins and tensors (loadable with
``weights_only=True``)::

    {"format": "panoptic-bench-dsnet/1", "stage": "semantic" | "offset" | "ds",
     "epoch": completed epochs of that stage, "config": DSNetConfig.to_dict(),
     "class_map": ClassMap.to_dict(), "class_weights": [float] | None,
     "backbone": state_dict, "shift": state_dict | None,
     "optimizer": state_dict | None, "rng": {"torch": ByteTensor} | None,
     "average": state_dict | None, "metrics": [per-epoch dict, ...]}

``average`` is the running weight mean of an unfinished stage with ``optim.swa_epochs``
(:mod:`panoptic_bench.dsnet.training.averaging`). :func:`export_checkpoint` drops the optimizer,
RNG state and average for a small release file.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import nn

from panoptic_bench.dsnet.config import DSNetConfig
from panoptic_bench.dsnet.data.datasets import ClassMap
from panoptic_bench.errors import InputError
from panoptic_bench.io import atomic_open

FORMAT = "panoptic-bench-dsnet/1"
STAGES = ("semantic", "offset", "ds")

__all__ = [
    "Checkpoint",
    "FORMAT",
    "STAGES",
    "build_backbone",
    "build_grid",
    "build_shift",
    "load_weights",
    "export_checkpoint",
    "is_official",
    "resolve_checkpoint",
    "shipped_checkpoints",
    "SHIPPED",
    "load_checkpoint",
    "save_checkpoint",
]


#: Short name -> file in ``panoptic_bench/checkpoints/`` of every checkpoint a release may ship
#: (``.json``: an ensemble file, :mod:`panoptic_bench.dsnet.inference.ensemble_file`).
SHIPPED: dict[str, str] = {
    "synthetic": "dsnet_synthetic.pt",
    "synthetic-backbone": "backbone_synthetic.pt",
    "synthetic-realistic": "dsnet_synthetic_realistic.pt",
    "synthetic-materials-road": "dsnet_synthetic_materials_road.pt",
    "synthetic-low-crowns": "dsnet_synthetic_low_crowns.pt",
    "synthetic-fences": "dsnet_synthetic_fences.pt",
    "synthetic-low-fences": "dsnet_synthetic_low_fences.pt",
    "synthetic-mixed": "dsnet_synthetic_mixed.pt",
    "synthetic-road-gain": "dsnet_synthetic_road_gain.pt",
    "synthetic-full-density": "dsnet_synthetic_full_density.pt",
    "synthetic-held-bn": "dsnet_synthetic_held_bn.pt",
    "synthetic-sign-boards": "dsnet_synthetic_sign_boards.pt",
    "synthetic-buildings": "dsnet_synthetic_buildings.pt",
    "synthetic-buildings-start2": "dsnet_synthetic_buildings_start2.pt",
    "synthetic-buildings-start3": "dsnet_synthetic_buildings_start3.pt",
    "synthetic-ensemble": "ensemble_synthetic.json",
    "semantickitti-cpu": "dsnet_semantickitti_cpu.pt",
    "semantickitti-cpu-backbone": "backbone_semantickitti_cpu.pt",
    "semantickitti-cpu-heldout": "dsnet_semantickitti_cpu_heldout0506.pt",
    "nuscenes-synthetic": "dsnet_nuscenes_synthetic.pt",
}


def _shipped_dir() -> Path:
    from importlib import resources

    return Path(str(resources.files("panoptic_bench"))) / "checkpoints"


def shipped_checkpoints() -> dict[str, Path]:
    """Short name -> path of the shipped checkpoints present in this install."""
    return {n: _shipped_dir() / f for n, f in SHIPPED.items() if (_shipped_dir() / f).is_file()}


def resolve_checkpoint(name_or_path: str | Path) -> Path:
    """The checkpoint file of a short name (:data:`SHIPPED`) or a path.

    Raises
    ------
    InputError
        A known name whose file is not shipped, or an unknown name that is not a file; the
        message lists the shipped names.
    """
    text = str(name_or_path)
    present = ", ".join(shipped_checkpoints()) or "none"
    if text in SHIPPED:
        path = _shipped_dir() / SHIPPED[text]
        if not path.is_file():
            raise InputError(
                f"checkpoint {text!r} ({SHIPPED[text]}) is not shipped with this install; "
                f"shipped: {present}"
            )
        return path
    path = Path(text)
    if not path.exists() and path.suffix == "" and "/" not in text:
        raise InputError(
            f"unknown checkpoint name {text!r}: shipped names are {present} "
            f"(known names: {', '.join(SHIPPED)}); or give a .pt path"
        )
    return path


def build_grid(cfg: DSNetConfig) -> Any:
    """The cylindrical grid of the config (``voxelize.CylinderGrid``)."""
    from panoptic_bench.dsnet.model.voxelize import CylinderGrid

    g = cfg.grid
    return CylinderGrid(
        size=g.size,
        rho_range=g.rho_range,
        phi_range_deg=g.phi_range_deg,
        z_range=g.z_range,
        official_cells=is_official(cfg),
    )


def is_official(cfg: DSNetConfig) -> bool:
    """True when the config builds the official DS-Net network (``model.variant: official``)."""
    from panoptic_bench.dsnet.config import NetworkVariant

    return cfg.model.variant is NetworkVariant.OFFICIAL


def build_backbone(cfg: DSNetConfig, num_classes: int) -> nn.Module:
    """The Cylinder3D backbone with semantic and offset heads, from explicit config values."""
    from panoptic_bench.dsnet.model.network import PanopticBackbone

    m = cfg.model
    return PanopticBackbone(
        num_classes=num_classes,
        init_size=m.init_size,
        grid=build_grid(cfg),
        point_hidden=m.point_hidden,
        point_feature_dim=m.point_feature_dim,
        voxel_feature_dim=m.voxel_feature_dim,
        offset_hidden=m.offset_hidden,
        spconv1_rulebooks=is_official(cfg),
        offset_norm_first=is_official(cfg),
        fast_inference=is_official(cfg),
        remission_input=m.remission_input,
        level_ground=m.level_ground,
        shape_features=m.shape_features,
        shape_points=cfg.augment.max_points,
        norm=m.norm,
    )


def build_shift(cfg: DSNetConfig, feature_dim: int) -> nn.Module:
    """The dynamic shifting module of the config's ``dynamic_shift`` section."""
    from panoptic_bench.dsnet.model.dynamic_shift import DynamicShift

    d = cfg.dynamic_shift
    if is_official(cfg):  # per iteration Linear(F, F) -> BatchNorm1d -> ReLU -> Linear(F, l)
        return DynamicShift(
            feature_dim,
            bandwidths=d.bandwidths,
            iterations=d.iterations,
            kernel=d.kernel,
            hidden=feature_dim,
            batch_norm=True,
        )
    return DynamicShift(
        feature_dim,
        bandwidths=d.bandwidths,
        iterations=d.iterations,
        kernel=d.kernel,
    )


@dataclass
class Checkpoint:
    """A loaded checkpoint (see the module docstring for the stored fields)."""

    stage: str
    epoch: int
    config: DSNetConfig
    class_map: ClassMap
    backbone: dict[str, torch.Tensor]
    shift: dict[str, torch.Tensor] | None = None
    optimizer: dict | None = None
    rng: dict | None = None
    average: dict[str, torch.Tensor] | None = None
    class_weights: list[float] | None = None
    metrics: list[dict] = field(default_factory=list)
    path: Path | None = None

    @property
    def has_shift(self) -> bool:
        """True for a DS-Net (stage ``ds``) checkpoint."""
        return self.shift is not None

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "stage": self.stage,
            "epoch": self.epoch,
            "config": self.config.to_dict(),
            "class_map": self.class_map.to_dict(),
            "class_weights": self.class_weights,
            "backbone": self.backbone,
            "shift": self.shift,
            "optimizer": self.optimizer,
            "rng": self.rng,
            "average": self.average,
            "metrics": self.metrics,
        }


def save_checkpoint(ckpt: Checkpoint, path: str | Path) -> None:
    """Atomically write ``ckpt`` to ``path``."""
    with atomic_open(path, "wb") as fh:
        torch.save(ckpt.to_dict(), fh)


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> Checkpoint:
    """Read a checkpoint written by :func:`save_checkpoint`.

    Raises
    ------
    InputError
        Missing file, not a panoptic-bench DS-Net checkpoint, or an invalid stored config.
    """
    path = Path(path)
    if path.suffix.lower() == ".json" and path.is_file():
        raise InputError(
            "an ensemble file, not one checkpoint: `infer` and `demo` take it as --checkpoint", path
        )
    if not path.is_file():
        raise InputError("checkpoint not found; train one with `panoptic-bench train`", path)
    try:
        raw = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unpickling failure is a user-file problem
        raise InputError(f"cannot read checkpoint ({type(exc).__name__}: {exc})", path) from None
    if not isinstance(raw, dict) or raw.get("format") != FORMAT:
        raise InputError(f"not a panoptic-bench DS-Net checkpoint (format {FORMAT})", path)
    _check_raw(raw, path)
    try:
        class_map = ClassMap.from_dict(raw["class_map"])
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"invalid class_map ({type(exc).__name__}: {exc})", path) from None
    return Checkpoint(
        stage=raw["stage"],
        epoch=raw["epoch"],
        config=DSNetConfig.from_dict(raw["config"], source=path),
        class_map=class_map,
        backbone=raw["backbone"],
        shift=raw.get("shift"),
        optimizer=raw.get("optimizer"),
        rng=raw.get("rng"),
        average=raw.get("average"),
        class_weights=raw.get("class_weights"),
        metrics=list(raw.get("metrics") or []),
        path=path,
    )


def _check_raw(raw: dict, path: Path) -> None:
    """Raise :class:`InputError` for a checkpoint dict with missing or ill-typed entries."""
    for key in ("stage", "epoch", "config", "class_map", "backbone"):
        if key not in raw:
            raise InputError(f"checkpoint has no {key!r} entry", path)
    if raw["stage"] not in STAGES:
        raise InputError(f"stage must be one of {', '.join(STAGES)}, got {raw['stage']!r}", path)
    epoch = raw["epoch"]
    if isinstance(epoch, bool) or not isinstance(epoch, int) or epoch < 0:
        raise InputError(f"epoch must be an integer >= 0, got {epoch!r}", path)
    if not isinstance(raw["config"], dict) or not isinstance(raw["class_map"], dict):
        raise InputError("config and class_map must be mappings", path)
    for key in ("backbone", "shift"):
        state = raw.get(key)
        if key == "shift" and state is None:
            continue
        if not isinstance(state, dict) or not state:
            raise InputError(f"{key} weights are empty or not a state dict", path)
        if not all(isinstance(v, torch.Tensor) for v in state.values()):
            raise InputError(f"{key} weights hold values that are not tensors", path)
    if raw["stage"] == "ds" and raw.get("shift") is None:
        raise InputError("stage ds checkpoint without dynamic shifting weights ('shift')", path)


def load_weights(module: nn.Module, state: dict, path: Path | None, what: str) -> None:
    """``module.load_state_dict(state)``; a key or shape mismatch is an :class:`InputError`.

    A checkpoint whose weights do not fit the network its own config and class map describe
    (wrong shapes, missing or extra tensors, a 5-class map for a 20-class head) is a bad file.
    """
    try:
        module.load_state_dict(state)
    except RuntimeError as exc:
        first = next((ln.strip() for ln in str(exc).splitlines()[1:] if ln.strip()), str(exc))
        raise InputError(
            f"{what} weights do not fit the network of its config: {first}", path
        ) from None


def widen_point_inputs(state: dict, module: nn.Module) -> dict:
    """``state`` with the point MLP's first layers padded to ``module``'s wider input.

    A backbone with ``shape_features`` takes more point inputs than one without; started from
    the narrower one's weights, the new inputs get a neutral BatchNorm (mean 0, variance 1,
    weight 1, bias 0) and zero columns in the first Linear, so the widened network computes
    exactly what the start did until training moves them. Other tensors are left alone (a real
    mismatch still fails in ``load_state_dict``).
    """
    own = module.state_dict()
    out = dict(state)
    fills = {"running_mean": 0.0, "running_var": 1.0, "weight": 1.0, "bias": 0.0}
    for key, value in state.items():
        target = own.get(key)
        if (
            target is None
            or target.shape == value.shape
            or not key.startswith("encoder.point_mlp.")
        ):
            continue
        if key.startswith("encoder.point_mlp.0.") and value.ndim == 1 and len(value) < len(target):
            pad = torch.full((len(target) - len(value),), fills[key.rsplit(".", 1)[1]])
            out[key] = torch.cat([value, pad.to(value.dtype)])
        elif key == "encoder.point_mlp.1.weight" and value.shape[0] == target.shape[0]:
            pad = value.new_zeros((value.shape[0], target.shape[1] - value.shape[1]))
            out[key] = torch.cat([value, pad], dim=1)
    return out


def export_checkpoint(src: str | Path, dst: str | Path, half: bool = False) -> Path:
    """Copy a checkpoint without optimizer, RNG state and weight average (a release file).

    Parameters
    ----------
    half : bool
        Store floating-point weights as float16 (they are cast back to float32 on load by
        ``load_state_dict``); halves the size.
    """
    ckpt = load_checkpoint(src)
    ckpt.optimizer = None
    ckpt.rng = None
    ckpt.average = None
    if half:
        ckpt.backbone = _half(ckpt.backbone)
        ckpt.shift = None if ckpt.shift is None else _half(ckpt.shift)
    save_checkpoint(ckpt, dst)
    return Path(dst)


def _half(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    return {k: v.half() if v.is_floating_point() else v for k, v in state.items()}
