"""``guardrail import kitti``: frames of a KITTI odometry sequence, merged into a drive folder."""

from __future__ import annotations

import argparse
from pathlib import Path

from guardrail_core.cli import common


def add_parser(subparsers: common.Subparsers) -> None:
    from guardrail_core.importers.kitti import KITTI_SENSOR_HEIGHT_M

    own = common.options_parser()
    own.add_argument(
        "sequence_dir",
        type=Path,
        metavar="SEQUENCE_DIR",
        help="a KITTI odometry sequence folder (velodyne/, calib.txt, poses.txt, times.txt)",
    )
    own.add_argument(
        "--frames",
        metavar="LIST",
        help="frames to merge: 280,281 or 270-290 or a mix (default: every frame with a scan)",
    )
    own.add_argument("--out", type=Path, required=True, help="drive folder to write")
    own.add_argument(
        "--sensor-height",
        type=float,
        default=KITTI_SENSOR_HEIGHT_M,
        metavar="METRES",
        help=f"the scanner's height above the road (default {KITTI_SENSOR_HEIGHT_M}, KITTI's car)",
    )
    parser = subparsers.add_parser(
        "kitti",
        help="frames of a KITTI odometry sequence, merged with their poses",
        description="Merge frames of a KITTI odometry sequence folder (velodyne/NNNNNN.bin, "
        "calib.txt, poses.txt, times.txt, optional image_2/) into a drive folder: points in "
        "the world of the sequence's frame 0, the scan lattice as ring x azimuth (rings "
        "recovered from the point order and elevation), the trajectory from the poses, "
        "image_2 as a calibrated camera.",
        parents=[own, common.overwrite_options(), common.quiet_options()],
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from guardrail_core.formats.drive import open_drive
    from guardrail_core.formats.drive_summary import describe_drive
    from guardrail_core.importers.kitti import import_kitti, parse_frames

    frames = parse_frames(args.frames) if args.frames else None
    result = import_kitti(
        args.sequence_dir,
        args.out,
        frames=frames,
        sensor_height_m=args.sensor_height,
        overwrite=args.overwrite,
        progress=not args.quiet,
    )
    print(
        f"imported {len(result.frames)} frames ({result.n_points:,} points, {result.rings} rings, "
        f"{result.n_images} images) into {result.out}"
    )
    print(describe_drive(open_drive(result.out)))
    return 0
