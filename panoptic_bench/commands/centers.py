"""``panoptic-bench centers simulate``: "simulated regression" centre files from ground truth."""

from __future__ import annotations

import argparse


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
    sim.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    sim.add_argument(
        "--split", choices=["train", "valid", "test"], help="SemanticKITTI scan selection"
    )
    sim.add_argument("--sequences", nargs="+", help="SemanticKITTI sequences, e.g. 08")
    sim.add_argument("--zero-noise", action="store_true", help="exact ground-truth centres")
    sim.add_argument("--base-sigma", type=float, help="noise std at size 0, range 0 (m)")
    sim.add_argument("--size-gain", type=float, help="std growth per metre of box diagonal")
    sim.add_argument("--range-gain", type=float, help="std growth per metre of range")
    sim.add_argument("--across-ratio", type=float, help="across-ray / along-ray std")
    sim.add_argument("--outlier-rate", type=float, help="fraction of outlier points")
    sim.add_argument("--workers", type=int, default=1, help="worker processes (default 1)")
    sim.set_defaults(func=simulate)


def simulate(args: argparse.Namespace) -> int:
    """Handler of ``centers simulate``."""
    from panoptic_bench.baselines.regression import SIMULATED, RegressionNoise
    from panoptic_bench.baselines.run import (
        simulate_centers_nuscenes,
        simulate_centers_semantickitti,
    )
    from panoptic_bench.errors import InputError
    from panoptic_bench.io import ensure_output_dir

    keys = ("base_sigma", "size_gain", "range_gain", "across_ratio", "outlier_rate")
    given = {k: getattr(args, k) for k in keys if getattr(args, k) is not None}
    try:
        noise = RegressionNoise.zero() if args.zero_noise else RegressionNoise.from_dict(given)
    except ValueError as exc:
        raise InputError(f"bad noise parameters: {exc}") from None
    if (args.version is None) != (args.eval_set is None):
        raise InputError("nuScenes needs both --version and --eval-set")
    out = ensure_output_dir(args.output, inputs=(args.dataset,))
    if args.version is not None:
        if args.split or args.sequences:
            raise InputError("--split/--sequences select SemanticKITTI scans; use --eval-set")
        n = simulate_centers_nuscenes(
            args.dataset, args.version, args.eval_set, out, noise=noise, seed=args.seed,
            workers=args.workers,
        )  # fmt: skip
        print(f"wrote {n} {SIMULATED} centre files under {out}/centers (not a network result)")
        return 0
    n = simulate_centers_semantickitti(
        args.dataset, out, noise=noise, seed=args.seed, split=args.split,
        sequences=args.sequences, workers=args.workers,
    )  # fmt: skip
    print(f"wrote {n} {SIMULATED} centre files under {out}/sequences (not a network result)")
    return 0
