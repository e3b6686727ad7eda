"""``guardrail export RUN_DIR --las OUT.laz``: the drive's points with the run's result."""

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
        required=True,
        metavar="OUT",
        help="file to write: OUT.laz (compressed) or OUT.las",
    )
    own.add_argument(
        "--drive", type=Path, help="the drive of the run (default: the path in run.json)"
    )
    parser = subparsers.add_parser(
        "export",
        help="write a run's result onto the drive's points as LAS/LAZ for GIS tools",
        description="Write every point of the run's drive in map coordinates (LAS 1.4, the "
        "drive's CRS) with the run's result: class 64 guardrail, 65 guardrail pole, 11 road "
        "surface (where the drive left points unclassified), and the extra dimensions "
        "segment_id, guardrail_probability and run_id. See docs/run-folder.md.",
        parents=[own, common.overwrite_options()],
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from guardrail_core.export.las import export_run_las, format_summary

    summary = export_run_las(args.run_dir, args.las, drive_dir=args.drive, overwrite=args.overwrite)
    for line in summary.warnings:
        print(f"warning: {line}", file=sys.stderr)
    print(format_summary(summary))
    return 0
