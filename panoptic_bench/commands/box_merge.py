"""``panoptic-bench box-merge``: semantic prediction + detector boxes → panoptic (SemanticKITTI)."""

from __future__ import annotations

import argparse


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
    kitti.add_argument("--sequences", nargs="+", help="explicit sequences, e.g. 08")
    kitti.add_argument("--output", required=True, help="prediction root to write")
    kitti.set_defaults(func=merge_kitti)
    sim = sub.add_parser(
        "simulate-boxes",
        help='write "simulated detector" boxes from SemanticKITTI ground truth',
    )
    sim.add_argument("--dataset", required=True, help="labelled SemanticKITTI root")
    sim.add_argument("--output", required=True, help="boxes root to write")
    sim.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    sim.add_argument("--sequences", nargs="+", help="explicit sequences, e.g. 08")
    sim.add_argument("--miss-rate", type=float, default=0.1, help="probability a GT box is missed")
    sim.add_argument("--fp-rate", type=float, default=0.2, help="false positives per GT box")
    sim.add_argument("--position-sigma", type=float, default=0.2, help="centre jitter (m)")
    sim.add_argument("--size-sigma", type=float, default=0.1, help="relative size jitter")
    sim.add_argument("--yaw-sigma", type=float, default=0.05, help="yaw jitter (rad)")
    sim.set_defaults(func=simulate_boxes)


def merge_kitti(args: argparse.Namespace) -> int:
    """Handler of ``box-merge semantickitti``."""
    from panoptic_bench.baselines.box_merge import MergeMode, box_merge_semantickitti
    from panoptic_bench.io import ensure_output_dir

    out = ensure_output_dir(args.output, inputs=(args.dataset, args.semantic, args.boxes))
    n = box_merge_semantickitti(
        args.dataset, args.semantic, args.boxes, out, MergeMode(args.mode), sequences=args.sequences
    )
    print(f"box-merge ({args.mode}): wrote {n} predictions under {out}/sequences")
    return 0


def simulate_boxes(args: argparse.Namespace) -> int:
    """Handler of ``box-merge simulate-boxes``."""
    from panoptic_bench.baselines.box_merge import DetectorNoise, simulate_boxes_semantickitti
    from panoptic_bench.io import ensure_output_dir

    noise = DetectorNoise(
        args.position_sigma, args.size_sigma, args.yaw_sigma, args.miss_rate, args.fp_rate
    )
    out = ensure_output_dir(args.output, inputs=(args.dataset,))
    n = simulate_boxes_semantickitti(
        args.dataset, out, noise=noise, seed=args.seed, sequences=args.sequences
    )
    print(f"wrote {n} simulated-detector boxes files under {out}/sequences (not a detector result)")
    return 0
