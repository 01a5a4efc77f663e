"""``panoptic-bench nuscenes ...``: nuScenes tools (panoptic label generation)."""

from __future__ import annotations

import argparse

from panoptic_bench import cli_args as ca


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
    labels.add_argument(
        "--out-dir",
        required=True,
        help="output root: the dataroot itself or a directory outside it",
    )
    labels.add_argument(
        "--workers", type=ca.workers, default=1, help="worker processes (default 1)"
    )
    ca.add_overwrite(labels, "existing panoptic/<version> labels")
    labels.set_defaults(func=make_labels)


def make_labels(args: argparse.Namespace) -> int:
    """Handler of ``nuscenes make-labels``."""
    from pathlib import Path

    from panoptic_bench.datasets.nuscenes_panoptic import make_panoptic_labels
    from panoptic_bench.errors import InputError

    root, out = Path(args.dataroot).resolve(), Path(args.out_dir).resolve()
    if root in out.parents:
        raise InputError(
            "--out-dir lies inside the dataroot; use the dataroot itself or a directory outside it",
            args.out_dir,
        )
    labels = out / "panoptic" / args.version
    existing = labels.is_dir() and any(labels.iterdir())
    if not args.overwrite and (existing or (out / args.version / "panoptic.json").exists()):
        raise InputError("panoptic labels exist already; pass --overwrite to replace them", labels)
    rows = make_panoptic_labels(args.dataroot, args.version, args.out_dir, workers=args.workers)
    print(f"wrote {len(rows)} panoptic label files to {args.out_dir}/panoptic/{args.version}")
    return 0
