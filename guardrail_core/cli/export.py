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
    import importlib

    from guardrail_core.errors import InvalidOptionError

    wanted = [name for name in _EXPORTS if getattr(args, name)]
    if not wanted:
        raise InvalidOptionError(
            "nothing to write: give at least one of --las, --cityjson, --opendrive, --3dtiles, "
            "--osm"
        )
    for name in wanted:
        module, export, describe = _EXPORTS[name]
        library = importlib.import_module(f"guardrail_core.export.{module}")
        summary = getattr(library, export)(
            args.run_dir, getattr(args, name), drive_dir=args.drive, overwrite=args.overwrite
        )
        for line in getattr(summary, "warnings", ()):
            print(f"warning: {line}", file=sys.stderr)
        print(getattr(library, describe)(summary))
    return 0


#: Option (its ``args`` name) -> (module of guardrail_core.export, its export function, its
#: summary formatter); every export takes (run_dir, out, drive_dir=, overwrite=). The modules
#: load only when their format is asked for.
_EXPORTS = {
    "las": ("las", "export_run_las", "format_summary"),
    "cityjson": ("cityjson", "export_run_cityjson", "format_cityjson_summary"),
    "opendrive": ("opendrive", "export_run_opendrive", "format_opendrive_summary"),
    "tiles3d": ("tiles3d", "export_run_3dtiles", "format_tiles_summary"),
    "osm": ("osm", "export_run_osm", "format_osm_summary"),
}
