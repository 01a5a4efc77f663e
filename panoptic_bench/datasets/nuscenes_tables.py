"""The part of a nuScenes dataroot that scoring needs, read without importing the devkit.

Importing ``nuscenes`` costs about two CPU seconds (its package imports the map and rendering
stack), more than scoring a mini split. :class:`NuScenesTables` reads only the JSON tables an
evaluation uses (``scene``, ``sample``, ``sample_data``, ``calibrated_sensor``, ``sensor``,
``category`` and ``lidarseg`` / ``panoptic`` where present) and offers the same lookups as
``nuscenes.NuScenes`` for them: ``get(table, token)``, the table lists as attributes,
``sample["data"][channel]`` for key frames and ``lidarseg_name2idx_mapping``.
:func:`devkit_splits` reads the split lists of the installed devkit's ``utils/splits.py`` without
importing its package. The devkit stays the reference: tests compare both readers.
"""

from __future__ import annotations

import ast
import functools
import importlib.util
from pathlib import Path
from typing import Any

from panoptic_bench.datasets.nuscenes_reader import _read_table
from panoptic_bench.errors import InputError

__all__ = ["NuScenesTables", "devkit_splits"]

_REQUIRED = ("scene", "sample", "sample_data", "calibrated_sensor", "sensor", "category")
_OPTIONAL = ("lidarseg", "panoptic")
_SPLIT_NAMES = ("train", "val", "test", "mini_train", "mini_val", "train_detect", "train_track")


@functools.cache
def devkit_splits() -> dict[str, list[str]]:
    """Split name -> scene names, as ``nuscenes.utils.splits.create_splits_scenes()`` returns.

    The module's top-level list assignments are evaluated on their own (no import of the
    ``nuscenes`` package).
    """
    spec = importlib.util.find_spec("nuscenes")
    if spec is None or not spec.submodule_search_locations:
        raise InputError("nuscenes-devkit is not installed (pip install nuscenes-devkit)")
    path = Path(next(iter(spec.submodule_search_locations))) / "utils" / "splits.py"
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    names: dict[str, Any] = {}
    allowed = {"list": list, "sorted": sorted, "set": set}
    for node in tree.body:
        if isinstance(node, ast.Assign) and all(isinstance(t, ast.Name) for t in node.targets):
            code = compile(ast.Module([node], type_ignores=[]), str(path), "exec")
            exec(code, {"__builtins__": allowed}, names)  # list literals and set/sorted only
    missing = [s for s in _SPLIT_NAMES if s not in names]
    if missing:
        raise InputError(f"cannot read the devkit splits {missing}", path)
    return {s: list(names[s]) for s in _SPLIT_NAMES}


class NuScenesTables:
    """JSON tables of a dataroot with the lookups of ``nuscenes.NuScenes`` used for scoring.

    Parameters
    ----------
    dataroot : str or Path
        Folder holding ``<version>/*.json``.
    version : str
        E.g. ``"v1.0-mini"``.
    """

    def __init__(self, dataroot: str | Path, version: str) -> None:
        self.dataroot = str(dataroot)
        self.version = version
        self.table_root = Path(dataroot) / version
        self.table_names = list(_REQUIRED)
        for name in _REQUIRED:
            setattr(self, name, _read_table(self.table_root / f"{name}.json"))
        for name in _OPTIONAL:
            if (self.table_root / f"{name}.json").is_file():
                setattr(self, name, _read_table(self.table_root / f"{name}.json"))
                self.table_names.append(name)
        self._token2ind: dict[str, dict[str, int]] = {}
        try:
            for name in self.table_names:
                self._token2ind[name] = {r["token"]: i for i, r in enumerate(getattr(self, name))}
            self.lidarseg_name2idx_mapping = {c["name"]: c["index"] for c in self.category}
            for rec in self.sample:
                rec["data"] = {}
            for rec in self.sample_data:
                cs = self.get("calibrated_sensor", rec["calibrated_sensor_token"])
                rec["channel"] = self.get("sensor", cs["sensor_token"])["channel"]
                if rec["is_key_frame"]:
                    self.get("sample", rec["sample_token"])["data"][rec["channel"]] = rec["token"]
        except (KeyError, TypeError) as exc:
            raise InputError(f"inconsistent nuScenes tables ({exc!r})", self.table_root) from None

    def get(self, table_name: str, token: str) -> dict:
        """The record ``token`` of ``table_name`` (KeyError if absent, as the devkit)."""
        return getattr(self, table_name)[self._token2ind[table_name][token]]
