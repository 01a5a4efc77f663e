"""Augmented training samples: a :class:`~.datasets.LidarDataset` wrapped for PyTorch.

:class:`TrainingSet` applies augmentation on the training split with a random stream derived from
``(seed, epoch, index)``, so that a run is reproducible whatever the worker count or a resume; it
attaches teacher probabilities (:mod:`.soft_labels`) when distilling; :func:`collate` keeps a
batch as a list of samples.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from panoptic_bench.dsnet.config import AugmentConfig
from panoptic_bench.dsnet.data.augment import (
    augment_points,
    augment_remission,
    class_ids,
    class_remission_gain,
    tilt_points,
)
from panoptic_bench.dsnet.data.datasets import LidarDataset, LidarSample
from panoptic_bench.dsnet.data.density import thin
from panoptic_bench.dsnet.data.mix import mix_pair
from panoptic_bench.dsnet.data.soft_labels import read_soft_labels, soft_label_path

if TYPE_CHECKING:
    from panoptic_bench.dsnet.data.bank import InstanceBank

__all__ = ["TrainingSet", "collate"]


class TrainingSet:
    """A :class:`LidarDataset` as a PyTorch map-style dataset of augmented numpy samples.

    Parameters
    ----------
    dataset : LidarDataset
    augment : AugmentConfig or None
        None disables augmentation (validation).
    seed : int
        Base seed; the stream for sample ``i`` in epoch ``e`` is ``(seed, e, i)``; scene mixing
    (``augment.mix_prob`` > 0) draws from its own stream ``(seed, e, i, 1)``, so a config
    without mixing gives exactly the samples it gave before mixing existed; instance pasting
    (``augment.paste_prob`` > 0, from ``bank``) draws from ``(seed, e, i, 2)``.
    bank : InstanceBank, optional
        Instances to paste; required when ``augment.paste_prob`` > 0.
    soft_root : path, optional
        Root of teacher probabilities (:mod:`.soft_labels`): every sample then carries them in
        ``soft`` (not with scene mixing).
    """

    def __init__(
        self,
        dataset: LidarDataset,
        augment: AugmentConfig | None,
        seed: int = 0,
        bank: InstanceBank | None = None,
        soft_root: str | Path | None = None,
    ):
        if augment is not None and augment.paste_prob > 0 and bank is None:
            raise ValueError("augment.paste_prob > 0 needs an InstanceBank")
        if soft_root is not None and augment is not None and augment.mix_prob > 0:
            raise ValueError("teacher probabilities cannot be carried through scene mixing")
        self.soft_root = None if soft_root is None else Path(soft_root)
        self.dataset = dataset
        self.augment = augment
        self.seed = seed
        self.bank = bank
        self.epoch = 0
        names = augment.remission_class_gain_classes if augment is not None else ()
        key = "augment.remission_class_gain_classes"  # class_map is only read when names are given
        self._gain_only = class_ids(dataset.class_map.class_names, names, key) if names else None

    def set_epoch(self, epoch: int) -> None:
        """Select the augmentation stream of ``epoch`` (call before iterating)."""
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.dataset)

    def partners(self, index: int) -> list[int]:
        """Indices that scan ``index`` may be mixed with: other sequences first, else any other."""
        keys = self.dataset.keys()
        group = keys[index][0] if len(keys[index]) > 1 else None
        other = [j for j, k in enumerate(keys) if j != index and (group is None or k[0] != group)]
        return other or [j for j in range(len(keys)) if j != index]

    def _mixed(self, sample: LidarSample, index: int) -> LidarSample:
        aug = self.augment
        rng = np.random.default_rng([self.seed, self.epoch, index, 1])
        if len(self.dataset) < 2 or rng.random() >= aug.mix_prob:
            return sample
        options = self.partners(index)
        partner = self.dataset.load(options[int(rng.integers(len(options)))])
        return mix_pair(sample, partner, rng, aug.mix_sector_deg, aug.mix_paste_copies)

    def _pasted(self, sample: LidarSample, index: int) -> LidarSample:
        aug = self.augment
        rng = np.random.default_rng([self.seed, self.epoch, index, 2])
        if rng.random() >= aug.paste_prob:
            return sample
        count = int(rng.integers(aug.paste_count[0], aug.paste_count[1] + 1))
        return self.bank.paste(sample, rng, count)

    def __getitem__(self, index: int) -> LidarSample:
        sample = self.dataset.load(index)
        if self.soft_root is not None:
            path = soft_label_path(self.soft_root, sample.key)
            num_classes = self.dataset.class_map.num_classes
            sample.soft = read_soft_labels(path, len(sample.xyz), num_classes)
        if self.augment is not None:
            aug = self.augment
            if aug.mix_prob > 0:
                sample = self._mixed(sample, index)
            if aug.paste_prob > 0:
                sample = self._pasted(sample, index)
            rng = np.random.default_rng([self.seed, self.epoch, index])
            sample, _ = thin(sample, aug.max_points, rng)
            sample.xyz = augment_points(
                sample.xyz,
                rng,
                rotate=aug.rotate,
                flip=aug.flip,
                scale_range=aug.scale_range,
                translate_std=aug.translate_std,
            )
            sample.xyz = tilt_points(sample.xyz, rng, aug.pitch_std_deg, aug.roll_std_deg)
            if tuple(aug.remission_class_gain) != (1.0, 1.0):  # own stream: the others stay put
                class_rng = np.random.default_rng([self.seed, self.epoch, index, 3])
                sample.remission = class_remission_gain(
                    sample.remission,
                    sample.sem,
                    class_rng,
                    aug.remission_class_gain,
                    self._gain_only,
                )
            sample.remission = augment_remission(
                sample.remission,
                rng,
                aug.remission_gain,
                aug.remission_gamma,
                aug.remission_zero_prob,
            )
        return sample


def collate(samples: list[LidarSample]) -> list[LidarSample]:
    """Keep the list: the model's voxelizer builds the batch (it knows the grid)."""
    return list(samples)
