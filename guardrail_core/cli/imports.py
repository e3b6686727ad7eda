"""``guardrail import las|kitti|lidar``: data recorded elsewhere into an ordinary drive folder."""

from __future__ import annotations

from guardrail_core.cli import common, import_kitti, import_las, import_lidar


def add_parser(subparsers: common.Subparsers) -> None:
    parser = subparsers.add_parser(
        "import",
        help="import a LAS/LAZ mobile-mapping delivery, KITTI scans or any spinning LiDAR's "
        "frames as a drive folder",
        description="Turn data recorded elsewhere into a drive folder that every other command "
        "reads.",
    )
    sources = parser.add_subparsers(dest="source", required=True, metavar="SOURCE")
    import_las.add_parser(sources)
    import_kitti.add_parser(sources)
    import_lidar.add_parser(sources)
