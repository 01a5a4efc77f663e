"""The ``panoptic-bench`` command line: parse arguments, call the library.

Each sub-command lives in a module of :mod:`panoptic_bench.commands` that defines
``register(subparsers)``; the module adds its parser(s) and sets ``func`` to a handler
``handler(args) -> int``. Handlers import heavy libraries lazily so ``--help`` is fast.
User errors (:class:`~panoptic_bench.errors.InputError`) become one line on stderr and
exit status 2.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from collections.abc import Sequence

from panoptic_bench import __version__, commands
from panoptic_bench.errors import InputError


def build_parser() -> argparse.ArgumentParser:
    """Build the full argument parser from every module in :mod:`panoptic_bench.commands`."""
    parser = argparse.ArgumentParser(
        prog="panoptic-bench",
        description="LiDAR panoptic segmentation: exact scoring, labels, DS-Net and baselines.",
    )
    parser.add_argument("--version", action="version", version=f"panoptic-bench {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the process exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except InputError as exc:
        print(f"panoptic-bench: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("panoptic-bench: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
