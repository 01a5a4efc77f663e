"""``panoptic-bench ablate``: DS-Net ablations (Tables 4/5, Figs. 4a-c, 5-7) on a frozen backbone."""

from __future__ import annotations

import argparse

from panoptic_bench import cli_args as ca


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``ablate`` command."""
    p = subparsers.add_parser(
        "ablate",
        help="DS-Net ablations on a frozen stage-2 backbone: Tables 4/5, Figs. 4a-c and 5-7",
        description=(
            "Run the frozen backbone of a stage-2 checkpoint once over the scans, train one "
            "dynamic shifting module per variant on the cached outputs (Table 4 bandwidth sets, "
            "Table 5 iterations 1-5, direct regression), score each variant and the heuristic "
            "clusterings of the same regressed centres into OUT/runs/<name> (scores.json, "
            "run.json) and build the report into OUT/report."
        ),
    )
    p.add_argument("--checkpoint", required=True, help="stage-2 (offset) checkpoint")
    p.add_argument("--data", required=True, help="labelled SemanticKITTI-format root")
    p.add_argument("--out", required=True, help="output directory (runs/, report/)")
    p.add_argument(
        "--train-sequences",
        type=ca.parse_sequences,
        default=None,
        help="sequences the DS variants train on (default: the checkpoint's training sequences)",
    )
    p.add_argument(
        "--val-sequences",
        type=ca.parse_sequences,
        default=None,
        help="scored sequences (default: the checkpoint's validation sequences)",
    )
    p.add_argument(
        "--steps", type=ca.nonneg_int, default=300, help="Adam steps per variant (default 300)"
    )
    p.add_argument(
        "--max-train-scans",
        type=ca.nonneg_int,
        default=0,
        help="evenly spaced training subset (0 = all)",
    )
    p.add_argument(
        "--max-val-scans",
        type=ca.nonneg_int,
        default=0,
        help="evenly spaced validation subset (0 = all)",
    )
    p.add_argument(
        "--lr",
        type=ca.float_range(0.0, 10.0, lo_open=True),
        help="Adam learning rate (default: the config's)",
    )
    p.add_argument("--seed", type=ca.seed, default=0, help="training seed (default 0)")
    p.add_argument("--data-label", help="name of the data in run.json / tables (default: --data)")
    p.add_argument(
        "--quick",
        action="store_true",
        help="fewer variants (default, one other bandwidth set, 1 iteration, direct regression)",
    )
    p.add_argument("--no-report", action="store_true", help="only the run directories")
    p.add_argument("--threads", type=ca.threads, help="torch CPU threads (default: torch's)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=handler)


def handler(args: argparse.Namespace) -> int:
    """Run the ablation and print one summary line per run."""
    import shlex
    import sys

    import torch

    from panoptic_bench.dsnet.ablation.run import run_ablation
    from panoptic_bench.errors import InputError

    for name in ("steps", "max_train_scans", "max_val_scans"):
        if getattr(args, name) < 0:
            raise InputError(f"--{name.replace('_', '-')} must be >= 0")
    if args.lr is not None and not args.lr > 0:
        raise InputError(f"--lr must be > 0, got {args.lr}")
    from panoptic_bench.io import check_output_location

    check_output_location(args.out, (args.data,))  # never write into the dataset
    if args.threads:
        torch.set_num_threads(args.threads)
    summary = run_ablation(
        args.checkpoint,
        args.data,
        args.out,
        train_sequences=args.train_sequences,
        val_sequences=args.val_sequences,
        steps=args.steps,
        max_train_scans=args.max_train_scans,
        max_val_scans=args.max_val_scans,
        quick=args.quick,
        lr=args.lr,
        seed=args.seed,
        data_label=args.data_label,
        report=not args.no_report,
        command=shlex.join(["panoptic-bench", *sys.argv[1:]]),
        progress=not args.no_progress,
    )
    print(f"{'run':<28} {'PQ':>6} {'PQ_th':>6} {'PQ_st':>6} {'mIoU':>6}")
    for row in summary.rows:
        vals = " ".join(f"{100 * row[k]:6.1f}" for k in ("PQ", "PQ_th", "PQ_st", "mIoU"))
        print(f"{row['run']:<28} {vals}")
    print(f"total {summary.seconds['total']:.0f} s")
    if summary.report is not None:
        print(summary.report)
    return 0
