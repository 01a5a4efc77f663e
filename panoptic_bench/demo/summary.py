"""Terminal output of the demo: numbered stage lines with timings and the final summary table."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TextIO

__all__ = ["SUMMARY_METRICS", "Stages", "summary_rows", "summary_table"]

#: Columns of the summary table (``scores.json`` ``all`` keys).
SUMMARY_METRICS = ("PQ", "PQ_dagger", "RQ", "SQ", "PQ_th", "PQ_st", "mIoU")


class Stages:
    """Numbered stage headers: ``[3] title`` before, ``    done in 1.2 s`` after.

    Parameters
    ----------
    stream : text stream, optional
        Where to print (default: standard output).
    """

    def __init__(self, stream: TextIO | None = None) -> None:
        self.stream = stream
        self.count = 0
        self.seconds: list[tuple[str, float]] = []

    @contextmanager
    def __call__(self, title: str) -> Iterator[None]:
        stream = self.stream or sys.stdout
        self.count += 1
        print(f"[{self.count}] {title}", file=stream, flush=True)
        t0 = time.perf_counter()
        yield
        dt = time.perf_counter() - t0
        self.seconds.append((title, dt))
        print(f"    done in {dt:.1f} s", file=stream, flush=True)


def summary_rows(runs: Sequence[Path]) -> list[dict[str, object]]:
    """One row per run directory: run name, method, dataset and the metrics in percent."""
    from panoptic_bench.reports.runs import load_runs

    rows = []
    for run in load_runs(list(runs)):
        row: dict[str, object] = {
            "Run": run.path.name,
            "Method": run.method,
            "Dataset": run.meta.dataset or "-",
        }
        for m in SUMMARY_METRICS:
            value = run.overall.get(m)
            row[m] = None if value is None else 100.0 * float(value)
        rows.append(row)
    return rows


def summary_table(runs: Sequence[Path], seconds: float | None = None) -> str:
    """Plain-text table of :func:`summary_rows` (values in %), plus the wall time if given."""
    rows = summary_rows(runs)
    header = ["Method", "Dataset", *("PQ†" if m == "PQ_dagger" else m for m in SUMMARY_METRICS)]
    cells = [
        [
            str(r["Method"]),
            str(r["Dataset"]),
            *("-" if r[m] is None else f"{r[m]:.1f}" for m in SUMMARY_METRICS),
        ]
        for r in rows
    ]
    widths = [max(len(h), *(len(c[i]) for c in cells)) if cells else len(h) for i, h in
              enumerate(header)]  # fmt: skip

    def line(values: Sequence[str]) -> str:
        parts = [
            v.ljust(w) if i < 2 else v.rjust(w) for i, (v, w) in enumerate(zip(values, widths))
        ]
        return "  ".join(parts).rstrip()

    out = [line(header), line(["-" * w for w in widths]), *(line(c) for c in cells)]
    text = "\n".join(out) + "\n"
    if seconds is not None:
        text += f"(values in %; wall time {seconds:.0f} s)\n"
    return text
