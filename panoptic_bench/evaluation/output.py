"""Dataset-agnostic result files of an evaluation: ``scores.txt``, ``scores.json``, ``per_class.csv``.

``scores.json`` (fractions in [0, 1])::

    {"all": {"PQ", "PQ_dagger", "SQ", "RQ", "PQ_th", "SQ_th", "RQ_th",
             "PQ_st", "SQ_st", "RQ_st", "mIoU", "accuracy", "mIoU_present"},
     "classes": {name: {"PQ", "SQ", "RQ", "IoU"}},
     "by_range": [{"range": [lo, hi], "points": n, "all": {...}, "classes": {...}}, ...],
     ...extra keys}

``scores.txt`` holds the official codalab keys of semantic-kitti-api ``evaluate_panoptic.py`` as
YAML (``pq_mean, pq_dagger, sq_mean, rq_mean, iou_mean, pq_stuff, rq_stuff, sq_stuff, pq_things,
rq_things, sq_things``). ``per_class.csv``: ``class,kind,PQ,SQ,RQ,IoU`` (fractions, full precision).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from panoptic_bench.io import check_output_location, write_json, write_text
from panoptic_bench.metrics.by_range import RangeStats
from panoptic_bench.metrics.panoptic import PanopticResult

__all__ = [
    "CODALAB_KEYS",
    "check_output_location",
    "codalab_scores",
    "comparison_table",
    "interval_table",
    "percent_table",
    "scores_dict",
    "text_table",
    "write_scores",
]

#: codalab key -> key of :meth:`PanopticResult.summary`
CODALAB_KEYS: dict[str, str] = {
    "pq_mean": "PQ",
    "pq_dagger": "PQ_dagger",
    "sq_mean": "SQ",
    "rq_mean": "RQ",
    "iou_mean": "mIoU",
    "pq_stuff": "PQ_st",
    "rq_stuff": "RQ_st",
    "sq_stuff": "SQ_st",
    "pq_things": "PQ_th",
    "rq_things": "RQ_th",
    "sq_things": "SQ_th",
}


def _classes(result: PanopticResult, class_names, things, stuff) -> dict[str, dict[str, float]]:
    """Per-class metrics, things first then stuff (the order of the official tables)."""
    per = result.per_class(class_names)
    return {class_names[c]: per[class_names[c]] for c in (*things, *stuff)}


def scores_dict(
    result: PanopticResult,
    *,
    class_names: Sequence[str],
    things: Sequence[int],
    stuff: Sequence[int],
    by_range: RangeStats | None = None,
    extra: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The ``scores.json`` structure (see the module docstring) as plain Python objects."""
    scores: dict[str, Any] = {
        "all": result.summary(things, stuff),
        "classes": _classes(result, class_names, things, stuff),
        "by_range": [],
    }
    if by_range is not None:
        for (lo, hi, res), n in zip(by_range.compute(), by_range.point_counts()):
            scores["by_range"].append(
                {
                    "range": [lo, hi],
                    "points": n,
                    "all": res.summary(things, stuff),
                    "classes": _classes(res, class_names, things, stuff),
                }
            )
    for key, value in (extra or {}).items():
        if key in scores:
            raise ValueError(f"extra key {key!r} would overwrite a scores.json entry")
        scores[key] = value
    return scores


def codalab_scores(summary: Mapping[str, float]) -> dict[str, float]:
    """The official ``scores.txt`` mapping from a :meth:`PanopticResult.summary` dict."""
    return {key: float(summary[ours]) for key, ours in CODALAB_KEYS.items()}


def text_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """Fixed-width text table: first column left-aligned, the others right-aligned."""
    widths = [max(len(str(r[i])) for r in (header, *rows)) for i in range(len(header))]
    lines = []
    for r in (header, *rows):
        cells = [str(r[0]).ljust(widths[0])]
        cells += [str(c).rjust(w) for c, w in zip(r[1:], widths[1:])]
        lines.append("  ".join(cells).rstrip())
    return "\n".join(lines) + "\n"


def _pct(value: float) -> str:
    return f"{100 * value:6.2f}"


def percent_table(scores: Mapping[str, Any]) -> str:
    """Human-readable tables in percent from a ``scores.json`` dict.

    Returns
    -------
    str
        Per-class PQ/SQ/RQ/IoU, the headline metrics and (if present) one row per range bin.
    """
    classes = scores["classes"]
    cols = list(next(iter(classes.values()))) if classes else ["PQ", "SQ", "RQ", "IoU"]
    rows = [[name, *(_pct(m[c]) for c in cols)] for name, m in classes.items()]
    out = text_table(["class", *cols], rows) + "\n"
    bins = scores.get("by_range") or []
    metrics = list(scores["all"])
    head = ["", *(["points"] if bins else []), *metrics]
    rows = [["all", *([""] if bins else []), *(_pct(scores["all"][m]) for m in metrics)]]
    for b in bins:
        name = f"{b['range'][0]:g}-{b['range'][1]:g} m"
        points = "" if b.get("points") is None else str(b["points"])
        rows.append([name, points, *(_pct(b["all"][m]) for m in metrics)])
    return out + text_table(head, rows)


def interval_table(boot: Mapping[str, Any]) -> str:
    """The ``bootstrap`` entry of ``scores.json`` as a text table in percent."""
    rows = [
        [name, _pct(m["estimate"]), _pct(m["low"]), _pct(m["high"])]
        for name, m in boot["metrics"].items()
    ]
    level = f"{100 * boot['level']:g} %"
    unit = f"{boot['n_units']} {boot.get('unit', 'scan')}s"
    head = f"{level} intervals, {boot['n_boot']} bootstrap replicates of {unit} "
    return head + f"({boot['caveat']}):\n" + text_table(["", "value", "low", "high"], rows)


def comparison_table(cmp: Mapping[str, Any], names: Sequence[str] = ("A", "B")) -> str:
    """A paired comparison (:meth:`PairedResult.to_dict`) as a text table in percent."""
    a, b = names
    rows = [
        [
            name,
            _pct(m["a"]),
            _pct(m["b"]),
            f"{100 * m['diff']:+7.2f}",
            f"[{100 * m['low']:+.2f}, {100 * m['high']:+.2f}]",
            f"{m['p_b_greater']:.3f}",
        ]
        for name, m in cmp["metrics"].items()
    ]
    level = f"{100 * cmp['level']:g} %"
    head = ["", "A", "B", "B - A", f"{level} interval", "P(B > A)"]
    intro = (
        f"A = {a}\nB = {b}\npaired bootstrap, {cmp['n_boot']} replicates of the same "
        f"{cmp['n_units']} {cmp.get('unit', 'scan')}s ({cmp['caveat']}):\n"
    )
    return intro + text_table(head, rows)


def write_scores(
    out_dir: str | Path,
    result: PanopticResult,
    *,
    class_names: Sequence[str],
    things: Sequence[int],
    stuff: Sequence[int],
    by_range: RangeStats | None = None,
    extra: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Write ``scores.txt``, ``scores.json`` and ``per_class.csv`` atomically into ``out_dir``.

    Parameters
    ----------
    out_dir : path
        An existing output directory (see :func:`panoptic_bench.io.ensure_output_dir`).
    result : PanopticResult
    class_names : sequence of str
        Name of every class id.
    things, stuff : sequence of int
        Thing and stuff class ids (together the included classes).
    by_range : RangeStats, optional
        Per-range-bin accumulators, written under ``by_range``.
    extra : mapping, optional
        Additional top-level ``scores.json`` entries (e.g. ``{"n_scans": 4071}``).

    Returns
    -------
    dict
        The ``scores.json`` content.
    """
    out = Path(out_dir)
    scores = scores_dict(
        result,
        class_names=class_names,
        things=things,
        stuff=stuff,
        by_range=by_range,
        extra=extra,
    )
    lines = ["class,kind,PQ,SQ,RQ,IoU"]
    kinds = {class_names[c]: "thing" for c in things} | {class_names[c]: "stuff" for c in stuff}
    for name, m in scores["classes"].items():
        lines.append(f"{name},{kinds[name]},{m['PQ']!r},{m['SQ']!r},{m['RQ']!r},{m['IoU']!r}")
    text = yaml.safe_dump(codalab_scores(scores["all"]), default_flow_style=False)
    write_text(out / "scores.txt", text)
    write_json(out / "scores.json", scores)
    write_text(out / "per_class.csv", "\n".join(lines) + "\n")
    return scores
