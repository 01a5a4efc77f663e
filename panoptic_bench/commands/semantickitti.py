"""``panoptic-bench semantickitti remap`` and the ``eval semantickitti`` target."""

from __future__ import annotations

import argparse


def _sequences(text: str) -> list[str]:
    items = [s.strip() for s in text.split(",") if s.strip()]
    if not items or not all(s.isdigit() for s in items):
        raise argparse.ArgumentTypeError(f"expected sequence numbers like 08,09; got {text!r}")
    return items


def add_dataset_arguments(p: argparse.ArgumentParser) -> None:
    """``--dataset``, ``--predictions``, ``--split``, ``--sequences`` (shared with ``validate``)."""
    p.add_argument("--dataset", required=True, help="root holding sequences/XX/{velodyne,labels}")
    p.add_argument(
        "--predictions",
        required=True,
        help="root holding sequences/XX/predictions/NNNNNN.label (raw ids, uint32)",
    )
    p.add_argument(
        "--split",
        choices=["train", "valid", "test"],
        default="valid",
        help="sequences of this split (default: valid = 08)",
    )
    p.add_argument(
        "--sequences",
        type=_sequences,
        default=None,
        metavar="08,...",
        help="comma-separated sequences; overrides --split",
    )


def add_parser(eval_subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add ``semantickitti`` to the sub-commands of ``eval``."""
    p = eval_subparsers.add_parser(
        "semantickitti",
        help="SemanticKITTI panoptic scores (same numbers as the official evaluate_panoptic.py)",
        description=(
            "Score SemanticKITTI predictions exactly as semantic-kitti-api evaluate_panoptic.py. "
            "Writes scores.txt (codalab keys), scores.json and per_class.csv to --output and "
            "prints the tables in percent."
        ),
    )
    add_dataset_arguments(p)
    p.add_argument(
        "--min-inst-points",
        type=int,
        default=50,
        help="unmatched segments smaller than this count neither as FP nor FN (default 50)",
    )
    p.add_argument("--workers", type=int, default=1, help="worker processes (default 1)")
    p.add_argument(
        "--by-range",
        default=None,
        metavar="EDGES",
        help="also score per range bin, comma-separated edges in metres, e.g. 0,10,20,30,40,50,80",
    )
    p.add_argument("--output", required=True, help="output directory (not inside the inputs)")
    p.set_defaults(func=run_eval)
    return p


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``semantickitti remap``."""
    parser = subparsers.add_parser("semantickitti", help="SemanticKITTI label tools")
    sub = parser.add_subparsers(dest="semantickitti_command", metavar="COMMAND", required=True)
    p = sub.add_parser(
        "remap",
        help="map label files raw ids -> train ids 0-19 (or back with --inverse)",
        description=(
            "Rewrite every .label file under --input into the same relative path under --output, "
            "mapping the low 16 bits raw -> train ids (learning_map) or train -> raw ids "
            "(learning_map_inv, --inverse) and keeping the instance bits. Never writes into "
            "--input; nothing is written if any file is bad."
        ),
    )
    p.add_argument("--input", required=True, help="directory searched recursively for .label")
    p.add_argument("--output", required=True, help="output directory (not inside --input)")
    p.add_argument("--inverse", action="store_true", help="train ids -> raw ids")
    p.set_defaults(func=run_remap)


def run_eval(args: argparse.Namespace) -> int:
    """Handler of ``eval semantickitti``."""
    from panoptic_bench.evaluation.output import check_output_location, percent_table
    from panoptic_bench.evaluation.semantickitti import evaluate_semantickitti
    from panoptic_bench.io import ensure_output_dir

    inputs = (args.dataset, args.predictions)
    check_output_location(args.output, inputs)
    ev = evaluate_semantickitti(
        args.dataset,
        args.predictions,
        split=args.split,
        sequences=args.sequences,
        min_points=args.min_inst_points,
        workers=args.workers,
        by_range=args.by_range,
    )
    scores = ev.write(ensure_output_dir(args.output, inputs=inputs))
    print(f"{ev.n_scans} scans of sequences {', '.join(ev.sequences)} (values in %):")
    print(percent_table(scores))
    print(f"results written to {args.output}")
    return 0


def run_remap(args: argparse.Namespace) -> int:
    """Handler of ``semantickitti remap``."""
    from panoptic_bench.evaluation.semantickitti_tools import remap_tree

    n = remap_tree(args.input, args.output, inverse=args.inverse)
    print(
        f"{n} label files remapped {'train -> raw' if args.inverse else 'raw -> train'} ids "
        f"into {args.output}"
    )
    return 0
