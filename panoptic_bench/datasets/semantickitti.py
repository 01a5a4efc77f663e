"""SemanticKITTI format: label facts, scan/label readers and writers, dataset listing.

The label facts (raw labels, ``learning_map``, colour map, splits, things/stuff) come from the
packaged ``panoptic_bench/data/semantic-kitti.yaml``, loaded once by :func:`get_labels`. Lookup
tables are numpy arrays built once; no per-point Python.

File formats
------------
- ``sequences/XX/velodyne/NNNNNN.bin``: float32 ``(x, y, z, remission)`` per point.
- ``sequences/XX/labels/NNNNNN.label`` (ground truth) and ``sequences/XX/predictions/NNNNNN.label``
  (predictions): uint32 per point, low 16 bits = raw semantic id, high 16 bits = instance id.

Example
-------
>>> from panoptic_bench.datasets.semantickitti import LABELS, to_train
>>> LABELS.class_names[1]
'car'
>>> int(to_train(np.array([252]))[0])  # moving-car -> car
1
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
import yaml

from panoptic_bench.errors import InputError
from panoptic_bench.io import write_array

__all__ = [
    "LABELS",
    "SemanticKittiLabels",
    "ScanRef",
    "get_labels",
    "list_scans",
    "list_sequence",
    "make_label",
    "prediction_path",
    "read_labels",
    "read_scan",
    "sequence_dirs",
    "split_label",
    "to_raw",
    "to_train",
    "write_labels",
    "write_scan",
]

LUT_SIZE = 1 << 16


@dataclass(frozen=True, eq=False)
class SemanticKittiLabels:
    """The SemanticKITTI label facts and the lookup tables built from them.

    Attributes
    ----------
    raw_names : dict[int, str]
        Raw label id -> name (``10 -> "car"``, ``252 -> "moving-car"``).
    class_names : tuple of str
        The 20 train-id class names, index = train id, ``0 = "unlabeled"``.
    thing_ids, stuff_ids : tuple of int
        Train ids of thing classes (1..8) and stuff classes (9..19).
    ignore_ids : tuple of int
        Train ids ignored in evaluation (``(0,)``).
    learning_map, learning_map_inv : dict[int, int]
        Raw -> train id and train id -> raw id.
    color_map : dict[int, tuple[int, int, int]]
        Raw id -> colour, **BGR** as in the official file.
    splits : dict[str, list[int]]
        ``train`` / ``valid`` / ``test`` sequence numbers.
    train_lut : ndarray of shape (65536,), uint8
        Raw semantic id -> train id; unknown raw ids map to 0.
    valid_raw : ndarray of shape (65536,), bool
        True for the raw ids defined in ``labels``.
    inv_lut : ndarray of shape (20,), uint16
        Train id -> raw id.
    """

    raw_names: dict[int, str]
    class_names: tuple[str, ...]
    thing_ids: tuple[int, ...]
    stuff_ids: tuple[int, ...]
    ignore_ids: tuple[int, ...]
    learning_map: dict[int, int]
    learning_map_inv: dict[int, int]
    color_map: dict[int, tuple[int, int, int]]
    splits: dict[str, list[int]]
    train_lut: np.ndarray
    valid_raw: np.ndarray
    inv_lut: np.ndarray

    @property
    def num_classes(self) -> int:
        """Number of train ids including ``unlabeled`` (20)."""
        return len(self.class_names)

    @classmethod
    def from_dict(cls, data: dict) -> SemanticKittiLabels:
        """Build from the parsed YAML mapping (keys as in the official ``semantic-kitti.yaml``)."""
        raw_names = {int(k): str(v) for k, v in data["labels"].items()}
        lmap = {int(k): int(v) for k, v in data["learning_map"].items()}
        linv = {int(k): int(v) for k, v in data["learning_map_inv"].items()}
        num = len(linv)
        if sorted(linv) != list(range(num)):
            raise ValueError("learning_map_inv must define train ids 0..C-1")
        class_names = tuple(raw_names[linv[i]] for i in range(num))
        index = {name: i for i, name in enumerate(class_names)}
        thing_ids = tuple(sorted(index[n] for n in data["things"]))
        stuff_ids = tuple(sorted(index[n] for n in data["stuff"]))
        ignore_ids = tuple(sorted(int(k) for k, v in data["learning_ignore"].items() if v))

        train_lut = np.zeros(LUT_SIZE, dtype=np.uint8)
        train_lut[list(lmap)] = list(lmap.values())
        valid_raw = np.zeros(LUT_SIZE, dtype=bool)
        valid_raw[list(raw_names)] = True
        inv_lut = np.array([linv[i] for i in range(num)], dtype=np.uint16)
        for arr in (train_lut, valid_raw, inv_lut):
            arr.flags.writeable = False
        return cls(
            raw_names=raw_names,
            class_names=class_names,
            thing_ids=thing_ids,
            stuff_ids=stuff_ids,
            ignore_ids=ignore_ids,
            learning_map=lmap,
            learning_map_inv=linv,
            color_map={int(k): tuple(int(c) for c in v) for k, v in data["color_map"].items()},
            splits={str(k): [int(s) for s in v] for k, v in data["split"].items()},
            train_lut=train_lut,
            valid_raw=valid_raw,
            inv_lut=inv_lut,
        )


@functools.cache
def get_labels() -> SemanticKittiLabels:
    """Load the packaged label facts once (``panoptic_bench/data/semantic-kitti.yaml``)."""
    text = (resources.files("panoptic_bench") / "data" / "semantic-kitti.yaml").read_text("utf-8")
    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml: ~10x faster at start-up
    return SemanticKittiLabels.from_dict(yaml.load(text, Loader=loader))


LABELS: SemanticKittiLabels = get_labels()


# --------------------------------------------------------------------------- label arithmetic


def to_train(raw_sem: np.ndarray) -> np.ndarray:
    """Map raw semantic ids to train ids through ``learning_map`` (unknown ids -> 0).

    Parameters
    ----------
    raw_sem : array of shape (n,), integer
        Raw semantic ids; full uint32 labels are accepted (only the low 16 bits are used).

    Returns
    -------
    ndarray of shape (n,), uint8
    """
    raw_sem = np.asarray(raw_sem)
    return LABELS.train_lut[raw_sem & 0xFFFF]


def to_raw(train: np.ndarray) -> np.ndarray:
    """Map train ids (0..19) to raw ids through ``learning_map_inv``.

    Parameters
    ----------
    train : array of shape (n,), integer in [0, 20)

    Returns
    -------
    ndarray of shape (n,), uint16
    """
    train = np.asarray(train)
    if train.size and (train.min() < 0 or train.max() >= len(LABELS.inv_lut)):
        raise ValueError(f"train ids must lie in [0, {len(LABELS.inv_lut)})")
    return LABELS.inv_lut[train]


def split_label(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split uint32 labels into ``(semantic raw id, instance id)``, both uint16 of shape (n,)."""
    labels = np.asarray(labels, dtype=np.uint32)
    return (labels & 0xFFFF).astype(np.uint16), (labels >> 16).astype(np.uint16)


def make_label(sem_raw: np.ndarray, inst: np.ndarray) -> np.ndarray:
    """Combine raw semantic ids and instance ids (each < 65536) into uint32 labels of shape (n,)."""
    sem_raw = np.asarray(sem_raw)
    inst = np.asarray(inst)
    for name, arr in (("sem_raw", sem_raw), ("inst", inst)):
        if arr.size and (arr.min() < 0 or arr.max() > 0xFFFF):
            raise ValueError(f"{name} must lie in [0, 65535]")
    return (inst.astype(np.uint32) << 16) | sem_raw.astype(np.uint32)


# --------------------------------------------------------------------------- file readers / writers


def _read(path: Path, dtype: np.dtype, record: int, what: str) -> np.ndarray:
    path = Path(path)
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise InputError(f"{what} file not found", path) from None
    except OSError as exc:
        raise InputError(f"cannot read {what} file ({exc.strerror})", path) from None
    if not path.is_file():
        raise InputError(f"{what} path is not a regular file", path)
    if size % record:
        raise InputError(
            f"{what} file size {size} is not a multiple of {record} bytes; "
            "the file is truncated or not in SemanticKITTI format",
            path,
        )
    try:
        return np.fromfile(path, dtype=dtype)
    except OSError as exc:
        raise InputError(f"cannot read {what} file ({exc})", path) from None


def read_scan(path: str | Path) -> np.ndarray:
    """Read a ``.bin`` scan.

    Returns
    -------
    ndarray of shape (n_points, 4), float32
        ``x, y, z, remission``.

    Raises
    ------
    InputError
        Missing, unreadable or truncated file, or NaN / infinite values (a corrupt scan).
    """
    points = _read(Path(path), np.float32, 16, "scan").reshape(-1, 4)
    bad = ~np.isfinite(points).all(axis=1)
    if bad.any():
        raise InputError(
            f"{int(bad.sum())} point(s) with NaN or infinite values (first: point "
            f"{int(np.flatnonzero(bad)[0])}); the scan is corrupt",
            path,
        )
    return points


def read_labels(path: str | Path) -> np.ndarray:
    """Read a ``.label`` file: ndarray of shape (n_points,), uint32."""
    return _read(Path(path), np.uint32, 4, "label")


def write_scan(path: str | Path, points: np.ndarray) -> None:
    """Atomically write ``points`` (shape (n, 4), cast to float32) as a ``.bin`` scan."""
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 4:
        raise ValueError(f"points must have shape (n, 4), got {points.shape}")
    write_array(path, points.astype(np.float32, copy=False))


def write_labels(path: str | Path, labels: np.ndarray) -> None:
    """Atomically write uint32 labels of shape (n,) as a ``.label`` file."""
    labels = np.asarray(labels)
    if labels.ndim != 1:
        raise ValueError(f"labels must have shape (n,), got {labels.shape}")
    if labels.size and (labels.min() < 0 or labels.max() > 0xFFFFFFFF):
        raise ValueError("labels must fit in uint32")
    write_array(path, labels.astype(np.uint32, copy=False))


# --------------------------------------------------------------------------- dataset listing


@dataclass(frozen=True)
class ScanRef:
    """One scan of a SemanticKITTI tree: ``sequence`` ("08"), ``frame`` ("000123") and paths.

    ``label`` is the ground-truth path ``sequences/XX/labels/NNNNNN.label`` (it may not exist,
    e.g. on the test split).
    """

    sequence: str
    frame: str
    scan: Path
    label: Path


def _seq_name(seq: int | str) -> str:
    try:
        return f"{int(seq):02d}"
    except ValueError:
        raise InputError(f"sequence {seq!r} is not a number (use e.g. 08)") from None


def _listdir(path: Path) -> list[str]:
    try:
        return sorted(os.listdir(path))
    except FileNotFoundError:
        raise InputError("directory not found", path) from None
    except OSError as exc:
        raise InputError(f"cannot read directory ({exc.strerror or exc})", path) from None


def sequence_dirs(
    root: str | Path, *, split: str | None = None, sequences: list | tuple | None = None
) -> list[Path]:
    """The sequence directories ``root/sequences/XX`` selected by ``split`` or ``sequences``.

    With neither, every sequence directory present is returned. ``sequences`` wins over ``split``.
    Raises :class:`InputError` for an unknown split or an unreadable ``sequences`` directory.
    """
    base = Path(root) / "sequences"
    if sequences is not None:
        names = [_seq_name(s) for s in sequences]
    elif split is not None:
        if split not in LABELS.splits:
            raise InputError(f"unknown split {split!r}; choose one of {sorted(LABELS.splits)}")
        names = [_seq_name(s) for s in LABELS.splits[split]]
    else:
        names = [n for n in _listdir(base) if (base / n).is_dir()]
        if not names:
            raise InputError("no sequence directories found", base)
    return [base / n for n in names]


def list_sequence(seq_dir: str | Path) -> list[ScanRef]:
    """List the scans of one sequence directory (``velodyne/*.bin``), sorted by frame.

    Raises :class:`InputError` if the directory is missing, unreadable or holds no scans.
    """
    seq_dir = Path(seq_dir)
    velo = seq_dir / "velodyne"
    if not seq_dir.is_dir():
        raise InputError("sequence directory not found", seq_dir)
    frames = [n[:-4] for n in _listdir(velo) if n.endswith(".bin")]
    if not frames:
        raise InputError("empty sequence: no .bin scans in velodyne/", velo)
    return [
        ScanRef(seq_dir.name, f, velo / f"{f}.bin", seq_dir / "labels" / f"{f}.label")
        for f in frames
    ]


def list_scans(
    root: str | Path, *, split: str | None = None, sequences: list | tuple | None = None
) -> list[ScanRef]:
    """List the scans of a SemanticKITTI tree.

    Parameters
    ----------
    root : path
        Dataset root holding ``sequences/XX/velodyne``.
    split : {"train", "valid", "test"}, optional
        Select the split's sequences (from the packaged ``split``).
    sequences : list of int or str, optional
        Explicit sequences (``[8]`` or ``["08"]``); overrides ``split``.

    Returns
    -------
    list of ScanRef
        Sorted by sequence then frame.
    """
    refs: list[ScanRef] = []
    for seq_dir in sequence_dirs(root, split=split, sequences=sequences):
        refs.extend(list_sequence(seq_dir))
    return refs


def prediction_path(pred_root: str | Path, ref: ScanRef) -> Path:
    """``pred_root/sequences/XX/predictions/NNNNNN.label`` for the scan ``ref``."""
    return Path(pred_root) / "sequences" / ref.sequence / "predictions" / f"{ref.frame}.label"
