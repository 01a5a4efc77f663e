"""``panoptic-bench eval TARGET``: score predictions against a dataset.

Each target is a module of :mod:`panoptic_bench.commands` with ``add_parser(eval_subparsers)``;
a new dataset is one more entry in :data:`EVAL_TARGETS`.
"""

from __future__ import annotations

import argparse
import importlib

#: modules of panoptic_bench.commands that add a sub-command to ``eval``
EVAL_TARGETS: list[str] = [
    "semantickitti",
    "eval_semantickitti_4d",
    "eval_nuscenes",
    "eval_compare",
    "eval_confusions",
    "eval_breakdown",
]


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``eval`` group and one sub-command per module in :data:`EVAL_TARGETS`."""
    parser = subparsers.add_parser(
        "eval",
        help="score panoptic predictions (PQ, PQ-dagger, SQ, RQ, mIoU; LSTQ, PAT for 4D)",
        description="Score panoptic predictions against a dataset; see 'eval TARGET --help'.",
    )
    sub = parser.add_subparsers(dest="eval_target", metavar="TARGET", required=True)
    for name in EVAL_TARGETS:
        importlib.import_module(f"{__package__}.{name}").add_parser(sub)
