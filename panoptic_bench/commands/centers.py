"""``panoptic-bench centers simulate``: "simulated regression" centre files from ground truth."""

from __future__ import annotations

import argparse

from panoptic_bench import cli_args as ca


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``centers``."""
    centers = subparsers.add_parser("centers", help="regressed-centre files")
    csub = centers.add_subparsers(dest="centers_command", metavar="COMMAND", required=True)
    sim = csub.add_parser(
        "simulate",
        help='write "simulated regression" centres from SemanticKITTI or nuScenes ground truth',
        description="Semantic prediction = ground truth; centres = tight-box centres plus noise "
        "elongated along the viewing ray (growing with size and range) and outliers. "
        "SemanticKITTI: OUTPUT/sequences/XX/centers/NNNNNN.npz. nuScenes (with --version and "
        "--eval-set; needs panoptic labels): OUTPUT/centers/<lidar token>.npz.",
    )
    sim.add_argument(
        "--dataset", "--dataroot", dest="dataset", required=True,
        help="labelled SemanticKITTI root or nuScenes dataroot",
    )  # fmt: skip
    sim.add_argument("--version", help="nuScenes: version, e.g. v1.0-mini")
    sim.add_argument("--eval-set", help="nuScenes: devkit split, e.g. mini_val")
    sim.add_argument("--output", required=True, help="centre root to write")
    sim.add_argument("--seed", type=ca.seed, default=0, help="random seed (default 0)")
    ca.add_scan_selection(sim, split_help="SemanticKITTI: scans of this split")
    sim.add_argument("--zero-noise", action="store_true", help="exact ground-truth centres")
    sim.add_argument(
        "--base-sigma", type=ca.float_range(0.0, 100.0), help="noise std at size 0, range 0 (m)"
    )
    sim.add_argument(
        "--size-gain", type=ca.float_range(0.0, 100.0), help="std growth per metre of box diagonal"
    )
    sim.add_argument(
        "--range-gain", type=ca.float_range(0.0, 100.0), help="std growth per metre of range"
    )
    sim.add_argument(
        "--across-ratio", type=ca.float_range(0.0, 100.0), help="across-ray / along-ray std"
    )
    sim.add_argument("--outlier-rate", type=ca.probability, help="fraction of outlier points")
    sim.add_argument("--workers", type=ca.workers, default=1, help="worker processes (default 1)")
    ca.add_overwrite(sim, "the --output tree")
    sim.set_defaults(func=simulate)


def simulate(args: argparse.Namespace) -> int:
    """Handler of ``centers simulate``."""
    from panoptic_bench.baselines.regression import SIMULATED, RegressionNoise
    from panoptic_bench.baselines.run import (
        simulate_centers_nuscenes,
        simulate_centers_semantickitti,
    )
    from panoptic_bench.errors import InputError
    from panoptic_bench.io import output_tree

    keys = ("base_sigma", "size_gain", "range_gain", "across_ratio", "outlier_rate")
    given = {k: getattr(args, k) for k in keys if getattr(args, k) is not None}
    try:
        noise = RegressionNoise.zero() if args.zero_noise else RegressionNoise.from_dict(given)
    except ValueError as exc:
        raise InputError(f"bad noise parameters: {exc}") from None
    if (args.version is None) != (args.eval_set is None):
        raise InputError("nuScenes needs both --version and --eval-set")
    if args.version is not None and (args.split or args.sequences):
        raise InputError("--split/--sequences select SemanticKITTI scans; use --eval-set")
    out = args.output
    with output_tree(out, overwrite=args.overwrite, inputs=(args.dataset,)) as tmp:
        if args.version is not None:
            n = simulate_centers_nuscenes(
                args.dataset, args.version, args.eval_set, tmp, noise=noise, seed=args.seed,
                workers=args.workers,
            )  # fmt: skip
        else:
            n = simulate_centers_semantickitti(
                args.dataset, tmp, noise=noise, seed=args.seed, split=args.split,
                sequences=args.sequences, workers=args.workers,
            )  # fmt: skip
    where = "centers" if args.version is not None else "sequences"
    print(f"wrote {n} {SIMULATED} centre files under {out}/{where} (not a network result)")
    return 0
