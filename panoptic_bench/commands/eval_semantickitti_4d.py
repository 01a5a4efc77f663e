"""``panoptic-bench eval semantickitti-4d``: SemanticKITTI 4D panoptic scores (LSTQ)."""

from __future__ import annotations

import argparse

from panoptic_bench import cli_args as ca


def add_parser(eval_subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add ``semantickitti-4d`` to the sub-commands of ``eval``."""
    from panoptic_bench.commands.semantickitti import add_dataset_arguments

    p = eval_subparsers.add_parser(
        "semantickitti-4d",
        help="SemanticKITTI 4D panoptic LSTQ (same numbers as 4D-PLS Panoptic4DEval)",
        description=(
            "Score 4D predictions (instance ids label >> 16 consistent along each sequence) with "
            "LSTQ = sqrt(S_assoc * S_cls). --mode reference reproduces the benchmark code "
            "(4D-PLS), quirks included; --mode corrected fixes them (ground truth scores 1.0). "
            "Writes scores.json, scores.txt and per_class.csv to --output."
        ),
    )
    add_dataset_arguments(p)
    p.add_argument(
        "--min-inst-points",
        type=ca.nonneg_int,
        default=50,
        help="ground-truth segments need more than (corrected: at least) this many points "
        "in a frame to join their tube (default 50)",
    )
    p.add_argument(
        "--mode",
        choices=["reference", "corrected"],
        default="reference",
        help="rule set (default reference = the benchmark's code)",
    )
    p.add_argument("--workers", type=ca.workers, default=1, help="worker processes (default 1)")
    p.add_argument(
        "--by-range",
        type=ca.range_edges,
        default=None,
        metavar="EDGES",
        help="also score per range bin, comma-separated edges in metres, e.g. 0,10,20,40,80",
    )
    p.add_argument("--output", required=True, help="output directory (not inside the inputs)")
    ca.add_overwrite(p, "the --output directory")
    p.set_defaults(func=run)
    return p


def _table(scores: dict) -> str:
    lines = [f"{'class':<16}{'IoU':>8}{'AQ':>8}{'tubes':>7}"]
    for name, m in scores["classes"].items():
        lines.append(f"{name:<16}{100 * m['IoU']:8.2f}{100 * m['AQ']:8.2f}{m['tubes']:7d}")
    head = scores["all"]
    for key in ("LSTQ", "S_assoc", "S_cls"):
        v = head[key]
        lines.append(f"{key:<16}{'nan' if v is None else f'{100 * v:.2f}':>8}")
    for row in scores.get("by_range") or []:
        lo, hi = row["range"]
        v = row["all"]["LSTQ"]
        lines.append(f"LSTQ {lo:g}-{hi:g} m{'':<4}{'nan' if v is None else f'{100 * v:.2f}':>8}")
    return "\n".join(lines) + "\n"


def run(args: argparse.Namespace) -> int:
    """Handler of ``eval semantickitti-4d``."""
    from panoptic_bench.evaluation.semantickitti_4d import evaluate_semantickitti_4d
    from panoptic_bench.evaluation.workers import retain_freed_memory
    from panoptic_bench.io import check_output_dir, output_tree

    inputs = (args.dataset, args.predictions)
    check_output_dir(args.output, overwrite=args.overwrite, inputs=inputs)
    retain_freed_memory()
    ev = evaluate_semantickitti_4d(
        args.dataset,
        args.predictions,
        split=args.split,
        sequences=args.sequences,
        min_points=args.min_inst_points,
        mode=args.mode,
        workers=args.workers,
        by_range=args.by_range,
    )
    with output_tree(args.output, overwrite=args.overwrite, inputs=inputs) as tmp:
        scores = ev.write(tmp)
    print(f"{ev.n_scans} scans of sequences {', '.join(ev.sequences)}, {args.mode} rules (%):")
    print(_table(scores), end="")
    if scores["all"]["phantom_class_0"] and args.mode == "reference":
        print("note: class 0 predicted on labelled points adds a phantom class to S_cls")
    print(f"results written to {args.output}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Nothing to add at the top level: ``commands/eval.py`` calls :func:`add_parser`."""
