"""Typed DS-Net configuration: frozen dataclasses, validated, round-tripping through YAML.

A configuration file is a YAML mapping with one section per dataclass below (``grid``,
``model``, ``optim``, ``augment``, ``loss``, ``dynamic_shift``, ``inference``, ``data``).
Every section and every key is optional (defaults are the paper's SemanticKITTI values), but
an unknown key is an error that names the key and the file: a typo never silently falls back
to a default. YAML is only the file format; values are numbers, booleans, lists of numbers and
enum names.

Example
-------
>>> cfg = DSNetConfig.from_dict({"optim": {"lr": 0.001}})
>>> cfg.optim.lr
0.001
>>> DSNetConfig.from_dict(cfg.to_dict()) == cfg
True
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from panoptic_bench.dsnet.config_augment import AugmentConfig  # also re-exported
from panoptic_bench.dsnet.config_enums import (  # noqa: F401 - re-exported
    Clusterer,
    DatasetFormat,
    HeldStatistics,
    LRSchedule,
    NetworkVariant,
    ShiftKernel,
)
from panoptic_bench.dsnet.config_fields import section_from_dict, section_to_dict
from panoptic_bench.dsnet.config_optim import OptimConfig  # also re-exported
from panoptic_bench.errors import InputError

#: Values of ``inference.bn_stats`` (:mod:`panoptic_bench.dsnet.inference.scan_norm`).
BN_STATS = ("running", "scan")
#: Values of ``inference.orphans`` (:func:`panoptic_bench.baselines.panoptic.orphans_to_stuff`).
ORPHANS = ("keep", "stuff")
#: Values of ``model.norm`` (:mod:`panoptic_bench.dsnet.model.renorm`).
NORMS = ("batch", "renorm")


@dataclass(frozen=True)
class GridConfig:
    """Cylindrical voxel grid: cells along (rho, phi, z) and the clipped ranges (m, degrees, m)."""

    size: tuple[int, int, int] = (480, 360, 32)
    rho_range: tuple[float, float] = (3.0, 50.0)
    phi_range_deg: tuple[float, float] = (-180.0, 180.0)
    z_range: tuple[float, float] = (-3.0, 1.5)

    @property
    def min_bound(self) -> tuple[float, float, float]:
        """Lower corner (rho m, phi rad, z m)."""
        return (self.rho_range[0], math.radians(self.phi_range_deg[0]), self.z_range[0])

    @property
    def max_bound(self) -> tuple[float, float, float]:
        """Upper corner (rho m, phi rad, z m)."""
        return (self.rho_range[1], math.radians(self.phi_range_deg[1]), self.z_range[1])

    def validate(self) -> list[str]:
        problems = [f"grid.size must be positive, got {self.size}"] if min(self.size) < 1 else []
        for name in ("rho_range", "phi_range_deg", "z_range"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                problems.append(f"grid.{name} must be increasing, got {[lo, hi]}")
        return problems


@dataclass(frozen=True)
class ModelConfig:
    """Backbone width and head sizes (the class count comes from the data).

    ``point_hidden`` / ``point_feature_dim``: per-point MLP before max-pooling into voxels;
    ``voxel_feature_dim``: compressed voxel features entering the U-Net; ``offset_hidden``:
    hidden width of the offset MLP (DS-Net: ``init_size``). The per-point features handed to
    dynamic shifting have ``init_size`` channels. ``variant``: :class:`NetworkVariant`
    (``nominal`` when a config or checkpoint does not name one). ``remission_input``: False
    feeds the network a zero remission channel (same 9-D input, same weights' shapes), for a
    model that must not lean on a sensor's intensity calibration (the synthetic-to-real
    shortcut of issue 13); inference follows the checkpoint's config. ``level_ground``: every
    scan is rotated so that its fitted ground plane is level before it is voxelized, in
    training and inference (:mod:`panoptic_bench.dsnet.data.level`; no weight changes, so a
    model trained without it can initialise one with it). ``shape_features``: the point MLP also
    takes the 4 local shape features of :mod:`panoptic_bench.dsnet.data.shape` (linearity,
    planarity, scattering, verticality of each point's 0.5 m cube), measured on at most
    ``augment.max_points`` points so that training and inference see the same density; a model
    trained without them initialises one with them (the new inputs start with zero weights).
    ``norm``: ``batch`` (default) or ``renorm``, Batch Renormalization of every backbone BatchNorm
    in training (:mod:`panoptic_bench.dsnet.model.renorm`; same weights and inference, so either
    initialises the other).
    """

    variant: NetworkVariant = NetworkVariant.NOMINAL
    remission_input: bool = True
    level_ground: bool = False
    shape_features: bool = False
    init_size: int = 32
    point_hidden: tuple[int, ...] = (64, 128, 256)
    point_feature_dim: int = 256
    voxel_feature_dim: int = 16
    offset_hidden: int = 32
    norm: str = "batch"

    def validate(self) -> list[str]:
        names = ("init_size", "point_feature_dim", "voxel_feature_dim", "offset_hidden")
        problems = [
            f"model.{n} must be >= 1, got {getattr(self, n)}" for n in names if getattr(self, n) < 1
        ]
        if not self.point_hidden or min(self.point_hidden) < 1:
            problems.append(f"model.point_hidden must be positive widths, got {self.point_hidden}")
        if self.shape_features and self.variant is NetworkVariant.OFFICIAL:
            problems.append("model.shape_features is not part of the official network")
        if self.norm not in NORMS:
            problems.append(f"model.norm must be one of {', '.join(NORMS)}, got {self.norm!r}")
        return problems


@dataclass(frozen=True)
class LossConfig:
    """Loss weights: semantic (CE + Lovász), offset L1, dynamic shifting per iteration.

    Distillation (off by default): with ``distill`` = a > 0 the CE target of every labelled
    training point is ``(1 - a) * its label + a * the teacher's class probabilities``, read from
    ``distill_probs`` (the root of an ``infer --save-probs`` run on the training root,
    :mod:`panoptic_bench.dsnet.data.soft_labels`); Lovász-softmax keeps the labels.
    """

    ce: float = 1.0
    lovasz: float = 1.0
    offset: float = 1.0
    class_weight_power: float = 0.5
    ds_iteration_weights: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0)
    distill: float = 0.0
    distill_probs: str = ""

    def validate(self) -> list[str]:
        names = ("ce", "lovasz", "offset")
        problems = [f"loss.{n} must be >= 0" for n in names if getattr(self, n) < 0]
        if not 0.0 <= self.distill <= 1.0:
            problems.append(f"loss.distill must be in [0, 1], got {self.distill}")
        elif self.distill > 0 and not self.distill_probs:
            problems.append(
                "loss.distill > 0 needs loss.distill_probs (an infer --save-probs root)"
            )
        return problems


@dataclass(frozen=True)
class DynamicShiftConfig:
    """Dynamic shifting module (paper §3.2, appendix §4)."""

    bandwidths: tuple[float, ...] = (0.2, 1.7, 3.2)
    iterations: int = 4
    kernel: ShiftKernel = ShiftKernel.FLAT
    max_seeds: int = 10000
    freeze_backbone: bool = True

    def validate(self) -> list[str]:
        problems = []
        if not self.bandwidths or min(self.bandwidths) <= 0:
            problems.append(f"dynamic_shift.bandwidths must be positive, got {self.bandwidths}")
        if self.iterations < 1:
            problems.append("dynamic_shift.iterations must be >= 1")
        if self.max_seeds < 1:
            problems.append("dynamic_shift.max_seeds must be >= 1")
        return problems


@dataclass(frozen=True)
class InferenceConfig:
    """Clustering of regressed centres at inference and the panoptic assembly.

    ``match_training_density`` predicts each scan at the training density (``augment.max_points``
    points, :mod:`panoptic_bench.dsnet.data.density`) and spreads the prediction to every point.
    ``tta_views`` > 1 averages the backbone over that many rotated / mirrored views of each scan
    (:mod:`panoptic_bench.dsnet.inference.tta`); 1 is the plain forward pass.
    ``bn_stats``: ``"running"`` (BatchNorms use their training averages) or ``"scan"`` (each
    BatchNorm of the backbone normalises with the statistics of the scan being predicted, as in
    training with one scan per batch; :mod:`panoptic_bench.dsnet.inference.scan_norm`).
    ``orphans``: fate of points predicted as a thing class that end with no instance (their
    cluster is under ``min_points`` or is noise): ``"keep"`` their class, or take their most
    probable ``"stuff"`` class (:func:`panoptic_bench.baselines.panoptic.orphans_to_stuff`).
    """

    clusterer: Clusterer = Clusterer.MEANSHIFT
    bandwidth: float = 1.2
    ds_clusterer: Clusterer = Clusterer.MEANSHIFT
    ds_bandwidth: float = 0.65
    min_points: int = 50
    fusion: bool = True
    match_training_density: bool = False
    tta_views: int = 1
    bn_stats: str = "running"
    orphans: str = "keep"

    def validate(self) -> list[str]:
        problems = []
        for name in ("bandwidth", "ds_bandwidth"):
            if not getattr(self, name) > 0:
                problems.append(f"inference.{name} must be > 0")
        if self.min_points < 1:
            problems.append("inference.min_points must be >= 1")
        if not 1 <= self.tta_views <= 16:
            problems.append("inference.tta_views must be in 1..16")
        if self.bn_stats not in BN_STATS:
            problems.append(f"inference.bn_stats must be one of {', '.join(BN_STATS)}")
        if self.orphans not in ORPHANS:
            problems.append(f"inference.orphans must be one of {', '.join(ORPHANS)}")
        return problems


@dataclass(frozen=True)
class DataConfig:
    """Which dataset layout, which splits; SemanticKITTI sequences or nuScenes split names.

    ``num_classes`` (train ids including the ignored id 0) must match the dataset's class map;
    it is checked when the data is opened. ``max_*_samples`` = 0 means every sample.
    """

    format: DatasetFormat = DatasetFormat.SEMANTICKITTI
    num_classes: int = 20
    train_split: str = "train"
    val_split: str = "valid"
    train_sequences: tuple[str, ...] = ()
    val_sequences: tuple[str, ...] = ()
    nuscenes_version: str = "v1.0-trainval"
    max_train_samples: int = 0
    max_val_samples: int = 0

    def validate(self) -> list[str]:
        return [] if self.num_classes >= 2 else ["data.num_classes must be >= 2"]


SECTIONS: dict[str, type] = {
    "grid": GridConfig,
    "model": ModelConfig,
    "optim": OptimConfig,
    "augment": AugmentConfig,
    "loss": LossConfig,
    "dynamic_shift": DynamicShiftConfig,
    "inference": InferenceConfig,
    "data": DataConfig,
}


@dataclass(frozen=True)
class DSNetConfig:
    """The whole DS-Net configuration: one frozen dataclass per section."""

    grid: GridConfig = field(default_factory=GridConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    dynamic_shift: DynamicShiftConfig = field(default_factory=DynamicShiftConfig)
    inference: InferenceConfig = field(default_factory=InferenceConfig)
    data: DataConfig = field(default_factory=DataConfig)

    @classmethod
    def from_dict(cls, mapping: dict[str, Any], source: str | Path | None = None) -> DSNetConfig:
        """Build a config from a nested mapping.

        Parameters
        ----------
        mapping : dict
            ``{section: {key: value}}``; missing sections/keys take defaults.
        source : str or Path, optional
            File the mapping came from, named in error messages.

        Raises
        ------
        InputError
            Unknown section or key, or a value of the wrong type or out of range.
        """
        if not isinstance(mapping, dict):
            raise InputError("a DS-Net config must be a mapping of sections", source)
        unknown = sorted(set(mapping) - set(SECTIONS), key=str)
        if unknown:
            raise InputError(
                f"unknown config section {unknown[0]!r}; known sections: {', '.join(SECTIONS)}",
                source,
            )
        sections = {
            name: section_from_dict(
                kind, name, {} if mapping.get(name) is None else mapping[name], source
            )
            for name, kind in SECTIONS.items()
        }
        cfg = cls(**sections)
        problems = [p for s in sections.values() for p in s.validate()]
        if len(cfg.loss.ds_iteration_weights) < cfg.dynamic_shift.iterations:
            problems.append(
                "loss.ds_iteration_weights needs one weight per dynamic_shift iteration"
            )
        if cfg.loss.distill > 0 and cfg.augment.mix_prob > 0:
            problems.append("loss.distill and augment.mix_prob cannot be combined")
        if problems:
            raise InputError("invalid config: " + "; ".join(problems), source)
        return cfg

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Plain nested dict of builtins (lists, numbers, strings), ready for YAML/JSON."""
        return {name: section_to_dict(getattr(self, name)) for name in SECTIONS}

    def replace(self, **sections: Any) -> DSNetConfig:
        """Return a copy with some sections' fields replaced: ``replace(optim={"lr": 1e-3})``."""
        new = {}
        for name, changes in sections.items():
            if name not in SECTIONS:
                raise KeyError(f"unknown config section {name!r}")
            new[name] = dataclasses.replace(getattr(self, name), **changes)
        return dataclasses.replace(self, **new)


def load_config(path: str | Path) -> DSNetConfig:
    """Read a YAML config file; errors name the file and the offending key."""
    import yaml

    path = Path(path)
    if not path.is_file():
        raise InputError("config file not found; see configs/dsnet_*.yaml", path)
    try:
        mapping = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    except yaml.YAMLError as exc:
        raise InputError(f"not valid YAML ({exc})", path) from None
    return DSNetConfig.from_dict(mapping, source=path)


def save_config(cfg: DSNetConfig, path: str | Path) -> None:
    """Write ``cfg`` as YAML (atomically)."""
    import yaml

    from panoptic_bench.io import write_text

    write_text(path, yaml.safe_dump(cfg.to_dict(), sort_keys=False))
