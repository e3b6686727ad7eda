"""``guardrail simulate``: a mapping drive with exact ground truth, into a drive folder."""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING

from guardrail_core.cli import common

if TYPE_CHECKING:
    from guardrail_core.formats.drive import DriveSource
    from guardrail_core.synth.simulate import SimulationSummary


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
        "--tile-m",
        type=float,
        default=None,
        metavar="METRES",
        help="write the points in tiles of this many metres of driving (default 25); the "
        "same seed gives the same points whatever the tiles",
    )
    own.add_argument(
        "--scanner",
        choices=("profile", "multibeam"),
        help="profile: the RIEGL VQ-250 profile scanner of the paper's vehicle (the default); "
        "multibeam: a Velodyne HDL-64E as on the KITTI car, one frame every --frame-every metres",
    )
    own.add_argument(
        "--lidar",
        metavar="SENSOR",
        help="with --scanner multibeam: the spinning LiDAR's beams and turn (hdl64e, the "
        "default; pandar64, os1-128, os1-64, vlp16, hdl32e)",
    )
    own.add_argument(
        "--frame-every",
        type=float,
        metavar="METRES",
        help="with --scanner multibeam: metres between frames (default 60)",
    )
    own.add_argument(
        "--range-noise",
        type=float,
        metavar="METRES",
        help="1 sigma of the range noise (default 0.005 profile, 0.02 multibeam)",
    )
    own.add_argument(
        "--dropout",
        type=float,
        metavar="P",
        help="probability of losing any return, on top of weak and porous surfaces' losses "
        "(default 0.01)",
    )
    own.add_argument(
        "--intensity-gain",
        type=float,
        metavar="FACTOR",
        help="factor on every intensity: a scanner calibrated differently (default 1)",
    )
    own.add_argument(
        "--no-roadside",
        dest="roadside",
        action="store_false",
        help="a random scene's verges level and bare: no embankments, ditches, hedges, shrubs "
        "or tall grass",
    )
    own.add_argument(
        "--long-runs",
        type=float,
        default=0.0,
        metavar="SHARE",
        help="share (0-1) of a random scene's guardrail runs that are 40-120 m long, as along "
        "embankments and motorways (default 0: runs of 6-24 m)",
    )
    own.add_argument(
        "--height-jitter",
        type=float,
        default=0.0,
        metavar="SHARE",
        help="each of a random scene's guardrail runs built up to this share (0-0.5) taller or "
        "lower than its design, as real guardrails stand (default 0: every run as designed)",
    )
    own.add_argument(
        "--night",
        action="store_true",
        help="take the images at night: no sun, the vehicle's lamps light what is near, the "
        "camera's gain turned up",
    )
    own.add_argument(
        "--medians",
        type=float,
        default=0.0,
        metavar="SHARE",
        help="share (0-1) of a random scene's left-side beam runs that are a motorway median: "
        "a second beam back to back, facing the other carriageway, with a hedge between "
        "(default 0)",
    )
    own.add_argument(
        "--traffic",
        type=float,
        default=0.0,
        metavar="SHARE",
        help="cars in the lanes beside the vehicle's, one every 10-45 m kept with this "
        "probability (0-1; default 0: none)",
    )
    own.add_argument(
        "--young-trees",
        type=float,
        default=0.0,
        metavar="SHARE",
        help="young trees on stakes (and, half the time, a low hedge) close behind that share "
        "(0-1) of a random scene's pipe railings, as along town kerbs (default 0)",
    )
    own.add_argument(
        "--damage",
        type=float,
        default=0.0,
        metavar="SHARE",
        help="share (0-1) of a random scene's guardrail runs that are damaged: one to three of "
        "dents (10-100 mm deep, 0.3-1.5 m long), bent (20-100 mm) or missing pipes, missing or "
        "leaning (2-10 deg) posts, a rail lowered 10-80 mm by repaving, a missing or bent run "
        "end; each recorded in truth/objects.json (default 0)",
    )
    own.add_argument(
        "--curb-height",
        type=float,
        metavar="METRES",
        help="a random scene's curb height (default 0.15; 0: no curb, sidewalks and guardrails "
        "at road level, as on a motorway's shoulder)",
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
    from guardrail_core.errors import InvalidOptionError
    from guardrail_core.formats.drive import open_drive
    from guardrail_core.synth.random_scene import random_scene_spec
    from guardrail_core.synth.scene import load_scene_spec
    from guardrail_core.synth.simulate import SimulationOptions, simulate_drive

    if args.scene:
        spec = load_scene_spec(args.scene)
        if args.length is not None:
            print(
                "note: --length is ignored with --scene (the spec sets the drive)", file=sys.stderr
            )
        for given, option in (
            (not args.roadside, "--no-roadside"),
            (args.long_runs != 0.0, "--long-runs"),
            (args.curb_height is not None, "--curb-height"),
            (args.height_jitter != 0.0, "--height-jitter"),
            (args.medians != 0.0, "--medians"),
            (args.traffic != 0.0, "--traffic"),
            (args.young_trees != 0.0, "--young-trees"),
            (args.damage != 0.0, "--damage"),
        ):
            if given:
                print(
                    f"note: {option} is ignored with --scene (the spec sets the street)",
                    file=sys.stderr,
                )
    else:
        designs = args.designs.split(",") if args.designs else None
        spec = random_scene_spec(
            args.seed,
            args.length if args.length is not None else 100.0,
            designs=designs,
            roadside=args.roadside,
            long_runs=args.long_runs,
            curb_height=args.curb_height,
            height_jitter=args.height_jitter,
            medians=args.medians,
            traffic=args.traffic,
            young_trees=args.young_trees,
            damage=args.damage,
        )
    scanner = dict(spec.get("scanner") or {})
    if args.lidar is not None and args.scanner == "profile":
        raise InvalidOptionError("--lidar names a spinning LiDAR: it goes with --scanner multibeam")
    if args.scanner or args.lidar:
        scanner["kind"] = args.scanner or "multibeam"
        if args.frame_every is not None:
            scanner["frame_every_m"] = args.frame_every
        if args.lidar is not None:
            scanner["sensor"] = args.lidar
    for key, value in (
        ("range_noise_m", args.range_noise),
        ("dropout", args.dropout),
        ("intensity_gain", args.intensity_gain),
    ):
        if value is not None:
            scanner[key] = value
    if scanner:
        spec["scanner"] = scanner
    from guardrail_core.formats.drive_tiles import DEFAULT_DRIVE_TILE_M

    options = SimulationOptions(
        image_every_m=args.image_every,
        image_size=args.image_size,
        compress=not args.las,
        night=args.night,
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
        tile_m=DEFAULT_DRIVE_TILE_M if args.tile_m is None else args.tile_m,
    )
    timing = ", ".join(f"{k} {v:.1f} s" for k, v in summary.seconds.items())
    print(f"simulated {summary.length_m:.1f} m in {sum(summary.seconds.values()):.1f} s ({timing})")
    # The drive without its points: a long drive's points do not fit in memory.
    print(describe_simulation(summary, open_drive(summary.out)))
    return 0


def describe_simulation(summary: SimulationSummary, source: DriveSource) -> str:
    """Lines describing a simulated drive from what the simulation counted and the drive's
    metadata (its points are not read)."""
    from guardrail_core.classes import GUARDRAIL_CLASSES, TruthClass

    size_mb = sum(p.stat().st_size for p in source.root.rglob("*") if p.is_file()) / 1e6
    scanner = source.scanner
    per_camera = Counter(record.camera for record in source.images)
    runs = [o for o in source.objects if o.get("kind") == "guardrail"]
    others = Counter(o.get("kind") for o in source.objects if o.get("kind") != "guardrail")
    on_rails = sum(n for c, n in summary.points_by_class.items() if c in GUARDRAIL_CLASSES)
    return "\n".join(
        [
            f"drive      {source.root.resolve()}  ({size_mb:.1f} MB)",
            f"CRS        {source.crs}, local origin {', '.join(f'{v:.3f}' for v in source.origin)}",
            f"trajectory {summary.length_m:.1f} m in {summary.duration_s:.1f} s, "
            f"{len(source.trajectory)} poses",
            f"points     {summary.n_points:,} in {summary.n_tiles} tile(s), from a {scanner.kind} "
            f"scanner at {scanner.rotation_rate_hz:g} turns/s",
            f"images     {len(source.images)}: "
            + ", ".join(
                f"{name} {n} ({source.cameras[name].width}x{source.cameras[name].height})"
                for name, n in per_camera.items()
            ),
            f"truth      {len(runs)} guardrail runs "
            f"({', '.join(sorted({r['design'] for r in runs}))}), {on_rails:,} guardrail points "
            f"({100 * on_rails / max(summary.n_points, 1):.1f}%)",
            "           others: " + ", ".join(f"{k} {n}" for k, n in sorted(others.items())),
            "           points by class: "
            + ", ".join(
                f"{TruthClass(c).name.lower()} {n:,}"
                for c, n in sorted(summary.points_by_class.items())
            ),
        ]
    )
