"""``panoptic-bench synth ...``: the synthetic ray-cast LiDAR world (datasets and realism stats)."""

from __future__ import annotations

import argparse

from panoptic_bench import cli_args as ca


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``synth`` command group."""
    parser = subparsers.add_parser(
        "synth", help="synthetic ray-cast LiDAR street scenes (SemanticKITTI / nuScenes format)"
    )
    sub = parser.add_subparsers(dest="synth_command", metavar="SUBCOMMAND", required=True)

    kitti = sub.add_parser(
        "semantickitti",
        help="simulate HDL-64E sequences in the SemanticKITTI layout",
        description=(
            "Write sequences/XX/{velodyne,labels,poses.txt,calib.txt,times.txt} of ray-cast "
            "street scenes (10 Hz, about 120k points per scan). Deterministic for a seed."
        ),
    )
    kitti.add_argument("--out", required=True, help="dataset root to write")
    kitti.add_argument(
        "--sequences",
        default="00:40,08:20",
        help="SEQ:FRAMES list, e.g. 00:40,08:20 (default)",
    )
    kitti.add_argument("--seed", type=ca.seed, default=0, help="global seed (default 0)")
    kitti.add_argument("--overwrite", action="store_true", help="write into a non-empty --out")
    kitti.add_argument(
        "--profile",
        default="classic",
        help="world/sensor profile: classic (default, the original world), realistic, or a "
        "YAML file of overrides (e.g. configs/synth_realistic.yaml); a comma-separated list "
        "mixes worlds: the k-th sequence of --sequences uses the (k mod n)-th profile",
    )
    kitti.set_defaults(func=semantickitti)

    nus = sub.add_parser(
        "nuscenes",
        help="simulate HDL-32E scenes as a nuScenes dataroot (lidarseg + boxes)",
        description=(
            "Write a nuScenes dataroot that NuScenes(version, dataroot) loads: keyframes at 2 Hz, "
            "lidarseg in the 32 general classes, global-frame annotation boxes."
        ),
    )
    nus.add_argument("--out", required=True, help="dataroot to write")
    nus.add_argument("--version", default="v1.0-mini", help="nuScenes version (default v1.0-mini)")
    nus.add_argument(
        "--scenes", type=ca.positive_int, default=4, help="number of scenes (default 4)"
    )
    nus.add_argument(
        "--samples", type=ca.positive_int, default=10, help="keyframes per scene (default 10)"
    )
    nus.add_argument("--seed", type=ca.seed, default=0, help="global seed (default 0)")
    nus.add_argument("--overwrite", action="store_true", help="write into a non-empty --out")
    nus.add_argument(
        "--profile",
        default="classic",
        help="world/sensor profile: classic (default, the original world), realistic, or a "
        "YAML file of overrides (e.g. configs/synth_realistic.yaml)",
    )
    nus.set_defaults(func=nuscenes)

    stats = sub.add_parser(
        "stats",
        help="realism statistics: synthetic vs real SemanticKITTI scans (table + figure)",
        description=(
            "Compare real and synthetic scans side by side: points per scan, class "
            "frequencies, thing instances, points per car vs range, range histogram, "
            "remission (zeros, darkness, per class and range), road plane height, sensor "
            "pitch/roll, ground roughness, kerb and terrain heights, street layout, ego hole, "
            "points per ring and unlabelled clutter. Writes realism.md, realism.csv, "
            "realism.json, realism.png and realism_sensor.png under --out. Without "
            "--synthetic, --synthetic-scans scans of --profile are simulated in memory."
        ),
    )
    stats.add_argument("--real", required=True, help="real SemanticKITTI root (labelled scans)")
    stats.add_argument(
        "--synthetic", default=None, help="synthetic SemanticKITTI root (default: simulate)"
    )
    stats.add_argument(
        "--synthetic-scans",
        type=ca.positive_int,
        default=12,
        help="scans to simulate without --synthetic, one street each (default 12)",
    )
    stats.add_argument("--seed", type=ca.seed, default=0, help="seed of the simulated scans")
    stats.add_argument("--out", required=True, help="output directory")
    stats.add_argument(
        "--max-scans",
        type=ca.positive_int,
        default=200,
        help="at most this many scans per tree (default 200)",
    )
    stats.add_argument("--figure", default=None, help="also write the PNG figure to this path")
    stats.add_argument("--overwrite", action="store_true", help="write into a non-empty --out")
    stats.add_argument(
        "--profile",
        default="classic",
        help="world/sensor profile: classic (default, the original world), realistic, or a "
        "YAML file of overrides (e.g. configs/synth_realistic.yaml)",
    )
    stats.set_defaults(func=stats_handler)


def semantickitti(args: argparse.Namespace) -> int:
    """Handler of ``synth semantickitti``."""
    from panoptic_bench.datasets.synthetic.profile_files import load_profile
    from panoptic_bench.datasets.synthetic.writers import generate_semantickitti, parse_sequences
    from panoptic_bench.io import output_tree

    seqs = parse_sequences(args.sequences)
    names = [n.strip() for n in args.profile.split(",")]
    profiles = [load_profile(n) for n in names]  # every file checked before anything is written
    with output_tree(args.out, overwrite=args.overwrite) as tmp:  # all or nothing (Ctrl-C, ENOSPC)
        generate_semantickitti(tmp, seqs, seed=args.seed, overwrite=True, profile=profiles)
    print(f"wrote {sum(seqs.values())} scans in {len(seqs)} sequence(s) to {args.out}")
    if len(profiles) > 1:
        for i, (name, prof) in enumerate(zip(names, profiles)):
            mine = [s for k, s in enumerate(seqs) if k % len(profiles) == i]
            print(f"  world {prof.name} ({name}): sequences {', '.join(mine) or '-'}")
    return 0


def nuscenes(args: argparse.Namespace) -> int:
    """Handler of ``synth nuscenes``."""
    from panoptic_bench.datasets.synthetic.profile_files import load_profile
    from panoptic_bench.datasets.synthetic.writers import generate_nuscenes
    from panoptic_bench.io import output_tree

    profile = load_profile(args.profile)
    with output_tree(args.out, overwrite=args.overwrite) as tmp:  # all or nothing (Ctrl-C, ENOSPC)
        generate_nuscenes(
            tmp, args.version, args.scenes, args.samples, seed=args.seed, overwrite=True,
            profile=profile,
        )  # fmt: skip
    root = args.out
    from panoptic_bench.datasets.nuscenes_spec import synthetic_scene_plan

    complete = ", ".join(synthetic_scene_plan(args.version, args.scenes)[1])
    print(
        f"wrote {args.scenes} scene(s) x {args.samples} sample(s) of {args.version} to {root}; "
        f"complete devkit split(s): {complete}"
    )
    return 0


def stats_handler(args: argparse.Namespace) -> int:
    """Handler of ``synth stats``."""
    from panoptic_bench.datasets.synthetic.profile_files import load_profile
    from panoptic_bench.datasets.synthetic.stats import compare

    real, synth = compare(
        args.real,
        args.synthetic,
        args.out,
        max_scans=args.max_scans,
        figure=args.figure,
        overwrite=args.overwrite,
        synthetic_scans=args.synthetic_scans,
        seed=args.seed,
        profile=load_profile(args.profile),
    )
    print(
        f"car points vs range log-log slope (10-50 m): real {real.slope:.2f}, "
        f"synthetic {synth.slope:.2f}; table and figure in {args.out}"
    )
    return 0
