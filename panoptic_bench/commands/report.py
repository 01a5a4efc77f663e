"""``panoptic-bench report``: paper-layout tables and figures from run directories."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``report`` command."""
    p = subparsers.add_parser(
        "report",
        help="tables (md/csv/tex) and figures (png) beside the paper's numbers, with index.md",
        description=(
            "Read scores.json (and optional run.json, analysis.json, shift_iterations.npz, "
            "bev.npz) from each run directory and write the paper's Tables 1-8 layouts with the "
            "published numbers beside ours, Figs. 3-7, PQ by range, a bird's-eye panoptic view "
            "and DIR/index.md linking everything. Metrics are read, never recomputed."
        ),
    )
    p.add_argument(
        "--results",
        nargs="+",
        required=True,
        metavar="RUN_DIR",
        help="run directories holding scores.json (or scores.json paths)",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.set_defaults(func=handler)


def handler(args: argparse.Namespace) -> int:
    """Build the report and print the path of index.md."""
    from pathlib import Path

    from panoptic_bench.io import output_tree
    from panoptic_bench.reports.index import build_report, report_command

    out = Path(args.out)
    out.resolve().parent.mkdir(parents=True, exist_ok=True)  # temp tree beside it: same links
    # all-or-nothing: tables, figures and index.md appear together or not at all (full disk)
    with output_tree(out, overwrite=True) as tmp:
        index = build_report(args.results, tmp, command=report_command(args.results, args.out))
    print(out / Path(index).relative_to(tmp))
    return 0
