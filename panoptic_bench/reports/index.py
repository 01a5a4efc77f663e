"""``build_report``: every applicable table and figure for a set of run directories, plus index.md.

Inputs per run directory (see :mod:`panoptic_bench.reports.runs` for ``scores.json`` and
``run.json``); the optional files below feed the analysis figures and are read as is:

``analysis.json`` (every key optional; unknown keys are an error)::

    {"centres_per_voxel": {"distance_m": [5, 15, ...],             # Fig. 3a
                           "counts": [..] or {label: [..]}},
     "bandwidth_rq": {"bandwidth_m": [0.4, 0.8, ...],              # Fig. 3b
                      "rq": {class: [fractions]}},
     "learned_bandwidth": {"size_m": {class: m},                   # Fig. 5
                           "bandwidth_m": {class: m}},
     "bandwidth_per_iteration": {"bandwidth_m": {class: [m per iteration]},   # Fig. 7
                                 "lower_limit": 0.2}}

``shift_iterations.npz`` (Fig. 6): ``points`` (n, >=2), ``seeds`` (n_panels, m, >=2),
``bandwidths`` (n_panels, m).

``bev.npz`` (bird's-eye panoptic view): ``xyz`` (n, >=2) float, ``pred_sem``, ``pred_inst``,
``gt_sem``, ``gt_inst`` (n,) int, ``thing_classes`` (k,) int.

``viewer_scans.npz`` (interactive viewer pages ``viewer/<run>.html`` of the best and the worst
scan by PQ): see :mod:`panoptic_bench.viewer.report`.

Figs. 4a/4b/4c are drawn from ``scores.json`` of runs whose ``run.json`` has ``ablation`` keys
``framework`` / ``clustering`` / ``bandwidth_learning``; PQ by range from ``by_range``.
"""

from __future__ import annotations

import json
import re
import shlex
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np
from tqdm import tqdm

from panoptic_bench.errors import InputError
from panoptic_bench.io import ensure_output_dir, write_text
from panoptic_bench.reports import bev, figures
from panoptic_bench.reports.intervals import interval_markdown
from panoptic_bench.reports.render import to_markdown, write_table
from panoptic_bench.reports.runs import ABLATION_KEYS, Run, load_runs
from panoptic_bench.reports.tables import build_tables
from panoptic_bench.viewer.report import viewer_markdown, viewer_pages

ANALYSIS_FILE = "analysis.json"
SHIFT_FILE = "shift_iterations.npz"
BEV_FILE = "bev.npz"
ANALYSIS_KEYS = (
    "centres_per_voxel",
    "bandwidth_rq",
    "learned_bandwidth",
    "bandwidth_per_iteration",
)
ABLATION_TITLES = {
    "framework": ("fig4a_framework", "Fig. 4a: framework ablation"),
    "clustering": ("fig4b_clustering", "Fig. 4b: clustering algorithms"),
    "bandwidth_learning": ("fig4c_bandwidth_learning", "Fig. 4c: bandwidth learning style"),
}


@dataclass
class _Job:
    """One figure to draw: file stem, title, source runs and the drawing call."""

    stem: str
    title: str
    sources: list[Run]
    draw: Callable[[Path], Path]
    input_file: Path | None = None
    outputs: list[Path] = field(default_factory=list)


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "-", text).strip("-").lower() or "run"


def _run_slugs(runs: Sequence[Run]) -> list[str]:
    slugs: list[str] = []
    for run in runs:
        base = _slug(run.path.name if run.path.is_dir() else run.path.parent.name)
        slug, k = base, 2
        while slug in slugs:
            slug, k = f"{base}-{k}", k + 1
        slugs.append(slug)
    return slugs


def _labels(runs: Sequence[Run]) -> list[str]:
    """Method names, with the data appended where two runs share a method name."""
    names = [r.method for r in runs]
    return [f"{r.method} ({r.data})" if names.count(r.method) > 1 else r.method for r in runs]


def _read_analysis(run_dir: Path) -> dict | None:
    path = run_dir / ANALYSIS_FILE
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise InputError(f"malformed JSON (line {exc.lineno}: {exc.msg})", path) from None
    if not isinstance(data, dict):
        raise InputError("analysis.json must hold a JSON object", path)
    unknown = sorted(set(data) - set(ANALYSIS_KEYS))
    if unknown:
        raise InputError(f"unknown key(s) {unknown}; allowed: {list(ANALYSIS_KEYS)}", path)
    return data


def _read_npz(path: Path, keys: Sequence[str]) -> dict[str, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as npz:
            missing = [k for k in keys if k not in npz.files]
            if missing:
                raise InputError(f"missing array(s) {missing}; expected {list(keys)}", path)
            return {k: npz[k] for k in keys}
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise InputError(f"not a readable .npz archive ({exc})", path) from None


def _guard(path: Path, draw: Callable[[Path], Path]) -> Callable[[Path], Path]:
    """Turn shape/key errors from drawing user-supplied arrays into an InputError on ``path``."""

    def run(out: Path) -> Path:
        try:
            return draw(out)
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise InputError(f"cannot draw a figure from this file: {exc}", path) from None

    return run


def _analysis_jobs(run: Run, slug: str, data: dict, path: Path) -> list[_Job]:
    specs = []
    try:
        if "centres_per_voxel" in data:
            d = data["centres_per_voxel"]
            draw = partial(figures.plot_centres_vs_distance, d["distance_m"], d["counts"])
            specs.append(
                ("fig3a_centres_vs_distance", "Fig. 3a: regressed centres per voxel", draw)
            )
        if "bandwidth_rq" in data:
            d = data["bandwidth_rq"]
            draw = partial(figures.plot_bandwidth_vs_rq, d["bandwidth_m"], d["rq"])
            specs.append(("fig3b_bandwidth_vs_rq", "Fig. 3b: mean-shift bandwidth vs RQ", draw))
        if "learned_bandwidth" in data:
            d = data["learned_bandwidth"]
            draw = partial(figures.plot_bandwidth_vs_size, d["size_m"], d["bandwidth_m"])
            specs.append(("fig5_bandwidth_vs_size", "Fig. 5: learned bandwidth vs size", draw))
        if "bandwidth_per_iteration" in data:
            d = data["bandwidth_per_iteration"]
            draw = partial(
                figures.plot_bandwidth_vs_iteration,
                d["bandwidth_m"],
                lower_limit=d.get("lower_limit"),
            )
            specs.append(("fig7_bandwidth_vs_iteration", "Fig. 7: bandwidth vs iteration", draw))
    except (KeyError, TypeError, AttributeError) as exc:
        raise InputError(f"missing or malformed entry {exc}; see 'report' docs", path) from None
    return [
        _Job(f"{stem}_{slug}", title, [run], _guard(path, fn), path) for stem, title, fn in specs
    ]


def _figure_jobs(runs: Sequence[Run]) -> list[_Job]:
    jobs: list[_Job] = []
    for key in ABLATION_KEYS:
        chosen = [r for r in runs if key in r.meta.ablation]
        if chosen:
            values = {
                r.meta.ablation[key]: {m: r.overall.get(m) for m in ("PQ", "PQ_th")} for r in chosen
            }
            stem, title = ABLATION_TITLES[key]
            jobs.append(
                _Job(stem, title, chosen, partial(figures.plot_ablation, values, title=title))
            )
    ranged = [r for r in runs if r.by_range]
    if ranged:
        labels = dict(zip(map(id, runs), _labels(runs)))
        series = {}
        for run in ranged:
            ranges = [[e["range"][0], e["range"][1]] for e in run.by_range]
            ranges = [[lo, np.inf if hi is None else hi] for lo, hi in ranges]
            pq = [e["all"].get("PQ") for e in run.by_range]
            series[labels[id(run)]] = (ranges, [np.nan if v is None else v for v in pq])
        draw = partial(figures.plot_pq_vs_range, series)
        jobs.append(_Job("pq_vs_range", "PQ by distance (ours)", ranged, draw))
    for run, slug in zip(runs, _run_slugs(runs)):
        run_dir = run.path if run.path.is_dir() else run.path.parent
        analysis = _read_analysis(run_dir)
        if analysis:
            jobs += _analysis_jobs(run, slug, analysis, run_dir / ANALYSIS_FILE)
        path = run_dir / SHIFT_FILE
        if path.is_file():
            arr = _read_npz(path, ("points", "seeds", "bandwidths"))
            draw = partial(
                figures.plot_shift_iterations, arr["points"], arr["seeds"], arr["bandwidths"]
            )
            title = "Fig. 6: seeds over the dynamic shifting iterations"
            jobs.append(
                _Job(f"fig6_shift_iterations_{slug}", title, [run], _guard(path, draw), path)
            )
        path = run_dir / BEV_FILE
        if path.is_file():
            keys = ("xyz", "pred_sem", "pred_inst", "gt_sem", "gt_inst", "thing_classes")
            arr = _read_npz(path, keys)
            panels = [
                (run.method, arr["pred_sem"], arr["pred_inst"]),
                ("ground truth", arr["gt_sem"], arr["gt_inst"]),
            ]
            draw = partial(
                _draw_bev, arr["xyz"], panels, arr["thing_classes"].tolist(), title=run.data
            )
            title = "Bird's-eye panoptic view (prediction | ground truth)"
            jobs.append(_Job(f"bev_panoptic_{slug}", title, [run], _guard(path, draw), path))
    return jobs


def _draw_bev(xyz, panels, thing_classes, path: Path, *, title: str) -> Path:
    return bev.plot_bev_panoptic(xyz, panels, thing_classes, path, title=title)


def report_command(results: Sequence[str | Path], out_dir: str | Path) -> str:
    """The CLI line that rebuilds a report: ``panoptic-bench report --results ... --out ...``."""
    args = ["panoptic-bench", "report", "--results", *map(str, results), "--out", str(out_dir)]
    return shlex.join(args)


def _index_markdown(runs, tables, jobs, command: str, results, viewers=()) -> str:
    lines = [
        "# panoptic-bench report",
        "",
        "Rebuild everything on this page with:",
        "",
        "```bash",
        command,
        "```",
        "",
        "Numbers are read from each run's `scores.json` (written by `panoptic-bench eval`); the",
        "report recomputes nothing but the intervals (from `per_scan.npz`). Rows marked **ours**",
        "were computed on the data named in their Data column; rows marked paper are the",
        "published numbers of the DS-Net paper.",
        "",
        "## Runs",
        "",
        "| Run | Method | Dataset | Data | Produced by | Notes |",
        "|---|---|---|---|---|---|",
    ]
    for given, run in zip(results, runs):
        ds = " ".join(p for p in (run.meta.dataset, run.meta.split) if p) or "-"
        cmd = f"`{run.meta.command}`" if run.meta.command else "-"
        notes = run.meta.notes or "-"
        cells = [f"`{given}`", run.method, ds, run.data, cmd, notes]
        lines.append("| " + " | ".join(c.replace("|", r"\|") for c in cells) + " |")
    lines += ["", "## Tables", ""]
    for table in tables:
        links = ", ".join(f"[{ext}](tables/{table.name}.{ext})" for ext in ("md", "csv", "tex"))
        lines += [to_markdown(table), f"Files: {links}; produced by `{command}`.", ""]
    lines += interval_markdown(runs, [str(r) for r in results])
    lines += ["## Figures", ""]
    if not jobs:
        lines += ["No run provided figure inputs.", ""]
    for job in jobs:
        src = ", ".join(f"`{s}`" for s in dict.fromkeys(str(r.path) for r in job.sources))
        extra = f" and `{job.input_file}`" if job.input_file else ""
        lines += [
            f"### {job.title}",
            "",
            f"![{job.title}](figures/{job.stem}.png)",
            "",
            f"From {src}{extra}; produced by `{command}`.",
            "",
        ]
    lines += viewer_markdown(viewers, command)
    return "\n".join(lines).rstrip("\n") + "\n"


def build_report(
    results: Sequence[str | Path],
    out_dir: str | Path,
    *,
    command: str | None = None,
) -> Path:
    """Write every applicable table and figure for ``results`` into ``out_dir`` with index.md.

    Parameters
    ----------
    results : sequence of str or Path
        Run directories (each holding ``scores.json``, optionally ``run.json``,
        ``analysis.json``, ``shift_iterations.npz``, ``bev.npz``) or ``scores.json`` paths.
    out_dir : str or Path
        Output directory (created; existing files of the same names are replaced). Tables go to
        ``tables/NAME.{md,csv,tex}``, figures to ``figures/NAME.png``.
    command : str, optional
        The command line recorded in index.md; default :func:`report_command`.

    Returns
    -------
    Path
        ``out_dir / "index.md"``.

    Raises
    ------
    InputError
        No results, a missing ``scores.json``, malformed JSON or arrays; names the file.
    """
    if not results:
        raise InputError("no result directories given; pass --results RUN_DIR [RUN_DIR ...]")
    runs = load_runs(list(results))
    inputs = tuple(r.path if r.path.is_dir() else r.path.parent for r in runs)
    out = ensure_output_dir(out_dir, overwrite=True, inputs=inputs)
    command = command or report_command(results, out_dir)
    tables = build_tables(runs)
    jobs = _figure_jobs(runs)
    for table in tqdm(tables, desc="tables", unit="table", disable=None):
        write_table(table, out / "tables")
    for job in tqdm(jobs, desc="figures", unit="fig", disable=None):
        job.outputs.append(job.draw(out / "figures" / f"{job.stem}.png"))
    viewers = viewer_pages(runs, _run_slugs(runs), out)
    index = out / "index.md"
    write_text(index, _index_markdown(runs, tables, jobs, command, results, viewers))
    return index
