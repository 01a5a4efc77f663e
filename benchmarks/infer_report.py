"""Markdown tables of ``bench_infer.py`` (split from it): stages, peak RSS, ratios, checks."""

from __future__ import annotations

import os
import platform

STAGES = [  # (key, label)
    ("voxelize", "voxelize (cylindrical grid, 9-D point features)"),
    ("backbone", "backbone: point MLP + U-Net + semantic & offset heads"),
    ("ms12", "BwF: mean shift 1.2 (bin seeding) + small-instance filter"),
    ("fusion", "BwF: consensus fusion"),
    ("fps", "DS: FPS seeds"),
    ("shift", "DS: dynamic shift (4 iterations × 3 bandwidths)"),
    ("ms065", "DS: mean shift 0.65 on converged seeds"),
    ("assign", "DS: nearest-seed assignment"),
    ("ds_fusion", "DS: small-instance filter + consensus fusion"),
    ("total_bwf", "**total Backbone with Fusion** (`Predictor.predict`)"),
    ("total_ds", "**total DS-Net** (`Predictor.predict`)"),
    ("median_backbone", "backbone, median of the frames"),
    ("median_total_bwf", "total Backbone with Fusion, median of the frames"),
    ("median_total_ds", "total DS-Net, median of the frames"),
]


def render(
    results: list[dict], load: tuple, repeats: dict, wall: float, threads: int, device: str
) -> str:
    """The ``benchmarks/results/infer.md`` text of one run (``results``: one dict per worker)."""
    cols = [f"{r['config']} ({r.get('variant', 'nominal')}) / {r['scan']}" for r in results]
    head = "| | " + " | ".join(cols) + " |\n|---|" + "---:|" * len(cols)
    by = {(r["config"], r["scan"]): r for r in results}
    lines = [
        "## Inference cost per frame (`bench_infer.py`)",
        "",
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, torch threads "
        f"{threads}, device {device}, `torch.inference_mode()`, random-initialised weights; "
        + (
            "CUDA: not measured (no GPU was lent when these figures were taken); "
            * (device == "cpu")
        )
        + "load average "
        f"{load[0][0]:.2f} before / {load[1][0]:.2f} after (1 min; other work shares the "
        "machine, absolute ms are noisy); one fresh process per column, a small-input "
        f"backbone call first (start-up costs). End-to-end: best (and median) of {repeats['CPU']} "
        f"frames per method (CPU config) / {repeats['paper']} (paper config); the backbone row is "
        "the fastest backbone call inside those frames; the other stages best of 3 on the same "
        f"inputs. Whole run {wall:.0f} s. "
        "Inside a frame's timing: `Predictor.predict` on a scan already in memory "
        "(voxelization, backbone, clustering, fusion); not inside: process start, imports, "
        "building the network, reading the `.bin` file (≈ 5 ms) and writing predictions. "
        "The official code cannot run here (CUDA, spconv 1.x), so the reference is the straightforward path of the same network in the same run (last table). "
        "Scans: `sequences/00/velodyne/000000.bin` (real) and a synthetic HDL-64E sweep "
        "(seed 0, sequence 08, frame 0). "
        "The backbone runs in full; its logits and offsets are then replaced by the ground truth "
        "and the simulated regression, so that clustering sees what a trained model would "
        "give it (see the module docstring).",
        "",
    ]
    busy = max(r["load_start"] for r in results)
    if threads > 1 and busy + threads > (os.cpu_count() or 1) + 1.0:
        lines += [
            f"**Oversubscribed:** load {busy:.1f} + {threads} thread(s) on {os.cpu_count()} "
            "cores. OpenMP parallel regions then wait for descheduled threads (tens of ms per "
            "sparse-conv `index_add_`), so figures, ratios included, can be off by 10× and more; "
            "re-run on an idle machine (or with `--threads 1`).",
            "",
        ]
    lines += [
        head,
    ]
    size = ["load_start", "load_end", "points", "voxels", "things", "seeds"]
    size += ["instances_bwf", "instances_ds"]
    for key in size:
        cells = [f"{r[key]:.2f}" if isinstance(r[key], float) else str(r[key]) for r in results]
        lines.append(f"| {key.replace('_', ' ')} | " + " | ".join(cells))
    lines[-len(size) :] = [s + " |" for s in lines[-len(size) :]]
    lines.append("| params (M) | " + " | ".join(f"{r['params_m']:.2f}" for r in results) + " |")
    for key, label in STAGES:
        cells = [f"{r[key]:.0f}" if r[key] >= 10 else f"{r[key]:.1f}" for r in results]
        lines.append(f"| {label}, ms | " + " | ".join(cells) + " |")
    lines += ["", "Peak RSS, MiB (fresh process per column; Δ = above the baseline after imports):"]
    lines += ["", head]
    rss = [
        ("baseline after imports", lambda r: r["rss_import"]),
        (
            "Δ after loading the scan, building the networks",
            lambda r: r["rss_model"] - r["rss_import"],
        ),
        ("Δ peak after a BwF frame", lambda r: r["rss_bwf"] - r["rss_import"]),
        ("Δ peak after a DS-Net frame", lambda r: r["rss_ds"] - r["rss_import"]),
        ("**absolute peak** (whole run)", lambda r: r["rss_peak"]),
    ]
    for label, fn in rss:
        lines.append(f"| {label} | " + " | ".join(f"{fn(r):.0f}" for r in results) + " |")
    lines += ["", "Ratios (same run, same scan):", "", "| ratio | scan | value |", "|---|---|---:|"]
    for r in results:
        ratio = r["total_ds"] / r["total_bwf"]
        lines.append(f"| DS-Net / BwF total, {r['config']} config | {r['scan']} | {ratio:.2f}× |")
    official, nominal = by.get(("paper", "real")), by.get(("paper-nominal", "real"))
    if official and nominal:
        for key, name in (("backbone", "backbone"), ("total_ds", "DS-Net total")):
            ratio = nominal[key] / official[key]
            lines.append(
                f"| nominal / official paper network (effective kernels, VFE 256 vs 64), {name} "
                f"| real | **{ratio:.2f}×** ({nominal[key]:.0f} vs {official[key]:.0f} ms) |"
            )
    for scan in ("real", "synthetic"):
        cpu, paper = by.get(("CPU", scan)), by.get(("paper", scan))
        if cpu and paper:
            for key, name in (("backbone", "backbone"), ("total_ds", "DS-Net total")):
                ratio = paper[key] / cpu[key]
                lines.append(f"| paper / CPU config, {name} | {scan} | **{ratio:.1f}×** |")
    for r in results:
        if "ref_nocache" in r:
            ratio = r["ref_nocache"] / r["ref_cached"]
            lines.append(
                f"| no kernel-map reuse / ours, backbone, {r['config']} config | {r['scan']} | "
                f"**{ratio:.2f}×** ({r['ref_nocache']:.0f} vs {r['ref_cached']:.0f} ms) |"
            )
    lines += check_lines(results)
    return "\n".join(lines) + "\n"


def check_lines(results: list[dict]) -> list[str]:
    """Fast inference path vs the straightforward per-offset path on the same scan and weights."""
    rows = [r for r in results if "check" in r]
    if not rows:
        return []
    lines = [
        "",
        "Outputs of the inference path (official network: `dsnet/sparse/tiles.py`, `pairs.py`, "
        "`fused.py`) vs the "
        "straightforward per-offset path (`fast_inference=False`, run at one thread), same "
        "random weights, same scan: max |difference| / max |value| of the raw backbone "
        "outputs, and the fraction of points whose `Predictor.predict` semantic class and "
        "instance id (DS-Net, real backbone outputs, no oracle) are equal.",
        "",
        "| check | scan | " + " | ".join(r["config"] for r in rows) + " |",
        "|---|---|" + "---:|" * len(rows),
    ]
    keys = [
        ("sem_logits", "semantic logits, rel. max diff", "{:.1e}"),
        ("offsets", "offsets, rel. max diff", "{:.1e}"),
        ("point_features", "point features, rel. max diff", "{:.1e}"),
        ("sem_equal", "per-point semantic class equal", "{:.4%}"),
        ("inst_equal", "per-point instance id equal", "{:.4%}"),
        ("ref_backbone_ms", "straightforward backbone (1 thread), ms", "{:.0f}"),
    ]
    for key, label, fmt in keys:
        cells = [fmt.format(r["check"][key]) for r in rows]
        lines.append(f"| {label} | {rows[0]['scan']} | " + " | ".join(cells) + " |")
    return lines
