"""``panoptic-bench eval nuscenes``: Panoptic nuScenes scoring (devkit-identical numbers).

``commands/eval.py`` owns the ``eval`` group and calls :func:`add_parser`; while it is absent,
:func:`register` provides an ``eval`` group holding only this target.
"""

from __future__ import annotations

import argparse

from panoptic_bench import cli_args as ca


def add_parser(eval_subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add ``nuscenes`` to the sub-commands of ``eval``."""
    p = eval_subparsers.add_parser(
        "nuscenes",
        help="Panoptic nuScenes PQ/SQ/RQ/mIoU, or with --task tracking PAT/PTQ/LSTQ/MOTSA "
        "(same numbers as the devkit evaluator)",
        description=(
            "Score RES/panoptic/<eval-set>/<sample_data_token>_panoptic.npz (key 'data', uint16: "
            "challenge class x 1000 + instance) against the dataroot's panoptic ground truth. "
            "Writes segmentation-result.json or, for --task tracking (frames in scene order, "
            "instance ids consistent along each scene), tracking-result.json (devkit structure), "
            "plus scores.txt, scores.json and per_class.csv."
        ),
    )
    p.add_argument("--dataroot", required=True, help="nuScenes dataroot with panoptic labels")
    p.add_argument("--version", required=True, help="e.g. v1.0-mini, v1.0-trainval")
    p.add_argument("--result-path", required=True, help="folder holding panoptic/<eval-set>/")
    p.add_argument("--eval-set", required=True, help="devkit split: mini_val, val, test, ...")
    p.add_argument(
        "--min-inst-points",
        type=ca.nonneg_int,
        default=15,
        help="unmatched segments smaller than this are not counted (default 15, as the devkit)",
    )
    p.add_argument(
        "--by-range",
        type=ca.range_edges,
        default=None,
        metavar="EDGES",
        help="also score per range bin, comma-separated edges in metres, e.g. 0,10,20,30,50",
    )
    p.add_argument(
        "--task",
        choices=["segmentation", "tracking"],
        default="segmentation",
        help="segmentation (PQ ...) or tracking (PAT, PTQ, LSTQ, MOTSA ... plus segmentation); "
        "meta.task of RES/<eval-set>/submission.json wins, as in the devkit",
    )
    p.add_argument("--workers", type=ca.workers, default=1, help="worker processes (default 1)")
    p.add_argument("--output", required=True, help="output directory")
    ca.add_overwrite(p, "the --output directory")
    p.set_defaults(func=run)
    return p


def register(subparsers: argparse._SubParsersAction) -> None:
    """Provide ``eval nuscenes`` on its own unless ``commands/eval.py`` already owns ``eval``."""
    if "eval" in subparsers.choices:
        return
    parser = subparsers.add_parser("eval", help="score predictions")
    sub = parser.add_subparsers(dest="eval_target", metavar="TARGET", required=True)
    add_parser(sub)


def run(args: argparse.Namespace) -> int:
    """Handler of ``eval nuscenes``."""
    from panoptic_bench.errors import InputError
    from panoptic_bench.evaluation.nuscenes import evaluate_nuscenes, write_nuscenes_result
    from panoptic_bench.evaluation.output import percent_table
    from panoptic_bench.evaluation.workers import retain_freed_memory
    from panoptic_bench.io import check_output_dir, output_tree
    from panoptic_bench.metrics.by_range import parse_edges

    retain_freed_memory()
    edges = None
    if args.by_range is not None:
        try:
            edges = parse_edges(args.by_range)
        except ValueError as exc:
            raise InputError(f"--by-range: {exc}") from None
    inputs = (args.dataroot, f"{args.result_path}/panoptic")
    check_output_dir(args.output, overwrite=args.overwrite, inputs=inputs)
    task = submission_task(args.result_path, args.eval_set) or args.task
    if task == "tracking":
        return _run_tracking(args, inputs, edges)
    evaluation = evaluate_nuscenes(
        args.dataroot,
        args.version,
        args.result_path,
        args.eval_set,
        min_inst_points=args.min_inst_points,
        by_range=edges,
        workers=args.workers,
    )
    with output_tree(args.output, overwrite=args.overwrite, inputs=inputs) as tmp:
        scores = write_nuscenes_result(evaluation, tmp, inputs=inputs)
    print(percent_table(scores), end="")
    print(f"{evaluation.n_samples} samples of {args.eval_set}; results written to {args.output}")
    return 0


def submission_task(result_path: str, eval_set: str) -> str | None:
    """``meta.task`` of ``RES/<eval_set>/submission.json`` (where the devkit reads it), if any."""
    import json
    from pathlib import Path

    from panoptic_bench.errors import InputError

    path = Path(result_path) / eval_set / "submission.json"
    if not path.is_file():
        return None
    try:
        meta = json.loads(path.read_text()).get("meta", {})
    except (OSError, ValueError, AttributeError) as exc:
        raise InputError(f"cannot read submission.json ({exc})", path) from None
    task = meta.get("task") if isinstance(meta, dict) else None
    if task is not None and task not in ("segmentation", "tracking"):
        raise InputError(f"meta.task must be segmentation or tracking, got {task!r}", path)
    return task


def _run_tracking(args: argparse.Namespace, inputs: tuple, edges) -> int:
    from panoptic_bench.errors import InputError
    from panoptic_bench.evaluation.nuscenes_tracking import evaluate_nuscenes_tracking
    from panoptic_bench.io import output_tree

    if edges is not None:
        raise InputError("--by-range is available for --task segmentation only")
    ev = evaluate_nuscenes_tracking(
        args.dataroot,
        args.version,
        args.result_path,
        args.eval_set,
        min_inst_points=args.min_inst_points,
        workers=args.workers,
    )
    with output_tree(args.output, overwrite=args.overwrite, inputs=inputs) as tmp:
        scores = ev.write(tmp, inputs=inputs)
    t = scores["tracking"]["all"]
    cells = [f"{k} {'nan' if t[k] is None else f'{100 * t[k]:.2f}'}" for k in t]
    print("tracking (%): " + ", ".join(cells))
    print(
        f"{ev.segmentation.n_samples} samples in {ev.n_scenes} scenes of {args.eval_set}; "
        f"results written to {args.output}"
    )
    return 0
