"""Shared option types and option groups of the command line, checked at parse time.

Every numeric option has a range: the ``type=`` callables here reject values outside it (and
NaN / infinity) while argparse parses, so the error names the option (``argument --bandwidth:
must be > 0, got 0``), exits with status 2 and nothing has been read or written yet. The scan
selection (``--split`` / ``--sequences`` / ``--scan``) and the output options (``--output`` /
``--overwrite``) are one vocabulary added by the helpers below, so a new command gets the same
spelling and the same checks by calling them.

Examples
--------
>>> import argparse
>>> p = argparse.ArgumentParser()
>>> _ = p.add_argument("--radius", type=positive_float)
>>> add_scan_selection(p)
>>> p.parse_args(["--radius", "1.5", "--sequences", "8,09"]).sequences
['08', '09']
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable, Sequence

__all__ = [
    "SPLITS",
    "SequencesAction",
    "add_overwrite",
    "add_scan_selection",
    "device",
    "float_range",
    "int_range",
    "metres",
    "nonneg_float",
    "nonneg_int",
    "parse_sequences",
    "positive_float",
    "positive_int",
    "probability",
    "range_edges",
    "scan_id",
    "seed",
    "selected_sequences",
    "threads",
    "workers",
]

#: SemanticKITTI split names accepted by ``--split``.
SPLITS = ("train", "valid", "test")

_SEQ = re.compile(r"[0-9]{1,4}")
_SCAN = re.compile(r"([0-9]{1,4})/([0-9]{1,6})")


def _describe(lo: float | None, hi: float | None, lo_open: bool, hi_open: bool) -> str:
    parts = []
    if lo is not None:
        parts.append(f"{'>' if lo_open else '>='} {lo:g}")
    if hi is not None:
        parts.append(f"{'<' if hi_open else '<='} {hi:g}")
    return " and ".join(parts) if parts else "a number"


def float_range(
    lo: float | None = None,
    hi: float | None = None,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
) -> Callable[[str], float]:
    """An argparse ``type`` for a finite float in ``[lo, hi]`` (ends open with ``*_open``).

    Parameters
    ----------
    lo, hi : float, optional
        Bounds (None: unbounded on that side). NaN and infinities are always rejected.
    lo_open, hi_open : bool
        Exclude the bound itself (``lo_open=True, lo=0``: strictly positive).

    Returns
    -------
    callable
        ``str -> float``; raises ``argparse.ArgumentTypeError`` naming the allowed range.
    """
    want = _describe(lo, hi, lo_open, hi_open)

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        bad = not math.isfinite(value)
        bad = bad or (lo is not None and (value <= lo if lo_open else value < lo))
        bad = bad or (hi is not None and (value >= hi if hi_open else value > hi))
        if bad:
            raise argparse.ArgumentTypeError(f"must be a finite number {want}, got {text!r}")
        return value

    parse.__name__ = "float"  # argparse's fallback message says "invalid float value"
    return parse


def int_range(lo: int | None = None, hi: int | None = None) -> Callable[[str], int]:
    """An argparse ``type`` for an integer in ``[lo, hi]`` (decimal digits, optional sign)."""
    want = _describe(lo, hi, False, False)

    def parse(text: str) -> int:
        if not re.fullmatch(r"[+-]?[0-9]+", text.strip()):
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}")
        value = int(text)
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise argparse.ArgumentTypeError(f"must be an integer {want}, got {text!r}")
        return value

    parse.__name__ = "int"
    return parse


#: Strictly positive finite float (radii, bandwidths, learning rates).
positive_float = float_range(0.0, lo_open=True)
#: A distance in metres, > 0 and at most 10 km (radii, bandwidths: a LiDAR sees ~100 m).
metres = float_range(0.0, 1e4, lo_open=True)
#: Non-negative finite float (noise sigmas, merge distances).
nonneg_float = float_range(0.0)
#: Probability or rate in [0, 1].
probability = float_range(0.0, 1.0)
#: Integer >= 1 (counts, iterations, sizes).
positive_int = int_range(1)
#: Integer >= 0 (``0`` = "all" / "none" where documented).
nonneg_int = int_range(0)
#: Random seed accepted by numpy and torch alike.
seed = int_range(0, 2**32 - 1)
#: Worker processes.
workers = int_range(1, 1024)
#: torch CPU threads.
threads = int_range(1, 1024)


def device(text: str) -> str:
    """An argparse ``type`` for a torch device: ``cpu``, ``cuda`` or ``cuda:N`` that exists here."""
    text = text.strip()
    if not re.fullmatch(r"cpu|cuda(:[0-9]+)?", text):
        raise argparse.ArgumentTypeError(f"expected cpu, cuda or cuda:N, got {text!r}")
    if text.startswith("cuda"):
        import torch

        if not torch.cuda.is_available():
            raise argparse.ArgumentTypeError(
                f"{text!r}: CUDA is not available on this machine; use cpu"
            )
        index = int(text.partition(":")[2] or 0)
        if index >= torch.cuda.device_count():
            raise argparse.ArgumentTypeError(
                f"{text!r}: this machine has {torch.cuda.device_count()} CUDA device(s)"
            )
    return text


def parse_sequences(items: str | Sequence[str]) -> list[str]:
    """Sequence ids from ``"08,09"`` or ``["08", "09"]`` (or both mixed), zero-padded to 2.

    Raises
    ------
    argparse.ArgumentTypeError
        An id that is not a plain ASCII number, an empty list, or a sequence given twice.
    """
    words = [items] if isinstance(items, str) else list(items)
    out: list[str] = []
    for word in words:
        for part in word.split(","):
            part = part.strip()
            if not part:
                continue
            if not _SEQ.fullmatch(part):
                raise argparse.ArgumentTypeError(
                    f"expected sequence numbers like 08,09; got {part!r}"
                )
            seq = part.zfill(2)
            if seq in out:
                raise argparse.ArgumentTypeError(f"sequence {seq} given twice")
            out.append(seq)
    if not out:
        raise argparse.ArgumentTypeError("expected sequence numbers like 08,09; got nothing")
    return out


class SequencesAction(argparse.Action):
    """``--sequences 08,09`` and ``--sequences 08 09`` alike: a list of zero-padded ids."""

    def __call__(self, parser, namespace, values, option_string=None) -> None:  # noqa: D102
        try:
            setattr(namespace, self.dest, parse_sequences(values))
        except argparse.ArgumentTypeError as exc:
            parser.error(f"argument {option_string}: {exc}")


def scan_id(text: str) -> str:
    """An argparse ``type`` for one scan, ``SEQ/FRAME`` (``8/0`` -> ``08/000000``)."""
    m = _SCAN.fullmatch(text.strip())
    if not m:
        raise argparse.ArgumentTypeError(f"expected SEQ/FRAME like 08/000000, got {text!r}")
    return f"{m.group(1).zfill(2)}/{m.group(2).zfill(6)}"


def add_scan_selection(
    p: argparse.ArgumentParser,
    *,
    split_default: str | None = None,
    split_help: str | None = None,
    scan: bool = False,
) -> None:
    """Add the shared ``--split`` / ``--sequences`` (and optionally ``--scan``) options.

    ``--sequences`` takes ``08,09`` or ``08 09``, overrides ``--split``, and rejects ids that are
    not numbers or appear twice. ``--scan SEQ/FRAME`` selects one scan.
    """
    p.add_argument(
        "--split",
        choices=SPLITS,
        default=split_default,
        help=split_help or "scans of this SemanticKITTI split (train, valid = 08, test)",
    )
    p.add_argument(
        "--sequences",
        nargs="+",
        action=SequencesAction,
        default=None,
        metavar="SEQ",
        help="sequences, e.g. 08 or 00,01 (overrides --split; each at most once)",
    )
    if scan:
        p.add_argument("--scan", type=scan_id, metavar="SEQ/FRAME", help="one scan, e.g. 08/000000")


def add_overwrite(p: argparse.ArgumentParser, what: str = "the output") -> None:
    """Add ``--overwrite``: without it a command refuses to replace an existing, non-empty output."""
    p.add_argument(
        "--overwrite",
        action="store_true",
        help=f"replace {what} if it already exists and is not empty (default: refuse)",
    )


def selected_sequences(split: str | None, sequences: list[str] | None) -> list[str] | None:
    """``--sequences`` if given, else the sequences of ``--split`` (None: both unset)."""
    if sequences:
        return list(sequences)
    if split is None:
        return None
    from panoptic_bench.datasets.semantickitti import LABELS

    return [f"{int(s):02d}" for s in LABELS.splits[split]]


def range_edges(text: str) -> tuple[float, ...]:
    """An argparse ``type`` for ``--by-range``: >= 2 finite, increasing, non-negative edges (m)."""
    try:
        edges = tuple(float(e) for e in text.split(",") if e.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected numbers like 0,10,20; got {text!r}") from None
    if (
        len(edges) < 2
        or not all(math.isfinite(e) for e in edges)
        or edges[0] < 0
        or any(b <= a for a, b in zip(edges, edges[1:]))
    ):
        raise argparse.ArgumentTypeError(
            f"expected >= 2 finite, increasing, non-negative edges like 0,10,20; got {text!r}"
        )
    return edges
