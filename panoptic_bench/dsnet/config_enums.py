"""The named values of a DS-Net config (enum members are written by name in YAML).

Re-exported by :mod:`panoptic_bench.dsnet.config`, where the config sections use them.
"""

from __future__ import annotations

import enum

__all__ = [
    "Clusterer",
    "DatasetFormat",
    "HeldStatistics",
    "LRSchedule",
    "NetworkVariant",
    "ShiftKernel",
]


class DatasetFormat(enum.Enum):
    """On-disk layout of a data root."""

    SEMANTICKITTI = "semantickitti"
    NUSCENES = "nuscenes"


class Clusterer(enum.Enum):
    """Heuristic clustering of regressed centres (names of ``panoptic_bench.baselines``)."""

    MEANSHIFT = "meanshift"
    BFS = "bfs"
    DBSCAN = "dbscan"
    HDBSCAN = "hdbscan"


class ShiftKernel(enum.Enum):
    """Dynamic-shifting kernel: candidate weighting (paper) or direct bandwidth regression."""

    FLAT = "flat"
    GAUSSIAN = "gaussian"


class NetworkVariant(enum.Enum):
    """Which DS-Net network a config builds.

    ``nominal``: every conv acts with its nominal asymmetric kernel, offset head conv ->
    LeakyReLU -> BatchNorm, dynamic-shift MLP Linear -> ReLU -> Linear, cells of range / size,
    argmax over the non-ignored classes (the network of panoptic-bench's CPU checkpoints).
    ``official``: the network of the DS-Net code and its released checkpoints (spconv 1.x
    effective kernels, offset head conv -> BatchNorm -> LeakyReLU, dynamic-shift MLP with
    BatchNorm, cells of range / (size - 1), the official inference rules).
    """

    NOMINAL = "nominal"
    OFFICIAL = "official"


class LRSchedule(enum.Enum):
    """Learning rate over a stage's epochs: constant (paper) or flat then half cosine."""

    CONSTANT = "constant"
    COSINE = "cosine"


class HeldStatistics(enum.Enum):
    """Which BatchNorm statistics ``optim.freeze_bn`` holds through a stage.

    ``start``: those of the checkpoint the stage starts from (``--init`` or the previous stage);
    ``train``: measured once at the start of the stage, with the start weights, as the
    equal-weight mean over every training scan of the stage's first epoch.
    """

    START = "start"
    TRAIN = "train"
