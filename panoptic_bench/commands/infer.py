"""``panoptic-bench infer``: run a DS-Net checkpoint on a split and write predictions."""

from __future__ import annotations

import argparse

CLUSTERERS = ("meanshift", "bfs", "dbscan", "hdbscan")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "infer",
        help="predict a split with a DS-Net / backbone checkpoint",
        description=(
            "Write official-format predictions (scorable by `panoptic-bench eval`), the "
            "regressed-centre .npz files and, for DS-Net checkpoints, the per-seed dynamic "
            "shifting diagnostics. A backbone checkpoint gives 'Backbone with Fusion' (mean "
            "shift 1.2 + consensus fusion); --clusterer swaps the clustering, fed the same centres."
        ),
    )
    p.add_argument("--checkpoint", required=True, help="checkpoint written by `train`")
    p.add_argument("--data", required=True, help="dataset root")
    p.add_argument(
        "--split", required=True, help="split name (valid, val...) or sequences (08 or 00,01)"
    )
    p.add_argument("--out", required=True, help="prediction root")
    p.add_argument("--clusterer", choices=CLUSTERERS, help="heuristic clustering of the centres")
    p.add_argument("--bandwidth", type=float, help="mean-shift bandwidth / BFS radius / eps (m)")
    p.add_argument("--no-fusion", action="store_true", help="skip consensus fusion")
    p.add_argument("--save-features", action="store_true", help="store features in the .npz")
    p.add_argument("--max-scans", type=int, default=0, help="only the first N scans (0 = all)")
    p.add_argument("--device", default="cpu", help="cpu or cuda")
    p.add_argument("--threads", type=int, help="torch CPU threads (default: torch's)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=handler)


def handler(args: argparse.Namespace) -> int:
    import shlex
    import sys

    import torch

    from panoptic_bench.dsnet.config import Clusterer
    from panoptic_bench.dsnet.inference.run import run_inference
    from panoptic_bench.errors import InputError

    if args.bandwidth is not None and not args.bandwidth > 0:
        raise InputError(f"--bandwidth must be > 0, got {args.bandwidth}")
    if args.threads:
        torch.set_num_threads(args.threads)
    summary = run_inference(
        args.checkpoint,
        args.data,
        args.split,
        args.out,
        clusterer=Clusterer(args.clusterer) if args.clusterer else None,
        bandwidth=args.bandwidth,
        fusion=False if args.no_fusion else None,
        save_features=args.save_features,
        max_samples=args.max_scans,
        device=args.device,
        progress=not args.no_progress,
        command=shlex.join(["panoptic-bench", *sys.argv[1:]]),
    )
    print(
        f"{summary.method}: {summary.num_scans} scans, {summary.ms_per_frame:.1f} ms/frame "
        f"-> {summary.out}"
    )
    return 0
