"""A small reader over the nuScenes devkit: keyframe LIDAR_TOP sweeps, lidarseg and panoptic labels.

Everything the rest of the package reads from a nuScenes dataroot goes through
:class:`NuScenesLidar`, which turns the devkit's assertions into :class:`InputError` messages that
name the file or token: an unknown version folder, a missing lidarseg/panoptic table or label file,
a label file whose length differs from the sweep's point count, a sample without LIDAR_TOP.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from panoptic_bench.errors import InputError

LIDAR_CHANNEL = "LIDAR_TOP"
POINT_DIMS = 5  # x, y, z, intensity, ring index (float32)


def _read_table(path: Path) -> list[dict]:
    try:
        with open(path, encoding="utf-8") as fh:
            rows = json.load(fh)
    except FileNotFoundError:
        raise InputError("table missing", path) from None
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read table ({exc})", path) from None
    return check_table_rows(rows, path)


#: Keys every row of a devkit table must have (beyond ``token``), as the devkit indexes them.
TABLE_KEYS = {
    "sample_data": ("sample_token", "ego_pose_token", "calibrated_sensor_token", "filename"),
    "sample": ("scene_token", "timestamp"),
    "sample_annotation": ("sample_token", "instance_token", "translation", "size", "rotation"),
    "lidarseg": ("sample_data_token", "filename"),
    "panoptic": ("sample_data_token", "filename"),
}
#: Keys whose values are file names relative to the dataroot (must be strings).
_FILE_KEYS = ("filename",)


def check_table_rows(rows: Any, path: Path) -> list[dict]:
    """Raise :class:`InputError` unless ``rows`` is a list of objects with the keys of its table.

    Parameters
    ----------
    rows : object
        The parsed JSON of ``path`` (``<version>/<table>.json``).
    path : Path
        The table file (its stem names the table).
    """
    if not isinstance(rows, list):
        raise InputError(f"table is not a JSON list (got {type(rows).__name__})", path)
    need = ("token", *TABLE_KEYS.get(path.stem, ()))
    for i, row in enumerate(rows):
        if not isinstance(row, dict):
            raise InputError(f"row {i} is not a JSON object (got {type(row).__name__})", path)
        missing = [k for k in need if k not in row]
        if missing:
            raise InputError(f"row {i} has no {', '.join(missing)}", path)
        for key in _FILE_KEYS:
            if key in row and not isinstance(row[key], str):
                raise InputError(f"row {i}: {key} must be a string, got {row[key]!r}", path)
    return rows


def check_tables(dataroot: str | Path, version: str) -> None:
    """Check the shape of every ``<version>/*.json`` table before the devkit indexes them."""
    for path in sorted((Path(dataroot) / version).glob("*.json")):
        check_table_rows(_read_table(path), path)


def check_label_table(dataroot: str | Path, version: str, task: str) -> list[dict] | None:
    """Check a ``lidarseg`` / ``panoptic`` table and its files; ``None`` if the table is absent.

    Raises :class:`InputError` naming the first missing label file.
    """
    table = Path(dataroot) / version / f"{task}.json"
    if not table.is_file():
        return None
    rows = _read_table(table)
    for row in rows:
        path = Path(dataroot) / row.get("filename", "")
        if not path.is_file():
            raise InputError(
                f"{task} file of sample_data {row.get('sample_data_token')} listed in {table} "
                "is missing",
                path,
            )
    return rows


def _check_root(dataroot: str | Path, version: str) -> Path:
    root = Path(dataroot)
    if not root.is_dir():
        raise InputError("nuScenes dataroot not found", root)
    if not (root / version).is_dir():
        found = sorted(p.name for p in root.iterdir() if (p / "sample.json").is_file())
        raise InputError(
            f"unknown version folder {version!r} (found: {', '.join(found) or 'none'}); "
            "pass --version with one of these",
            root / version,
        )
    check_tables(root, version)
    for task in ("lidarseg", "panoptic"):
        check_label_table(root, version, task)
    return root


def open_tables(dataroot: str | Path, version: str) -> Any:
    """The tables scoring needs, without importing the devkit (see ``nuscenes_tables``).

    Returns
    -------
    panoptic_bench.datasets.nuscenes_tables.NuScenesTables
    """
    from panoptic_bench.datasets.nuscenes_tables import NuScenesTables

    return NuScenesTables(_check_root(dataroot, version), version)


def open_nuscenes(dataroot: str | Path, version: str) -> Any:
    """Load ``nuscenes.NuScenes(version, dataroot)`` quietly, with clear errors.

    Returns
    -------
    nuscenes.NuScenes
    """
    from nuscenes import NuScenes

    root = _check_root(dataroot, version)
    try:
        return NuScenes(version=version, dataroot=str(root), verbose=False)
    except FileNotFoundError as exc:
        raise InputError(f"cannot load nuScenes {version}: missing {exc.filename}", root) from None
    except (AssertionError, KeyError, ValueError) as exc:
        raise InputError(f"cannot load nuScenes {version}: {exc}", root / version) from None


class NuScenesLidar:
    """Keyframe LIDAR_TOP sweeps and their labels from a nuScenes dataroot.

    Parameters
    ----------
    dataroot : str or Path
        Directory holding ``<version>/``, ``samples/``, ``lidarseg/``, ``panoptic/``.
    version : str
        E.g. ``"v1.0-mini"``.
    nusc : nuscenes.NuScenes, optional
        An already loaded devkit object (otherwise loaded with :func:`open_nuscenes`).
    """

    def __init__(self, dataroot: str | Path, version: str, nusc: Any | None = None) -> None:
        self.dataroot = Path(dataroot)
        self.version = version
        self.nusc = nusc if nusc is not None else open_nuscenes(dataroot, version)

    @classmethod
    def tables_only(cls, dataroot: str | Path, version: str) -> NuScenesLidar:
        """A reader over :func:`open_tables` (no devkit import: fast start for scoring)."""
        return cls(dataroot, version, nusc=open_tables(dataroot, version))

    @property
    def table_root(self) -> Path:
        return self.dataroot / self.version

    def lidar_token(self, sample: dict) -> str:
        """The keyframe LIDAR_TOP sample_data token of a ``sample`` record."""
        tok = sample["data"].get(LIDAR_CHANNEL)
        if tok is None:
            raise InputError(
                f"sample {sample['token']} has no keyframe {LIDAR_CHANNEL} sample_data",
                self.table_root / "sample_data.json",
            )
        return tok

    def sample_data_tokens(self, eval_set: str | None = None) -> list[str]:
        """Keyframe LIDAR_TOP sample_data tokens.

        ``eval_set=None`` gives every sample in table order (the order of label generation);
        a split name (``"mini_val"``, ``"val"``...) gives its scenes' samples in the devkit's
        ``get_samples_in_eval_set`` order. Split scenes absent from the dataroot are an error.
        """
        if eval_set is None:
            return [self.lidar_token(s) for s in self.nusc.sample]
        from panoptic_bench.datasets.nuscenes import scene_names

        names = scene_names(self.version, eval_set)
        by_name = {rec["name"]: rec for rec in self.nusc.scene}
        missing = [n for n in names if n not in by_name]
        if missing:
            raise InputError(
                f"eval set {eval_set!r} needs {len(missing)} scene(s) absent from the dataroot "
                f"(first: {missing[0]})",
                self.table_root / "scene.json",
            )
        tokens = []
        for name in names:
            scene = by_name[name]
            tok, n = scene["first_sample_token"], 0
            while tok:
                sample = self.nusc.get("sample", tok)
                tokens.append(self.lidar_token(sample))
                n += 1
                tok = "" if tok == scene["last_sample_token"] else sample["next"]
            if n != scene["nbr_samples"]:
                raise InputError(
                    f"scene {name} lists {scene['nbr_samples']} samples but links {n}",
                    self.table_root / "scene.json",
                )
        return tokens

    def points_path(self, sd_token: str) -> Path:
        """Path of the ``.pcd.bin`` sweep of a sample_data token."""
        return self.dataroot / self.nusc.get("sample_data", sd_token)["filename"]

    def num_points(self, sd_token: str) -> int:
        """Point count of a sweep from its file size (float32 x 5 per point)."""
        path = self.points_path(sd_token)
        try:
            size = path.stat().st_size
        except FileNotFoundError:
            raise InputError(f"sweep of sample_data {sd_token} is missing", path) from None
        if size % (4 * POINT_DIMS):
            raise InputError(f"size {size} is not a multiple of {4 * POINT_DIMS} bytes", path)
        return size // (4 * POINT_DIMS)

    def load_points(self, sd_token: str) -> np.ndarray:
        """The sweep as float32 of shape (n_points, 5): x, y, z, intensity, ring (sensor frame)."""
        self.num_points(sd_token)
        path = self.points_path(sd_token)
        points = np.fromfile(path, dtype=np.float32).reshape(-1, POINT_DIMS)
        bad = ~np.isfinite(points).all(axis=1)
        if bad.any():
            raise InputError(f"{int(bad.sum())} point(s) with NaN or infinite values", path)
        return points

    def label_path(self, sd_token: str, task: str = "lidarseg") -> Path:
        """Path of the ``lidarseg`` or ``panoptic`` label file of a sample_data token."""
        if not hasattr(self.nusc, task):
            raise InputError(
                f"no {task} table: this dataroot has no nuScenes-{task} labels",
                self.table_root / f"{task}.json",
            )
        try:
            rec = self.nusc.get(task, sd_token)
        except KeyError:
            raise InputError(
                f"sample_data {sd_token} has no {task} record", self.table_root / f"{task}.json"
            ) from None
        return self.dataroot / rec["filename"]

    def load_lidarseg(self, sd_token: str) -> np.ndarray:
        """General-class labels, uint8 of shape (n_points,), checked against the point count."""
        path = self.label_path(sd_token, "lidarseg")
        if not path.is_file():
            raise InputError(f"lidarseg file of sample_data {sd_token} is missing", path)
        labels = np.fromfile(path, dtype=np.uint8)
        self._check_count(labels, sd_token, path)
        return labels

    def load_panoptic(self, sd_token: str) -> np.ndarray:
        """Panoptic labels (1000 x general class + instance), uint16 of shape (n_points,)."""
        path = self.label_path(sd_token, "panoptic")
        labels = load_panoptic_npz(path)
        self._check_count(labels, sd_token, path)
        return labels

    def _check_count(self, labels: np.ndarray, sd_token: str, path: Path) -> None:
        n = self.num_points(sd_token)
        if len(labels) != n:
            raise InputError(
                f"{len(labels)} labels but the sweep of sample_data {sd_token} has {n} points",
                path,
            )


def load_panoptic_npz(path: str | Path) -> np.ndarray:
    """Read the ``data`` array of a panoptic ``.npz`` (1-D integer array), with clear errors."""
    path = Path(path)
    if not path.is_file():
        raise InputError("panoptic file is missing", path)
    from panoptic_bench.io import read_npz

    arrays = read_npz(path, keys=("data",))
    data = arrays["data"]
    if data.ndim != 1 or not np.issubdtype(data.dtype, np.integer):
        raise InputError(f"'data' must be a 1-D integer array, got {data.dtype} {data.shape}", path)
    return data
