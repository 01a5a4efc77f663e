"""``panoptic-bench demo``: the whole pipeline on the embedded default, and the committed reports."""

from __future__ import annotations

import argparse
import os
import shlex

from panoptic_bench import cli_args as ca


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``demo`` command."""
    p = subparsers.add_parser(
        "demo",
        help="end-to-end demo: synthetic data -> DS-Net / baselines -> evaluation -> report",
        description=(
            "Synthesize a SemanticKITTI-format world (train 00 + val 08) and a nuScenes-format "
            "v1.0-mini dataroot, build the Panoptic nuScenes labels, regress centres (DS-Net "
            "with the shipped checkpoint, or the labelled simulated regression when none is "
            "shipped), cluster them with BFS, DBSCAN, HDBSCAN and mean shift, merge the same "
            "semantics with a simulated detector's boxes (box-merge), score every method with the project's evaluators into DIR/runs/<name>, and build the report "
            "(DIR/index.md, tables, figures). With --real-scans ROOT, the same SemanticKITTI "
            "methods on the labelled scans under ROOT instead."
        ),
    )
    p.add_argument(
        "--out",
        default=None,
        metavar="DIR",
        help="report directory (default reports/demo, or reports/real-scans with --real-scans)",
    )
    p.add_argument(
        "--quick", action="store_true", help="less data (10 val scans, 6 nuScenes sweeps)"
    )
    p.add_argument(
        "--workers",
        type=ca.workers,
        default=min(2, os.cpu_count() or 1),
        help="worker processes (default: min(2, CPUs)); results do not depend on it",
    )
    p.add_argument(
        "--report-only",
        action="store_true",
        help="keep only the report set (index.md, tables, figures, runs/*/scores.json, "
        "run.json): generated data goes to a temporary directory and is deleted; this is how "
        "the committed reports/synthetic and reports/real-scans are rebuilt",
    )
    p.add_argument(
        "--real-scans",
        default=None,
        metavar="ROOT",
        help="run on the labelled SemanticKITTI scans under ROOT (e.g. ../shared/data/semantickitti)",
    )
    p.add_argument(
        "--checkpoint",
        default=None,
        metavar="NAME|PATH",
        help="with --real-scans: DS-Net checkpoint (a path or a shipped name such as "
        "semantickitti-cpu; default: the shipped real-data model, else the synthetic one)",
    )
    ca.add_scan_selection(
        p, split_help="with --real-scans: score only the scans of this SemanticKITTI split"
    )
    p.add_argument(
        "--no-checkpoint",
        action="store_true",
        help="ignore a shipped DS-Net checkpoint: simulated regression only",
    )
    p.set_defaults(func=handler)


def _command(args: argparse.Namespace, out: str) -> str:
    """The canonical command line recorded in index.md (without --workers)."""
    words = ["panoptic-bench", "demo"]
    if args.real_scans:
        words += ["--real-scans", args.real_scans]
        if args.split and not args.sequences:
            words += ["--split", args.split]
        if args.sequences:
            words += ["--sequences", ",".join(args.sequences)]
        if args.checkpoint:
            words += ["--checkpoint", args.checkpoint]
    words += ["--out", out]
    words += [flag for flag, on in (("--quick", args.quick), ("--report-only", args.report_only),
              ("--no-checkpoint", args.no_checkpoint)) if on]  # fmt: skip
    return shlex.join(words)


def handler(args: argparse.Namespace) -> int:
    """Run the demo, print the summary table and the path of index.md."""
    from panoptic_bench.errors import InputError

    if args.workers < 1:
        raise InputError(f"--workers must be >= 1, got {args.workers}")
    if args.real_scans and args.quick:
        raise InputError("--quick applies to the synthetic demo, not to --real-scans")
    if not args.real_scans and (args.checkpoint or args.sequences or args.split):
        raise InputError("--checkpoint, --split and --sequences apply to --real-scans only")
    if args.checkpoint and args.no_checkpoint:
        raise InputError("--checkpoint and --no-checkpoint exclude each other")
    out = args.out or ("reports/real-scans" if args.real_scans else "reports/demo")
    if args.real_scans:  # the scans are only read: never write the report into them
        from panoptic_bench.io import check_output_location

        check_output_location(out, (args.real_scans,))
    common = {
        "workers": args.workers,
        "keep_work": not args.report_only,
        "use_checkpoint": not args.no_checkpoint,
        "command": _command(args, out),
    }
    if args.real_scans:
        from panoptic_bench.demo.real import run_real_scans

        chosen = ca.selected_sequences(args.split, args.sequences)
        seqs = tuple(chosen) if chosen else None
        ckpt = None
        if args.checkpoint:
            from panoptic_bench.demo.steps import resolve_checkpoint_arg

            ckpt = resolve_checkpoint_arg(args.checkpoint)
        result = run_real_scans(args.real_scans, out, checkpoint=ckpt, sequences=seqs, **common)
    else:
        from panoptic_bench.demo.config import FULL, QUICK
        from panoptic_bench.demo.pipeline import run_demo

        result = run_demo(out, size=QUICK if args.quick else FULL, **common)
    print()
    print(result.summary, end="")
    for item in result.missing:
        print(f"not included: {item}")
    print(f"centres for the clusterings: {result.regression}")
    print(f"report: {result.index}")
    return 0
