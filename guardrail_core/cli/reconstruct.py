"""``guardrail reconstruct``: reconstruct a run folder's guardrails again, with other parameters."""

from __future__ import annotations

import argparse
from pathlib import Path

from guardrail_core.cli import common


def add_parser(subparsers: common.Subparsers) -> None:
    own = common.options_parser()
    own.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="run folder (guardrail process)")
    own.add_argument(
        "--drive", type=Path, help="the drive of the run (default: the path in run.json)"
    )
    parser = subparsers.add_parser(
        "reconstruct",
        help="reconstruct the guardrails of a run folder again, with other parameters",
        description="Reconstruct the guardrail runs of RUN_DIR (poles, unit shapes superimposed "
        "with ICP, pipes or beam sections, meshes and inventory) and replace "
        "RUN_DIR/reconstruction. `guardrail process` already did this with the defaults.",
        parents=[own, common.reconstruction_options(), common.quiet_options()],
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from guardrail_core.formats.drive import drive_parts, open_drive
    from guardrail_core.formats.run_folder_paths import RunFolder
    from guardrail_core.reconstruct.drive_input import gather_reconstruction_points
    from guardrail_core.reconstruct.writing import reconstruct_into

    params = common.reconstruction_params(args)
    run_folder = RunFolder(Path(args.run_dir))
    source = open_drive(args.drive or run_folder.info().drive.path, with_truth=False)
    label = run_folder.segments()["label"]
    # Only the guardrail points and the road near them, a tile at a time: a survey never whole.
    xyz, point_segment = gather_reconstruction_points(
        source, run_folder, label, params.runs.ground_reach_m
    )
    summary = reconstruct_into(
        Path(args.run_dir),
        xyz,
        point_segment,
        label,
        source.trajectory.position,
        origin=source.origin,
        crs=source.crs,
        params=params,
        inputs=drive_parts(source.root),
        progress=not args.quiet,
    )
    print(common.reconstruction_summary(summary))
    print(f"wrote {run_folder.reconstruction.root}")
    return 0
