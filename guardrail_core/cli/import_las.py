"""``guardrail import las``: a LAS/LAZ delivery (points, trajectory, images, calibration)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from guardrail_core.cli import common


def add_parser(subparsers: common.Subparsers) -> None:
    from guardrail_core.importers.las_delivery import (
        DEFAULT_CHUNK_POINTS,
        DEFAULT_REFERENCE_HEIGHT_M,
        DEFAULT_TILE_M,
    )

    own = common.options_parser()
    own.add_argument("points", type=Path, nargs="+", metavar="POINTS", help="LAS/LAZ file(s)")
    own.add_argument("--trajectory", type=Path, required=True, metavar="CSV", help="trajectory CSV")
    own.add_argument("--out", type=Path, required=True, help="drive folder to write")
    own.add_argument(
        "--trajectory-degrees",
        action="store_true",
        help="the trajectory's roll, pitch, yaw are in degrees (default radians)",
    )
    own.add_argument(
        "--reference-height",
        type=float,
        default=DEFAULT_REFERENCE_HEIGHT_M,
        metavar="METRES",
        help="height of the trajectory's reference point above the road "
        f"(default {DEFAULT_REFERENCE_HEIGHT_M})",
    )
    own.add_argument("--images", type=Path, metavar="CSV", help="image list: file,camera,gps_time")
    own.add_argument(
        "--calibration",
        type=Path,
        nargs="+",
        action="extend",
        metavar="FILE",
        help="camera calibration: OpenCV YAML (cv2.FileStorage), YAML or JSON; one file per "
        "camera or one for several",
    )
    own.add_argument(
        "--scanner",
        type=Path,
        metavar="FILE",
        help="scanner parameters, JSON or YAML with the keys of drive.json's scanner block",
    )
    own.add_argument("--rotations-per-second", type=float, metavar="HZ", help="mirror rotations")
    own.add_argument("--measurements-per-second", type=float, metavar="HZ", help="pulse rate")
    own.add_argument(
        "--t0",
        type=float,
        metavar="SECONDS",
        help="GPS time of pulse 0, the lattice's epoch (default: the first point's whole second)",
    )
    own.add_argument(
        "--scanner-mount",
        metavar="NUMBERS",
        help="T_vehicle_scanner: x,y,z,roll,pitch,yaw (metres, degrees) or 16 numbers of the "
        "4x4 matrix, row by row; write --scanner-mount=-0.6,... when it starts with a minus "
        "(default: the simulator's mount)",
    )
    own.add_argument(
        "--crs",
        help="map CRS, e.g. EPSG:6677 (default: the one the LAS file declares, else 'unknown'); "
        "replaces the file's",
    )
    own.add_argument(
        "--tile-m",
        type=float,
        default=DEFAULT_TILE_M,
        metavar="METRES",
        help=f"metres of driving per tile of the drive's points (default {DEFAULT_TILE_M:g})",
    )
    own.add_argument(
        "--chunk-points",
        type=int,
        default=DEFAULT_CHUNK_POINTS,
        metavar="N",
        help="points read from a LAS/LAZ file at a time; memory grows with it "
        f"(default {DEFAULT_CHUNK_POINTS:,})",
    )
    parser = subparsers.add_parser(
        "las",
        help="a LAS/LAZ delivery: points with GPS time, trajectory, images and calibration",
        description="Turn a mobile-mapping delivery into a drive folder: LAS/LAZ points (any "
        "point format with gps_time, map coordinates), a trajectory CSV (time, x, y, z, roll, "
        "pitch, yaw), optionally an image list CSV (file, camera, gps_time) with the cameras' "
        "calibration (OpenCV YAML or JSON), and the scanner's rates for the scan lattice. "
        "The points stream in GPS-time order, chunk by chunk, into tiles of --tile-m metres: "
        "memory does not grow with the delivery. Formats: docs/import.md.",
        parents=[own, common.las_options(), common.overwrite_options(), common.quiet_options()],
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from guardrail_core.importers.las_delivery import import_las_delivery, read_scanner_file

    # Options override the scanner file's values, one by one.
    fields = read_scanner_file(args.scanner) if args.scanner else {}
    for key, value in (
        ("rotation_rate_hz", args.rotations_per_second),
        ("measurement_rate_hz", args.measurements_per_second),
        ("t0_s", args.t0),
        ("T_vehicle_scanner", args.scanner_mount),
    ):
        if value is not None:
            fields[key] = value
    result = import_las_delivery(
        args.points,
        args.trajectory,
        args.out,
        scanner=fields,
        images_csv=args.images,
        calibration=args.calibration,
        crs=args.crs,
        reference_height_m=args.reference_height,
        trajectory_degrees=args.trajectory_degrees,
        tile_m=args.tile_m,
        chunk_points=args.chunk_points,
        compress=not args.las,
        overwrite=args.overwrite,
        progress=not args.quiet,
    )
    for note in result.notes:
        print(f"note: {note}", file=sys.stderr)
    crs_from = "none declared" if result.crs_from == "none" else f"from the {result.crs_from}"
    # The drive is not loaded to describe it: a survey's points do not fit in memory.
    print(
        f"imported {result.n_points:,} points in {result.n_tiles} tiles and {result.n_images} "
        f"images into {result.out} (CRS {result.crs}, {crs_from}; scanner t0 "
        f"{result.scanner.t0_s:.6f} s)"
    )
    return 0
