"""``guardrail import las|kitti``: data recorded elsewhere into an ordinary drive folder."""

from __future__ import annotations

from guardrail_core.cli import common, import_kitti, import_las


def add_parser(subparsers: common.Subparsers) -> None:
    parser = subparsers.add_parser(
        "import",
        help="import a LAS/LAZ mobile-mapping delivery or KITTI scans as a drive folder",
        description="Turn data recorded elsewhere into a drive folder that every other command "
        "reads.",
    )
    sources = parser.add_subparsers(dest="source", required=True, metavar="SOURCE")
    import_las.add_parser(sources)
    import_kitti.add_parser(sources)
