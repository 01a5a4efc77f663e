"""``panoptic-bench eval breakdown``: one true class's predictions, bin by bin of a point quantity."""

from __future__ import annotations

import argparse
import math

from panoptic_bench import cli_args as ca


def _numbers(text: str) -> tuple[float, ...]:
    """An argparse ``type``: comma-separated finite numbers (negative allowed)."""
    try:
        out = tuple(float(e) for e in text.split(",") if e.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected numbers like 0,0.1,0.5; got {text!r}") from None
    if not out or not all(math.isfinite(v) for v in out):
        raise argparse.ArgumentTypeError(f"expected finite numbers like 0,0.1,0.5; got {text!r}")
    return out


def _pair(text: str) -> tuple[float, float]:
    """An argparse ``type`` for ``MIN,MAX`` metres."""
    v = _numbers(text)
    if len(v) != 2 or not (0 <= v[0] < v[1]):
        raise argparse.ArgumentTypeError(f"expected MIN,MAX with 0 <= MIN < MAX; got {text!r}")
    return v[0], v[1]


def add_parser(eval_subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add ``breakdown`` to the sub-commands of ``eval``."""
    from panoptic_bench.commands.semantickitti import add_dataset_arguments
    from panoptic_bench.metrics.point_features import FEATURES

    p = eval_subparsers.add_parser(
        "breakdown",
        help="which points of one true class go where: its predicted classes by range, height "
        "above the road, roughness or remission",
        description=(
            "For the points of one true class of a SemanticKITTI tree, count their predicted "
            "classes separately in bins of a per-point quantity: range (m), height above the "
            "plane of the scan's true road points within 20 m (m), roughness (|second height "
            "difference| to the ring neighbours within 0.5 m, m) or remission. Labels are mapped "
            "and checked as 'eval semantickitti' maps them, so the bins of a quantity every point "
            "has add up to the true class's row of its confusion matrix. Prints the table and "
            "writes breakdown.csv (counts of every class), breakdown.txt and breakdown.png."
        ),
    )
    add_dataset_arguments(p)
    p.add_argument("--class", dest="true_class", required=True, help="true class, e.g. terrain")
    p.add_argument("--by", choices=FEATURES, required=True, help="the binned quantity")
    p.add_argument(
        "--edges",
        type=_numbers,
        default=None,
        help="bin edges, comma-separated and increasing; write --edges=-1,0,1 for negative ones "
        "(default: a set per quantity)",
    )
    p.add_argument(
        "--within",
        type=_pair,
        default=None,
        metavar="MIN,MAX",
        help="only points whose range (m) lies in [MIN, MAX)",
    )
    p.add_argument("--top", type=ca.int_range(1, 19), default=6, help="classes shown (default 6)")
    p.add_argument("--output", required=True, help="output directory (not inside the inputs)")
    ca.add_overwrite(p, "the --output directory")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_breakdown)
    return p


def run_breakdown(args: argparse.Namespace) -> int:
    """Handler of ``eval breakdown``."""
    from panoptic_bench.evaluation.breakdown import breakdown_semantickitti, write_breakdown
    from panoptic_bench.io import check_output_dir, output_tree

    inputs = (args.dataset, args.predictions)
    check_output_dir(args.output, overwrite=args.overwrite, inputs=inputs)
    b = breakdown_semantickitti(
        args.dataset,
        args.predictions,
        true_class=args.true_class,
        feature=args.by,
        edges=args.edges,
        split=args.split,
        sequences=args.sequences,
        within=args.within,
        progress=False if args.no_progress else None,
    )
    with output_tree(args.output, overwrite=args.overwrite, inputs=inputs) as tmp:
        text = write_breakdown(tmp, b, args.top)
    print(text, end="")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Nothing to add at the top level: ``commands/eval.py`` calls :func:`add_parser`."""
