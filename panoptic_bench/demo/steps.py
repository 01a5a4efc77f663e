"""Data, regression and clustering steps of the demo, one small function per stage.

Every step reads and writes ordinary dataset / prediction trees, the same files the CLI
commands read and write, so each can be replaced by the command named in its docstring.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from panoptic_bench.demo.config import ClusteringSpec, DemoSize

__all__ = [
    "KITTI_TRAIN",
    "KITTI_VAL",
    "NUS_EVAL_SET",
    "NUS_VERSION",
    "Workspace",
    "build_nuscenes_labels",
    "cluster_nuscenes_centres",
    "cluster_semantickitti_centres",
    "dsnet_regression",
    "find_checkpoint",
    "simulate_nuscenes_centres",
    "simulate_semantickitti_centres",
    "synthesize_nuscenes",
    "synthesize_semantickitti",
]

KITTI_TRAIN = "00"
KITTI_VAL = "08"
NUS_VERSION = "v1.0-mini"
NUS_EVAL_SET = "mini_val"


@dataclass(frozen=True)
class Workspace:
    """Where the demo writes.

    Attributes
    ----------
    out : Path
        The report directory (``index.md``, ``tables/``, ``figures/``, ``runs/``).
    work : Path
        Generated data: datasets, regressed centres, predictions (never in git).
    work_label : str
        How ``work`` is written in recorded commands (``$WORK`` for a temporary directory, so
        that committed ``run.json`` files do not depend on where the demo ran).
    """

    out: Path
    work: Path
    work_label: str = ""

    def show(self, path: Path) -> str:
        """``path`` as written in recorded commands (see ``work_label``)."""
        path = Path(path)
        if self.work_label and path.is_relative_to(self.work):
            return f"{self.work_label}/{path.relative_to(self.work).as_posix()}"
        return path.as_posix()

    @property
    def runs(self) -> Path:
        """``out/runs``: one run directory per method (``scores.json``, ``run.json``)."""
        return self.out / "runs"

    @property
    def kitti(self) -> Path:
        """The synthetic SemanticKITTI-format root."""
        return self.work / "semantickitti"

    @property
    def nuscenes(self) -> Path:
        """The synthetic nuScenes-format dataroot."""
        return self.work / "nuscenes"

    def centres(self, name: str) -> Path:
        """Root of one set of regressed-centre files."""
        return self.work / "centers" / name

    def predictions(self, name: str) -> Path:
        """Root of one prediction tree."""
        return self.work / "predictions" / name


# --------------------------------------------------------------------------- data


def synthesize_semantickitti(ws: Workspace, size: DemoSize) -> Path:
    """Synthetic HDL-64E sequences ``00`` (train) and ``08`` (val) in the SemanticKITTI layout.

    Same as ``panoptic-bench synth semantickitti --sequences 00:T,08:V --seed S``.
    """
    from panoptic_bench.datasets.synthetic.writers import generate_semantickitti

    seqs = {KITTI_TRAIN: size.train_frames, KITTI_VAL: size.val_frames}
    return generate_semantickitti(ws.kitti, seqs, seed=size.seed, overwrite=True)


def synthesize_nuscenes(ws: Workspace, size: DemoSize) -> Path:
    """Synthetic HDL-32E scenes as a ``v1.0-mini`` nuScenes dataroot (lidarseg + boxes).

    Same as ``panoptic-bench synth nuscenes --scenes N --samples K --seed S``.
    """
    from panoptic_bench.datasets.synthetic.writers import generate_nuscenes

    return generate_nuscenes(
        ws.nuscenes, NUS_VERSION, size.nus_scenes, size.nus_samples, seed=size.seed, overwrite=True
    )


def build_nuscenes_labels(ws: Workspace, workers: int = 1) -> int:
    """Panoptic nuScenes labels from lidarseg + boxes, written into the dataroot.

    Same as ``panoptic-bench nuscenes make-labels --dataroot D --version v1.0-mini --out-dir D``.
    Returns the number of label files.
    """
    from panoptic_bench.datasets.nuscenes_panoptic import make_panoptic_labels

    return len(make_panoptic_labels(ws.nuscenes, NUS_VERSION, ws.nuscenes, workers=workers))


# --------------------------------------------------------------------------- regression


def find_checkpoint(name: str) -> Path | None:
    """The shipped checkpoint ``panoptic_bench/checkpoints/<name>``, or None.

    None as well when the DS-Net network code it needs cannot be imported.
    """
    path = Path(str(resources.files("panoptic_bench"))) / "checkpoints" / name
    if not path.is_file():
        return None
    for module in (
        "panoptic_bench.dsnet.model.network",
        "panoptic_bench.dsnet.model.dynamic_shift",
    ):
        if importlib.util.find_spec(module) is None:
            return None
    return path


def resolve_checkpoint_arg(text: str) -> Path:
    """A ``--checkpoint`` value: a path, or the short name of a shipped checkpoint."""
    from panoptic_bench.dsnet.checkpoint import resolve_checkpoint

    return Path(resolve_checkpoint(text))


def checkpoint_label(path: Path) -> str:
    """``panoptic_bench/checkpoints/NAME`` for a shipped checkpoint, else the path as given."""
    shipped = Path(str(resources.files("panoptic_bench"))) / "checkpoints"
    path = Path(path)
    if path.resolve().parent == shipped.resolve():
        return f"panoptic_bench/checkpoints/{path.name}"
    return path.as_posix()


#: What each shipped checkpoint was trained on (its file records sequence ids, not the root).
TRAINED_ON = {
    "dsnet_synthetic.pt": "trained on the synthetic world only",
    "backbone_synthetic.pt": "trained on the synthetic world only",
    "dsnet_synthetic_realistic.pt": "trained on the realistic synthetic world only",
    "dsnet_synthetic_materials_road.pt": (
        "trained on the synthetic worlds only (realistic, then realistic-materials-road)"
    ),
    "dsnet_synthetic_low_crowns.pt": (
        "trained on the synthetic worlds only (realistic, then realistic-materials-road-raised-verges-low-crowns)"
    ),
    "dsnet_synthetic_fences.pt": (
        "trained on the synthetic worlds only (realistic, then realistic-low-crowns-fences)"
    ),
    "dsnet_synthetic_low_fences.pt": (
        "trained on the synthetic worlds only (realistic, then realistic-low-crowns-low-fences)"
    ),
    "dsnet_synthetic_mixed.pt": (
        "trained on the synthetic worlds only (realistic, then realistic-low-crowns-low-fences,"
        " realistic-low-fences-tight-materials and realistic-low-fences-raised-lots mixed by street)"
    ),
    "dsnet_synthetic_road_gain.pt": (
        "trained on the synthetic worlds only (as dsnet_synthetic_mixed.pt, with a per-scan"
        " remission gain on road and parking)"
    ),
    "dsnet_synthetic_full_density.pt": (
        "trained on the synthetic worlds only (as dsnet_synthetic_road_gain.pt, on every point of"
        " every scan instead of 25000)"
    ),
    "dsnet_synthetic_held_bn.pt": (
        "trained on the synthetic worlds only (lowered kerbs, remission in the real order, every"
        " point, BatchNorm statistics held at the pre-trained model's)"
    ),
    "dsnet_synthetic_sign_boards.pt": (
        "trained on the synthetic worlds only (as dsnet_synthetic_held_bn.pt, with low sign posts"
        " carrying plates of the real size)"
    ),
    "dsnet_synthetic_buildings.pt": (
        "trained on the synthetic worlds only (as dsnet_synthetic_sign_boards.pt, with twice the"
        " building frontages)"
    ),
    "dsnet_synthetic_buildings_start2.pt": (
        "trained on the synthetic worlds only (as dsnet_synthetic_buildings.pt, fine-tuned from a"
        " second draw of its start, seed 1)"
    ),
    "dsnet_synthetic_buildings_start3.pt": (
        "trained on the synthetic worlds only (as dsnet_synthetic_buildings.pt, fine-tuned from a"
        " third draw of its start, seed 2)"
    ),
    "ensemble_synthetic.json": (
        "three networks trained on the synthetic worlds only (dsnet_synthetic_buildings.pt and its"
        " fine-tunes from two more draws of its start), four test-time views each"
    ),
    "dsnet_nuscenes_synthetic.pt": "trained on a synthetic nuScenes world (seed 1000) only",
    "dsnet_semantickitti_cpu.pt": (
        "trained on real scans of sequences 00-07, 09, 10 + rare instances pasted from synthetic streets"
    ),
    "backbone_semantickitti_cpu.pt": (
        "trained on real scans of sequences 00-07, 09, 10 + rare instances pasted from synthetic streets"
    ),
    "dsnet_semantickitti_cpu_heldout0506.pt": (
        "trained on real scans of sequences 00-04, 07, 09, 10 (05 and 06 held out)"
        " + rare instances pasted from synthetic streets"
    ),
}


def training_overlap_note(checkpoint: Path, sequences: Sequence[str]) -> str:
    """What the checkpoint was trained on, for the notes of its rows ('; ...').

    Shipped checkpoints are described by :data:`TRAINED_ON`; for another checkpoint the note
    names the scored sequences that are among its training sequence ids (of whatever root it
    was trained on: the file does not record the root).
    """
    from panoptic_bench.dsnet.checkpoint import load_checkpoint
    from panoptic_bench.dsnet.inference.ensemble_file import is_ensemble_file, read_ensemble_file

    checkpoint = Path(checkpoint)
    if checkpoint_label(checkpoint).startswith("panoptic_bench/checkpoints/"):
        if checkpoint.name in TRAINED_ON:
            return f"; {TRAINED_ON[checkpoint.name]}"
    if is_ensemble_file(checkpoint):  # one note per member
        spec = read_ensemble_file(checkpoint)
        parts = [training_overlap_note(m, sequences).removeprefix("; ") for m in spec.members]
        return "; " + " | ".join(f"member {i + 1}: {p or 'no note'}" for i, p in enumerate(parts))
    data = load_checkpoint(checkpoint).config.data
    if data.format.value != "semantickitti":
        return ""
    trained = set(data.train_sequences)
    if not trained:
        from panoptic_bench.datasets.semantickitti import LABELS

        trained = {f"{int(s):02d}" for s in LABELS.splits.get(data.train_split, [])}
    both = sorted(trained & set(sequences))
    if not both:
        return "; none of the scored sequences is among its training sequence ids"
    return (
        f"; its training sequence ids ({', '.join(sorted(trained))}) include the scored "
        f"{', '.join(both)}: training-data numbers if it was trained on this root"
    )


def dsnet_regression(
    checkpoint: Path, dataset: Path, sequences: Sequence[str], out: Path, *, threads: int = 1
) -> str:
    """DS-Net inference: official predictions plus the regressed-centre files under ``out``.

    Same as ``panoptic-bench infer --checkpoint C --data D --split 08 --out OUT --threads 1``.
    Returns the method label (``DS-Net`` for a DS-Net checkpoint). One torch thread by default:
    the committed reports then regenerate bit for bit on any machine (float sums do not depend
    on the thread count), and torch's OpenMP threads never compete with numba's threads of the
    dynamic-shifting kernel or with the evaluation workers.
    """
    import torch

    from panoptic_bench.dsnet.inference.run import run_inference

    if threads:
        torch.set_num_threads(threads)
    torch.manual_seed(0)
    summary = run_inference(checkpoint, dataset, ",".join(sequences), out, device="cpu")
    return summary.method


def simulate_semantickitti_centres(
    dataset: Path, sequences: Sequence[str], out: Path, *, seed: int, workers: int = 1
) -> int:
    """Simulated regression (ground-truth semantics, noisy box centres) for SemanticKITTI scans.

    Same as ``panoptic-bench centers simulate --dataset D --sequences 08 --seed S --output OUT``.
    Never a network result. Returns the number of scans.
    """
    from panoptic_bench.baselines.run import simulate_centers_semantickitti

    return simulate_centers_semantickitti(
        dataset, out, seed=seed, sequences=list(sequences), workers=workers
    )


def simulate_nuscenes_centres(
    dataroot: Path,
    eval_set: str,
    out: Path,
    *,
    seed: int,
    workers: int = 1,
    version: str = NUS_VERSION,
) -> int:
    """Simulated regression for the keyframes of ``eval_set`` from their panoptic ground truth.

    Same as ``panoptic-bench centers simulate nuscenes`` (``out/centers/<lidar token>.npz``;
    semantics = ground truth in the challenge classes). Never a network result. Returns the
    number of sweeps.
    """
    from panoptic_bench.baselines.run import simulate_centers_nuscenes

    return simulate_centers_nuscenes(
        dataroot, version, eval_set, out, seed=seed, workers=workers
    )  # fmt: skip


# --------------------------------------------------------------------------- clustering


def cluster_semantickitti_centres(
    dataset: Path,
    centres: Path,
    sequences: Sequence[str],
    out: Path,
    spec: ClusteringSpec,
    *,
    fusion: bool = True,
    workers: int = 1,
) -> int:
    """Cluster regressed centres into SemanticKITTI ``.label`` predictions under ``out``.

    Same as ``panoptic-bench cluster semantickitti --dataset D --centers C --sequences 08
    --output OUT --method ...`` (minimum instance size 50). Returns the number of scans.
    """
    from panoptic_bench.baselines.clustering import MIN_POINTS_SEMANTICKITTI
    from panoptic_bench.baselines.run import AssemblyOptions, cluster_semantickitti

    opts = AssemblyOptions(spec.make(), MIN_POINTS_SEMANTICKITTI, fusion=fusion)
    return cluster_semantickitti(
        dataset, centres, out, opts, sequences=list(sequences), workers=workers
    )


def cluster_nuscenes_centres(
    dataroot: Path,
    eval_set: str,
    centres: Path,
    out: Path,
    spec: ClusteringSpec,
    *,
    workers: int = 1,
    version: str = NUS_VERSION,
) -> int:
    """Cluster regressed centres into Panoptic nuScenes predictions under ``out``.

    Same as ``panoptic-bench cluster nuscenes --dataset D --version v1.0-mini --eval-set
    mini_val --centers C --output OUT --method ...`` (minimum instance size 5).
    """
    from panoptic_bench.baselines.clustering import MIN_POINTS_NUSCENES
    from panoptic_bench.baselines.run import AssemblyOptions, cluster_nuscenes

    opts = AssemblyOptions(spec.make(), MIN_POINTS_NUSCENES)
    return cluster_nuscenes(dataroot, version, eval_set, centres, out, opts, workers=workers)
