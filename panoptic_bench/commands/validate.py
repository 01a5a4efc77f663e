"""``panoptic-bench validate semantickitti``: list every problem of a prediction tree."""

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
