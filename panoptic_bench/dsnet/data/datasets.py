"""DS-Net data: one small dataset interface over SemanticKITTI-format and nuScenes-format roots.

Every dataset class lists its samples and loads one of them as a :class:`LidarSample` (points,
remission, semantic train ids, instance ids); :mod:`.training_set` wraps one for training
(augmentation, pasting, teacher probabilities).

Nothing is read at import; label remaps are numpy lookup tables built once by the format modules.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from panoptic_bench.dsnet.config import DataConfig, DatasetFormat
from panoptic_bench.errors import InputError

__all__ = [
    "ClassMap",
    "LidarDataset",
    "LidarSample",
    "NuScenesDataset",
    "SemanticKittiDataset",
    "open_dataset",
    "unread_sequences",
]


@dataclass(frozen=True)
class ClassMap:
    """Class facts stored with a checkpoint: names per train id, things, ignored ids."""

    dataset: str
    class_names: tuple[str, ...]
    thing_ids: tuple[int, ...]
    stuff_ids: tuple[int, ...]
    ignore_ids: tuple[int, ...]

    @property
    def num_classes(self) -> int:
        """Number of train ids, including the ignored ones."""
        return len(self.class_names)

    def to_dict(self) -> dict[str, Any]:
        return {
            "dataset": self.dataset,
            "class_names": list(self.class_names),
            "thing_ids": list(self.thing_ids),
            "stuff_ids": list(self.stuff_ids),
            "ignore_ids": list(self.ignore_ids),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ClassMap:
        return cls(
            dataset=str(d["dataset"]),
            class_names=tuple(d["class_names"]),
            thing_ids=tuple(int(i) for i in d["thing_ids"]),
            stuff_ids=tuple(int(i) for i in d["stuff_ids"]),
            ignore_ids=tuple(int(i) for i in d["ignore_ids"]),
        )

    def thing_lut(self) -> np.ndarray:
        """Boolean array of shape (num_classes,): True for thing train ids."""
        lut = np.zeros(self.num_classes, dtype=bool)
        lut[list(self.thing_ids)] = True
        return lut


@dataclass
class LidarSample:
    """One labelled scan.

    Attributes
    ----------
    xyz : ndarray of shape (n, 3), float32
    remission : ndarray of shape (n,), float32
    sem : ndarray of shape (n,), int64
        Train ids (ignored ids, e.g. 0, where unlabelled).
    inst : ndarray of shape (n,), int64
        Instance ids, unique within the scan over all classes; 0 for stuff / no instance.
    key : tuple of str
        Identifier used to write the prediction (``(sequence, frame)`` or ``(token,)``).
    soft : ndarray of shape (n, C), float16, optional
        A teacher's class probabilities (distillation, :mod:`.soft_labels`); None otherwise.
    """

    xyz: np.ndarray
    remission: np.ndarray
    sem: np.ndarray
    inst: np.ndarray
    key: tuple[str, ...]
    soft: np.ndarray | None = None


class LidarDataset(Protocol):
    """The interface shared by the dataset classes."""

    class_map: ClassMap

    def __len__(self) -> int: ...

    def keys(self) -> list[tuple[str, ...]]: ...

    def load(self, index: int) -> LidarSample: ...


def _unique_instances(sem: np.ndarray, inst: np.ndarray, things: np.ndarray) -> np.ndarray:
    """Renumber (class, instance) pairs of thing points to 1..K; stuff and id 0 become 0."""
    keep = things[sem] & (inst > 0)
    out = np.zeros(sem.shape, dtype=np.int64)
    if keep.any():
        pair = sem[keep].astype(np.int64) << 32 | inst[keep].astype(np.int64)
        _, out[keep] = np.unique(pair, return_inverse=True)
        out[keep] += 1
    return out


class SemanticKittiDataset:
    """Scans of a SemanticKITTI-format root (real SemanticKITTI or the synthetic world).

    Parameters
    ----------
    root : path
        Holds ``sequences/XX/velodyne/*.bin`` and, when labelled, ``labels/*.label``.
    split : str, optional
        ``train`` / ``valid`` / ``test`` (the official sequence lists).
    sequences : sequence of str, optional
        Explicit sequences; wins over ``split``.
    max_samples : int
        Keep only the first ``max_samples`` scans (0 = all).
    """

    def __init__(
        self,
        root: str | Path,
        split: str | None = None,
        sequences: Sequence[str] | None = None,
        max_samples: int = 0,
    ) -> None:
        from panoptic_bench.datasets import semantickitti as sk

        self.root = Path(root)
        self.refs = sk.list_scans(self.root, split=split, sequences=sequences or None)
        if max_samples:
            self.refs = self.refs[:max_samples]
        lab = sk.LABELS
        self.class_map = ClassMap(
            "semantickitti", lab.class_names, lab.thing_ids, lab.stuff_ids, lab.ignore_ids
        )
        self._things = self.class_map.thing_lut()

    def __len__(self) -> int:
        return len(self.refs)

    def keys(self) -> list[tuple[str, ...]]:
        return [(r.sequence, r.frame) for r in self.refs]

    def load(self, index: int) -> LidarSample:
        from panoptic_bench.datasets import semantickitti as sk

        ref = self.refs[index]
        points = sk.read_scan(ref.scan)
        if ref.label.is_file():
            labels = sk.read_labels(ref.label)
            if len(labels) != len(points):
                raise InputError(
                    f"{len(labels)} labels for {len(points)} points in {ref.scan}", ref.label
                )
            sem = sk.to_train(labels).astype(np.int64)
            inst = _unique_instances(sem, (labels >> 16).astype(np.int64), self._things)
        else:
            sem = np.zeros(len(points), dtype=np.int64)
            inst = np.zeros(len(points), dtype=np.int64)
        return LidarSample(
            xyz=np.ascontiguousarray(points[:, :3]),
            remission=np.ascontiguousarray(points[:, 3]),
            sem=sem,
            inst=inst,
            key=(ref.sequence, ref.frame),
        )


class NuScenesDataset:
    """Keyframe LIDAR_TOP samples of a nuScenes-format root, through the devkit reader.

    Parameters
    ----------
    root : path
        nuScenes data root (``samples/``, ``lidarseg/``, ``panoptic/``, ``VERSION/``).
    split : str
        Official split name (``train``, ``val``, ``mini_train``, ...).
        Semantic ids are the 16 challenge classes (+ 0 = ignored) of the devkit's
        ``PanopticClassMapper``; instance ids come from the panoptic labels.
    version : str
        Table version, e.g. ``v1.0-trainval`` or ``v1.0-mini``.
    max_samples : int
        Keep only the first ``max_samples`` samples (0 = all).
    """

    def __init__(
        self, root: str | Path, split: str, version: str = "v1.0-trainval", max_samples: int = 0
    ) -> None:
        from nuscenes.eval.panoptic.utils import PanopticClassMapper

        from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar

        self.root = Path(root)
        self.reader = NuScenesLidar(self.root, version)
        self.tokens = self.reader.sample_data_tokens(split)
        if max_samples:
            self.tokens = self.tokens[:max_samples]
        mapper = PanopticClassMapper(self.reader.nusc)
        coarse = mapper.get_coarse2idx()
        names = [""] * len(coarse)
        for name, idx in coarse.items():
            names[idx] = name
        fine2coarse = mapper.get_fine_idx_2_coarse_idx()
        self._lut = np.zeros(max(fine2coarse) + 1, dtype=np.int64)
        self._lut[list(fine2coarse)] = list(fine2coarse.values())
        self.class_map = ClassMap(
            "nuscenes",
            tuple(names),
            tuple(sorted(mapper.things.values())),
            tuple(sorted(mapper.stuff.values())),
            (0,),
        )
        self._things = self.class_map.thing_lut()

    def __len__(self) -> int:
        return len(self.tokens)

    def keys(self) -> list[tuple[str, ...]]:
        return [(t,) for t in self.tokens]

    def load(self, index: int) -> LidarSample:
        token = self.tokens[index]
        points = self.reader.load_points(token)
        panoptic = self.reader.load_panoptic(token).astype(np.int64)
        sem = self._lut[panoptic // 1000]
        inst = _unique_instances(sem, panoptic % 1000, self._things)
        return LidarSample(
            xyz=np.ascontiguousarray(points[:, :3], dtype=np.float32),
            remission=np.ascontiguousarray(points[:, 3], dtype=np.float32),
            sem=sem,
            inst=inst,
            key=(token,),
        )


def open_dataset(root: str | Path, data: DataConfig, which: str) -> LidarDataset:
    """Open the ``train`` or ``val`` part of ``root`` as described by the config's data section.

    Raises :class:`InputError` if the dataset's class count differs from ``data.num_classes``.
    """
    if which not in ("train", "val"):
        raise ValueError(f"which must be 'train' or 'val', got {which!r}")
    split = data.train_split if which == "train" else data.val_split
    max_samples = data.max_train_samples if which == "train" else data.max_val_samples
    if data.format is DatasetFormat.SEMANTICKITTI:
        seqs = data.train_sequences if which == "train" else data.val_sequences
        ds: LidarDataset = SemanticKittiDataset(root, split, seqs, max_samples)
    else:
        ds = NuScenesDataset(root, split, data.nuscenes_version, max_samples)
    if ds.class_map.num_classes != data.num_classes:
        raise InputError(
            f"config data.num_classes={data.num_classes} but the {data.format.value} class map "
            f"has {ds.class_map.num_classes} classes; fix the config",
            root,
        )
    if len(ds) == 0:
        raise InputError(f"no samples in the {which} split ({split})", root)
    return ds


def unread_sequences(root: str | Path, data: DataConfig) -> list[str]:
    """Labelled SemanticKITTI sequences under ``root`` that neither training nor validation reads.

    A sequence counts when ``root/sequences/XX/labels`` is a directory; the training and
    validation lists are ``data.train_sequences`` / ``data.val_sequences``, or the official
    split's sequences where a list is empty. Always empty for nuScenes and for a root without a
    ``sequences`` directory (``open_dataset`` reports that).

    Returns
    -------
    list of str
        Sequence names, sorted (e.g. ``["22", "23"]``).
    """
    from panoptic_bench.datasets import semantickitti as sk

    base = Path(root) / "sequences"
    if data.format is not DatasetFormat.SEMANTICKITTI or not base.is_dir():
        return []
    read = set()
    for split, seqs in (
        (data.train_split, data.train_sequences),
        (data.val_split, data.val_sequences),
    ):
        read |= {d.name for d in sk.sequence_dirs(root, split=split, sequences=seqs or None)}
    labelled = [d.name for d in sk.sequence_dirs(root) if (d / "labels").is_dir()]
    return [name for name in labelled if name not in read]
