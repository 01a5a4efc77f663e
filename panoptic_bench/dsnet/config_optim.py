"""The ``optim`` section of the DS-Net configuration (split from :mod:`.config`).

Re-exported by :mod:`panoptic_bench.dsnet.config`; import it from there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from panoptic_bench.dsnet.config_enums import HeldStatistics, LRSchedule


@dataclass(frozen=True)
class OptimConfig:
    """Adam optimisation, learning-rate schedule, epochs per training stage, batch size, seed.

    ``lr_schedule`` is ``constant`` (the paper) or ``cosine``: the learning rate stays at ``lr``
    for the first ``lr_flat_epochs`` epochs of a stage, then follows a half cosine down to
    ``lr_min`` at the stage's last epoch. The rate of an epoch depends only on the epoch and the
    stage's total, so resuming reproduces it.

    Weight averaging (off by default, :mod:`panoptic_bench.dsnet.training.averaging`):
    ``swa_epochs`` = k > 0 makes the semantic and offset stages end on the mean of the backbone's
    weights over every step of their last k epochs, with BatchNorm statistics measured again on
    ``swa_bn_scans`` training scans of the last epoch's order (0: all of them).

    ``freeze_bn`` (off by default): in the semantic and offset stages every BatchNorm of the
    backbone normalises with the running statistics it starts the stage with (from ``--init`` or
    the previous stage), in training as at inference, and never updates them
    (:mod:`panoptic_bench.dsnet.training.batchnorm`); it cannot be combined with ``swa_epochs``,
    which re-measures them. ``freeze_bn_from`` picks the held statistics: ``start`` (those of the
    start checkpoint) or ``train`` (measured once at the start of the stage, with the start
    weights, over every training scan of its first epoch; a fresh network can then hold too).
    ``bn_noise`` = sigma > 0 (needs ``freeze_bn``) restyles every held BatchNorm's input in
    training by a random per-channel scale 1 + sigma * a and shift sigma * b in held units.
    """

    lr: float = 0.002
    lr_schedule: LRSchedule = LRSchedule.CONSTANT
    lr_min: float = 0.0
    lr_flat_epochs: int = 0
    weight_decay: float = 0.0
    batch_size: int = 2
    epochs_semantic: int = 40
    epochs_offset: int = 40
    epochs_ds: int = 10
    seed: int = 0
    num_workers: int = 0
    val_every: int = 1
    swa_epochs: int = 0
    swa_bn_scans: int = 0
    freeze_bn: bool = False
    freeze_bn_from: HeldStatistics = HeldStatistics.START
    bn_noise: float = 0.0

    def validate(self) -> list[str]:
        problems = []
        if not self.lr > 0:
            problems.append(f"optim.lr must be > 0, got {self.lr}")
        if not 0 <= self.lr_min <= self.lr:
            problems.append(f"optim.lr_min must be in [0, lr], got {self.lr_min}")
        if self.lr_flat_epochs < 0:
            problems.append(f"optim.lr_flat_epochs must be >= 0, got {self.lr_flat_epochs}")
        if self.batch_size < 1:
            problems.append(f"optim.batch_size must be >= 1, got {self.batch_size}")
        names = ("epochs_semantic", "epochs_offset", "epochs_ds", "num_workers")
        for name in names + ("swa_epochs", "swa_bn_scans"):
            if getattr(self, name) < 0:
                problems.append(f"optim.{name} must be >= 0")
        if self.val_every < 1:
            problems.append(f"optim.val_every must be >= 1, got {self.val_every}")
        if self.freeze_bn and self.swa_epochs > 0:
            problems.append(
                "optim.freeze_bn holds the BatchNorm statistics and optim.swa_epochs re-measures "
                "them: set only one"
            )
        if self.freeze_bn_from is not HeldStatistics.START and not self.freeze_bn:
            problems.append("optim.freeze_bn_from applies only with optim.freeze_bn: true")
        if not 0 <= self.bn_noise <= 1:
            problems.append(f"optim.bn_noise must be in [0, 1], got {self.bn_noise}")
        elif self.bn_noise > 0 and not self.freeze_bn:
            problems.append("optim.bn_noise restyles held BatchNorms: set optim.freeze_bn: true")
        return problems

    def lr_at(self, epoch: int, total: int) -> float:
        """Learning rate of 0-based ``epoch`` in a stage of ``total`` epochs."""
        if self.lr_schedule is LRSchedule.CONSTANT or epoch < self.lr_flat_epochs:
            return self.lr
        span = max(total - self.lr_flat_epochs, 1)
        frac = min((epoch - self.lr_flat_epochs) / span, 1.0)
        return self.lr_min + 0.5 * (self.lr - self.lr_min) * (1.0 + math.cos(math.pi * frac))
