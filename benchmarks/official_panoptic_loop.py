"""The official SemanticKITTI single-scan evaluation loop, as a process of its own.

What semantic-kitti-api ``evaluate_panoptic.py`` does, step by step, with the same evaluator
algorithm (nuscenes-devkit ships it as ``PanopticEval``): load the label config, build the
``learning_map`` lookup table, list the label and prediction files of the split, and for every
scan read both files, remap to train ids, ``addBatch`` with the full label as instance id; then
``getPQ`` / ``getSemIoU`` and write ``scores.txt``. Used by ``bench_eval_process.py`` as the
reference process. Usage::

    python official_panoptic_loop.py --dataset D --predictions P --data_cfg CFG [--sequences 08]
        [--min_inst_points 50] --output OUT
"""

from __future__ import annotations

import argparse
import importlib.util
import os

import numpy as np
import yaml


def _panoptic_eval_class():
    """The devkit's ``PanopticEval`` loaded from its file alone: the official tool imports only
    its own ``eval_np`` (numpy), not the whole nuScenes devkit package."""
    pkg = importlib.util.find_spec("nuscenes")
    path = os.path.join(
        os.path.dirname(pkg.origin), "eval", "panoptic", "panoptic_seg_evaluator.py"
    )
    spec = importlib.util.spec_from_file_location("official_eval_np", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.PanopticEval


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--dataset", required=True)
    ap.add_argument("--predictions", required=True)
    ap.add_argument("--data_cfg", required=True)
    ap.add_argument("--sequences", default="08")
    ap.add_argument("--min_inst_points", type=int, default=50)
    ap.add_argument("--output", required=True)
    args = ap.parse_args()
    with open(args.data_cfg) as fh:
        cfg = yaml.safe_load(fh)
    remap = cfg["learning_map"]
    lut = np.zeros(max(remap) + 100, dtype=np.int32)
    lut[list(remap)] = list(remap.values())
    ignore = [c for c, ign in cfg["learning_ignore"].items() if ign]
    ev = _panoptic_eval_class()(
        len(cfg["learning_map_inv"]), ignore=ignore, min_points=args.min_inst_points
    )
    labels, preds = [], []
    for seq in args.sequences.split(","):
        seq = f"{int(seq):02d}"
        ldir = os.path.join(args.dataset, "sequences", seq, "labels")
        pdir = os.path.join(args.predictions, "sequences", seq, "predictions")
        labels += sorted(os.path.join(ldir, f) for f in os.listdir(ldir) if f.endswith(".label"))
        preds += sorted(os.path.join(pdir, f) for f in os.listdir(pdir) if f.endswith(".label"))
    assert len(labels) == len(preds)
    for lf, pf in zip(labels, preds):
        gt = np.fromfile(lf, dtype=np.uint32)
        pr = np.fromfile(pf, dtype=np.uint32)
        ev.addBatch(lut[pr & 0xFFFF], pr, lut[gt & 0xFFFF], gt)
    pq, sq, rq, _, _, _ = ev.getPQ()
    miou, _ = ev.getSemIoU()
    os.makedirs(args.output, exist_ok=True)
    with open(os.path.join(args.output, "scores.txt"), "w") as fh:
        yaml.safe_dump({"pq_mean": float(pq), "sq_mean": float(sq), "rq_mean": float(rq),
                        "iou_mean": float(miou)}, fh)  # fmt: skip


if __name__ == "__main__":
    main()
