"""``guardrail reconstruct``: reconstruct a run folder's guardrails again, with other parameters."""

from __future__ import annotations

import argparse
from pathlib import Path

from guardrail_core.cli import common


def add_parser(subparsers: common.Subparsers) -> None:
    own = common.options_parser()
    own.add_argument("run_dir", type=Path, metavar="RUN_DIR")
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
    from guardrail_core.formats.drive import drive_parts, load_drive
    from guardrail_core.formats.run_folder import load_run
    from guardrail_core.reconstruct.pipeline import reconstruct_into

    params = common.reconstruction_params(args)
    run_folder = load_run(args.run_dir)
    drive = load_drive(args.drive or run_folder.info.drive.path, with_truth=False)
    if len(drive.points) != len(run_folder.point_segment):
        from guardrail_core.errors import RunFolderError

        raise RunFolderError(
            f"{args.run_dir}: made from a drive of {len(run_folder.point_segment)} points, but "
            f"{drive.root} has {len(drive.points)}; give the right drive with --drive"
        )
    summary = reconstruct_into(
        Path(args.run_dir),
        drive.points.xyz,
        run_folder.point_segment,
        run_folder.segments["label"],
        drive.trajectory.position,
        origin=drive.origin,
        crs=drive.crs,
        params=params,
        inputs=drive_parts(drive.root),
        progress=not args.quiet,
    )
    print(common.reconstruction_summary(summary))
    print(f"wrote {run_folder.folder.reconstruction.root}")
    return 0
