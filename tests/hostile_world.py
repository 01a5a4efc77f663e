"""Tiny shared inputs and the one assertion of the hostile-input suite (tests/test_hostile_*.py).

:func:`kitti_world` writes a two-scan SemanticKITTI sequence 08 (a few hundred points each),
perfect predictions, simulated centres and simulated-detector boxes; :func:`nuscenes_world` a
small v1.0-mini dataroot with panoptic labels and perfect predictions. :func:`refused` runs one
command and checks the promise of the README: exit status 2, one message naming the file or
option, no traceback, nothing new in the output location, every input byte-identical.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from panoptic_bench import __version__  # noqa: F401  (the package must import cleanly)
from panoptic_bench.cli import main

RAW_STUFF = [40, 44, 48, 50, 70, 72]
RAW_THINGS = [10, 18, 30]
NU_VERSION = "v1.0-mini"


def digest(root: Path) -> dict[str, str]:
    """Relative path -> sha1 of every file under ``root`` (also the directory structure)."""
    root = Path(root)
    if root.is_file():
        return {root.name: hashlib.sha1(root.read_bytes()).hexdigest()}
    out = {}
    for p in sorted(root.rglob("*")):
        rel = str(p.relative_to(root))
        out[rel] = hashlib.sha1(p.read_bytes()).hexdigest() if p.is_file() else "dir"
    return out


def listing(folder: Path) -> list[str]:
    """Every path under ``folder`` (hidden temp files included); [] when it does not exist."""
    folder = Path(folder)
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*")) if folder.exists() else []


def run(argv: Iterable, capsys) -> tuple[int, str, str]:
    """``panoptic-bench ARGV`` in this process: (status, stdout, stderr)."""
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


def refused(
    argv: Iterable,
    capsys,
    *,
    names: str | Iterable[str],
    inputs: Iterable[Path] = (),
    watch: Iterable[Path] = (),
) -> str:
    """Run ``argv``; assert the promise for bad input. Returns stderr.

    Parameters
    ----------
    names : str or iterable of str
        Each must appear in the message (the offending file or option, what is wrong).
    inputs : paths
        Trees (or files) that must be byte-identical afterwards.
    watch : paths
        Directories whose listing (hidden files included) must not change: the output location.
    """
    inputs, watch = [Path(p) for p in inputs], [Path(p) for p in watch]
    before = [digest(p) for p in inputs]
    seen = [listing(p) for p in watch]
    status, _, err = run(argv, capsys)
    assert status == 2, f"exit {status}, stderr: {err}"
    assert "Traceback" not in err
    assert err.startswith("panoptic-bench") or err.startswith("usage:"), err
    for name in [names] if isinstance(names, str) else names:
        assert str(name) in err, f"{name!r} not in: {err}"
    assert [digest(p) for p in inputs] == before, "an input was modified"
    assert [listing(p) for p in watch] == seen, "something was written to the output location"
    return err


def _scan(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Points in a few clumps (things) over scattered stuff; labels raw sem | inst << 16."""
    from panoptic_bench.datasets.semantickitti import make_label

    pts = rng.uniform(-30, 30, (n, 4)).astype(np.float32)
    pts[:, 2] = rng.uniform(-2, 2, n)
    sem = rng.choice(RAW_STUFF, n)
    inst = np.zeros(n, dtype=np.int64)
    for k in range(3):  # three objects of 60 points, 1.5 m wide
        idx = np.arange(k * 60, (k + 1) * 60)
        pts[idx, :3] = rng.uniform(-20, 20, 3) + rng.uniform(-0.75, 0.75, (60, 3))
        sem[idx], inst[idx] = RAW_THINGS[k], k + 1
    return pts, make_label(sem, inst)


def kitti_world(root: Path, n_scans: int = 2, n_points: int = 400) -> dict[str, Path]:
    """data/, pred/ (perfect), centers/ (simulated, exact) and boxes/ under ``root``."""
    from panoptic_bench.datasets import semantickitti as sk

    rng = np.random.default_rng(0)
    data, pred = root / "data", root / "pred"
    for i in range(n_scans):
        pts, lab = _scan(rng, n_points)
        sk.write_scan(data / "sequences/08/velodyne" / f"{i:06d}.bin", pts)
        sk.write_labels(data / "sequences/08/labels" / f"{i:06d}.label", lab)
        sk.write_labels(pred / "sequences/08/predictions" / f"{i:06d}.label", lab)
    world = {"root": root, "data": data, "pred": pred}
    world["centers"], world["boxes"] = root / "centers", root / "boxes"
    assert main(["centers", "simulate", "--dataset", str(data), "--output", str(world["centers"]),
                 "--zero-noise"]) == 0  # fmt: skip
    assert main(["box-merge", "simulate-boxes", "--dataset", str(data), "--output",
                 str(world["boxes"])]) == 0  # fmt: skip
    return world


def nuscenes_world(root: Path) -> dict[str, Path]:
    """A small v1.0-mini dataroot with panoptic labels, centres and perfect predictions."""
    from nuscenes_world import write_mini

    from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar
    from panoptic_bench.evaluation.nuscenes import ChallengeClasses

    dataroot = write_mini(root / "nus")
    args = ["nuscenes", "make-labels", "--dataroot", dataroot, "--version", NU_VERSION]
    assert main([str(a) for a in [*args, "--out-dir", dataroot]]) == 0
    reader = NuScenesLidar(dataroot, NU_VERSION)
    lut = ChallengeClasses.from_nusc(reader.nusc).lut
    res = root / "res"
    folder = res / "panoptic" / "mini_val"
    folder.mkdir(parents=True)
    for tok in reader.sample_data_tokens("mini_val"):
        gt = reader.load_panoptic(tok).astype(np.int64)
        pred = (lut[gt // 1000] * 1000 + gt % 1000).astype(np.uint16)
        np.savez_compressed(folder / f"{tok}_panoptic.npz", data=pred)
    centers = root / "nus-centers"
    assert main(["centers", "simulate", "--dataset", str(dataroot), "--version", NU_VERSION,
                 "--eval-set", "mini_val", "--zero-noise", "--output", str(centers)]) == 0  # fmt: skip
    return {
        "dataroot": dataroot,
        "res": res,
        "centers": centers,
        "tokens": sorted(folder.iterdir()),
    }


def umask_mode(mode: int = 0o666) -> int:
    """``mode`` under the current umask (what an ordinary file write gets)."""
    mask = os.umask(0)
    os.umask(mask)
    return mode & ~mask
