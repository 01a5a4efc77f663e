"""``run_real_scans``: the demo's SemanticKITTI methods on real labelled scans.

``make report`` builds the committed real-scan report sets with it: DS-Net with a checkpoint
(by default the shipped real-data model ``dsnet_semantickitti_cpu.pt``, else the synthetic
one), the four clusterings on its centres with and without consensus fusion, box-merge, and one
DS-Net row per sequence when several are scored; or the simulated regression without a
checkpoint.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

from panoptic_bench.demo import steps
from panoptic_bench.demo.kitti import (
    DSNET_CHECKPOINT,
    REAL_CHECKPOINT,
    DemoResult,
    KittiTarget,
    run_kitti_methods,
)
from panoptic_bench.demo.pipeline import drop_unreported_files, prepare_workspace
from panoptic_bench.demo.summary import Stages, summary_table
from panoptic_bench.errors import InputError, InputErrors

__all__ = ["default_real_checkpoint", "real_target", "run_real_scans"]


def real_target(
    root: str | Path,
    *,
    seed: int = 0,
    sequences: tuple[str, ...] | None = None,
    checkpoint: Path | None = None,
) -> KittiTarget:
    """The labelled scans of a SemanticKITTI root, as a :class:`KittiTarget` (prefix ``real``).

    Parameters
    ----------
    sequences : tuple of str, optional
        Only these sequences (default: every sequence under ``root``).
    checkpoint : Path, optional
        DS-Net checkpoint of the DS-Net row (see :func:`default_real_checkpoint`).

    Raises
    ------
    InputError
        No scans, or scans without their ``labels/NNNNNN.label``.
    """
    from panoptic_bench.datasets.semantickitti import LABELS, list_scans

    refs = list_scans(root, sequences=list(sequences) if sequences else None)
    missing = [f"{r.label}: label file missing" for r in refs if not r.label.is_file()]
    if missing:
        raise InputErrors(missing, header="--real-scans needs labelled scans")
    seqs = tuple(dict.fromkeys(r.sequence for r in refs))
    split = "val" if all(int(s) in LABELS.splits["valid"] for s in seqs) else "train"
    data = f"{len(refs)} real SemanticKITTI scans, seq {', '.join(seqs)}"
    return KittiTarget(
        Path(root), seqs, data, "real", seed, min(len(refs), 5), split, checkpoint, len(seqs) > 1
    )


def default_real_checkpoint() -> Path | None:
    """The shipped real-data DS-Net checkpoint, else the synthetic one, else None."""
    return steps.find_checkpoint(REAL_CHECKPOINT) or steps.find_checkpoint(DSNET_CHECKPOINT)


def run_real_scans(
    root: str | Path,
    out: str | Path,
    *,
    workers: int = 1,
    keep_work: bool = False,
    use_checkpoint: bool = True,
    command: str | None = None,
    seed: int = 0,
    checkpoint: str | Path | None = None,
    sequences: tuple[str, ...] | None = None,
) -> DemoResult:
    """Run the SemanticKITTI methods on the labelled scans under ``root``; report into ``out``.

    Parameters
    ----------
    root : str or Path
        SemanticKITTI root with ``sequences/XX/{velodyne,labels}`` (read only).
    out : str or Path
        Report directory (``index.md``, ``tables/``, ``figures/``, ``runs/real-*``).
    workers : int
        Worker processes.
    keep_work : bool
        Keep centres and predictions in ``out/work``. False (default): a temporary directory,
        deleted at the end, and ``bev.npz`` (real points) removed once drawn.
    use_checkpoint : bool
        Add DS-Net (and the clusterings on its centres); False: simulated regression only.
    command : str, optional
        Command line recorded in ``index.md``.
    seed : int
        Seed of the simulated regression.
    checkpoint : str or Path, optional
        DS-Net checkpoint (a path); default :func:`default_real_checkpoint`.
    sequences : tuple of str, optional
        Score only these sequences of ``root``.

    Returns
    -------
    DemoResult
    """
    from panoptic_bench.reports.index import build_report

    if not Path(root).is_dir():
        raise InputError("real-scan root not found; pass a SemanticKITTI root", root)
    ckpt = Path(checkpoint) if checkpoint else default_real_checkpoint()
    if checkpoint and not ckpt.is_file():
        raise InputError("checkpoint not found", ckpt)
    target = real_target(root, seed=seed, sequences=sequences, checkpoint=ckpt)
    tmp = None if keep_work else tempfile.mkdtemp(prefix="panoptic-bench-real-")
    ws = prepare_workspace(out, tmp)
    result = DemoResult(ws.out / "index.md", [])
    stages = Stages()
    t0 = time.perf_counter()
    try:
        run_kitti_methods(ws, target, stages, result, workers, use_checkpoint)
        with stages("report: tables, figures, index.md"):
            build_report(result.runs, ws.out, command=command)
        if not keep_work:
            drop_unreported_files(result.runs)
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    result.summary = summary_table(result.runs, time.perf_counter() - t0)
    return result
