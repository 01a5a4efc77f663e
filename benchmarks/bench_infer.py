"""CPU cost of DS-Net inference per frame: stages, end-to-end totals and peak RSS.

Configurations ``configs/dsnet_synthetic_cpu.yaml`` (CPU, the nominal network) and
``configs/dsnet_semantickitti.yaml`` (paper: the official DS-Net network, ``model.variant:
official``, with its effective kernels, voxel rule and inference rules), random-initialised weights (``torch.manual_seed(0)``; the backbone's cost does not depend
on training), on the real scan ``../shared/data/semantickitti/sequences/00/velodyne/000000.bin``
and on a synthetic ~120k-point HDL-64E sweep (``panoptic_bench.datasets.synthetic``, seed 0,
sequence 08, frame 0).

What a random network predicts is not what a trained one predicts, and the clustering stages
depend on it (how many thing points, where their centres are). So the real backbone runs in
full, and its semantic logits and offsets are then replaced by the scan's ground truth
(unlabelled points -> a stuff class) and the simulated regression of
:mod:`panoptic_bench.baselines.regression` (default noise, seed 0): the clustering stages see
the inputs a trained model would give them. Point features (dynamic shifting's MLP input) and
the shift module's weights stay random. End-to-end totals are ``Predictor.predict`` (the
function ``panoptic-bench infer`` calls per scan): voxelize -> backbone -> semantic + offsets ->
mean shift 1.2 (Backbone with Fusion) or dynamic shifting (FPS seeds, shift, mean shift 0.65,
nearest seed) -> consensus fusion. Stages are the same library calls timed one by one.

Each (configuration, scan) runs in a fresh subprocess with torch threads = 2 (``--threads N``;
use 1 while other jobs keep the cores busy: with 2 threads every OpenMP parallel region then
waits for a descheduled thread and a frame can take 10-100x longer) under
``torch.inference_mode()``; peak RSS is ``getrusage(RUSAGE_SELF).ru_maxrss`` after the first
Backbone-with-Fusion frame and after the first DS-Net frame, minus the baseline after imports.
A small-input backbone call comes first (start-up costs); end-to-end timings are the best of N
frames per method, the other stages the best of 3 on the same inputs.

Same-run references (no external baseline exists: the official code does not build on CPU):
paper / CPU config cost, DS-Net / Backbone-with-Fusion cost, and the backbone with kernel-map
reuse switched off (every submanifold layer rebuilds its own map and neighbour pairs) / ours.

Usage: ``.venv/bin/python benchmarks/bench_infer.py [--quick | --paper-only] [--threads N]``;
writes ``benchmarks/results/infer.md``. CUDA: not measured (no GPU was available).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
CONFIGS = {
    "CPU": "configs/dsnet_synthetic_cpu.yaml",
    "paper": "configs/dsnet_semantickitti.yaml",
    "paper-nominal": "configs/dsnet_semantickitti.yaml",  # + NOMINAL_PAPER: the network before
}
# the paper config before it built the official network (nominal kernels, VFE width 256)
NOMINAL_PAPER = {"variant": "nominal", "point_feature_dim": 256}
KITTI = ROOT.parent / "shared" / "data" / "semantickitti"
THREADS = 2  # default; --threads overrides (workers read PB_BENCH_THREADS)
DEVICE = "cpu"  # --device overrides (workers read PB_BENCH_DEVICE)
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
]


def _rss_mib() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: KiB


def _load_scan(kind: str):
    """A LidarSample (ground truth included) of the real or the synthetic scan."""
    import numpy as np

    from panoptic_bench.datasets import semantickitti as sk
    from panoptic_bench.dsnet.data.datasets import LidarSample, SemanticKittiDataset

    if kind == "real":
        ds = SemanticKittiDataset(KITTI, sequences=["00"])
        return ds.load(0), ds.class_map
    from panoptic_bench.datasets.synthetic import Sequence

    sw = Sequence(seed=0, key=8, n_frames=1).frame(0).sweep
    sem = sk.to_train(sw.label).astype(np.int64)
    things = np.isin(sem, sk.LABELS.thing_ids)
    inst = np.where(things, sw.instance.astype(np.int64), 0)
    sample = LidarSample(sw.xyz, sw.remission, sem, inst, ("08", "000000"))
    return sample, SemanticKittiDataset(KITTI, sequences=["00"]).class_map


def _oracle(net, sample, class_map):
    """The real backbone, its logits / offsets then replaced by GT + simulated regression.

    Returns the wrapper (it records the wall time of every backbone call in ``.times`` and
    the last raw output in ``.last``), the oracle train ids and the offsets.
    """
    import dataclasses

    import numpy as np
    import torch

    from panoptic_bench.baselines.regression import simulate_offsets

    sem = sample.sem.copy()
    sem[np.isin(sem, class_map.ignore_ids)] = class_map.stuff_ids[0]
    logits = torch.zeros(len(sem), class_map.num_classes)
    logits[torch.arange(len(sem)), torch.from_numpy(sem)] = 10.0
    off = simulate_offsets(sample.xyz, sample.sem, sample.inst, class_map.thing_ids, seed=0)
    offsets = torch.from_numpy(off)

    class Oracle(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.net, self.times, self.last = net, [], None

        def forward(self, batch):
            t0 = time.perf_counter()
            self.last = self.net(batch)
            self.times.append((time.perf_counter() - t0) * 1e3)
            return dataclasses.replace(self.last, sem_logits=logits, offsets=offsets)

    return Oracle(), sem, off.astype(np.float64)


def _best(fn, repeats: int) -> tuple[float, object]:
    best, result = float("inf"), None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        best = min(best, (time.perf_counter() - t0) * 1e3)
    return best, result


def worker(config: str, scan: str, repeats: int, warmup: bool, no_cache_ref: bool) -> dict:
    """Everything measured for one (configuration, scan), in this (fresh) process."""
    import numpy as np
    import torch

    from panoptic_bench.baselines.panoptic import consensus_fusion, filter_small_instances
    from panoptic_bench.dsnet.checkpoint import (
        build_backbone,
        build_grid,
        build_shift,
        is_official,
    )
    from panoptic_bench.dsnet.config import Clusterer, load_config
    from panoptic_bench.dsnet.inference.clustering import make_clusterer
    from panoptic_bench.dsnet.inference.official import official_seeds
    from panoptic_bench.dsnet.inference.predictor import Predictor
    from panoptic_bench.dsnet.model import shift_ops  # noqa: F401 - numba kernels load with imports
    from panoptic_bench.dsnet.model.dynamic_shift import (
        assign_to_seeds,
        cluster_seeds,
        select_seeds,
    )
    from panoptic_bench.dsnet.model.voxelize import collate
    from panoptic_bench.dsnet.sparse import functional as spf

    torch.set_num_threads(int(os.environ.get("PB_BENCH_THREADS", THREADS)))
    device = torch.device(os.environ.get("PB_BENCH_DEVICE", "cpu"))
    rss_import = _rss_mib()
    cfg = load_config(ROOT / CONFIGS[config])
    if config == "paper-nominal":
        from panoptic_bench.dsnet.config import NetworkVariant

        cfg = cfg.replace(model={**NOMINAL_PAPER, "variant": NetworkVariant.NOMINAL})
    sample, cmap = _load_scan(scan)
    torch.manual_seed(0)
    net = build_backbone(cfg, cmap.num_classes).to(device).eval()
    shift = build_shift(cfg, cfg.model.init_size).to(device).eval()
    model, sem, off = _oracle(net, sample, cmap)
    res: dict = {"config": config, "scan": scan, "points": len(sample.xyz)}
    official = is_official(cfg)
    res["variant"] = cfg.model.variant.value
    res["device"] = device.type
    res["load_start"] = os.getloadavg()[0]
    res["params_m"] = sum(p.numel() for p in net.parameters()) / 1e6
    res["rss_model"] = _rss_mib()
    bwf = Predictor(model, None, cfg, cmap, device)
    dsnet = Predictor(model, shift, cfg, cmap, device)
    best = {"total_bwf": float("inf"), "total_ds": float("inf")}
    scan4 = np.concatenate([sample.xyz, sample.remission[:, None]], axis=1)
    with torch.inference_mode():
        net(collate([scan4[::25]], build_grid(cfg), device))  # start-up costs, small input
        if warmup:
            bwf.predict(sample)
            dsnet.predict(sample)
            model.times.clear()
        for _ in range(repeats):  # end to end; backbone time recorded inside
            for key, pred in (("total_bwf", bwf), ("total_ds", dsnet)):
                t0 = time.perf_counter()
                out = pred.predict(sample)
                best[key] = min(best[key], (time.perf_counter() - t0) * 1e3)
                res.setdefault("rss_bwf" if key == "total_bwf" else "rss_ds", _rss_mib())
                res.setdefault("instances_" + key[6:], int(out.inst.max()))
        res.update(best, backbone=min(model.times))
        # the other stages, one by one, on the same inputs
        features = model.last.point_features
        n = max(repeats, 3)
        res["voxelize"], batch = _best(lambda: collate([scan4], build_grid(cfg), device), n)
        res["voxels"] = int(batch.voxel_coords.shape[0])
        things = np.flatnonzero(cmap.thing_lut()[sem])
        centres = sample.xyz[things].astype(np.float64) + off[things]
        res["things"] = len(things)
        ms12 = make_clusterer(Clusterer.MEANSHIFT, cfg.inference.bandwidth)
        mp = cfg.inference.min_points

        def bwf_cluster():
            inst = np.zeros(len(sem), dtype=np.int64)
            inst[things] = filter_small_instances(ms12.fit_predict(centres), mp)
            return inst

        res["ms12"], inst = _best(bwf_cluster, n)
        res["fusion"], _ = _best(lambda: consensus_fusion(sem, inst, cmap.num_classes), n)
        if official:  # FPS on the points' xyz, nearest seed by xyz (official rules)
            pts = sample.xyz[things].astype(np.float64)

            def fps():
                got = official_seeds(pts, cfg.dynamic_shift.max_seeds)
                return np.arange(len(pts)) if got is None else got

            res["fps"], idx = _best(fps, n)
        else:
            res["fps"], idx = _best(lambda: select_seeds(centres, cfg.dynamic_shift.max_seeds), n)
        space = pts if official else centres
        res["seeds"] = len(idx)
        seeds = torch.from_numpy(centres[idx]).float().to(device)
        feats = features[torch.from_numpy(things[idx]).to(features.device)].float()
        res["shift"], sh = _best(lambda: shift(seeds, feats), n)
        final = sh.final.double().cpu().numpy()
        ms065 = make_clusterer(cfg.inference.ds_clusterer, cfg.inference.ds_bandwidth)
        res["ms065"], seed_lab = _best(lambda: cluster_seeds(final, ms065), n)
        res["assign"], lab = _best(lambda: assign_to_seeds(space, space[idx], seed_lab), n)

        def ds_fuse():
            out_inst = np.zeros(len(sem), dtype=np.int64)
            _, dense = np.unique(lab, return_inverse=True)
            out_inst[things] = filter_small_instances(dense.reshape(-1), mp)
            return consensus_fusion(sem, out_inst, cmap.num_classes)

        res["ds_fusion"], _ = _best(ds_fuse, n)
        if no_cache_ref:  # paired with a cached run each time, so both see the same load
            original = spf.submanifold_map

            def no_reuse(x, kernel_size):  # drop the maps and pairs earlier layers built
                for key in [k for k in x.cache if k[0] in ("subm", "offset")]:
                    del x.cache[key]
                return original(x, kernel_size)

            cached, fresh = [], []
            for _ in range(repeats):
                cached.append(_best(lambda: net(batch), 1)[0])
                spf.submanifold_map = no_reuse
                try:
                    fresh.append(_best(lambda: net(batch), 1)[0])
                finally:
                    spf.submanifold_map = original
            res["ref_cached"], res["ref_nocache"] = min(cached), min(fresh)
    res.update(rss_import=rss_import, rss_peak=_rss_mib(), load_end=os.getloadavg()[0])
    return res


def run_worker(config: str, scan: str, repeats: int, warmup: bool, no_cache_ref: bool) -> dict:
    n = str(THREADS)
    env = dict(os.environ, OMP_NUM_THREADS=n, NUMBA_NUM_THREADS=n, PB_BENCH_THREADS=n)
    env["PB_BENCH_DEVICE"] = DEVICE
    flags = [str(repeats), str(int(warmup)), str(int(no_cache_ref))]
    cmd = [sys.executable, __file__, "--worker", config, scan, *flags]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=ROOT, check=False)
    if proc.returncode:
        raise RuntimeError(f"worker {config}/{scan} failed:\n{proc.stderr}")
    res = json.loads(proc.stdout.strip().splitlines()[-1])
    res["wall_s"] = time.perf_counter() - t0
    print(f"  {config}/{scan}: {res['wall_s']:.0f} s", file=sys.stderr, flush=True)
    return res


def render(results: list[dict], load: tuple, repeats: dict, wall: float) -> str:
    cols = [f"{r['config']} ({r.get('variant', 'nominal')}) / {r['scan']}" for r in results]
    head = "| | " + " | ".join(cols) + " |\n|---|" + "---:|" * len(cols)
    by = {(r["config"], r["scan"]): r for r in results}
    lines = [
        "## Inference cost per frame (`bench_infer.py`)",
        "",
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, torch threads "
        f"{THREADS}, device {DEVICE}, `torch.inference_mode()`, random-initialised weights; "
        + (
            "CUDA: not measured (no GPU was lent when these figures were taken); "
            * (DEVICE == "cpu")
        )
        + "load average "
        f"{load[0][0]:.2f} before / {load[1][0]:.2f} after (1 min; other work shares the "
        "machine, absolute ms are noisy); one fresh process per column, a small-input "
        f"backbone call first (start-up costs). End-to-end: best of {repeats['CPU']} frames "
        f"per method (CPU config) / {repeats['paper']} (paper config); the backbone row is the "
        "fastest backbone call inside those frames; the other stages best of 3 on the same "
        f"inputs. Whole run {wall:.0f} s. "
        "Scans: `sequences/00/velodyne/000000.bin` (real) and a synthetic HDL-64E sweep "
        "(seed 0, sequence 08, frame 0). "
        "The backbone runs in full; its logits and offsets are then replaced by the ground truth "
        "and the simulated regression, so that clustering sees what a trained model would "
        "give it (see the module docstring).",
        "",
    ]
    busy = max(r["load_start"] for r in results)
    if THREADS > 1 and busy + THREADS > (os.cpu_count() or 1) + 0.5:
        lines += [
            f"**Oversubscribed:** load {busy:.1f} + {THREADS} thread(s) on {os.cpu_count()} "
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
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    global THREADS, DEVICE
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--worker"]:
        config, scan, *flags = argv[1:]
        print(json.dumps(worker(config, scan, *(int(f) for f in flags))))
        return 0
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="real scan only, fewer repeats")
    parser.add_argument("--device", default="cpu", help="cpu (default) or cuda")
    parser.add_argument(
        "--paper-only", action="store_true", help="only the paper (official) config, real scan"
    )
    parser.add_argument(
        "--threads", type=int, default=THREADS, help="torch / numba / OpenMP threads (default 2)"
    )
    args = parser.parse_args(argv)
    THREADS, DEVICE = args.threads, args.device
    repeats = {"CPU": 2, "paper": 1, "paper-nominal": 1}
    # (config, scan, warm-up frames, kernel-map reference); the paper config forward costs
    # 10-60 s per frame on 2 shared cores, so it runs once per method, on the real scan
    runs = [("CPU", "real", False, True)]
    if args.paper_only:
        runs = [("paper", "real", False, False)]
    elif not args.quick:
        runs += [("CPU", "synthetic", False, False), ("paper", "real", False, False)]
        runs += [("paper-nominal", "real", False, False)]
    t0, load0 = time.perf_counter(), os.getloadavg()
    results = [run_worker(c, s, repeats[c], w, ref) for c, s, w, ref in runs]
    text = render(results, (load0, os.getloadavg()), repeats, time.perf_counter() - t0)
    print(text)
    from panoptic_bench.io import write_text

    write_text(HERE / "results" / "infer.md", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
