"""``panoptic-bench train``: DS-Net training stages (semantic, offset, dynamic shifting)."""

from __future__ import annotations

import argparse

from panoptic_bench import cli_args as ca


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "train",
        help="train DS-Net (stage 1 semantic, stage 2 offsets, stage ds dynamic shifting)",
        description=(
            "Train DS-Net on a SemanticKITTI-format or nuScenes-format root. Each stage starts "
            "from the previous stage's checkpoint in RUN_DIR/checkpoints. Launch with torchrun "
            "for several processes (DDP; gloo on CPU)."
        ),
    )
    p.add_argument("--config", required=True, help="YAML config (see configs/dsnet_*.yaml)")
    p.add_argument("--data", required=True, help="dataset root")
    p.add_argument("--out", required=True, help="run directory (checkpoints, metrics.csv)")
    p.add_argument(
        "--stage", default="all", choices=("semantic", "offset", "ds", "all"), help="default all"
    )
    p.add_argument("--resume", action="store_true", help="continue from the stage checkpoint")
    p.add_argument("--epochs", type=ca.nonneg_int, help="epochs per stage (overrides the config)")
    p.add_argument("--init", help="checkpoint to start the first stage from")
    p.add_argument("--device", type=ca.device, help="cpu or cuda (default: cuda when available)")
    p.add_argument("--threads", type=ca.threads, help="torch CPU threads (default: torch's)")
    p.add_argument("--notes", default="", help="free text stored in RUN_DIR/run.json")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=handler)


def handler(args: argparse.Namespace) -> int:
    import torch

    from panoptic_bench.dsnet.config import load_config
    from panoptic_bench.dsnet.training.train import train
    from panoptic_bench.errors import InputError

    if args.epochs is not None and args.epochs < 0:
        raise InputError(f"--epochs must be >= 0, got {args.epochs}")
    from panoptic_bench.io import check_output_location

    check_output_location(args.out, (args.data,))  # never write into the dataset
    if args.threads:
        torch.set_num_threads(args.threads)
    cfg = load_config(args.config)
    paths = train(
        cfg,
        args.data,
        args.out,
        stage=args.stage,
        resume=args.resume,
        epochs=args.epochs,
        init=args.init,
        device=args.device,
        progress=not args.no_progress,
        notes=args.notes,
    )
    for stage, path in paths.items():
        print(f"{stage}: {path}")
    return 0
