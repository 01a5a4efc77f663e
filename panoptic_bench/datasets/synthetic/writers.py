"""Write synthetic sequences as a SemanticKITTI tree or as a nuScenes dataset.

- :func:`generate_semantickitti`: ``sequences/XX/{velodyne/*.bin, labels/*.label, poses.txt,
  calib.txt, times.txt}`` exactly as SemanticKITTI / KITTI odometry lay them out (HDL-64E, 10 Hz).
- :func:`generate_nuscenes`: keyframes (2 Hz) of HDL-32E sweeps with lidarseg labels in the 32
  general classes and global-frame annotation boxes, written through
  :func:`panoptic_bench.datasets.nuscenes.write_dataset` so ``NuScenes()`` loads the result.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from tqdm import tqdm

from panoptic_bench.datasets.synthetic.sensor import HDL32E, Sweep
from panoptic_bench.datasets.synthetic.sequence import Frame, Sequence
from panoptic_bench.errors import InputError
from panoptic_bench.io import ensure_output_dir, write_text

__all__ = [
    "CALIB_TR",
    "NUSCENES_CATEGORY",
    "generate_nuscenes",
    "generate_semantickitti",
    "nuscenes_class_lut",
    "nuscenes_order",
    "nuscenes_sequence",
    "parse_sequences",
]

#: Velodyne -> left camera transform written to calib.txt (KITTI axes: x right, y down, z forward).
CALIB_TR = np.array(
    [[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, -0.08], [1.0, 0.0, 0.0, -0.27], [0.0, 0.0, 0.0, 1.0]]
)
_P = np.array([[718.856, 0.0, 607.1928], [0.0, 718.856, 185.2157], [0.0, 0.0, 1.0]])
_BASELINES = (0.0, -386.1448, 45.38225, -337.2877)

#: Raw SemanticKITTI id -> nuScenes general (lidarseg) class name.
NUSCENES_CLASS = {
    10: "vehicle.car", 252: "vehicle.car",
    11: "vehicle.bicycle", 31: "vehicle.bicycle", 253: "vehicle.bicycle",
    13: "vehicle.bus.rigid", 257: "vehicle.bus.rigid",
    15: "vehicle.motorcycle", 32: "vehicle.motorcycle", 255: "vehicle.motorcycle",
    18: "vehicle.truck", 258: "vehicle.truck",
    20: "vehicle.trailer", 259: "vehicle.trailer",
    30: "human.pedestrian.adult", 254: "human.pedestrian.adult",
    40: "flat.driveable_surface", 44: "flat.driveable_surface",
    48: "flat.sidewalk", 49: "flat.other", 72: "flat.terrain",
    50: "static.manmade", 51: "static.manmade", 80: "static.manmade", 81: "static.manmade",
    70: "static.vegetation", 71: "static.vegetation",
}  # fmt: skip

#: Thing category of the simulator -> nuScenes annotation category.
NUSCENES_CATEGORY = {
    "car": "vehicle.car",
    "truck": "vehicle.truck",
    "bus": "vehicle.bus.rigid",
    "other-vehicle": "vehicle.trailer",
    "bicycle": "vehicle.bicycle",
    "bicyclist": "vehicle.bicycle",
    "motorcycle": "vehicle.motorcycle",
    "motorcyclist": "vehicle.motorcycle",
    "person": "human.pedestrian.adult",
}

#: nuScenes LIDAR_TOP mounting on the ego vehicle (yaw -90 deg: sensor +y is forward).
NUS_LIDAR_TRANSLATION = (0.943, 0.0, 1.84)
NUS_LIDAR_ROTATION = (float(np.sqrt(0.5)), 0.0, 0.0, -float(np.sqrt(0.5)))
BOX_MARGIN = 0.06


def parse_sequences(text: str) -> dict[str, int]:
    """Parse ``"00:40,08:20"`` into ``{"00": 40, "08": 20}`` (sequence -> number of frames)."""
    out: dict[str, int] = {}
    for item in filter(None, (t.strip() for t in text.split(","))):
        name, _, count = item.partition(":")
        if not name.isdigit() or not count.isdigit() or int(count) < 1:
            raise InputError(f"bad sequence spec {item!r}; use SEQ:FRAMES, e.g. 00:40,08:20")
        if f"{int(name):02d}" in out:  # 08:1,8:2 would write sequence 08 twice
            raise InputError(f"sequence {int(name):02d} given twice in {text!r}")
        out[f"{int(name):02d}"] = int(count)
    if not out:
        raise InputError("no sequence given; use SEQ:FRAMES, e.g. 00:40,08:20")
    return out


def _rows(mats: list[np.ndarray]) -> str:
    mats = [np.where(np.abs(m) < 1e-12, 0.0, m) for m in mats]
    return "".join(" ".join(f"{v:.12e}" for v in m[:3].reshape(-1)) + "\n" for m in mats)


def _calib_text() -> str:
    lines = []
    for k, b in enumerate(_BASELINES):
        p = np.hstack([_P, [[b], [0.0], [0.0]]])
        lines.append(f"P{k}: " + " ".join(f"{v:.12e}" for v in p.reshape(-1)))
    lines.append("Tr: " + " ".join(f"{v:.12e}" for v in CALIB_TR[:3].reshape(-1)))
    return "\n".join(lines) + "\n"


def _write_kitti_frame(seq_dir: Path, frame: Frame) -> None:
    from panoptic_bench.datasets.semantickitti import make_label, write_labels, write_scan

    sw = frame.sweep
    name = f"{frame.index:06d}"
    write_scan(seq_dir / "velodyne" / f"{name}.bin", np.column_stack([sw.xyz, sw.remission]))
    write_labels(seq_dir / "labels" / f"{name}.label", make_label(sw.label, sw.instance))


def generate_semantickitti(
    out: str | Path,
    sequences: dict[str, int],
    seed: int = 0,
    overwrite: bool = False,
    progress: bool = True,
    profile=None,
) -> Path:
    """Simulate HDL-64E sequences and write them in the SemanticKITTI layout.

    Parameters
    ----------
    out : str or Path
        Dataset root; ``out/sequences/XX/...`` is written.
    sequences : dict of str to int
        Sequence name (``"08"``) -> number of frames (10 Hz).
    seed : int
        Global seed; sequence ``XX`` is a pure function of ``(seed, int(XX))``.
    overwrite : bool
        Allow writing into a non-empty ``out``.
    progress : bool
        Show a progress bar.
    profile : WorldProfile or str, or a list of them, optional
        World and sensor profile (``classic`` by default). A list mixes worlds: the k-th
        sequence of ``sequences`` (in its order) is written with ``profile[k % len(profile)]``,
        so each sequence equals the one that profile alone writes for it.

    Returns
    -------
    Path
        The dataset root.
    """
    from panoptic_bench.datasets.synthetic.profile_files import load_profile

    profiles = [
        load_profile(p) for p in (profile if isinstance(profile, list | tuple) else [profile])
    ]
    if not profiles:
        raise ValueError("profile: an empty list of world profiles")
    root = ensure_output_dir(out, overwrite=overwrite)
    total = sum(sequences.values())
    with tqdm(
        total=total, desc="synth semantickitti", unit="scan", disable=None if progress else True
    ) as bar:
        for k, (name, n_frames) in enumerate(sequences.items()):
            seq = Sequence(seed, int(name), n_frames, profile=profiles[k % len(profiles)])
            seq_dir = root / "sequences" / f"{int(name):02d}"
            poses, times = [], []
            first_inv = None
            for frame in seq:
                _write_kitti_frame(seq_dir, frame)
                if first_inv is None:
                    first_inv = np.linalg.inv(frame.pose)
                cam = CALIB_TR @ (first_inv @ frame.pose) @ np.linalg.inv(CALIB_TR)
                poses.append(cam)
                times.append(f"{frame.time:.6e}\n")
                bar.update(1)
            write_text(seq_dir / "poses.txt", _rows(poses))
            write_text(seq_dir / "times.txt", "".join(times))
            write_text(seq_dir / "calib.txt", _calib_text())
    return root


def nuscenes_class_lut() -> np.ndarray:
    """Raw SemanticKITTI id -> nuScenes general class index: ndarray (65536,), uint8 (0 = noise)."""
    from panoptic_bench.datasets.nuscenes import GENERAL_CLASSES

    lut = np.zeros(1 << 16, np.uint8)
    for raw, name in NUSCENES_CLASS.items():
        lut[raw] = GENERAL_CLASSES.index(name)
    return lut


def _quat_yaw(yaw: float) -> tuple[float, float, float, float]:
    return (float(np.cos(yaw / 2)), 0.0, 0.0, float(np.sin(yaw / 2)))


def _attributes(category: str, moving: bool) -> tuple[str, ...]:
    if category == "person":
        return ("pedestrian.moving",) if moving else ("pedestrian.standing",)
    if category in ("bicyclist", "motorcyclist"):
        return ("cycle.with_rider",)
    if category in ("bicycle", "motorcycle"):
        return ("cycle.without_rider",)
    return ("vehicle.moving",) if moving else ("vehicle.parked",)


def nuscenes_sequence(seed: int, index: int, samples: int, profile=None) -> Sequence:
    """The HDL-32E keyframe sequence (2 Hz) of scene ``index`` written by :func:`generate_nuscenes`."""
    return Sequence(
        seed,
        1000 + index,
        samples,
        model=HDL32E,
        rate=2.0,
        sensor_offset=NUS_LIDAR_TRANSLATION[:2],
        profile=profile,
    )


def nuscenes_order(sweep: Sweep) -> np.ndarray:
    """Point order of a sweep in the nuScenes file (by azimuth firing, then ring): (N,) int64."""
    return np.lexsort((sweep.ring, sweep.column))


def _nus_sample(seq: Sequence, frame: Frame, scene_name: str, stamp: int, lut: np.ndarray):
    from panoptic_bench.datasets.nuscenes import BoxSpec, SampleSpec

    sw = frame.sweep
    order = nuscenes_order(sw)
    xyz = sw.xyz[order]
    # aligned sensor frame (x forward, y left) -> nuScenes LIDAR_TOP frame (x right, y forward)
    pts = np.column_stack(
        [-xyz[:, 1], xyz[:, 0], xyz[:, 2], np.round(sw.remission[order] * 255.0), sw.ring[order]]
    ).astype(np.float32)
    x, y, yaw = seq.scene.ego_pose(frame.time)
    counts = np.bincount(sw.instance, minlength=len(seq.scene.things) + 1)
    xyz_t, yaw_t = seq.scene.thing_poses(frame.time)
    boxes = []
    for k, thing in enumerate(seq.scene.things):
        near = np.hypot(xyz_t[k, 0] - x, xyz_t[k, 1] - y) < 60.0
        if counts[k + 1] == 0 and not near:
            continue
        ln, w, h = thing.size
        m = 2 * BOX_MARGIN
        boxes.append(
            BoxSpec(
                instance=f"{scene_name}-{k + 1}",
                category=NUSCENES_CATEGORY[thing.category],
                translation=(float(xyz_t[k, 0]), float(xyz_t[k, 1]), float(xyz_t[k, 2] + h / 2)),
                size=(w + m, ln + m, h + m),
                rotation=_quat_yaw(float(yaw_t[k])),
                attributes=_attributes(thing.category, thing.moving),
            )
        )
    return SampleSpec(
        timestamp=stamp,
        ego_translation=(x, y, 0.0),
        ego_rotation=_quat_yaw(yaw),
        points=pts,
        lidarseg=lut[sw.label[order]],
        boxes=boxes,
    )


def _nus_scene_names(version: str, n: int) -> list[str]:
    """Scene names filling whole devkit splits, smallest first (see ``synthetic_scene_plan``)."""
    from panoptic_bench.datasets.nuscenes_spec import synthetic_scene_plan

    return synthetic_scene_plan(version, n)[0]


def generate_nuscenes(
    out: str | Path,
    version: str = "v1.0-mini",
    scenes: int = 4,
    samples: int = 10,
    seed: int = 0,
    overwrite: bool = False,
    progress: bool = True,
    profile=None,
) -> Path:
    """Simulate HDL-32E scenes and write them as a nuScenes dataroot with lidarseg and boxes.

    Parameters
    ----------
    out : str or Path
        Dataroot.
    version : str
        ``v1.0-mini`` (default), ``v1.0-trainval`` or ``v1.0-test``; scene names come from the
        devkit's splits of that version, alternating between its splits (train, val, ...).
    scenes : int
        Number of scenes.
    samples : int
        Keyframes per scene (2 Hz).
    seed : int
        Global seed.
    overwrite : bool
        Allow writing into a non-empty ``out``.
    progress : bool
        Show a progress bar.
    profile : WorldProfile or str, optional
        World and sensor profile (``classic`` by default); the realistic sensor (remission,
        zeros, dropout, pose, ego occlusion) applies to the HDL-32E too, with its own beams.

    Returns
    -------
    Path
        The dataroot.
    """
    from panoptic_bench.datasets.nuscenes import SceneSpec, write_dataset
    from panoptic_bench.datasets.synthetic.profile_files import load_profile

    profile = load_profile(profile)

    if scenes < 1 or samples < 1:
        raise InputError("--scenes and --samples must be at least 1")
    names = _nus_scene_names(version, scenes)
    root = ensure_output_dir(out, overwrite=overwrite)
    lut = nuscenes_class_lut()
    specs = []
    t0 = 1_532_402_927_647_951
    with tqdm(
        total=scenes * samples,
        desc="synth nuscenes",
        unit="sample",
        disable=None if progress else True,
    ) as bar:
        for s, name in enumerate(names):
            seq = nuscenes_sequence(seed, s, samples, profile)
            smp = []
            for frame in seq:
                stamp = t0 + s * 100_000_000 + frame.index * 500_000
                smp.append(_nus_sample(seq, frame, name, stamp, lut))
                bar.update(1)
            specs.append(
                SceneSpec(
                    name=name,
                    samples=smp,
                    lidar_translation=NUS_LIDAR_TRANSLATION,
                    lidar_rotation=NUS_LIDAR_ROTATION,
                    description=f"synthetic street, seed {seed}",
                )
            )
    write_dataset(root, version, specs)
    return root
