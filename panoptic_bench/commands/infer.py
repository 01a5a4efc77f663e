"""``panoptic-bench infer``: run a DS-Net checkpoint on a split and write predictions."""

from __future__ import annotations

import argparse

from panoptic_bench import cli_args as ca

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
    p.add_argument(
        "--checkpoint",
        required=True,
        help="checkpoint written by `train` or `checkpoint import-dsnet`, an ensemble file "
        "(`checkpoint ensemble`: members + views), or a shipped name: synthetic, "
        "synthetic-buildings, synthetic-ensemble, semantickitti-cpu, semantickitti-cpu-heldout, "
        "nuscenes-synthetic, ... (`checkpoint list`)",
    )
    p.add_argument("--data", required=True, help="dataset root")
    p.add_argument(
        "--split", help="split name (valid, val, mini_val...) or sequences (08 or 00,01)"
    )
    p.add_argument(
        "--sequences",
        nargs="+",
        action=ca.SequencesAction,
        metavar="SEQ",
        help="SemanticKITTI sequences, e.g. 08 or 00,01 (instead of --split)",
    )
    p.add_argument("--out", required=True, help="prediction root")
    ca.add_overwrite(p, "the --out tree")
    p.add_argument("--clusterer", choices=CLUSTERERS, help="heuristic clustering of the centres")
    p.add_argument(
        "--bandwidth", type=ca.metres, help="mean-shift bandwidth / BFS radius / eps (m)"
    )
    p.add_argument("--no-fusion", action="store_true", help="skip consensus fusion")
    p.add_argument("--save-features", action="store_true", help="store features in the .npz")
    p.add_argument(
        "--save-probs",
        action="store_true",
        help="also write every point's class probabilities (sequences/XX/probs/NNNNNN.npy, "
        "float16): the teacher targets of a training run with loss.distill",
    )
    p.add_argument(
        "--tta-views",
        type=ca.int_range(1, 16),
        help="test-time augmentation: average the backbone over K rotated / mirrored views "
        "(default: the checkpoint config's inference.tta_views, 1 = off)",
    )
    p.add_argument(
        "--bn-stats",
        choices=("running", "scan"),
        help="BatchNorm statistics at test time: the training averages (running) or each "
        "scan's own, as in training with one scan per batch (scan); default: the checkpoint "
        "config's inference.bn_stats",
    )
    p.add_argument(
        "--orphans",
        choices=("keep", "stuff"),
        help="points predicted as a thing class that end with no instance keep that class "
        "(keep) or take their most probable stuff class (stuff); default: the checkpoint "
        "config's inference.orphans",
    )
    p.add_argument(
        "--ensemble",
        nargs="+",
        default=[],
        metavar="CKPT",
        help="more checkpoints (paths or shipped names) whose class probabilities and offsets "
        "are averaged with --checkpoint's; dynamic shifting, density and settings stay "
        "--checkpoint's; the members must predict the same classes",
    )
    p.add_argument(
        "--max-scans", type=ca.nonneg_int, default=0, help="only the first N scans (0 = all)"
    )
    p.add_argument("--device", type=ca.device, default="cpu", help="cpu or cuda")
    p.add_argument("--threads", type=ca.threads, help="torch CPU threads (default: torch's)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=handler)


def handler(args: argparse.Namespace) -> int:
    import shlex
    import sys

    import torch

    from panoptic_bench.dsnet.config import Clusterer
    from panoptic_bench.dsnet.inference.run import run_inference
    from panoptic_bench.errors import InputError
    from panoptic_bench.io import output_tree

    if args.bandwidth is not None and not args.bandwidth > 0:
        raise InputError(f"--bandwidth must be > 0, got {args.bandwidth}")
    from panoptic_bench.dsnet.checkpoint import resolve_checkpoint

    checkpoint = resolve_checkpoint(args.checkpoint)
    ensemble = tuple(resolve_checkpoint(name) for name in args.ensemble)
    split = _split(args)
    if args.threads:
        torch.set_num_threads(args.threads)
    with output_tree(args.out, overwrite=args.overwrite, inputs=(args.data,)) as tmp:
        summary = run_inference(
            checkpoint,
            args.data,
            split,
            tmp,
            clusterer=Clusterer(args.clusterer) if args.clusterer else None,
            bandwidth=args.bandwidth,
            fusion=False if args.no_fusion else None,
            save_features=args.save_features,
            save_probs=args.save_probs,
            tta_views=args.tta_views,
            bn_stats=args.bn_stats,
            orphans=args.orphans,
            ensemble=ensemble,
            max_samples=args.max_scans,
            device=args.device,
            progress=not args.no_progress,
            command=shlex.join(["panoptic-bench", *sys.argv[1:]]),
        )
    print(
        f"{summary.method}: {summary.num_scans} scans, {summary.ms_per_frame:.1f} ms/frame "
        f"-> {args.out}"
    )
    return 0


def _split(args: argparse.Namespace) -> str:
    """The split string run_inference takes: a name, or comma-joined checked sequences."""
    from panoptic_bench.errors import InputError

    if args.sequences and args.split:
        raise InputError("give --split or --sequences, not both")
    if args.sequences:
        return ",".join(args.sequences)
    if not args.split:
        raise InputError("give --split (e.g. valid, mini_val) or --sequences (e.g. 08)")
    if all(part.strip().isascii() and part.strip().isdigit() for part in args.split.split(",")):
        try:  # old spelling --split 07,08: the same checks as --sequences
            return ",".join(ca.parse_sequences(args.split))
        except argparse.ArgumentTypeError as exc:
            raise InputError(f"--split: {exc}") from None
    return args.split
