"""``panoptic-bench box-merge``: semantic prediction + detector boxes → panoptic (both datasets)."""

from __future__ import annotations

import argparse

from panoptic_bench import cli_args as ca


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``box-merge``."""
    parser = subparsers.add_parser("box-merge", help="box-merge baseline (semantics + 3D boxes)")
    sub = parser.add_subparsers(dest="box_merge_command", metavar="COMMAND", required=True)
    kitti = sub.add_parser(
        "semantickitti",
        help="merge SemanticKITTI semantic predictions with boxes files",
        description="Boxes: BOXES/sequences/XX/boxes/NNNNNN.txt, one box per line "
        "'x y z l w h yaw class score' (LiDAR frame, class = train id or name).",
    )
    kitti.add_argument("--dataset", required=True, help="SemanticKITTI root (velodyne scans)")
    kitti.add_argument(
        "--semantic", required=True, help="prediction root with semantic .label files"
    )
    kitti.add_argument("--boxes", required=True, help="root of the boxes files")
    kitti.add_argument("--mode", choices=["devkit", "paper"], default="paper", help="merge rule")
    ca.add_scan_selection(kitti)
    kitti.add_argument("--output", required=True, help="prediction root to write")
    ca.add_overwrite(kitti, "the --output tree")
    kitti.set_defaults(func=merge_kitti)
    sim = sub.add_parser(
        "simulate-boxes",
        help='write "simulated detector" boxes from SemanticKITTI ground truth',
    )
    sim.add_argument("--dataset", required=True, help="labelled SemanticKITTI root")
    sim.add_argument("--output", required=True, help="boxes root to write")
    ca.add_scan_selection(sim)
    _add_noise_args(sim)
    ca.add_overwrite(sim, "the --output tree")
    sim.set_defaults(func=simulate_boxes)
    _register_nuscenes(sub)


def _add_noise_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seed", type=ca.seed, default=0, help="random seed (default 0)")
    p.add_argument(
        "--miss-rate", type=ca.probability, default=0.1, help="probability a GT box is missed"
    )
    p.add_argument(
        "--fp-rate", type=ca.float_range(0.0, 100.0), default=0.2, help="false positives per GT box"
    )
    p.add_argument(
        "--position-sigma", type=ca.float_range(0.0, 100.0), default=0.2, help="centre jitter (m)"
    )
    p.add_argument(
        "--size-sigma", type=ca.float_range(0.0, 10.0), default=0.1, help="relative size jitter"
    )
    p.add_argument(
        "--yaw-sigma", type=ca.float_range(0.0, 10.0), default=0.05, help="yaw jitter (rad)"
    )


def _add_nuscenes_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--dataset", "--dataroot", dest="dataset", required=True, help="nuScenes dataroot"
    )
    p.add_argument("--version", required=True, help="e.g. v1.0-mini")
    p.add_argument("--eval-set", required=True, help="devkit split: mini_val, val, ...")
    p.add_argument(
        "--task", choices=["detection", "tracking"], default="detection",
        help="submission kind: detection (ids = score rank) or tracking (ids = track ids)",
    )  # fmt: skip


def _register_nuscenes(sub: argparse._SubParsersAction) -> None:
    nus = sub.add_parser(
        "nuscenes",
        help="merge nuScenes lidarseg predictions with a detection/tracking submission JSON",
        description="Semantic: SEMANTIC/lidarseg/<version suffix or eval-set>/<lidar token>"
        "_lidarseg.bin (uint8 challenge classes 0..16). Boxes: standard nuScenes detection or "
        "tracking submission JSON. Writes OUTPUT/panoptic/<eval-set>/<token>_panoptic.npz, "
        "scorable by 'panoptic-bench eval nuscenes'. --mode devkit reproduces nuscenes-devkit "
        "get_panoptic_from_seg_det_or_track.py exactly; --mode paper gives every point in a box "
        "the box's class and instance.",
    )
    _add_nuscenes_args(nus)
    nus.add_argument("--semantic", required=True, help="root holding lidarseg/<...>/*.bin")
    nus.add_argument("--boxes", required=True, help="detection or tracking submission JSON")
    nus.add_argument("--mode", choices=["devkit", "paper"], default="paper", help="merge rule")
    nus.add_argument("--output", required=True, help="prediction root to write")
    ca.add_overwrite(nus, "the --output tree")
    nus.set_defaults(func=merge_nuscenes)
    sim = sub.add_parser(
        "simulate-nuscenes",
        help='write a "simulated detector" nuScenes submission JSON from ground-truth boxes',
        description="GT boxes of the eval set with centre/size/yaw jitter, misses and false "
        "positives; meta.source = 'simulated detector' (never a detector result).",
    )
    _add_nuscenes_args(sim)
    _add_noise_args(sim)
    sim.add_argument("--output", required=True, help="submission JSON to write")
    ca.add_overwrite(sim, "the --output file")
    sim.set_defaults(func=simulate_nuscenes)


def merge_kitti(args: argparse.Namespace) -> int:
    """Handler of ``box-merge semantickitti``."""
    from panoptic_bench.baselines.box_merge import MergeMode, box_merge_semantickitti
    from panoptic_bench.io import output_tree

    seqs = ca.selected_sequences(args.split, args.sequences)
    inputs = (args.dataset, args.semantic, args.boxes)
    with output_tree(args.output, overwrite=args.overwrite, inputs=inputs) as tmp:
        n = box_merge_semantickitti(
            args.dataset, args.semantic, args.boxes, tmp, MergeMode(args.mode), sequences=seqs
        )
    print(f"box-merge ({args.mode}): wrote {n} predictions under {args.output}/sequences")
    return 0


def simulate_boxes(args: argparse.Namespace) -> int:
    """Handler of ``box-merge simulate-boxes``."""
    from panoptic_bench.baselines.box_merge import DetectorNoise, simulate_boxes_semantickitti
    from panoptic_bench.io import output_tree

    noise = DetectorNoise(
        args.position_sigma, args.size_sigma, args.yaw_sigma, args.miss_rate, args.fp_rate
    )
    seqs = ca.selected_sequences(args.split, args.sequences)
    with output_tree(args.output, overwrite=args.overwrite, inputs=(args.dataset,)) as tmp:
        n = simulate_boxes_semantickitti(
            args.dataset, tmp, noise=noise, seed=args.seed, sequences=seqs
        )
    out = args.output
    print(f"wrote {n} simulated-detector boxes files under {out}/sequences (not a detector result)")
    return 0


def merge_nuscenes(args: argparse.Namespace) -> int:
    """Handler of ``box-merge nuscenes``."""
    from panoptic_bench.baselines.box_merge import MergeMode
    from panoptic_bench.baselines.box_merge_nuscenes import BoxTask, box_merge_nuscenes
    from panoptic_bench.io import output_tree

    inputs = (args.dataset, args.semantic, args.boxes)
    with output_tree(args.output, overwrite=args.overwrite, inputs=inputs) as tmp:
        n = box_merge_nuscenes(
            args.dataset, args.version, args.eval_set, args.semantic, args.boxes, tmp,
            MergeMode(args.mode), task=BoxTask(args.task),
        )  # fmt: skip
    out = args.output
    print(f"box-merge ({args.mode}): wrote {n} predictions under {out}/panoptic/{args.eval_set}")
    return 0


def simulate_nuscenes(args: argparse.Namespace) -> int:
    """Handler of ``box-merge simulate-nuscenes``."""
    from pathlib import Path

    from panoptic_bench.baselines.box_merge import DetectorNoise
    from panoptic_bench.baselines.box_merge_nuscenes import BoxTask
    from panoptic_bench.baselines.simulated_detector_nuscenes import (
        write_simulated_submission_nuscenes,
    )
    from panoptic_bench.io import check_output_file

    noise = DetectorNoise(
        args.position_sigma, args.size_sigma, args.yaw_sigma, args.miss_rate, args.fp_rate
    )
    check_output_file(args.output, overwrite=args.overwrite, inputs=(args.dataset,))
    out = Path(args.output).resolve()
    n = write_simulated_submission_nuscenes(
        args.dataset, args.version, args.eval_set, out, noise=noise, seed=args.seed,
        task=BoxTask(args.task),
    )  # fmt: skip
    print(f"wrote {n} simulated-detector boxes to {out} (not a detector result)")
    return 0
