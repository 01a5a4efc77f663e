"""Figure inputs the demo leaves in run directories: ``bev.npz`` and ``analysis.json``.

- :func:`write_bev_scan`: one scan's prediction and ground truth for the bird's-eye view;
- :func:`centres_per_voxel` (Fig. 3a): regressed centres per valid instance voxel vs distance;
- :func:`bandwidth_rq` (Fig. 3b): RQ of each things class vs the mean-shift bandwidth, from the
  same regressed centres.

Each reads the files of a SemanticKITTI dataset / centre / prediction tree.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tqdm import tqdm

__all__ = [
    "BEV_HALF_WIDTH_M",
    "FIG3A_EDGES",
    "FIG3B_BANDWIDTHS",
    "bandwidth_rq",
    "centres_per_voxel",
    "write_bev_scan",
]

#: Half side of the square crop of the bird's-eye view (m), and every k-th point kept.
BEV_HALF_WIDTH_M = 40.0
BEV_STRIDE = 2
#: Distance bins (m) of Fig. 3a.
FIG3A_EDGES = (0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0)
#: Mean-shift bandwidths (m) of Fig. 3b.
FIG3B_BANDWIDTHS = (0.4, 0.8, 1.2, 1.6, 2.0, 2.8, 3.6)


def _refs(dataset: Path, sequences: Sequence[str]):
    from panoptic_bench.datasets.semantickitti import list_scans

    return list_scans(dataset, split=None, sequences=list(sequences))


def write_bev_scan(run_dir: Path, scan: Path, label: Path, prediction: Path) -> Path:
    """Write ``run_dir/bev.npz`` for one scan, cropped to +-40 m and thinned to every 2nd point.

    Parameters
    ----------
    run_dir : Path
        Run directory.
    scan, label, prediction : Path
        The scan ``.bin``, its ground-truth ``.label`` and the predicted ``.label``.

    Returns
    -------
    Path
        The written file.
    """
    from panoptic_bench.datasets.semantickitti import LABELS, read_labels, read_scan, to_train
    from panoptic_bench.reports.inputs import write_bev

    xyz = read_scan(scan)[:, :3]
    gt, pred = read_labels(label), read_labels(prediction)
    keep = np.flatnonzero((np.abs(xyz[:, :2]) <= BEV_HALF_WIDTH_M).all(axis=1))[::BEV_STRIDE]
    return write_bev(
        run_dir,
        xyz[keep],
        to_train(pred[keep]),
        pred[keep] >> 16,
        to_train(gt[keep]),
        gt[keep] >> 16,
        LABELS.thing_ids,
    )


def _things_scan(ref, centres_root: Path):
    """Points, regressed centres, train ids and full labels of one scan's ground-truth things."""
    from panoptic_bench.baselines.centers import centers_path_semantickitti, read_centers
    from panoptic_bench.datasets.semantickitti import LABELS, read_labels, read_scan, to_train

    points = read_scan(ref.scan)
    gt = read_labels(ref.label)
    c = read_centers(centers_path_semantickitti(centres_root, ref.sequence, ref.frame))
    sem = to_train(gt)
    return points, c, sem, gt, np.isin(sem, LABELS.thing_ids)


def centres_per_voxel(
    dataset: Path, centres_root: Path, sequences: Sequence[str]
) -> dict[str, list[float]]:
    """Fig. 3a input: mean regressed centres per valid 0.2 m voxel of an instance, by distance.

    Ground-truth things instances of every scan are pooled (instance keys made unique per scan).

    Returns
    -------
    dict
        ``{"distance_m": bin centres, "counts": values}`` (NaN for empty bins), the
        ``centres_per_voxel`` section of ``analysis.json``.
    """
    from panoptic_bench.reports.inputs import centres_per_voxel_by_distance

    parts = []
    for k, ref in enumerate(_refs(dataset, sequences)):
        points, c, _, gt, things = _things_scan(ref, centres_root)
        things &= (gt >> 16) > 0
        xyz = points[things, :3].astype(np.float64)
        key = (np.int64(k) << 32) | gt[things].astype(np.int64)
        parts.append((xyz + c.offset[things], key, np.linalg.norm(xyz[:, :2], axis=1)))
    centres, key, dist = (np.concatenate(p) for p in zip(*parts))
    values = centres_per_voxel_by_distance(centres, key, dist, FIG3A_EDGES)
    mids = [(lo + hi) / 2 for lo, hi in zip(FIG3A_EDGES[:-1], FIG3A_EDGES[1:])]
    return {"distance_m": mids, "counts": [float(v) for v in values]}


def bandwidth_rq(
    dataset: Path,
    centres_root: Path,
    sequences: Sequence[str],
    *,
    max_scans: int,
    bandwidths: Sequence[float] = FIG3B_BANDWIDTHS,
) -> dict[str, object]:
    """Fig. 3b input: RQ per things class for mean shift at each bandwidth, same centres.

    Mean shift (bin seeding) + consensus fusion on the first ``max_scans`` scans; scored with
    the SemanticKITTI evaluator's kernel (minimum 50 points). Classes without ground-truth
    instances are left out.

    Returns
    -------
    dict
        ``{"bandwidth_m": [...], "rq": {class: [fraction per bandwidth]}}``, the
        ``bandwidth_rq`` section of ``analysis.json``.
    """
    from panoptic_bench.baselines.clustering import MIN_POINTS_SEMANTICKITTI, MeanShift
    from panoptic_bench.baselines.panoptic import assemble_panoptic, semantickitti_label
    from panoptic_bench.datasets.semantickitti import LABELS
    from panoptic_bench.evaluation.semantickitti import label_stats

    refs = _refs(dataset, sequences)[:max_scans]
    totals = [None] * len(bandwidths)
    for ref in tqdm(refs, desc="bandwidth sweep", unit="scan", disable=None):
        points, c, _, gt, _ = _things_scan(ref, centres_root)
        for i, bw in enumerate(bandwidths):
            sem, inst = assemble_panoptic(
                points, c.sem, c.offset, MeanShift(bw, bin_seeding=True),
                thing_ids=LABELS.thing_ids, min_points=MIN_POINTS_SEMANTICKITTI,
                num_classes=LABELS.num_classes,
            )  # fmt: skip
            stats, _ = label_stats(semantickitti_label(sem, inst), gt)
            totals[i] = stats if totals[i] is None else totals[i] + stats
    present = [c for c in LABELS.thing_ids if totals[0].tp[c] + totals[0].fn[c] > 0]
    results = [t.compute() for t in totals]
    rq = {LABELS.class_names[c]: [float(r.rq[c]) for r in results] for c in present}
    return {"bandwidth_m": [float(b) for b in bandwidths], "rq": rq}
