"""``panoptic-bench eval compare A B``: paired bootstrap of two scored prediction sets."""

from __future__ import annotations

import argparse

from panoptic_bench import cli_args as ca


def add_parser(eval_subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add ``compare`` to the sub-commands of ``eval``."""
    p = eval_subparsers.add_parser(
        "compare",
        help="is B better than A? paired bootstrap over the scans of two eval outputs",
        description=(
            "Compare two outputs of 'eval semantickitti' on the same scans: the difference "
            "B - A of every headline metric, its percentile interval from a paired scan-level "
            "bootstrap (the same resampled scans for both), and the fraction of replicates in "
            "which B is higher. Reads only their per_scan.npz files. Scans of one sequence are "
            "correlated, so with few sequences the interval is a lower bound on the uncertainty."
        ),
    )
    p.add_argument("a", metavar="A", help="eval output directory (or its per_scan.npz)")
    p.add_argument("b", metavar="B", help="eval output directory (or its per_scan.npz)")
    p.add_argument(
        "--bootstrap",
        type=ca.int_range(1, 100000),
        default=2000,
        metavar="N",
        help="bootstrap replicates (default 2000)",
    )
    p.add_argument(
        "--level",
        type=ca.float_range(0.0, 1.0, lo_open=True, hi_open=True),
        default=0.95,
        help="interval coverage (default 0.95)",
    )
    p.add_argument("--seed", type=ca.seed, default=0, help="resampling seed (default 0)")
    p.add_argument(
        "--unit",
        choices=("scan", "sequence"),
        default="scan",
        help="what is resampled: scans (default) or whole sequences, i.e. places (the per-scan "
        "counts summed per sequence; needs several sequences)",
    )
    p.add_argument("--output", help="also write compare.json and compare.txt to this directory")
    ca.add_overwrite(p, "the --output directory")
    p.set_defaults(func=run_compare)
    return p


def run_compare(args: argparse.Namespace) -> int:
    """Handler of ``eval compare``."""
    from panoptic_bench.evaluation.output import comparison_table
    from panoptic_bench.evaluation.per_scan import compare, read_per_scan
    from panoptic_bench.io import check_output_dir, output_tree, write_json, write_text

    inputs = (args.a, args.b)
    if args.output:
        check_output_dir(args.output, overwrite=args.overwrite, inputs=inputs)
    got = compare(
        read_per_scan(args.a),
        read_per_scan(args.b),
        n_boot=args.bootstrap,
        level=args.level,
        seed=args.seed,
        names=inputs,
        unit=args.unit,
    )
    result = {"a": str(args.a), "b": str(args.b), **got.to_dict()}
    table = comparison_table(result, names=inputs)
    if args.output:
        with output_tree(args.output, overwrite=args.overwrite, inputs=inputs) as tmp:
            write_json(tmp / "compare.json", result)
            write_text(tmp / "compare.txt", table)
    print(table, end="")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Nothing to add at the top level: ``commands/eval.py`` calls :func:`add_parser`."""
