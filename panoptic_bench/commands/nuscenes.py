"""``panoptic-bench nuscenes ...``: nuScenes tools (panoptic label generation)."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``nuscenes`` command group."""
    parser = subparsers.add_parser("nuscenes", help="nuScenes tools: panoptic label generation")
    sub = parser.add_subparsers(dest="nuscenes_command", metavar="SUBCOMMAND", required=True)
    labels = sub.add_parser(
        "make-labels",
        help="Panoptic nuScenes labels from lidarseg + boxes (byte-identical to the devkit)",
        description=(
            "Write panoptic/<version>/<token>_panoptic.npz, <version>/panoptic.json and "
            "<version>/category.json under --out-dir, exactly as the devkit's "
            "generate_panoptic_labels does. The dataroot is only read."
        ),
    )
    labels.add_argument("--dataroot", required=True, help="nuScenes dataroot with lidarseg")
    labels.add_argument("--version", required=True, help="e.g. v1.0-mini, v1.0-trainval")
    labels.add_argument("--out-dir", required=True, help="output root (may be the dataroot itself)")
    labels.add_argument("--workers", type=int, default=1, help="worker processes (default 1)")
    labels.set_defaults(func=make_labels)


def make_labels(args: argparse.Namespace) -> int:
    """Handler of ``nuscenes make-labels``."""
    from panoptic_bench.datasets.nuscenes_panoptic import make_panoptic_labels

    rows = make_panoptic_labels(args.dataroot, args.version, args.out_dir, workers=args.workers)
    print(f"wrote {len(rows)} panoptic label files to {args.out_dir}/panoptic/{args.version}")
    return 0
