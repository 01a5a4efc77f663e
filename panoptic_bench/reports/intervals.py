"""The report's "How sure" section: bootstrap intervals of every run that kept its per-scan counts.

A run directory written by ``eval semantickitti`` holds ``per_scan.npz``
(:mod:`panoptic_bench.evaluation.per_scan`); the intervals are resampled from those counts with
:func:`panoptic_bench.metrics.bootstrap.bootstrap` (fixed seed and replicate count, so a rebuilt
report is identical). Scans are resampled always; whole sequences too when a run spans at least
:data:`MIN_SEQUENCES` of them.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from panoptic_bench.reports.runs import SCORES_FILE, Run

N_BOOT = 1000
"""Replicates per interval (seed 0)."""

MIN_SEQUENCES = 3
"""Fewest sequences for a sequence-level interval (two give three distinct replicates)."""

METRICS = ("PQ", "PQ_th", "PQ_st", "mIoU")


def _run_dir(run: Run) -> Path:
    return run.path.parent if run.path.name == SCORES_FILE else run.path


def _cell(b, key: str) -> str:
    return f"{100 * b.estimate[key]:.1f} [{100 * b.low[key]:.1f}, {100 * b.high[key]:.1f}]"


def interval_rows(run: Run) -> list[list[str]]:
    """Rows ``[unit, n, PQ, PQ_th, PQ_st, mIoU]`` (cells ``value [low, high]`` in %) for one run.

    Empty when the run has no ``per_scan.npz``.
    """
    from panoptic_bench.evaluation.per_scan import FILE, by_sequence, read_per_scan
    from panoptic_bench.metrics.bootstrap import bootstrap

    path = _run_dir(run) / FILE
    if not path.is_file():
        return []
    per = read_per_scan(path)
    rows = []
    seqs = by_sequence(per)
    units = [("scan", per)] + ([("sequence", seqs)] if len(seqs.scans) >= MIN_SEQUENCES else [])
    for unit, data in units:
        b = bootstrap(data.stats, per.things, per.stuff, n_boot=N_BOOT, unit=unit)
        rows.append([unit, str(len(data.scans)), *(_cell(b, k) for k in METRICS)])
    return rows


def interval_markdown(runs: Sequence[Run], labels: Sequence[str]) -> list[str]:
    """Markdown lines of the section (nothing when no run kept its per-scan counts)."""
    body = []
    for run, label in zip(runs, labels):
        for row in interval_rows(run):
            body.append("| " + " | ".join([f"`{label}`", run.method, *row]) + " |")
    if not body:
        return []
    head = " | ".join(f"{k} [95 %]" for k in METRICS)
    return [
        "## How sure: bootstrap intervals",
        "",
        f"95 % percentile intervals from {N_BOOT} bootstrap replicates (seed 0) of each run's "
        "`per_scan.npz`: scans drawn with replacement and their counts summed (`scan`), and, "
        f"for runs over at least {MIN_SEQUENCES} sequences, whole sequences (`sequence`: "
        "another set of places like these). Scans of one sequence are correlated, so the "
        "scan-level interval is a lower bound on the uncertainty about unseen places. Compare "
        "two runs with `panoptic-bench eval compare RUN_A RUN_B` (paired).",
        "",
        f"| Run | Method | Resampled | n | {head} |",
        "|---|---|---|---:|" + "---:|" * len(METRICS),
        *body,
        "",
    ]
