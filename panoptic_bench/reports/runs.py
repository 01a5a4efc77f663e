"""Reading result directories for reports: ``scores.json`` plus optional ``run.json`` metadata.

A *run directory* is what ``eval`` / ``cluster`` / ``train`` / ``infer`` leave behind. The report
reads, and never recomputes:

``scores.json`` (required), written by the evaluator, metrics as fractions in [0, 1]::

    {"all": {"PQ", "PQ_dagger", "SQ", "RQ", "PQ_th", "SQ_th", "RQ_th",
             "PQ_st", "SQ_st", "RQ_st", "mIoU", "accuracy", "mIoU_present"},
     "classes": {name: {"PQ", "SQ", "RQ", "IoU"}},
     "by_range": [{"range": [lo, hi], "all": {...}}, ...]}      # optional; hi may be null
                                                                # or Infinity; the metrics may
                                                                # also sit in the entry itself

``run.json`` (optional) says what the numbers are. Every key is optional; unknown keys are an
error (so a typo does not silently drop a row from a table)::

    {"method": "DS-Net",                 # row label (default: the directory name)
     "dataset": "semantickitti",         # semantickitti | nuscenes | anything else
     "split": "val",                     # val | test | ...; picks Table 1 or 2
     "data": "synthetic world, seq 08",  # what the numbers were computed on (shown in tables)
     "notes": "...",                     # free text, listed in index.md
     "command": "panoptic-bench eval ...",  # the command that wrote scores.json
     "bandwidths": [0.2, 1.7, 3.2],      # DS-Net bandwidth candidates -> Table 4 row
     "iterations": 4,                    # DS-Net iterations -> Table 5 row
     "ablation": {"framework": "+ DS",   # Fig. 4a bar (backbone / + fusion / + DS)
                  "clustering": "DS",    # Fig. 4b bar (BFS, DBSCAN, HDBSCAN, Mean Shift, DS)
                  "bandwidth_learning": "weighted candidates"}}  # Fig. 4c bar

``scores.json`` may also be passed directly instead of its directory.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from panoptic_bench.errors import InputError

SCORES_FILE = "scores.json"
RUN_FILE = "run.json"
ABLATION_KEYS = ("framework", "clustering", "bandwidth_learning")
_FLAT_METRICS = frozenset(
    ("PQ", "PQ_dagger", "SQ", "RQ", "PQ_th", "SQ_th", "RQ_th", "PQ_st", "SQ_st", "RQ_st", "mIoU")
) | {"accuracy", "mIoU_present"}


@dataclass(frozen=True)
class RunMeta:
    """Contents of ``run.json`` (see the module docstring); every field optional."""

    method: str | None = None
    dataset: str | None = None
    split: str | None = None
    data: str | None = None
    notes: str | None = None
    command: str | None = None
    bandwidths: tuple[float, ...] | None = None
    iterations: int | None = None
    ablation: Mapping[str, str] = field(default_factory=dict)

    @classmethod
    def from_dict(cls, raw: Mapping[str, Any], path: str | Path | None = None) -> RunMeta:
        """Validate ``raw`` (the parsed ``run.json``); unknown keys or wrong types raise InputError."""
        if not isinstance(raw, Mapping):
            raise InputError("run.json must hold a JSON object", path)
        allowed = [f.name for f in fields(cls)]
        unknown = sorted(set(raw) - set(allowed))
        if unknown:
            raise InputError(f"unknown key(s) {unknown}; allowed: {allowed}", path)
        kwargs: dict[str, Any] = {}
        for key in ("method", "dataset", "split", "data", "notes", "command"):
            value = raw.get(key)
            if value is not None and not isinstance(value, str):
                raise InputError(f"'{key}' must be a string, got {value!r}", path)
            kwargs[key] = value
        bws = raw.get("bandwidths")
        if bws is not None:
            if not isinstance(bws, list) or not bws or not all(_is_number(b) for b in bws):
                raise InputError(f"'bandwidths' must be a list of numbers, got {bws!r}", path)
            kwargs["bandwidths"] = tuple(float(b) for b in bws)
        its = raw.get("iterations")
        if its is not None:
            if not isinstance(its, int) or isinstance(its, bool) or its < 0:
                raise InputError(f"'iterations' must be a non-negative integer, got {its!r}", path)
            kwargs["iterations"] = its
        abl = raw.get("ablation", {}) or {}
        if not isinstance(abl, Mapping) or not all(isinstance(v, str) for v in abl.values()):
            raise InputError("'ablation' must map figure keys to bar labels (strings)", path)
        bad = sorted(set(abl) - set(ABLATION_KEYS))
        if bad:
            raise InputError(f"unknown ablation key(s) {bad}; allowed: {list(ABLATION_KEYS)}", path)
        kwargs["ablation"] = dict(abl)
        return cls(**kwargs)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict without the fields left at None / empty (inverse of from_dict)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if value is None or (f.name == "ablation" and not value):
                continue
            out[f.name] = list(value) if f.name == "bandwidths" else value
            if f.name == "ablation":
                out[f.name] = dict(value)
        return out


@dataclass(frozen=True)
class Run:
    """One loaded run directory.

    Attributes
    ----------
    path : Path
        The directory (or the ``scores.json`` file) as given.
    meta : RunMeta
        Parsed ``run.json`` (all None when the file is absent).
    scores : dict
        Parsed ``scores.json``, metrics as fractions.
    """

    path: Path
    meta: RunMeta
    scores: dict

    @property
    def method(self) -> str:
        """Row label: ``run.json`` ``method``, else the directory name."""
        if self.meta.method:
            return self.meta.method
        return (self.path.parent if self.path.name == SCORES_FILE else self.path).name

    @property
    def data(self) -> str:
        """What the numbers were computed on: ``run.json`` ``data`` or ``dataset split``."""
        if self.meta.data:
            return self.meta.data
        parts = [p for p in (self.meta.dataset, self.meta.split) if p]
        return " ".join(parts) if parts else "unspecified data"

    @property
    def overall(self) -> dict[str, float]:
        """``scores["all"]``: metric -> fraction."""
        return self.scores["all"]

    @property
    def classes(self) -> dict[str, dict[str, float]]:
        """``scores["classes"]``: class name -> {"PQ", "SQ", "RQ", "IoU"} fractions ({} if absent)."""
        return self.scores.get("classes", {}) or {}

    @property
    def by_range(self) -> list[dict]:
        """``scores["by_range"]`` ([] if absent); a bin's ``hi`` may be None (open-ended)."""
        return self.scores.get("by_range", []) or []


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _read_json(path: Path) -> Any:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError("file not found", path) from None
    except OSError as exc:
        raise InputError(f"cannot read file ({exc.strerror})", path) from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(
            f"malformed JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})", path
        ) from None


def _check_metric(value: Any, where: str, path: Path) -> None:
    if value is None:
        return
    if not _is_number(value) or not (math.isnan(value) or -1e-9 <= value <= 1 + 1e-9):
        raise InputError(f"{where} must be a fraction in [0, 1] (or null), got {value!r}", path)


def validate_scores(scores: Any, path: str | Path) -> dict:
    """Check a parsed ``scores.json`` and return it with ``by_range`` normalised.

    Every ``by_range`` entry gets an ``"all"`` object (flat entries are folded into one) and an
    open upper bound ``None``. Raises InputError naming ``path`` on any structural problem.
    """
    path = Path(path)
    if not isinstance(scores, dict) or not isinstance(scores.get("all"), dict):
        raise InputError("scores.json must be an object with an 'all' object of metrics", path)
    missing = [k for k in ("PQ", "SQ", "RQ") if k not in scores["all"]]
    if missing:
        raise InputError(f"'all' lacks {missing}; was it written by 'panoptic-bench eval'?", path)
    for key, value in scores["all"].items():
        _check_metric(value, f"all.{key}", path)
    classes = scores.get("classes", {}) or {}
    if not isinstance(classes, dict):
        raise InputError("'classes' must map class names to metric objects", path)
    for name, metrics in classes.items():
        if not isinstance(metrics, dict):
            raise InputError(f"classes.{name} must be an object of metrics", path)
        for key, value in metrics.items():
            _check_metric(value, f"classes.{name}.{key}", path)
    by_range = scores.get("by_range", []) or []
    if not isinstance(by_range, list):
        raise InputError("'by_range' must be a list of {'range': [lo, hi], 'all': {...}}", path)
    normalized = []
    for i, entry in enumerate(by_range):
        rng = entry.get("range") if isinstance(entry, dict) else None
        ok = (
            isinstance(rng, list)
            and len(rng) == 2
            and _is_number(rng[0])
            and (rng[1] is None or _is_number(rng[1]))
        )
        if not ok:
            raise InputError(f"by_range[{i}] must be {{'range': [lo, hi], 'all': {{...}}}}", path)
        metrics = entry.get("all")
        if metrics is None:  # flat form: {"range": [lo, hi], "points": n, "PQ": ..., ...}
            metrics = {k: v for k, v in entry.items() if k in _FLAT_METRICS}
        if not isinstance(metrics, dict):
            raise InputError(f"by_range[{i}].all must be an object of metrics", path)
        for key, value in metrics.items():
            _check_metric(value, f"by_range[{i}].{key}", path)
        hi = None if rng[1] is None or math.isinf(rng[1]) else rng[1]
        normalized.append({**entry, "range": [rng[0], hi], "all": metrics})
    scores = dict(scores)
    scores["by_range"] = normalized
    return scores


def load_run(path: str | Path) -> Run:
    """Load one run directory (or a ``scores.json`` path).

    Raises
    ------
    InputError
        Missing ``scores.json``, malformed JSON, a metric outside [0, 1], or a bad ``run.json``;
        the message names the offending file.
    """
    path = Path(path)
    if path.is_dir():
        scores_path, run_path = path / SCORES_FILE, path / RUN_FILE
    elif path.suffix == ".json" and path.exists():
        scores_path, run_path = path, path.parent / RUN_FILE
    elif not path.exists():
        raise InputError("result directory not found; pass directories holding scores.json", path)
    else:
        raise InputError("not a run directory or a scores.json file", path)
    if not scores_path.is_file():
        raise InputError(f"no {SCORES_FILE} here; run 'panoptic-bench eval' first", scores_path)
    scores = validate_scores(_read_json(scores_path), scores_path)
    meta = RunMeta.from_dict(_read_json(run_path), run_path) if run_path.is_file() else RunMeta()
    return Run(path=path, meta=meta, scores=scores)


def load_runs(paths: list[str | Path]) -> list[Run]:
    """Load several run directories, keeping their order; see :func:`load_run`."""
    return [load_run(p) for p in paths]
