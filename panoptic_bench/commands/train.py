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
    p.add_argument(
        "--seed",
        type=ca.nonneg_int,
        help="random seed of the run: scan order, point subsets, augmentation, pasting "
        "(overrides optim.seed; stored in the checkpoints, so --resume needs the same value)",
    )
    p.add_argument("--init", help="checkpoint to start the first stage from")
    p.add_argument("--device", type=ca.device, help="cpu or cuda (default: cuda when available)")
    p.add_argument("--threads", type=ca.threads, help="torch CPU threads (default: torch's)")
    p.add_argument("--notes", default="", help="free text stored in RUN_DIR/run.json")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument(
        "--train-sequences",
        action=ca.SequencesAction,
        metavar="SEQS",
        help="SemanticKITTI sequences to train on, e.g. 00,01 (overrides data.train_sequences)",
    )
    p.add_argument(
        "--val-sequences",
        action=ca.SequencesAction,
        metavar="SEQS",
        help="held-out sequences to validate on, e.g. 05,06 (overrides data.val_sequences); "
        "one k-fold split per run, the split is stored in the run's checkpoints",
    )
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
    cfg = with_sequences(load_config(args.config), args.train_sequences, args.val_sequences)
    if args.seed is not None:
        import dataclasses

        cfg = dataclasses.replace(cfg, optim=dataclasses.replace(cfg.optim, seed=args.seed))
    _note_unread_sequences(args.data, cfg)
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


def _note_unread_sequences(root: str, cfg) -> None:
    """Say on stderr which labelled sequences of ``root`` this run will not read."""
    import sys

    from panoptic_bench.dsnet.data.datasets import unread_sequences

    unread = unread_sequences(root, cfg.data)
    if unread:
        print(
            f"note: {len(unread)} labelled sequence(s) under {root}/sequences are in neither "
            f"data.train_sequences nor data.val_sequences and are not read: {', '.join(unread)} "
            "(list them in the config or pass --train-sequences)",
            file=sys.stderr,
        )


def with_sequences(cfg, train: list[str] | None, val: list[str] | None):
    """``cfg`` with its SemanticKITTI train / validation sequences replaced where given.

    Raises
    ------
    InputError
        Sequences given for a nuScenes config, or a sequence in both sets (a frame-level leak:
        consecutive frames of one sequence are near-duplicates, so validate by held-out sequence).
    """
    import dataclasses

    from panoptic_bench.dsnet.config import DatasetFormat
    from panoptic_bench.errors import InputError

    if train is None and val is None:
        return cfg
    if cfg.data.format is not DatasetFormat.SEMANTICKITTI:
        raise InputError(
            "--train-sequences / --val-sequences need a SemanticKITTI config "
            f"(data.format is {cfg.data.format.value})"
        )
    data = dataclasses.replace(
        cfg.data,
        train_sequences=tuple(train) if train is not None else cfg.data.train_sequences,
        val_sequences=tuple(val) if val is not None else cfg.data.val_sequences,
    )
    both = sorted(set(data.train_sequences) & set(data.val_sequences))
    if both:
        raise InputError(
            f"sequence(s) {', '.join(both)} both trained on and validated on "
            f"(train {','.join(data.train_sequences)}; validation {','.join(data.val_sequences)}): "
            "validate on held-out sequences; give both --train-sequences and --val-sequences"
        )
    return dataclasses.replace(cfg, data=data)
