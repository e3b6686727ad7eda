"""``guardrail simulate``: a mapping drive with exact ground truth, into a drive folder."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from guardrail_core.cli import common


def add_parser(subparsers: common.Subparsers) -> None:
    own = common.options_parser()
    own.add_argument(
        "out", type=Path, help="drive folder to write (must not exist, or use --overwrite)"
    )
    own.add_argument(
        "--seed", type=int, default=0, help="random seed: same seed, same drive (default 0)"
    )
    own.add_argument(
        "--length", type=float, default=None, help="metres to drive in a random scene (default 100)"
    )
    own.add_argument(
        "--scene", help="scene spec YAML (a path, or the name of one in data_samples/scenes)"
    )
    own.add_argument(
        "--designs",
        metavar="NAME,...",
        help="guardrail designs a random scene may use (default: every shipped design)",
    )
    own.add_argument(
        "--image-every",
        type=float,
        default=5.0,
        metavar="METRES",
        help="camera trigger spacing (default 5)",
    )
    own.add_argument(
        "--image-size",
        type=common.image_size,
        default=(1024, 768),
        metavar="WxH",
        help="image size (default 1024x768)",
    )
    own.add_argument(
        "--scanner",
        choices=("profile", "multibeam"),
        help="profile: the RIEGL VQ-250 profile scanner of the paper's vehicle (the default); "
        "multibeam: a Velodyne HDL-64E as on the KITTI car, one frame every --frame-every metres",
    )
    own.add_argument(
        "--frame-every",
        type=float,
        metavar="METRES",
        help="with --scanner multibeam: metres between frames (default 60)",
    )
    parser = subparsers.add_parser(
        "simulate",
        help="simulate a mapping drive with exact ground truth",
        description="Simulate a mobile-mapping drive (profile laser scanner, cameras, trajectory) "
        "through a random street from --seed, or through the scene of --scene, into the drive folder OUT.",
        parents=[own, common.las_options(), common.overwrite_options(), common.quiet_options()],
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from guardrail_core.formats.drive import load_drive
    from guardrail_core.formats.drive_summary import describe_drive
    from guardrail_core.synth.scene import load_scene_spec, random_scene_spec
    from guardrail_core.synth.simulate import SimulationOptions, simulate_drive

    if args.scene:
        spec = load_scene_spec(args.scene)
        if args.length is not None:
            print(
                "note: --length is ignored with --scene (the spec sets the drive)", file=sys.stderr
            )
    else:
        designs = args.designs.split(",") if args.designs else None
        spec = random_scene_spec(
            args.seed, args.length if args.length is not None else 100.0, designs=designs
        )
    if args.scanner:
        spec["scanner"] = {**(spec.get("scanner") or {}), "kind": args.scanner}
        if args.frame_every is not None:
            spec["scanner"]["frame_every_m"] = args.frame_every
    options = SimulationOptions(
        image_every_m=args.image_every, image_size=args.image_size, compress=not args.las
    )
    scene_file = Path(args.scene) if args.scene and Path(args.scene).is_file() else None
    summary = simulate_drive(
        spec,
        args.out,
        seed=args.seed,
        options=options,
        overwrite=args.overwrite,
        inputs=[scene_file] if scene_file is not None else [],
        progress=not args.quiet,
    )
    timing = ", ".join(f"{k} {v:.1f} s" for k, v in summary.seconds.items())
    print(f"simulated {summary.length_m:.1f} m in {sum(summary.seconds.values()):.1f} s ({timing})")
    print(describe_drive(load_drive(summary.out)))
    return 0
