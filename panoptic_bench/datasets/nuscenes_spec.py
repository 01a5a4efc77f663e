"""The nuScenes vocabulary and the scene specifications that :func:`write_dataset` takes.

The 32 general lidarseg classes (their position is the devkit category ``index``), attributes,
visibility levels, the split scene names of each version (from the devkit's
``nuscenes.utils.splits``), deterministic tokens, and the ``BoxSpec`` / ``SampleSpec`` /
``SceneSpec`` dataclasses. Re-exported by :mod:`panoptic_bench.datasets.nuscenes`.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from panoptic_bench.errors import InputError

# The 32 general (fine) lidarseg classes; the position is the devkit category ``index``.
GENERAL_CLASSES: tuple[str, ...] = (
    "noise",
    "animal",
    "human.pedestrian.adult",
    "human.pedestrian.child",
    "human.pedestrian.construction_worker",
    "human.pedestrian.personal_mobility",
    "human.pedestrian.police_officer",
    "human.pedestrian.stroller",
    "human.pedestrian.wheelchair",
    "movable_object.barrier",
    "movable_object.debris",
    "movable_object.pushable_pullable",
    "movable_object.trafficcone",
    "static_object.bicycle_rack",
    "vehicle.bicycle",
    "vehicle.bus.bendy",
    "vehicle.bus.rigid",
    "vehicle.car",
    "vehicle.construction",
    "vehicle.emergency.ambulance",
    "vehicle.emergency.police",
    "vehicle.motorcycle",
    "vehicle.trailer",
    "vehicle.truck",
    "flat.driveable_surface",
    "flat.other",
    "flat.sidewalk",
    "flat.terrain",
    "static.manmade",
    "static.other",
    "static.vegetation",
    "vehicle.ego",
)
# The Panoptic nuScenes challenge classes (index = challenge id) and the general -> challenge map
# of the devkit's ``LidarsegClassMapper``; unlisted general classes map to 0 ("ignore").
CHALLENGE_CLASSES: tuple[str, ...] = (
    "ignore", "barrier", "bicycle", "bus", "car", "construction_vehicle", "motorcycle",
    "pedestrian", "traffic_cone", "trailer", "truck", "driveable_surface", "other_flat",
    "sidewalk", "terrain", "manmade", "vegetation",
)  # fmt: skip
GENERAL_TO_CHALLENGE: dict[str, str] = {
    "human.pedestrian.adult": "pedestrian",
    "human.pedestrian.child": "pedestrian",
    "human.pedestrian.police_officer": "pedestrian",
    "human.pedestrian.construction_worker": "pedestrian",
    "vehicle.car": "car",
    "vehicle.motorcycle": "motorcycle",
    "vehicle.bicycle": "bicycle",
    "vehicle.bus.bendy": "bus",
    "vehicle.bus.rigid": "bus",
    "vehicle.truck": "truck",
    "vehicle.construction": "construction_vehicle",
    "vehicle.trailer": "trailer",
    "movable_object.barrier": "barrier",
    "movable_object.trafficcone": "traffic_cone",
    "flat.driveable_surface": "driveable_surface",
    "flat.sidewalk": "sidewalk",
    "flat.terrain": "terrain",
    "flat.other": "other_flat",
    "static.manmade": "manmade",
    "static.vegetation": "vegetation",
}
N_CHALLENGE_THINGS = 10  # challenge ids 1..10 are things, 11..16 stuff


def devkit_set_order(names: tuple[str, ...]) -> list[str]:
    """The iteration order of a set literal of ``names`` in the installed devkit's bytecode.

    The devkit's ``PanopticClassMapper`` builds its thing / stuff dicts from set literals, so
    PQ-dagger's mean runs in hash order. A compiled set literal is a frozenset constant, stored
    in the ``.pyc`` in marshal order and copied into a new set at run time; doing the same here
    gives the same order under this process's hash seed (and so the devkit's PQ-dagger bits).
    """
    import marshal

    out: set[str] = set()
    out.update(frozenset(sorted(names, key=marshal.dumps)))
    return list(out)


ATTRIBUTES: tuple[str, ...] = (
    "vehicle.moving",
    "vehicle.stopped",
    "vehicle.parked",
    "cycle.with_rider",
    "cycle.without_rider",
    "pedestrian.sitting_lying_down",
    "pedestrian.standing",
    "pedestrian.moving",
)
VISIBILITY_LEVELS = {"1": "v0-40", "2": "v40-60", "3": "v60-80", "4": "v80-100"}
LIDAR_CHANNEL = "LIDAR_TOP"
_SPLITS_OF_VERSION = {
    "mini": ("mini_train", "mini_val"),
    "trainval": ("train", "val"),
    "test": ("test",),
}


@dataclass(frozen=True)
class BoxSpec:
    """One 3D box annotation in the GLOBAL frame.

    ``instance`` is a stable key of the object, unique in the dataset (it becomes the instance
    token); ``size`` is (w, l, h) as in nuScenes; ``rotation`` is a quaternion (w, x, y, z).
    """

    instance: str
    category: str
    translation: tuple[float, float, float]
    size: tuple[float, float, float]
    rotation: tuple[float, float, float, float]
    attributes: tuple[str, ...] = ()
    visibility: str = "4"


@dataclass
class SampleSpec:
    """One keyframe: ego pose, the LIDAR_TOP sweep (sensor frame), its lidarseg labels and boxes.

    ``points`` is float32 of shape (n_points, 5): x, y, z, intensity (0-255), ring index.
    ``lidarseg`` is uint8 of shape (n_points,): general class index 0..31.
    """

    timestamp: int
    ego_translation: tuple[float, float, float]
    ego_rotation: tuple[float, float, float, float]
    points: np.ndarray
    lidarseg: np.ndarray
    boxes: list[BoxSpec]


@dataclass
class SceneSpec:
    """One scene: a split scene name, its keyframes and the LIDAR_TOP calibration (ego frame)."""

    name: str
    samples: list[SampleSpec]
    lidar_translation: tuple[float, float, float]
    lidar_rotation: tuple[float, float, float, float]
    location: str = "singapore-onenorth"
    description: str = ""


def token(*parts: object) -> str:
    """Deterministic 32-hex token from a readable key (``token("scene", "scene-0103")``)."""
    return hashlib.md5("/".join(str(p) for p in parts).encode()).hexdigest()


def version_kind(version: str) -> str:
    """``"mini"``, ``"trainval"`` or ``"test"`` for a version string such as ``v1.0-mini``."""
    for kind in _SPLITS_OF_VERSION:
        if version.endswith(kind):
            return kind
    raise InputError(
        f"unknown nuScenes version {version!r}; use one ending in -mini, -trainval or -test"
    )


def scene_names(version: str, split: str) -> list[str]:
    """Scene names of a devkit split (``nuscenes.utils.splits``) valid for ``version``.

    Parameters
    ----------
    version : str
        E.g. ``"v1.0-mini"``.
    split : str
        E.g. ``"mini_val"``, ``"val"``, ``"train_detect"``.

    Returns
    -------
    list of str
        The scene names, in the devkit's order.
    """
    from panoptic_bench.datasets.nuscenes_tables import devkit_splits

    splits = devkit_splits()
    if split not in splits:
        raise InputError(f"unknown nuScenes split {split!r}; known: {', '.join(sorted(splits))}")
    kind = version_kind(version)
    allowed = {"mini": {"mini_train", "mini_val"}, "test": {"test"}}.get(
        kind, {"train", "val", "train_detect", "train_track"}
    )
    if split not in allowed:
        raise InputError(f"split {split!r} does not belong to version {version!r}")
    return list(splits[split])


def _valid_scene_names(version: str) -> set[str]:
    names: set[str] = set()
    for split in _SPLITS_OF_VERSION[version_kind(version)]:
        names.update(scene_names(version, split))
    return names


def synthetic_scene_plan(version: str, n: int) -> tuple[list[str], list[str]]:
    """Scene names for ``n`` synthetic scenes such that at least one devkit split is complete.

    The splits of the version are filled whole, smallest first (``v1.0-mini``: the 2 scenes of
    ``mini_val``, then the 8 of ``mini_train``), so the devkit's
    ``get_samples_in_panoptic_eval_set`` and the tracking evaluator find every scene of the
    completed splits.

    Parameters
    ----------
    version : str
        E.g. ``"v1.0-mini"``.
    n : int
        Number of scenes.

    Returns
    -------
    (list of str, list of str)
        The ``n`` scene names, and the devkit splits they complete (never empty).

    Raises
    ------
    InputError
        If ``n`` is smaller than the smallest split or larger than all scene names of the version.
    """
    kind = version_kind(version)
    splits = sorted(_SPLITS_OF_VERSION[kind], key=lambda s: (len(scene_names(version, s)), s))
    names: list[str] = []
    for split in splits:
        names.extend(x for x in scene_names(version, split) if x not in names)
    smallest = splits[0]
    need = len(scene_names(version, smallest))
    if n < need:
        raise InputError(
            f"--scenes {n}: the smallest devkit split of {version} is {smallest} with {need} "
            f"scenes; use --scenes >= {need} so that a split is complete"
        )
    if n > len(names):
        raise InputError(f"--scenes {n} exceeds the {len(names)} scene names of {version}")
    chosen = names[:n]
    complete = [s for s in splits if set(scene_names(version, s)) <= set(chosen)]
    return chosen, complete
