"""``panoptic-bench checkpoint``: inspect, export, average, import or re-estimate DS-Net checkpoints."""

from __future__ import annotations

import argparse

from panoptic_bench import cli_args as ca


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "checkpoint",
        help="show or export DS-Net checkpoints",
        description="Inspect a checkpoint written by `train`, export it for inference, average, "
        "import or re-estimate its BatchNorm statistics.",
    )
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    lst = sub.add_parser("list", help="the shipped short names, their files and what they are")
    lst.set_defaults(func=list_handler)
    show = sub.add_parser("show", help="stage, epoch, class map, metrics and config")
    show.add_argument(
        "checkpoint", help="a .pt file or a shipped short name (e.g. semantickitti-cpu)"
    )
    show.set_defaults(func=show_handler)
    exp = sub.add_parser(
        "export", help="copy without optimizer/RNG state (e.g. panoptic_bench/checkpoints/*.pt)"
    )
    exp.add_argument("checkpoint", help="a .pt file or a shipped short name")
    exp.add_argument("--out", required=True, help="destination .pt")
    exp.add_argument("--half", action="store_true", help="store weights as float16")
    exp.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    exp.set_defaults(func=export_handler)
    avg = sub.add_parser(
        "average",
        help="average the weights of checkpoints of one network (a model soup)",
        description="Write one checkpoint whose weights are the (weighted) mean of two or more "
        "checkpoints of the same network, stage and class map, e.g. the seeds of one recipe "
        "fine-tuned from the same start. BatchNorm statistics are averaged too; no data is read.",
    )
    avg.add_argument("checkpoints", nargs="+", help=".pt files or shipped short names")
    avg.add_argument("--out", required=True, help="destination .pt")
    avg.add_argument(
        "--weights",
        type=float,
        nargs="+",
        help="one positive weight per checkpoint (default equal)",
    )
    avg.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    avg.set_defaults(func=average_handler)
    ens = sub.add_parser(
        "ensemble",
        help="write an ensemble file: checkpoints + test-time views, used as one --checkpoint",
        description="Write a small JSON file naming two or more checkpoints (the first leads: "
        "dynamic shifting, density and settings) and the test-time views of each; `infer` and "
        "`demo` take it as --checkpoint and predict as `infer --checkpoint A --ensemble B ... "
        "--tta-views K` does. The members are checked (same classes, trained offset head) before "
        "the file is written; their paths are stored relative to the file.",
    )
    ens.add_argument("checkpoints", nargs="+", help=".pt files or shipped short names")
    ens.add_argument("--out", required=True, help="destination .json")
    ens.add_argument(
        "--tta-views", type=ca.int_range(1, 16), default=1, help="views per member (default 1)"
    )
    ens.add_argument("--notes", default="", help="what the members are (stored in the file)")
    ens.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    ens.set_defaults(func=ensemble_handler)
    imp = sub.add_parser(
        "import-dsnet",
        help="convert an official DS-Net checkpoint (sem_pretrain / offset_pretrain / dsnet_pretrain)",
        description="Read a checkpoint of the official DS-Net code (a dict with model_state or a "
        "bare state dict), detect its training step, map and reshape every tensor onto the "
        "official network of panoptic-bench and write one of our checkpoints.",
    )
    imp.add_argument("src", help="official .pth file")
    imp.add_argument("--out", required=True, help="destination .pt (written only on success)")
    imp.add_argument("--print-map", action="store_true", help="print the key mapping")
    imp.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    imp.set_defaults(func=import_handler)
    gap = sub.add_parser(
        "bn-gap",
        help="how far one dataset's activation statistics sit from another's (per BatchNorm)",
        description="Run the checkpoint's backbone on --scans evenly spaced scans of each root and "
        "compare, for every BatchNorm, the per-channel statistics of its input in units of the "
        "checkpoint's running statistics: offset of OTHER's channel means from DATA's, DATA's "
        "scan-to-scan spread of them, their ratio, and |log| of the channel spreads' ratio "
        "(medians over channels). Writes gap.csv and gap.png under --out.",
    )
    gap.add_argument("checkpoint", help="a .pt file or a shipped short name")
    gap.add_argument("--data", required=True, help="reference root, e.g. the training world")
    gap.add_argument("--other", required=True, help="root compared with it, e.g. real scans")
    gap.add_argument(
        "--split", default="train", help="split or sequences (00,01) of both roots (train)"
    )
    gap.add_argument(
        "--scans", type=ca.int_range(2), default=30, help="scans of each root (>= 2, default 30)"
    )
    gap.add_argument("--out", required=True, help="output directory")
    gap.add_argument("--overwrite", action="store_true", help="replace files in --out")
    gap.add_argument("--threads", type=ca.threads, help="torch CPU threads (default: torch's)")
    gap.add_argument("--no-progress", action="store_true", help="no progress bars")
    gap.set_defaults(func=gap_handler)
    rec = sub.add_parser(
        "recalibrate-bn",
        help="re-estimate the BatchNorm statistics on a dataset (weights unchanged)",
        description="Write a copy of the checkpoint whose backbone BatchNorm running mean and "
        "variance are the average over --scans evenly spaced scans of --data (in --view) of each "
        "scan's batch statistics; every weight stays bit-identical. Asks "
        "whether a network's held statistics or its features carry a result.",
    )
    rec.add_argument("checkpoint", help="a .pt file or a shipped short name")
    rec.add_argument("--data", required=True, help="root to estimate the statistics on")
    rec.add_argument("--split", default="train", help="split or sequences (00,01) (train)")
    rec.add_argument(
        "--scans", type=ca.int_range(1), default=200, help="scans to average (default 200)"
    )
    rec.add_argument(
        "--view",
        choices=("infer", "train"),
        default="infer",
        help="scans as `infer` feeds them (default) or as the checkpoint's training augmented "
        "them (its augment section, no mixing or pasting)",
    )
    rec.add_argument("--out", required=True, help="destination .pt")
    rec.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    rec.add_argument("--threads", type=ca.threads, help="torch CPU threads (default: torch's)")
    rec.add_argument("--no-progress", action="store_true", help="no progress bar")
    rec.set_defaults(func=recalibrate_handler)


def list_handler(args: argparse.Namespace) -> int:
    from panoptic_bench.demo.steps import TRAINED_ON
    from panoptic_bench.dsnet.checkpoint import SHIPPED, shipped_checkpoints
    from panoptic_bench.dsnet.inference.ensemble_file import is_ensemble_file, read_ensemble_file

    present = shipped_checkpoints()
    for name, file in SHIPPED.items():
        if name not in present:
            print(f"{name:28s} {file} (not in this install)")
            continue
        what = TRAINED_ON.get(file, "")
        if is_ensemble_file(present[name]):
            spec = read_ensemble_file(present[name])
            files = " + ".join(m.name for m in spec.members)
            what = f"ensemble of {len(spec.members)} ({files}), {spec.tta_views} views each; {what}"
        else:
            what = f"{present[name].stat().st_size / 1e6:.1f} MB; {what}"
        print(f"{name:28s} {file}: {what}")
    return 0


def show_handler(args: argparse.Namespace) -> int:
    import yaml

    from panoptic_bench.dsnet.checkpoint import load_checkpoint, resolve_checkpoint

    ck = load_checkpoint(resolve_checkpoint(args.checkpoint))
    n_params = sum(v.numel() for v in ck.backbone.values() if v.is_floating_point())
    print(
        f"stage {ck.stage}, epoch {ck.epoch}, dataset {ck.class_map.dataset}, "
        f"{ck.class_map.num_classes} classes, {n_params / 1e6:.2f} M backbone values, "
        f"dynamic shifting: {'yes' if ck.has_shift else 'no'}"
    )
    for row in ck.metrics:
        print(
            "  "
            + ", ".join(
                f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()
            )
        )
    print(yaml.safe_dump(ck.config.to_dict(), sort_keys=False), end="")
    return 0


def export_handler(args: argparse.Namespace) -> int:
    from pathlib import Path

    from panoptic_bench.dsnet.checkpoint import export_checkpoint, resolve_checkpoint
    from panoptic_bench.io import check_output_file

    src = resolve_checkpoint(args.checkpoint)
    check_output_file(args.out, overwrite=args.overwrite, inputs=(src,))
    out = export_checkpoint(src, args.out, half=args.half)
    print(f"{out} ({Path(out).stat().st_size / 1e6:.1f} MB)")
    return 0


def average_handler(args: argparse.Namespace) -> int:
    from pathlib import Path

    from panoptic_bench.dsnet.checkpoint import resolve_checkpoint, save_checkpoint
    from panoptic_bench.dsnet.soup import average_checkpoints
    from panoptic_bench.io import check_output_file

    srcs = [resolve_checkpoint(c) for c in args.checkpoints]
    check_output_file(args.out, overwrite=args.overwrite, inputs=tuple(srcs))
    ck = average_checkpoints(srcs, args.weights)
    save_checkpoint(ck, args.out)
    print(
        f"{args.out}: stage {ck.stage}, average of {len(srcs)} checkpoints "
        f"({Path(args.out).stat().st_size / 1e6:.1f} MB)"
    )
    return 0


def ensemble_handler(args: argparse.Namespace) -> int:
    from panoptic_bench.dsnet.checkpoint import resolve_checkpoint
    from panoptic_bench.dsnet.inference.ensemble_file import write_ensemble_file
    from panoptic_bench.dsnet.inference.run import load_predictor
    from panoptic_bench.io import check_output_file

    srcs = [resolve_checkpoint(c) for c in args.checkpoints]
    check_output_file(args.out, overwrite=args.overwrite, inputs=tuple(srcs))
    load_predictor(srcs[0], ensemble=tuple(srcs[1:]))  # the members' checks, before writing
    spec = write_ensemble_file(args.out, srcs, args.tta_views, args.notes)
    print(f"{spec.path}: {len(spec.members)} members, {spec.tta_views} view(s) each")
    return 0


def import_handler(args: argparse.Namespace) -> int:
    from pathlib import Path

    from panoptic_bench.dsnet.official.convert import import_official
    from panoptic_bench.io import check_output_file

    check_output_file(args.out, overwrite=args.overwrite, inputs=(args.src,))
    out, res = import_official(args.src, args.out, print_map=args.print_map)
    print(
        f"{out}: official step {res.step} -> stage {'semantic offset ds'.split()[res.step - 1]}, "
        f"{len(res.rows)} tensors ({Path(out).stat().st_size / 1e6:.1f} MB)"
    )
    return 0


def gap_handler(args: argparse.Namespace) -> int:
    import torch
    from tqdm import tqdm

    from panoptic_bench.dsnet import statistics_gap as sg
    from panoptic_bench.dsnet.checkpoint import (
        build_backbone,
        build_grid,
        load_checkpoint,
        resolve_checkpoint,
    )
    from panoptic_bench.dsnet.inference.run import check_fits, open_split
    from panoptic_bench.errors import InputError
    from panoptic_bench.io import check_output_dir

    if args.threads:
        torch.set_num_threads(args.threads)
    src = resolve_checkpoint(args.checkpoint)
    check_output_dir(args.out, overwrite=args.overwrite, inputs=(src, args.data, args.other))
    ck = load_checkpoint(src)
    net = build_backbone(ck.config, ck.class_map.num_classes)
    net.load_state_dict(ck.backbone)
    grid = build_grid(ck.config)
    stats = []
    for root in (args.data, args.other):
        check_fits(ck, root)
        ds = open_split(ck.config, root, args.split)
        if len(ds) < 2:
            raise InputError(f"{len(ds)} scans in split {args.split!r}; need at least 2", root)
        picks = sg.evenly_spaced(len(ds), args.scans)
        bar = tqdm(picks, desc=str(root), disable=args.no_progress, leave=False)
        stats.append(sg.held_unit_statistics(net, (ds.load(i) for i in bar), grid))
    rows = sg.layer_gaps(*stats)
    title = f"{src.name}: {args.other} against {args.data}"
    for path in sg.write_gap_files(rows, args.out, title):
        print(path)
    for r in rows:
        print(
            f"{r['layer']:48s} offset {r['offset']:.3f}  spread {r['spread']:.3f}  "
            f"ratio {r['ratio']:.2f}  |log std| {r['log_std']:.3f}"
        )
    return 0


def recalibrate_handler(args: argparse.Namespace) -> int:
    import torch
    from tqdm import tqdm

    from panoptic_bench.dsnet.bn_recalibration import recalibrate_checkpoint, view_samples
    from panoptic_bench.dsnet.checkpoint import load_checkpoint, resolve_checkpoint, save_checkpoint
    from panoptic_bench.dsnet.inference.run import check_fits, open_split
    from panoptic_bench.dsnet.statistics_gap import evenly_spaced
    from panoptic_bench.errors import InputError
    from panoptic_bench.io import check_output_file

    if args.threads:
        torch.set_num_threads(args.threads)
    src = resolve_checkpoint(args.checkpoint)
    check_output_file(args.out, overwrite=args.overwrite, inputs=(src, args.data))
    ck = load_checkpoint(src)
    check_fits(ck, args.data)
    ds = open_split(ck.config, args.data, args.split)
    if len(ds) == 0:
        raise InputError(f"no scans in split {args.split!r}", args.data)
    picks = evenly_spaced(len(ds), args.scans)
    bar = tqdm(picks, desc="BatchNorm statistics", disable=args.no_progress, leave=False)
    note = f"{args.data} split {args.split} ({args.view} view)"
    new, seen = recalibrate_checkpoint(ck, view_samples(ck, ds, bar, args.view), note)
    save_checkpoint(new, args.out)
    print(f"{args.out}: stage {new.stage}, BatchNorm statistics of {seen} scans of {note}")
    return 0
