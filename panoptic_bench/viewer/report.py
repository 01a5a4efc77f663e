"""Viewer pages of report sets: the best and the worst scan of a run by PQ.

A run directory may hold ``viewer_scans.npz`` (written by :func:`write_best_and_worst`, e.g. by
``panoptic-bench demo``); ``panoptic-bench report`` turns it into one self-contained page per scan,
``DIR/viewer/<run>-best.html`` and ``DIR/viewer/<run>-worst.html``, linked from ``index.md``.
Report pages draw
at most :data:`REPORT_MAX_POINTS` points per scan (a fixed random subset; the matching and the
numbers use every point) so that committed report sets stay small.

``viewer_scans.npz``: ``meta`` (0-d JSON string: ``{"classes": ViewClasses.to_dict(),
"scans": [{"name", "label", "anchor"}]}``) and per scan ``k``: ``s{k}_xyz`` float32 (n, 3),
``s{k}_{pred,gt}_{sem,inst}`` int64 (n,), optional ``s{k}_centres`` float32 (n, 3).
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tqdm import tqdm

from panoptic_bench.errors import InputError
from panoptic_bench.io import write_npz
from panoptic_bench.viewer.scene import ViewClasses, ViewScan, scan_pq

__all__ = [
    "REPORT_MAX_POINTS",
    "VIEWER_FILE",
    "read_viewer_scans",
    "viewer_markdown",
    "viewer_pages",
    "write_best_and_worst",
    "write_viewer_scans",
]

VIEWER_FILE = "viewer_scans.npz"
#: Points drawn per scan on report pages (about 0.5 MB of page per scan).
REPORT_MAX_POINTS = 30_000


def write_viewer_scans(
    run_dir: str | Path,
    scans: Sequence[ViewScan],
    classes: ViewClasses,
    labels: Sequence[str],
    anchors: Sequence[str],
) -> Path:
    """Write ``run_dir/viewer_scans.npz`` holding ``scans`` (see the module docstring)."""
    arrays: dict[str, np.ndarray] = {}
    for k, s in enumerate(scans):
        arrays[f"s{k}_xyz"] = np.asarray(s.xyz, np.float32)
        for key in ("pred_sem", "pred_inst", "gt_sem", "gt_inst"):
            arrays[f"s{k}_{key}"] = np.asarray(getattr(s, key), np.int64)
        if s.centres is not None:
            arrays[f"s{k}_centres"] = np.asarray(s.centres, np.float32)
    entries = [
        {"name": s.name, "label": lab, "anchor": a} for s, lab, a in zip(scans, labels, anchors)
    ]
    meta = json.dumps({"classes": classes.to_dict(), "scans": entries})
    path = Path(run_dir) / VIEWER_FILE
    write_npz(path, meta=np.array(meta), **arrays)
    return path


def read_viewer_scans(path: str | Path) -> tuple[list[ViewScan], ViewClasses, list[dict]]:
    """Read ``viewer_scans.npz``: the scans, their classes and the ``{"name", "label", "anchor"}``
    entries. Raises :class:`InputError` naming the file if it is malformed."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as npz:
            data = {k: npz[k] for k in npz.files}
        meta = json.loads(str(data["meta"]))
        classes = ViewClasses.from_dict(meta["classes"])
        scans = []
        for k, entry in enumerate(meta["scans"]):
            get = data.get
            scans.append(
                ViewScan(
                    entry["name"],
                    data[f"s{k}_xyz"],
                    data[f"s{k}_pred_sem"],
                    data[f"s{k}_pred_inst"],
                    data[f"s{k}_gt_sem"],
                    data[f"s{k}_gt_inst"],
                    get(f"s{k}_centres"),
                )  # fmt: skip
            )
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile) as exc:
        raise InputError(f"malformed viewer input ({exc})", path) from None
    return scans, classes, meta["scans"]


def write_best_and_worst(
    run_dir: str | Path,
    dataset: str | Path,
    predictions: str | Path,
    sequences: Sequence[str],
    *,
    centers: str | Path | None = None,
) -> Path:
    """Rank the SemanticKITTI scans of ``sequences`` by PQ and keep the best and the worst.

    PQ per scan is :func:`~panoptic_bench.viewer.scene.scan_pq` (mean over the classes present);
    ties go to the earlier scan. Writes ``run_dir/viewer_scans.npz`` and returns its path.
    """
    from panoptic_bench.datasets.semantickitti import list_scans
    from panoptic_bench.viewer.load import load_semantickitti

    refs = list_scans(dataset, sequences=list(sequences))
    scores = []
    for ref in tqdm(refs, desc="PQ per scan", unit="scan", disable=None):
        scan, classes = load_semantickitti(
            dataset, f"{ref.sequence}/{ref.frame}", predictions=predictions
        )
        pq = scan_pq(scan, classes)
        scores.append(-1.0 if np.isnan(pq) else pq)
    best, worst = int(np.argmax(scores)), int(np.argmin(scores))
    picked = [(best, "best scan by PQ", "best"), (worst, "worst scan by PQ", "worst")]
    if best == worst:
        picked = picked[:1]
    scans = []
    for i, _, _ in picked:
        ref = refs[i]
        scan, classes = load_semantickitti(
            dataset, f"{ref.sequence}/{ref.frame}", predictions=predictions, centers=centers
        )
        scans.append(scan)
    labels = [p[1] for p in picked]
    anchors = [p[2] for p in picked]
    return write_viewer_scans(run_dir, scans, classes, labels, anchors)


def viewer_pages(
    runs: Sequence,
    slugs: Sequence[str],
    out_dir: str | Path,
    *,
    max_points: int = REPORT_MAX_POINTS,
) -> list[dict]:
    """Write ``out_dir/viewer/<slug>-<anchor>.html`` (one page per scan, e.g. ``-best``,
    ``-worst``) for each run that has ``viewer_scans.npz``.

    Parameters
    ----------
    runs : sequence of panoptic_bench.reports.runs.Run
    slugs : sequence of str
        File stem per run (as for the figures).
    out_dir : path
        Report directory.
    max_points : int
        Points drawn per scan.

    Returns
    -------
    list of dict
        ``{"run", "method", "source", "scans": [{"name", "label", "anchor", "pq", "page"}]}``
        per run with pages (``page``: path relative to ``out_dir``).
    """
    from panoptic_bench.viewer.page import write_page

    pages = []
    for run, slug in zip(runs, slugs):
        run_dir = run.path if run.path.is_dir() else run.path.parent
        src = run_dir / VIEWER_FILE
        if not src.is_file():
            continue
        scans, classes, entries = read_viewer_scans(src)
        for entry, scan in zip(entries, scans):
            rel = f"viewer/{slug}-{entry['anchor']}.html"
            write_page(
                Path(out_dir) / rel, [scan], classes,
                title=f"{run.method}, {entry['label']}: prediction vs ground truth",
                labels=[entry["label"]], anchors=[entry["anchor"]], max_points=max_points,
                note=f"{run.data}. At most {max_points:,} points drawn (a fixed random subset).",
            )  # fmt: skip
            entry.update(pq=scan_pq(scan, classes), page=rel)
        pages.append(
            {"run": str(run.path), "method": run.method, "source": str(src), "scans": entries}
        )
    return pages


def viewer_markdown(pages: Sequence[dict], command: str) -> list[str]:
    """The ``## Viewer`` section of index.md (empty when there are no pages)."""
    if not pages:
        return []
    lines = [
        "## Viewer",
        "",
        "Interactive 3-D pages (one self-contained HTML file each, opens offline in a browser):",
        "prediction and ground truth side by side, coloured by class, instance or error (TP / FP /",
        "FN segments from the evaluator's matching). PQ per scan: mean over the classes present.",
        "",
    ]
    for page in pages:
        links = []
        for s in page["scans"]:
            pq = "n/a" if s["pq"] != s["pq"] else f"{100 * s['pq']:.1f} %"
            links.append(f"[{s['label']}: {s['name']}, PQ {pq}]({s['page']})")
        lines += [f"- {page['method']}: " + "; ".join(links) + f" (from `{page['source']}`)"]
    return lines + ["", f"Produced by `{command}`.", ""]
