"""``panoptic-bench view semantickitti|nuscenes``: one offline HTML page, prediction vs ground truth."""

from __future__ import annotations

import argparse

from panoptic_bench.cli_args import add_overwrite

_COMMON = (
    "Writes ONE self-contained HTML file (plotly.js embedded, no network request) with the "
    "prediction and the ground truth side by side in two 3-D views whose cameras move together. "
    "Colour by semantic class (official colour map), by instance (matched instances share a "
    "colour), by segment error (TP / FP / FN segments from the evaluator's matching) or by "
    "semantic error; click legend entries to hide classes; hover a point for class, instance id "
    "and segment IoU. Without predictions both sides show the ground truth."
)


def _common(p: argparse.ArgumentParser, centres_help: str) -> None:
    p.add_argument("--centers", default=None, metavar="ROOT", help=centres_help)
    p.add_argument("--out", required=True, metavar="FILE", help="HTML file to write")
    add_overwrite(p, "an existing --out file")
    p.add_argument(
        "--max-points",
        type=int,
        default=None,
        metavar="N",
        help="draw at most N points (a fixed random subset; matching and numbers use all points)",
    )


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``view semantickitti`` and ``view nuscenes``."""
    parser = subparsers.add_parser(
        "view", help="offline interactive 3-D viewer: prediction vs ground truth (one HTML file)"
    )
    sub = parser.add_subparsers(dest="view_command", metavar="DATASET", required=True)
    p = sub.add_parser(
        "semantickitti",
        help="one SemanticKITTI scan",
        description=f"View one SemanticKITTI scan. {_COMMON}",
    )
    p.add_argument("--dataset", required=True, help="root holding sequences/XX/{velodyne,labels}")
    p.add_argument(
        "--predictions",
        default=None,
        metavar="ROOT",
        help="root holding sequences/XX/predictions/NNNNNN.label (raw ids, uint32)",
    )
    p.add_argument("--scan", required=True, metavar="SEQ/FRAME", help="e.g. 08/000000")
    _common(p, "root holding sequences/XX/centers/NNNNNN.npz: regressed centres as a third layer")
    p.set_defaults(func=run_semantickitti)

    p = sub.add_parser(
        "nuscenes",
        help="one Panoptic nuScenes keyframe sweep",
        description=f"View one Panoptic nuScenes LIDAR_TOP keyframe sweep. {_COMMON}",
    )
    p.add_argument("--dataroot", required=True, help="nuScenes dataroot with panoptic labels")
    p.add_argument("--version", required=True, help="e.g. v1.0-mini")
    p.add_argument(
        "--result-path",
        default=None,
        metavar="RES",
        help="holds panoptic/<eval_set>/<token>_panoptic.npz",
    )
    p.add_argument(
        "--eval-set",
        default=None,
        help="folder under RES/panoptic (default: the one holding the token's file)",
    )
    p.add_argument("--sample-data-token", required=True, metavar="T", help="LIDAR_TOP token")
    p.add_argument(
        "--min-inst-points",
        type=int,
        default=15,
        help="as in 'eval nuscenes': unmatched segments below this are not counted (default 15)",
    )
    _common(p, "holds centers/<token>.npz: regressed centres as a third layer")
    p.set_defaults(func=run_nuscenes)


def _check_out(out: str, inputs: tuple, overwrite: bool) -> None:
    from pathlib import Path

    from panoptic_bench.errors import InputError

    path = Path(out).resolve()
    if path.is_dir():
        raise InputError("--out is a directory; name the HTML file to write", out)
    for src in inputs:
        if src is not None and Path(src).resolve() in path.parents:
            raise InputError(f"--out lies inside the input tree {src}; write elsewhere", out)
    if path.exists() and not overwrite:
        raise InputError("--out exists; pass --overwrite to replace it", out)


def _write(args: argparse.Namespace, scan, classes, title: str, given: bool) -> int:
    from panoptic_bench.errors import InputError
    from panoptic_bench.viewer.page import write_page

    if args.max_points is not None and args.max_points < 1:
        raise InputError(f"--max-points must be >= 1, got {args.max_points}")
    note = "" if given else "No predictions given: both sides show the ground truth."
    path = write_page(args.out, [scan], classes, title=title, max_points=args.max_points, note=note)
    print(f"viewer page written to {path}")
    return 0


def run_semantickitti(args: argparse.Namespace) -> int:
    """Handler of ``view semantickitti``."""
    from panoptic_bench.viewer.load import load_semantickitti

    _check_out(args.out, (args.dataset, args.predictions, args.centers), args.overwrite)
    scan, classes = load_semantickitti(
        args.dataset, args.scan, predictions=args.predictions, centers=args.centers
    )
    title = f"SemanticKITTI scan {scan.name}: prediction vs ground truth"
    return _write(args, scan, classes, title, args.predictions is not None)


def run_nuscenes(args: argparse.Namespace) -> int:
    """Handler of ``view nuscenes``."""
    from panoptic_bench.errors import InputError
    from panoptic_bench.viewer.load import load_nuscenes

    if args.min_inst_points < 0:
        raise InputError(f"--min-inst-points must be >= 0, got {args.min_inst_points}")
    _check_out(args.out, (args.dataroot, args.result_path, args.centers), args.overwrite)
    scan, classes = load_nuscenes(
        args.dataroot,
        args.version,
        args.sample_data_token,
        result_path=args.result_path,
        eval_set=args.eval_set,
        centers=args.centers,
        min_points=args.min_inst_points,
    )
    title = f"nuScenes sweep {scan.name}: prediction vs ground truth"
    return _write(args, scan, classes, title, args.result_path is not None)
