"""``panoptic-bench validate semantickitti|nuscenes``: list every problem of a prediction tree."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``validate`` group with its ``semantickitti`` target."""
    from panoptic_bench.commands.semantickitti import add_dataset_arguments

    parser = subparsers.add_parser("validate", help="check predictions before scoring them")
    sub = parser.add_subparsers(dest="validate_target", metavar="TARGET", required=True)
    p = sub.add_parser(
        "semantickitti",
        help="check a SemanticKITTI prediction tree against the dataset",
        description=(
            "Every scan of the split must have a prediction with one uint32 label per point and "
            "known raw ids; no extra files. Lists every problem found; exit status 2 if any."
        ),
    )
    add_dataset_arguments(p)
    p.set_defaults(func=run)
    n = sub.add_parser(
        "nuscenes",
        help="check a Panoptic nuScenes submission folder",
        description=(
            "Every sample of the eval set must have RES/panoptic/<eval-set>/<token>_panoptic.npz "
            "(key 'data', uint16, one label per point of the sweep, classes 0-16, instance ids "
            "only on thing classes 1-10), no extra files, and RES/<eval-set>/submission.json its "
            "meta fields (task, use_camera, use_lidar, use_radar, use_map, use_external). Lists "
            "every problem found; exit status 2 if any."
        ),
    )
    n.add_argument("--dataroot", required=True, help="nuScenes dataroot (tables and sweeps)")
    n.add_argument("--version", required=True, help="e.g. v1.0-mini, v1.0-trainval, v1.0-test")
    n.add_argument("--result-path", required=True, help="submission folder RES")
    n.add_argument("--eval-set", required=True, help="devkit split: mini_val, val, test, ...")
    n.set_defaults(func=run_nuscenes)


def run(args: argparse.Namespace) -> int:
    """Handler of ``validate semantickitti``."""
    from panoptic_bench.errors import InputErrors
    from panoptic_bench.evaluation.semantickitti_tools import validate_semantickitti

    n, problems = validate_semantickitti(
        args.dataset, args.predictions, split=args.split, sequences=args.sequences
    )
    if problems:
        raise InputErrors(problems, header=f"validation of {n} scans found problems")
    print(f"OK: {n} scans, every prediction present with one valid label per point")
    return 0


def run_nuscenes(args: argparse.Namespace) -> int:
    """Handler of ``validate nuscenes``."""
    from panoptic_bench.errors import InputErrors
    from panoptic_bench.evaluation.nuscenes_validate import validate_nuscenes

    n, problems = validate_nuscenes(args.dataroot, args.version, args.result_path, args.eval_set)
    if problems:
        raise InputErrors(problems, header=f"validation of {n} samples found problems")
    print(f"OK: {n} samples of {args.eval_set}, every prediction present and valid")
    return 0
