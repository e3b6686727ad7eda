"""``guardrail info``: validate a drive folder and describe it."""

from __future__ import annotations

import argparse
from pathlib import Path

from guardrail_core.cli import common


def add_parser(subparsers: common.Subparsers) -> None:
    parser = subparsers.add_parser(
        "info",
        help="describe a drive folder",
        description=(
            "Validate a drive folder (every point tile is read and every image decoded, at 1/8 "
            "scale) and describe it."
        ),
    )
    parser.add_argument("drive", type=Path, metavar="DRIVE", help="drive folder to check")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from guardrail_core.formats.drive import open_drive
    from guardrail_core.formats.drive_summary import count_points, describe_drive
    from guardrail_core.formats.image_check import check_images

    source = open_drive(args.drive)
    # Every tile is read (one at a time) and every image decoded: info validates the whole drive.
    counts = count_points(source)
    check_images(source.root, source.images, source.cameras)
    print(describe_drive(source, counts))
    return 0
