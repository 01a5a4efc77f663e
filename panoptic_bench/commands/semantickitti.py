"""``panoptic-bench semantickitti remap`` and the ``eval semantickitti`` target."""

from __future__ import annotations

import argparse

from panoptic_bench import cli_args as ca

#: ``08,09`` -> ``["08", "09"]`` (checked: numbers, each once); kept for modules importing it.
_sequences = ca.parse_sequences


def add_dataset_arguments(p: argparse.ArgumentParser) -> None:
    """``--dataset``, ``--predictions``, ``--split``, ``--sequences`` (shared with ``validate``)."""
    p.add_argument("--dataset", required=True, help="root holding sequences/XX/{velodyne,labels}")
    p.add_argument(
        "--predictions",
        required=True,
        help="root holding sequences/XX/predictions/NNNNNN.label (raw ids, uint32)",
    )
    ca.add_scan_selection(
        p, split_default="valid", split_help="sequences of this split (default: valid = 08)"
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
        type=ca.nonneg_int,
        default=50,
        help="unmatched segments smaller than this count neither as FP nor FN (default 50)",
    )
    p.add_argument("--workers", type=ca.workers, default=1, help="worker processes (default 1)")
    p.add_argument(
        "--by-range",
        type=ca.range_edges,
        default=None,
        metavar="EDGES",
        help="also score per range bin, comma-separated edges in metres, e.g. 0,10,20,30,40,50,80",
    )
    p.add_argument(
        "--bootstrap",
        type=ca.int_range(0, 100000),
        default=0,
        metavar="N",
        help="also give 95%% confidence intervals from N scan-level bootstrap replicates "
        "(scores.json key 'bootstrap'; 0 = off, the default); per_scan.npz is always written, "
        "see 'eval compare'",
    )
    p.add_argument(
        "--bootstrap-unit",
        choices=("scan", "sequence"),
        default="scan",
        help="what --bootstrap resamples: scans (default) or whole sequences (places)",
    )
    p.add_argument("--output", required=True, help="output directory (not inside the inputs)")
    ca.add_overwrite(p, "the --output directory")
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
    ca.add_overwrite(p, "the --output tree")
    p.set_defaults(func=run_remap)


def run_eval(args: argparse.Namespace) -> int:
    """Handler of ``eval semantickitti``."""
    from panoptic_bench.evaluation.output import percent_table
    from panoptic_bench.evaluation.semantickitti import evaluate_semantickitti
    from panoptic_bench.evaluation.workers import retain_freed_memory
    from panoptic_bench.io import check_output_dir, output_tree

    inputs = (args.dataset, args.predictions)
    check_output_dir(args.output, overwrite=args.overwrite, inputs=inputs)
    retain_freed_memory()
    ev = evaluate_semantickitti(
        args.dataset,
        args.predictions,
        split=args.split,
        sequences=args.sequences,
        min_points=args.min_inst_points,
        workers=args.workers,
        by_range=args.by_range,
    )
    with output_tree(args.output, overwrite=args.overwrite, inputs=inputs) as tmp:
        scores = ev.write(tmp, bootstrap=args.bootstrap, unit=args.bootstrap_unit)
    print(f"{ev.n_scans} scans of sequences {', '.join(ev.sequences)} (values in %):")
    print(percent_table(scores))
    if "bootstrap" in scores:
        from panoptic_bench.evaluation.output import interval_table

        print(interval_table(scores["bootstrap"]))
    print(f"results written to {args.output}")
    return 0


def run_remap(args: argparse.Namespace) -> int:
    """Handler of ``semantickitti remap``."""
    from panoptic_bench.evaluation.semantickitti_tools import remap_tree
    from panoptic_bench.io import output_tree

    with output_tree(args.output, overwrite=args.overwrite, inputs=(args.input,)) as tmp:
        n = remap_tree(args.input, tmp, inverse=args.inverse)
    print(
        f"{n} label files remapped {'train -> raw' if args.inverse else 'raw -> train'} ids "
        f"into {args.output}"
    )
    return 0
