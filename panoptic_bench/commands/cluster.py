"""``panoptic-bench cluster``: regressed centres → panoptic predictions (clustering baselines)."""

from __future__ import annotations

import argparse

from panoptic_bench import cli_args as ca


def _add_method_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--method", required=True, choices=["bfs", "dbscan", "hdbscan", "meanshift"],
        help="clustering of the regressed centres of things points",
    )  # fmt: skip
    g = p.add_argument_group("method parameters (defaults: paper presets where they exist)")
    g.add_argument("--radius", type=ca.metres, help="bfs: linking radius in m (default 1.2)")
    g.add_argument("--eps", type=ca.metres, help="dbscan: neighbourhood radius in m (default 0.5)")
    g.add_argument(
        "--min-samples", type=ca.positive_int, help="dbscan/hdbscan: core-point neighbours"
    )
    g.add_argument(
        "--min-cluster-size", type=ca.int_range(2), help="hdbscan: smallest cluster (default 5)"
    )
    g.add_argument(
        "--cluster-selection-epsilon",
        type=ca.float_range(0.0, 1e4),
        help="hdbscan: merge distance in m",
    )
    g.add_argument(
        "--bandwidth", type=ca.metres, help="meanshift: flat-kernel radius in m (default 1.2)"
    )
    g.add_argument("--bin-seeding", action="store_true", help="meanshift: seed from a grid")
    g.add_argument(
        "--max-iter", type=ca.positive_int, help="meanshift: maximum shifts per seed (default 300)"
    )
    g.add_argument(
        "--noise", choices=["singleton", "nearest"],
        help="dbscan/hdbscan noise points: own one-point cluster (default) or nearest cluster",
    )  # fmt: skip
    p.add_argument(
        "--min-points", type=ca.nonneg_int,
        help="drop instances with fewer points (default: 50 semantickitti, 5 nuscenes)",
    )  # fmt: skip
    p.add_argument(
        "--small", choices=["no-instance", "unlabeled"], default="no-instance",
        help="dropped instances: keep class with instance 0 (default) or become unlabeled",
    )  # fmt: skip
    p.add_argument("--no-fusion", action="store_true", help="skip consensus-driven fusion")
    p.add_argument("--workers", type=ca.workers, default=1, help="worker processes (default 1)")
    ca.add_overwrite(p, "the --output tree")


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``cluster``."""
    parser = subparsers.add_parser(
        "cluster", help="cluster regressed centres into panoptic predictions (baselines)"
    )
    sub = parser.add_subparsers(dest="dataset", metavar="DATASET", required=True)
    kitti = sub.add_parser(
        "semantickitti",
        help="SemanticKITTI tree",
        description="Reads CENTERS/sequences/XX/centers/NNNNNN.npz (keys sem, offset) and writes "
        "OUTPUT/sequences/XX/predictions/NNNNNN.label.",
    )
    kitti.add_argument(
        "--dataset", required=True, help="SemanticKITTI root (sequences/XX/velodyne)"
    )
    kitti.add_argument("--centers", required=True, help="root of the regressed-centre .npz files")
    ca.add_scan_selection(kitti)
    kitti.add_argument("--output", required=True, help="prediction root to write")
    _add_method_args(kitti)
    kitti.set_defaults(func=cluster_kitti)

    nus = sub.add_parser(
        "nuscenes",
        help="nuScenes dataroot",
        description="Reads CENTERS/centers/<lidar token>.npz and writes "
        "OUTPUT/panoptic/<eval-set>/<token>_panoptic.npz.",
    )
    nus.add_argument(
        "--dataset", "--dataroot", dest="dataset", required=True, help="nuScenes dataroot"
    )
    nus.add_argument("--version", required=True, help="e.g. v1.0-mini")
    nus.add_argument("--eval-set", required=True, help="devkit split: mini_val, val, ...")
    nus.add_argument("--centers", required=True, help="root of the regressed-centre .npz files")
    nus.add_argument("--output", required=True, help="prediction root to write")
    _add_method_args(nus)
    nus.set_defaults(func=cluster_nus)


def _options(args: argparse.Namespace, default_min_points: int):
    from panoptic_bench.baselines.clustering import make_clusterer
    from panoptic_bench.baselines.run import AssemblyOptions
    from panoptic_bench.errors import InputError

    presets = {"bfs": {"radius": 1.2}, "meanshift": {"bandwidth": 1.2}}
    params = {
        "bfs": {"radius": args.radius},
        "dbscan": {"eps": args.eps, "min_samples": args.min_samples, "noise": args.noise},
        "hdbscan": {
            "min_cluster_size": args.min_cluster_size,
            "min_samples": args.min_samples,
            "cluster_selection_epsilon": args.cluster_selection_epsilon,
            "noise": args.noise,
        },
        "meanshift": {
            "bandwidth": args.bandwidth,
            "bin_seeding": args.bin_seeding or None,
            "max_iter": args.max_iter,
        },
    }[args.method]
    for key, value in presets.get(args.method, {}).items():
        if params[key] is None:
            params[key] = value
    try:
        clusterer = make_clusterer(args.method, **params)
    except (TypeError, ValueError) as exc:
        raise InputError(f"bad --method parameters: {exc}") from None
    min_points = default_min_points if args.min_points is None else args.min_points
    return AssemblyOptions(clusterer, min_points, fusion=not args.no_fusion, small=args.small)


def cluster_kitti(args: argparse.Namespace) -> int:
    """Handler of ``cluster semantickitti``."""
    from panoptic_bench.baselines.clustering import MIN_POINTS_SEMANTICKITTI
    from panoptic_bench.baselines.run import cluster_semantickitti
    from panoptic_bench.io import output_tree

    opts = _options(args, MIN_POINTS_SEMANTICKITTI)
    inputs = (args.dataset, args.centers)
    with output_tree(args.output, overwrite=args.overwrite, inputs=inputs) as tmp:
        n = cluster_semantickitti(
            args.dataset, args.centers, tmp, opts, split=args.split, sequences=args.sequences,
            workers=args.workers,
        )  # fmt: skip
    print(f"{opts.clusterer!r}: wrote {n} predictions under {args.output}/sequences")
    return 0


def cluster_nus(args: argparse.Namespace) -> int:
    """Handler of ``cluster nuscenes``."""
    from panoptic_bench.baselines.clustering import MIN_POINTS_NUSCENES
    from panoptic_bench.baselines.run import cluster_nuscenes
    from panoptic_bench.io import output_tree

    opts = _options(args, MIN_POINTS_NUSCENES)
    inputs = (args.dataset, args.centers)
    with output_tree(args.output, overwrite=args.overwrite, inputs=inputs) as tmp:
        n = cluster_nuscenes(
            args.dataset, args.version, args.eval_set, args.centers, tmp, opts,
            workers=args.workers,
        )  # fmt: skip
    print(f"{opts.clusterer!r}: wrote {n} predictions under {args.output}/panoptic/{args.eval_set}")
    return 0
