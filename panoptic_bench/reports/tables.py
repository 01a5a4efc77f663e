"""Paper-layout tables from run directories, our numbers beside the paper's.

Every builder takes loaded :class:`~panoptic_bench.reports.runs.Run` objects and returns
:class:`~panoptic_bench.reports.render.ReportTable` objects (or None / [] when no run applies).
Numbers are copied from ``scores.json`` and converted from fractions to percent; nothing is
recomputed. Paper rows come first (``Source`` = ``paper``, ``Data`` = the paper's dataset split),
then ours (``Source`` = ``ours``, ``Data`` = what the run was computed on, from ``run.json``).

Example
-------
>>> from panoptic_bench.reports.runs import load_runs
>>> from panoptic_bench.reports.tables import build_tables
>>> from panoptic_bench.reports.render import write_table
>>> for table in build_tables(load_runs(["runs/dsnet"])):  # doctest: +SKIP
...     write_table(table, "reports/tables")
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import pandas as pd

from panoptic_bench.reports.paper import (
    MAIN_METRICS,
    PER_CLASS_TABLE,
    PRESENT_METRIC,
    SHORT_METRICS,
    main_table_for,
    normalize_name,
    paper_table_info,
    semantickitti_classes,
)
from panoptic_bench.reports.render import ReportTable
from panoptic_bench.reports.runs import Run

_DATASET_NAMES = {"semantickitti": "SemanticKITTI", "nuscenes": "nuScenes"}
_SPLIT_NAMES = {"val": "validation set", "test": "test set"}
NOTE = (
    "All values in %. Rows marked paper: published numbers of the DS-Net paper (Hong et al., "
    "CVPR 2021, Table {n}), {data}. Rows marked ours: computed by panoptic-bench on the data "
    "named in the Data column; they compare number-for-number with the paper only when that "
    "data is the paper's."
)
NOTE_OURS = "All values in %, computed by panoptic-bench on the data named in the Data column."
#: Columns of the Tables 1-3 layout: the paper's, then ours (empty in the paper's rows).
_MAIN_COLUMNS = (*MAIN_METRICS, PRESENT_METRIC)


def _pct(value: object) -> float:
    """Fraction -> percent; None / missing -> NaN."""
    if value is None:
        return float("nan")
    return 100.0 * float(value)


def _paper_data(number: int) -> str:
    info = paper_table_info(number)
    return f"{_DATASET_NAMES.get(info.dataset, info.dataset)} {info.split} (paper)"


def _paper_rows(number: int, label: str, columns: Sequence[str]) -> pd.DataFrame:
    info = paper_table_info(number)
    frame = info.frame.reindex(columns=list(columns))
    frame.insert(0, "Data", _paper_data(number))
    frame.insert(0, label, [str(i) for i in frame.index])
    frame.insert(0, "Source", "paper")
    return frame.reset_index(drop=True)


def _our_rows(runs: Sequence[Run], label: str, labels: Sequence[str], values: list[list]) -> list:
    return [
        {"Source": "ours", label: lab, "Data": run.data, **row}
        for run, lab, row in zip(runs, labels, values)
    ]


def _assemble(paper: pd.DataFrame | None, ours: list[dict], label: str, columns) -> pd.DataFrame:
    cols = ["Source", label, "Data", *columns]
    parts = [] if paper is None else [paper[cols]]
    if ours:
        parts.append(pd.DataFrame(ours, columns=cols))
    frame = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=cols)
    for col in columns:
        frame[col] = frame[col].astype(np.float64)
    return frame


def _metric_row(run: Run, columns: Sequence[str]) -> dict[str, float]:
    return {c: _pct(run.overall.get(c)) for c in columns}


def main_tables(runs: Sequence[Run]) -> list[ReportTable]:
    """Tables 1/2/3 layout: method x PQ, PQ†, RQ, SQ, PQ/RQ/SQ Th and St, mIoU, mIoU (present).

    The last column (``mIoU_present``, the mean over the classes with ground truth) is ours; the
    paper's rows leave it empty.

    Runs are grouped by the paper table of their ``dataset``/``split`` (SemanticKITTI val ->
    Table 1, test -> Table 2, nuScenes -> Table 3); runs of other datasets form a table without
    paper rows (``table_main_other``). Only groups with at least one run are returned.
    """
    groups: dict[int | None, list[Run]] = {}
    for run in runs:
        number = main_table_for(run.meta.dataset or "", run.meta.split or "val")
        groups.setdefault(number, []).append(run)
    tables = []
    for number in sorted(groups, key=lambda n: 99 if n is None else n):
        group = groups[number]
        ours = _our_rows(
            group,
            "Method",
            [r.method for r in group],
            [_metric_row(r, _MAIN_COLUMNS) for r in group],
        )
        if number is None:
            frame = _assemble(None, ours, "Method", _MAIN_COLUMNS)
            tables.append(
                ReportTable(
                    "table_main_other",
                    "Panoptic segmentation results (Tables 1-3 layout), datasets not in the paper",
                    "Method",
                    frame,
                    NOTE_OURS,
                )
            )
            continue
        info = paper_table_info(number)
        frame = _assemble(
            _paper_rows(number, "Method", _MAIN_COLUMNS), ours, "Method", _MAIN_COLUMNS
        )
        dataset = _DATASET_NAMES[info.dataset]
        split = _SPLIT_NAMES[info.split]
        tables.append(
            ReportTable(
                f"table{number}_{info.dataset}_{info.split}",
                f"Table {number}: panoptic segmentation, {dataset} {split} (paper) and ours",
                "Method",
                frame,
                NOTE.format(n=number, data=f"{dataset} {split}"),
            )
        )
    return tables


def format_bandwidths(bandwidths: Sequence[float]) -> str:
    """``(0.2, 1.7, 3.2)`` -> ``"0.2, 1.7, 3.2"`` (the paper's Table 4 spelling)."""
    return ", ".join(f"{b:.1f}" if round(b, 1) == b else f"{b:g}" for b in bandwidths)


def _ablation_table(
    runs: Sequence[Run],
    number: int,
    label: str,
    key: Callable[[Run], object],
    fmt: Callable[[object], str],
    name: str,
    what: str,
) -> ReportTable | None:
    chosen = sorted((r for r in runs if key(r) is not None), key=lambda r: key(r))
    if not chosen:
        return None
    ours = _our_rows(
        chosen,
        label,
        [fmt(key(r)) for r in chosen],
        [_metric_row(r, SHORT_METRICS) for r in chosen],
    )
    frame = _assemble(_paper_rows(number, label, SHORT_METRICS), ours, label, SHORT_METRICS)
    title = f"Table {number}: {what}, SemanticKITTI validation set (paper) and ours"
    note = NOTE.format(n=number, data="SemanticKITTI validation set")
    return ReportTable(name, title, label, frame, note)


def bandwidth_table(runs: Sequence[Run]) -> ReportTable | None:
    """Table 4: one row per run with ``run.json`` ``bandwidths``; None if there is none."""
    return _ablation_table(
        runs,
        4,
        "Bandwidth candidates (m)",
        lambda r: r.meta.bandwidths,
        format_bandwidths,
        "table4_bandwidths",
        "DS-Net bandwidth candidates",
    )


def iterations_table(runs: Sequence[Run]) -> ReportTable | None:
    """Table 5: one row per run with ``run.json`` ``iterations``; None if there is none."""
    return _ablation_table(
        runs,
        5,
        "Number of iterations",
        lambda r: r.meta.iterations,
        str,
        "table5_iterations",
        "number of dynamic shifting iterations",
    )


def _class_value(run: Run, cls: str, metric: str) -> float:
    wanted = normalize_name(cls)
    for name, metrics in run.classes.items():
        if normalize_name(name) == wanted:
            return _pct(metrics.get(metric))
    return float("nan")


def per_class_tables(runs: Sequence[Run]) -> list[ReportTable]:
    """Tables 6/7/8: per-class PQ, RQ, SQ; first column the run's overall value (copied).

    SemanticKITTI runs (``dataset`` spelled any way, e.g. ``semantic-kitti``) are set beside the
    paper's test-set rows in the paper's class order. Runs of other datasets with per-class
    scores get their own tables (``table6_per_class_pq_<dataset>``...) without paper rows, classes
    in the order of the first such run.
    """
    kitti = [r for r in runs if normalize_name(r.meta.dataset or "") == "semantickitti"]
    kitti = [r for r in kitti if r.classes]
    others: dict[str, list[Run]] = {}
    for run in runs:
        if run.classes and run not in kitti:
            others.setdefault(normalize_name(run.meta.dataset or "other") or "other", []).append(
                run
            )
    tables = []
    for metric, number in PER_CLASS_TABLE.items():
        if kitti:
            things, stuff = semantickitti_classes()
            cols = [metric, *things, *stuff]
            values = [
                {
                    metric: _pct(r.overall.get(metric)),
                    **{c: _class_value(r, c, metric) for c in cols[1:]},
                }
                for r in kitti
            ]
            ours = _our_rows(kitti, "Method", [r.method for r in kitti], values)
            frame = _assemble(_paper_rows(number, "Method", cols), ours, "Method", cols)
            title = f"Table {number}: per-class {metric}, SemanticKITTI test set (paper) and ours"
            note = NOTE.format(n=number, data="SemanticKITTI test set")
            tables.append(
                ReportTable(
                    f"table{number}_per_class_{metric.lower()}", title, "Method", frame, note
                )
            )
        for dataset, group in sorted(others.items()):
            names = list(group[0].classes)
            names += sorted({n for r in group for n in r.classes} - set(names))
            cols = [metric, *names]
            values = [
                {
                    metric: _pct(r.overall.get(metric)),
                    **{c: _class_value(r, c, metric) for c in names},
                }
                for r in group
            ]
            ours = _our_rows(group, "Method", [r.method for r in group], values)
            frame = _assemble(None, ours, "Method", cols)
            title = f"Per-class {metric} ({dataset}, Tables 6-8 layout)"
            name = f"table{number}_per_class_{metric.lower()}_{dataset}"
            tables.append(ReportTable(name, title, "Method", frame, NOTE_OURS))
    return tables


def range_label(lo: float, hi: float | None) -> str:
    """``(0, 10)`` -> ``"0-10 m"``; open bin ``(50, None)`` -> ``">=50 m"``."""
    if hi is None or (isinstance(hi, float) and math.isinf(hi)):
        return f">={lo:g} m"
    return f"{lo:g}-{hi:g} m"


def range_table(runs: Sequence[Run], metric: str = "PQ") -> ReportTable | None:
    """``metric`` per distance bin (``scores.json`` ``by_range``), one row per run; not in the paper."""
    chosen = [r for r in runs if r.by_range]
    if not chosen:
        return None
    bins: list[tuple] = []
    for run in chosen:
        for entry in run.by_range:
            key = (float(entry["range"][0]), entry["range"][1])
            if key not in bins:
                bins.append(key)
    bins.sort(key=lambda b: (b[0], math.inf if b[1] is None else b[1]))
    cols = [range_label(*b) for b in bins]
    values = []
    for run in chosen:
        row = dict.fromkeys(cols, float("nan"))
        for entry in run.by_range:
            row[range_label(float(entry["range"][0]), entry["range"][1])] = _pct(
                entry["all"].get(metric)
            )
        values.append(row)
    ours = _our_rows(chosen, "Method", [r.method for r in chosen], values)
    frame = _assemble(None, ours, "Method", cols)
    title = f"{metric} by distance from the sensor (ours; not in the paper)"
    return ReportTable(f"range_{metric.lower()}", title, "Method", frame, NOTE_OURS)


def build_tables(runs: Sequence[Run]) -> list[ReportTable]:
    """Every applicable table for ``runs``: Tables 1-3, 4, 5, 6-8 and the range table."""
    tables = list(main_tables(runs))
    tables += [t for t in (bandwidth_table(runs), iterations_table(runs)) if t is not None]
    tables += per_class_tables(runs)
    rng = range_table(runs)
    return tables + ([rng] if rng is not None else [])
