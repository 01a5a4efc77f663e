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

The official network runs its inference path (``PanopticBackbone(fast_inference=True)``, at two
threads or more without gradients: mask-sorted tile GEMMs for the wide submanifold and inverse
convs, :mod:`panoptic_bench.dsnet.sparse.tiles`; per-offset GEMMs with a parallel gather-sum for
the others, :mod:`~panoptic_bench.dsnet.sparse.pairs`; in-place eval BatchNorm, merged convs
sharing an input and folded point MLPs, :mod:`~panoptic_bench.dsnet.sparse.fused`); its column
ends with a check of that path against the straightforward per-offset path (run at one thread)
on the same scan and weights: raw outputs and ``Predictor.predict`` classes and instance ids.

Usage: ``.venv/bin/python benchmarks/bench_infer.py [--quick | --paper-only] [--threads N]
[--configs official,cpu,... --frames N]``; the official column alone:
``--configs official --threads 2 --frames 1``. Writes ``benchmarks/results/infer.md``; rendering
is in ``infer_report.py``. ``--device cuda`` times the same calls on a GPU (each stage waits for its
kernels); ``benchmarks/cuda_check.sh`` runs it on the device machine.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from infer_report import render  # noqa: E402

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
            _sync()
            self.times.append((time.perf_counter() - t0) * 1e3)
            return dataclasses.replace(self.last, sem_logits=logits, offsets=offsets)

    return Oracle(), sem, off.astype(np.float64)


def _sync() -> None:
    """Wait for queued CUDA work (a stage's wall time on a GPU includes its kernels)."""
    import torch

    if os.environ.get("PB_BENCH_DEVICE", "cpu").startswith("cuda"):
        torch.cuda.synchronize()


def _best(fn, repeats: int) -> tuple[float, object]:
    best, result = float("inf"), None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        _sync()
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
    times: dict[str, list[float]] = {"total_bwf": [], "total_ds": []}
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
                times[key].append((time.perf_counter() - t0) * 1e3)
                res.setdefault("rss_bwf" if key == "total_bwf" else "rss_ds", _rss_mib())
                res.setdefault("instances_" + key[6:], int(out.inst.max()))
        res.update({k: min(v) for k, v in times.items()}, backbone=min(model.times))
        res.update({"median_" + k: float(np.median(v)) for k, v in times.items()})
        res["median_backbone"] = float(np.median(model.times))
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
        if getattr(net, "fast_inference", False):
            res["check"] = fast_path_check(net, shift, cfg, cmap, sample, device)
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


def fast_path_check(net, shift, cfg, cmap, sample, device) -> dict:
    """The inference path vs the straightforward per-offset path, same weights and scan.

    Raw backbone outputs (max difference relative to the largest value) and the
    ``Predictor.predict`` DS-Net classes and instance ids (real backbone outputs, no oracle);
    the straightforward path runs at one thread (it is the faster one there).
    """
    import numpy as np
    import torch

    from panoptic_bench.dsnet.checkpoint import build_grid
    from panoptic_bench.dsnet.inference.predictor import Predictor
    from panoptic_bench.dsnet.model.forward import backbone_forward

    threads = torch.get_num_threads()
    outs, preds = {}, {}
    for fast in (True, False):
        net.fast_inference = fast
        torch.set_num_threads(threads if fast else 1)
        t0 = time.perf_counter()
        outs[fast] = backbone_forward(net, [sample], build_grid(cfg), device)
        elapsed = (time.perf_counter() - t0) * 1e3
        torch.manual_seed(0)
        preds[fast] = Predictor(net, shift, cfg, cmap, device).predict(sample)
    net.fast_inference = True
    torch.set_num_threads(threads)
    res: dict = {"ref_backbone_ms": elapsed}
    for key in ("sem_logits", "offsets", "point_features"):
        a, b = getattr(outs[False], key), getattr(outs[True], key)
        res[key] = float((a - b).abs().max()) / max(float(a.abs().max()), 1e-30)
    res["sem_equal"] = float(np.mean(preds[True].sem == preds[False].sem))
    res["inst_equal"] = float(np.mean(preds[True].inst == preds[False].inst))
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


RUNS = {  # --configs name -> (config, scan, warm-up frames, kernel-map reference)
    "cpu": ("CPU", "real", False, True),
    "cpu-synthetic": ("CPU", "synthetic", False, False),
    "official": ("paper", "real", False, False),
    "paper-nominal": ("paper-nominal", "real", False, False),
}


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
        "--configs",
        default=None,
        help=f"comma-separated columns among {', '.join(RUNS)} (default: all; --quick: cpu)",
    )
    parser.add_argument(
        "--frames", type=int, default=None, help="end-to-end frames per method (best of N)"
    )
    parser.add_argument(
        "--threads", type=int, default=THREADS, help="torch / numba / OpenMP threads (default 2)"
    )
    args = parser.parse_args(argv)
    THREADS, DEVICE = args.threads, args.device
    repeats = {"CPU": 2, "paper": 1, "paper-nominal": 1}
    if args.frames is not None:
        if args.frames < 1:
            parser.error("--frames must be >= 1")
        repeats = dict.fromkeys(repeats, args.frames)
    # the paper config forward costs seconds per frame on 2 shared cores, so by default it
    # runs once per method, on the real scan
    names = ["cpu"] if args.quick else list(RUNS)
    if args.paper_only:
        names = ["official"]
    if args.configs:
        names = [c.strip() for c in args.configs.split(",") if c.strip()]
        unknown = [c for c in names if c not in RUNS]
        if unknown or not names:
            parser.error(f"--configs: unknown {unknown}; choose among {', '.join(RUNS)}")
    runs = [RUNS[c] for c in names]
    t0, load0 = time.perf_counter(), os.getloadavg()
    results = [run_worker(c, s, repeats[c], w, ref) for c, s, w, ref in runs]
    load = (load0, os.getloadavg())
    text = render(results, load, repeats, time.perf_counter() - t0, THREADS, DEVICE)
    print(text)
    from panoptic_bench.io import write_text

    write_text(HERE / "results" / "infer.md", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
