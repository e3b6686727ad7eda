"""``guardrail export RUN_DIR --las OUT.laz --cityjson OUT.city.json --opendrive OUT.xodr
--3dtiles OUT_DIR --osm OUT.osm``: a run's result in GIS and 3D-map formats (any subset)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from guardrail_core.cli import common


def add_parser(subparsers: common.Subparsers) -> None:
    own = common.options_parser()
    own.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="run folder (guardrail process)")
    own.add_argument(
        "--las",
        type=Path,
        metavar="OUT",
        help="the drive's points with the run's classes: OUT.laz (compressed) or OUT.las",
    )
    own.add_argument(
        "--cityjson",
        type=Path,
        metavar="OUT",
        help="CityJSON 2.0: each guardrail run a CityFurniture object (OUT.city.json)",
    )
    own.add_argument(
        "--opendrive",
        type=Path,
        metavar="OUT",
        help="ASAM OpenDRIVE 1.8: a road along the trajectory, guardrails as barrier objects "
        "(OUT.xodr)",
    )
    own.add_argument(
        "--3dtiles",
        dest="tiles3d",
        type=Path,
        metavar="OUT_DIR",
        help="OGC 3D Tiles 1.1: a tileset.json and a glTF per run, georeferenced (a folder)",
    )
    own.add_argument(
        "--osm",
        type=Path,
        metavar="OUT",
        help="OpenStreetMap XML: a barrier=guard_rail way per run, WGS84 (OUT.osm; for review "
        "in JOSM, never to upload blindly)",
    )
    own.add_argument(
        "--drive", type=Path, help="the drive of the run (default: the path in run.json)"
    )
    parser = subparsers.add_parser(
        "export",
        help="write a run's result as LAS/LAZ, CityJSON, OpenDRIVE, 3D Tiles or OpenStreetMap",
        description="Write a run's result for GIS tools and 3D maps, in any subset of the "
        "formats below (at least one). --las: every point of the run's drive in map coordinates "
        "(LAS 1.4, the drive's CRS) with class 64 guardrail, 65 guardrail pole, 11 road surface, "
        "and the extra dimensions segment_id, guardrail_probability and run_id. The others write "
        "the reconstructed runs (meshes, poles and the inventory's attributes) in the drive's "
        "CRS (3D Tiles: ECEF; OpenStreetMap: WGS84). See docs/export.md.",
        parents=[own, common.overwrite_options()],
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from guardrail_core.errors import InvalidOptionError

    wanted = [
        name for name in ("las", "cityjson", "opendrive", "tiles3d", "osm") if getattr(args, name)
    ]
    if not wanted:
        raise InvalidOptionError(
            "nothing to write: give at least one of --las, --cityjson, --opendrive, --3dtiles, "
            "--osm"
        )
    for name in wanted:
        for line in _EXPORTS[name](args):
            print(line)
    return 0


def _las(args: argparse.Namespace) -> list[str]:
    from guardrail_core.export.las import export_run_las, format_summary

    summary = export_run_las(args.run_dir, args.las, drive_dir=args.drive, overwrite=args.overwrite)
    for line in summary.warnings:
        print(f"warning: {line}", file=sys.stderr)
    return [format_summary(summary)]


def _cityjson(args: argparse.Namespace) -> list[str]:
    from guardrail_core.export.cityjson import export_run_cityjson, format_cityjson_summary

    summary = export_run_cityjson(
        args.run_dir, args.cityjson, drive_dir=args.drive, overwrite=args.overwrite
    )
    return [format_cityjson_summary(summary)]


def _opendrive(args: argparse.Namespace) -> list[str]:
    from guardrail_core.export.opendrive import export_run_opendrive, format_opendrive_summary

    summary = export_run_opendrive(
        args.run_dir, args.opendrive, drive_dir=args.drive, overwrite=args.overwrite
    )
    return [format_opendrive_summary(summary)]


def _tiles3d(args: argparse.Namespace) -> list[str]:
    from guardrail_core.export.tiles3d import export_run_3dtiles, format_tiles_summary

    summary = export_run_3dtiles(
        args.run_dir, args.tiles3d, drive_dir=args.drive, overwrite=args.overwrite
    )
    return [format_tiles_summary(summary)]


def _osm(args: argparse.Namespace) -> list[str]:
    from guardrail_core.export.osm import export_run_osm, format_osm_summary

    summary = export_run_osm(args.run_dir, args.osm, drive_dir=args.drive, overwrite=args.overwrite)
    return [format_osm_summary(summary)]


_EXPORTS = {
    "las": _las,
    "cityjson": _cityjson,
    "opendrive": _opendrive,
    "tiles3d": _tiles3d,
    "osm": _osm,
}
