"""Box-merge steps of the demo: the same semantics as the clusterings + a *simulated detector*.

The semantic prediction is the ``sem`` of the regressed-centre files (ground truth under the
simulated regression, the backbone's prediction under DS-Net), written as an ordinary semantic
prediction tree; boxes come from the baselines' simulated detector (ground-truth boxes with
jitter, misses and false positives; never a detector result); the merge follows the paper's
rule (DS-Net §4.3, :class:`~panoptic_bench.baselines.box_merge.MergeMode` ``PAPER``).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tqdm import tqdm

__all__ = [
    "BOX_MERGE_NOTE",
    "box_merge_nuscenes_run",
    "box_merge_semantickitti_run",
    "semantic_tree_nuscenes",
    "semantic_tree_semantickitti",
]

BOX_MERGE_NOTE = (
    "box-merge, paper rule (DS-Net §4.3); boxes from the simulated detector (ground-truth boxes "
    "with jitter, 10% misses, 0.2 false positives per box; panoptic_bench.baselines.box_merge, "
    "seed {seed}), not a detector result; semantics: {semantics}"
)


def semantic_tree_semantickitti(
    dataset: Path, centres: Path, sequences: Sequence[str], out: Path
) -> int:
    """Write the ``sem`` of each centre file as a semantic ``.label`` prediction (instance 0)."""
    from panoptic_bench.baselines.centers import centers_path_semantickitti, read_centers
    from panoptic_bench.baselines.panoptic import semantickitti_label
    from panoptic_bench.datasets.semantickitti import list_scans, prediction_path, write_labels

    refs = list_scans(dataset, split=None, sequences=list(sequences))
    for ref in tqdm(refs, desc="semantic labels", unit="scan", disable=None):
        c = read_centers(centers_path_semantickitti(centres, ref.sequence, ref.frame))
        write_labels(prediction_path(out, ref), semantickitti_label(c.sem, np.zeros_like(c.sem)))
    return len(refs)


def box_merge_semantickitti_run(
    dataset: Path,
    centres: Path,
    sequences: Sequence[str],
    work: Path,
    out: Path,
    *,
    seed: int,
) -> int:
    """Semantics from ``centres`` + simulated-detector boxes → merged predictions under ``out``.

    Same as ``panoptic-bench box-merge simulate-boxes --dataset D --sequences 08 --seed S
    --output WORK/boxes`` then ``panoptic-bench box-merge semantickitti --dataset D --semantic
    WORK/semantic --boxes WORK/boxes --mode paper --sequences 08 --output OUT``.
    """
    from panoptic_bench.baselines.box_merge import (
        MergeMode,
        box_merge_semantickitti,
        simulate_boxes_semantickitti,
    )

    semantic, boxes = work / "semantic", work / "boxes"
    semantic_tree_semantickitti(dataset, centres, sequences, semantic)
    simulate_boxes_semantickitti(dataset, boxes, seed=seed, sequences=list(sequences))
    return box_merge_semantickitti(
        dataset, semantic, boxes, out, MergeMode.PAPER, sequences=list(sequences)
    )


def semantic_tree_nuscenes(
    dataroot: Path, version: str, eval_set: str, centres: Path, out: Path
) -> int:
    """Write the ``sem`` of each centre file as ``out/lidarseg/<version suffix>/<token>_lidarseg.bin``."""
    from panoptic_bench.baselines.centers import centers_path_nuscenes, read_centers
    from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar
    from panoptic_bench.io import write_array

    tokens = NuScenesLidar(dataroot, version).sample_data_tokens(eval_set)
    folder = out / "lidarseg" / version.split("-")[-1]
    for tok in tqdm(tokens, desc="lidarseg labels", unit="sweep", disable=None):
        c = read_centers(centers_path_nuscenes(centres, tok))
        write_array(folder / f"{tok}_lidarseg.bin", c.sem.astype(np.uint8))
    return len(tokens)


def box_merge_nuscenes_run(
    dataroot: Path,
    version: str,
    eval_set: str,
    centres: Path,
    work: Path,
    out: Path,
    *,
    seed: int,
) -> int:
    """Semantics from ``centres`` + a simulated-detector submission → Panoptic nuScenes files.

    Same as ``panoptic-bench box-merge simulate-nuscenes ... --seed S --output WORK/boxes.json``
    then ``panoptic-bench box-merge nuscenes ... --semantic WORK/semantic --boxes
    WORK/boxes.json --mode paper --output OUT``.
    """
    from panoptic_bench.baselines.box_merge import MergeMode
    from panoptic_bench.baselines.box_merge_nuscenes import box_merge_nuscenes
    from panoptic_bench.baselines.simulated_detector_nuscenes import (
        write_simulated_submission_nuscenes,
    )

    semantic, boxes = work / "semantic", work / "boxes.json"
    semantic_tree_nuscenes(dataroot, version, eval_set, centres, semantic)
    write_simulated_submission_nuscenes(dataroot, version, eval_set, boxes, seed=seed)
    return box_merge_nuscenes(
        dataroot, version, eval_set, semantic, boxes, out, MergeMode.PAPER
    )  # fmt: skip
