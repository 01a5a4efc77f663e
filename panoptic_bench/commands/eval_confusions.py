"""``panoptic-bench eval confusions A [B]``: the largest confusions of a scored prediction set."""

from __future__ import annotations

import argparse

from panoptic_bench import cli_args as ca


def add_parser(eval_subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add ``confusions`` to the sub-commands of ``eval``."""
    p = eval_subparsers.add_parser(
        "confusions",
        help="where each true class's points go: the largest confusions (or their change A -> B)",
        description=(
            "Read the per_scan.npz of an 'eval semantickitti' output and print the largest "
            "off-diagonal cells of its point confusion matrix (true class -> predicted class, "
            "points, share of the true class, share of the prediction). With a second output B "
            "of the same scans, rank the cells by how much they changed from A to B. Points of "
            "ignored true classes are left out; a point predicted as an ignored class counts as a "
            "miss of its true class, as in the evaluator."
        ),
    )
    p.add_argument("a", metavar="A", help="eval output directory (or its per_scan.npz)")
    p.add_argument("b", metavar="B", nargs="?", help="a second one on the same scans")
    p.add_argument("--top", type=ca.int_range(1, 400), default=15, help="cells listed (default 15)")
    p.add_argument("--figure", metavar="PNG", help="also draw A's matrix (row shares) to this PNG")
    p.add_argument(
        "--output", help="also write confusion.csv (A's full matrix) and confusions.txt here"
    )
    ca.add_overwrite(p, "the --output directory")
    p.set_defaults(func=run_confusions)
    return p


def run_confusions(args: argparse.Namespace) -> int:
    """Handler of ``eval confusions``."""
    from panoptic_bench.errors import InputError
    from panoptic_bench.evaluation.confusion import (
        confusion_matrix,
        confusion_rows,
        confusion_table,
        csv_text,
    )
    from panoptic_bench.evaluation.per_scan import read_per_scan
    from panoptic_bench.io import check_output_dir, output_tree, write_text

    inputs = tuple(x for x in (args.a, args.b) if x)
    if args.output:
        check_output_dir(args.output, overwrite=args.overwrite, inputs=inputs)
    a = read_per_scan(args.a)
    conf, other = confusion_matrix(a), None
    if args.b:
        b = read_per_scan(args.b)
        if b.class_names != a.class_names or sorted(b.scans) != sorted(a.scans):
            raise InputError(
                f"not the same scans and classes as {args.a}: compare outputs of one dataset",
                args.b,
            )
        other = confusion_matrix(b)
    table = confusion_table(confusion_rows(conf, a.class_names, args.top, other))
    intro = f"A = {args.a}\nB = {args.b}\n" if args.b else f"{args.a}\n"
    if args.figure:
        from panoptic_bench.reports.figures import plot_confusion

        plot_confusion(conf, a.class_names, args.figure, title=f"{args.a}"[-60:])
    if args.output:
        with output_tree(args.output, overwrite=args.overwrite, inputs=inputs) as tmp:
            write_text(tmp / "confusion.csv", csv_text(conf, a.class_names))
            write_text(tmp / "confusions.txt", intro + table)
    print(intro + table, end="")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Nothing to add at the top level: ``commands/eval.py`` calls :func:`add_parser`."""
