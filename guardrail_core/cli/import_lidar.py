"""``guardrail import lidar``: frames of any spinning multi-beam LiDAR (PCD, LAS/LAZ, KITTI .bin)."""

from __future__ import annotations

import argparse
from pathlib import Path

from guardrail_core.cli import common


def add_parser(subparsers: common.Subparsers) -> None:
    from guardrail_core.sensors.lidar_models import LIDAR_MODELS

    own = common.options_parser()
    own.add_argument(
        "frames", type=Path, nargs="+", metavar="FRAME", help="frame files, or folders of them"
    )
    own.add_argument("--out", type=Path, required=True, help="drive folder to write")
    own.add_argument(
        "--sensor",
        choices=sorted(LIDAR_MODELS),
        help="the LiDAR's beam table and turn rate, where the frames carry no ring field "
        "(default: the rings from the file's ring field, else from the frame's own elevations)",
    )
    own.add_argument(
        "--beams",
        type=Path,
        metavar="FILE",
        help="a beam table instead: one elevation a beam, degrees",
    )
    own.add_argument(
        "--poses",
        type=Path,
        metavar="FILE",
        help="the frames' poses: KITTI poses.txt (12 numbers a row) or a CSV of 4x4 matrices "
        "(16 numbers a row, or 17 with a time first); needed for several frames",
    )
    own.add_argument(
        "--times", type=Path, metavar="FILE", help="the frames' times, one a line (KITTI times.txt)"
    )
    own.add_argument(
        "--kitti-calib",
        type=Path,
        metavar="FILE",
        help="KITTI calib.txt: the poses are camera 0's, turned to the LiDAR's by its Tr",
    )
    own.add_argument(
        "--sensor-height",
        type=float,
        metavar="METRES",
        help="the LiDAR's height above the road (default: measured from the first frame's road)",
    )
    own.add_argument(
        "--camera",
        type=Path,
        action="append",
        default=[],
        metavar="CALIB",
        help="a camera calibration (JSON/YAML: K, distortion, size and its mounting on the "
        "LiDAR); repeatable",
    )
    own.add_argument(
        "--images",
        type=Path,
        metavar="DIR",
        help="the cameras' images, named as the frames: DIR/CAMERA/<frame>.png (or DIR/<frame>.png "
        "for one camera)",
    )
    own.add_argument(
        "--rotation-hz",
        type=float,
        metavar="HZ",
        help="turns per second (default: the sensor's, else 10)",
    )
    parser = subparsers.add_parser(
        "lidar",
        help="frames of any spinning multi-beam LiDAR (PCD, LAS/LAZ, KITTI .bin)",
        description="Import frames of a spinning multi-beam LiDAR (Velodyne, Hesai, Ouster, ...) "
        "into a drive folder: one frame alone, or a sequence merged with its poses; rings from "
        "the ring field or the beams' elevations, cameras with their distortion and mounting "
        "(docs/import.md).",
        parents=[own, common.overwrite_options(), common.quiet_options()],
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from guardrail_core.formats.drive import open_drive
    from guardrail_core.formats.drive_summary import describe_drive
    from guardrail_core.importers.lidar import import_lidar

    result = import_lidar(
        args.frames,
        args.out,
        sensor=args.sensor,
        beams=args.beams,
        poses=args.poses,
        times=args.times,
        kitti_calib=args.kitti_calib,
        sensor_height_m=args.sensor_height,
        calibrations=args.camera,
        images=args.images,
        rotation_hz=args.rotation_hz,
        overwrite=args.overwrite,
        progress=not args.quiet,
    )
    height = f"{result.sensor_height_m:.2f} m" + (
        " (measured from the road)" if result.sensor_height_estimated else ""
    )
    print(
        f"imported {result.frames} frame(s) ({result.n_points:,} points, {result.rings} rings "
        f"from the {result.rings_from}, {result.n_images} images, sensor {height}) into "
        f"{result.out}"
    )
    print(describe_drive(open_drive(result.out)))
    return 0
