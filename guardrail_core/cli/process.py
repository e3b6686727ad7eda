"""``guardrail process``: extract (and reconstruct) the guardrails of a drive into a run folder."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from guardrail_core.cli import common


def add_parser(subparsers: common.Subparsers) -> None:
    own = common.options_parser()
    own.add_argument("drive", type=Path)
    own.add_argument(
        "--model",
        type=Path,
        help="model folder (guardrail train; default: the model shipped with guardrail, trained "
        "on simulated drives of a profile and a multi-beam scanner)",
    )
    own.add_argument("--out", type=Path, required=True, help="run folder to write")
    parser = subparsers.add_parser(
        "process",
        help="extract guardrail segments from a drive",
        description="Remove the road, cut the rest into 0.5 m segments, crop each segment's "
        "image, classify it and correct the labels; write everything into the run folder.",
        parents=[
            own,
            common.overwrite_options("replace the run folder"),
            common.quiet_options(),
        ],
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from guardrail_core.extract.model_folder import DEFAULT_MODEL_DIR, load_model
    from guardrail_core.formats.drive import load_drive
    from guardrail_core.process import process_drive

    model_dir = args.model or DEFAULT_MODEL_DIR
    model = load_model(model_dir)
    if args.model is None:
        print(f"model: the default model shipped with guardrail ({model.version})")
    drive = load_drive(args.drive, with_truth=False)
    info = process_drive(
        drive,
        model,
        args.out,
        overwrite=args.overwrite,
        inputs=[model_dir],  # the drive's parts are inputs too (process_drive adds them)
        progress=not args.quiet,
    )
    counts = info.counts
    crops = counts.crops
    print(
        f"{counts.segments} segments from {counts.segment_points} of {counts.points} "
        f"points ({counts.road_points} road surface, {counts.off_road_points} far from the road)"
    )
    print(
        f"crops: {crops.ok} ok, {crops.no_image} with no image that holds all their points, "
        f"{crops.too_small} too small to crop"
    )
    if crops.ok == 0 and counts.segments:
        if model.segment_head is not None:
            print("note: no segment has a usable image: all were classified by their geometry")
        else:
            print(
                "warning: no segment has a usable image, and this model classifies crops only, "
                "so nothing could be classified",
                file=sys.stderr,
            )
    print(
        f"guardrail segments: {counts.guardrail_segments_raw} raw, "
        f"{counts.guardrail_segments} after label correction "
        f"({counts.guardrail_points} points)"
    )
    if info.reconstruction is not None:
        print(common.reconstruction_summary(info.reconstruction))
    print(f"wrote {args.out}")
    return 0
