"""The ``panoptic-bench`` command line: parse arguments, call the library.

Each sub-command lives in a module of :mod:`panoptic_bench.commands` that defines
``register(subparsers)``; the module adds its parser(s) and sets ``func`` to a handler
``handler(args) -> int``. Handlers import heavy libraries lazily so ``--help`` is fast.
User errors (:class:`~panoptic_bench.errors.InputError`) become one line on stderr and
exit status 2, as do a full disk and an unwritable output (``OSError`` ENOSPC / EACCES / EROFS).
A closed stdout (output piped into ``head``) ends the command quietly (status 141, as SIGPIPE).
"""

from __future__ import annotations

import argparse
import errno
import importlib
import os
import pkgutil
import sys
from collections.abc import Sequence

from panoptic_bench import __version__, commands
from panoptic_bench.errors import InputError, InputErrors


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
    try:
        return _main(argv)
    except BrokenPipeError:  # stdout closed early (``| head``), also while printing --help
        _silence_stdout()
        return 141


def _main(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # bad option (already printed, status 2) or --help / --version
        return exc.code if isinstance(exc.code, int) else int(exc.code is not None)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        status = int(args.func(args) or 0)
        if sys.stdout is not None:
            sys.stdout.flush()  # a closed pipe shows here, not at interpreter exit
        return status
    except InputError as exc:
        text = str(exc) if isinstance(exc, InputErrors) else " ".join(str(exc).split())
        return _fail(f"panoptic-bench: error: {text}", 2)
    except BrokenPipeError:
        raise
    except Exception as exc:
        from panoptic_bench.io import full_disk_error

        if _interrupted(exc):  # Ctrl-C inside a writer whose cleanup then failed
            return _fail("panoptic-bench: interrupted", 130)
        cause = full_disk_error(exc) or exc  # a full disk hidden behind a cleanup error
        if not isinstance(cause, OSError) or cause.errno not in USER_OS_ERRORS:
            raise
        where = f"{cause.filename}: " if cause.filename else ""
        hint = "check the permissions" if cause.errno in PERMISSION else "free space"
        msg = f"{where}{cause.strerror} while writing the output; {hint} or choose another output"
        return _fail(f"panoptic-bench: error: {msg}", 2)
    except KeyboardInterrupt:
        return _fail("panoptic-bench: interrupted", 130)


#: OSError numbers caused by the environment, not by a bug: full disk, quota, permissions.
PERMISSION = (errno.EACCES, errno.EPERM, errno.EROFS)
USER_OS_ERRORS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, *PERMISSION)


def _interrupted(exc: BaseException | None) -> bool:
    """True if a KeyboardInterrupt is in the context chain of ``exc``."""
    for _ in range(16):
        if exc is None:
            return False
        if isinstance(exc, KeyboardInterrupt):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


def _fail(message: str, status: int) -> int:
    """Print ``message`` on stderr (if there is one) and return ``status``."""
    try:
        print(message, file=sys.stderr)
    except (OSError, ValueError, AttributeError):
        pass
    return status


def _silence_stdout() -> None:
    """Point stdout at /dev/null so the interpreter's final flush cannot fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
