"""``guardrail process``: extract (and reconstruct) the guardrails of a drive into a run folder."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from guardrail_core.cli import common


def add_parser(subparsers: common.Subparsers) -> None:
    own = common.options_parser()
    own.add_argument("drive", type=Path, metavar="DRIVE", help="drive folder to process")
    own.add_argument(
        "--model",
        type=Path,
        help="model folder (guardrail train; default: the model shipped with guardrail, trained "
        "on simulated drives of a profile and a multi-beam scanner)",
    )
    own.add_argument("--out", type=Path, required=True, help="run folder to write")
    own.add_argument(
        "--set",
        action="append",
        metavar="STAGE.NAME=VALUE",
        help="one extraction or reconstruction parameter, e.g. "
        "classify.crop_probability_clip=1e-05 or pipes.slice_interval_m=0.02 (repeatable; "
        "stages: road, segments, crops, classify, correction; runs, poles, units, register, "
        "pipes, beams, sweep)",
    )
    tiles = own.add_argument_group("tiles and workers")
    tiles.add_argument(
        "--tile-m",
        type=float,
        default=100.0,
        metavar="METRES",
        help="metres of trajectory per processing tile, a multiple of 0.5 (default 100; 0: the "
        "whole drive as one tile)",
    )
    tiles.add_argument(
        "--margin-m",
        type=float,
        default=None,
        metavar="METRES",
        help="metres of its neighbours each tile sees on either side (default 10)",
    )
    tiles.add_argument(
        "--workers",
        type=int,
        default=None,
        help="worker processes of the embedded Dask LocalCluster (default: one per core; 0: "
        "no Dask, tiles one after another in this process)",
    )
    tiles.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run the tiles on an existing Dask cluster (tcp://HOST:PORT) instead; the drive, "
        "model and output folders must be on storage every worker sees, at the same paths",
    )
    tiles.add_argument(
        "--memory-limit",
        default="auto",
        help="memory per LocalCluster worker, Dask's syntax (e.g. 3GiB; default auto: the "
        "machine's memory shared equally)",
    )
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
    from guardrail_core.distributed import (
        ClusterSpec,
        dask_client,
        default_workers,
        on_every_worker,
    )

    workers = default_workers() if args.workers is None else args.workers
    cluster = ClusterSpec(workers=workers, scheduler=args.scheduler, memory_limit=args.memory_limit)
    # The cluster starts first, and its workers load the model while this process imports the
    # pipeline (seconds of each that would otherwise follow one another); unless the drive or
    # the model folder is plainly missing, which is said at once instead.
    plain = Path(args.drive, "drive.json").is_file() and (
        args.model is None or Path(args.model, "model.json").is_file()
    )
    with dask_client(cluster if plain else ClusterSpec()) as client:
        warming = []  # held, so that Dask keeps the tasks until they have run
        if client is not None:
            model_arg = None if args.model is None else str(args.model.resolve())
            warming = on_every_worker(client, "guardrail_core.process.tile_task:warm_up", model_arg)
        from guardrail_core.extract.classify.model_folder import DEFAULT_MODEL_DIR, load_model
        from guardrail_core.process import DEFAULT_MARGIN_M, process_drive_folder

        model_dir = args.model or DEFAULT_MODEL_DIR
        extraction, reconstruction = common.process_params(args.set or [])
        model = load_model(model_dir)
        if args.model is None:
            print(f"model: the default model shipped with guardrail ({model.version})")
        info = process_drive_folder(
            args.drive,
            model_dir,
            args.out,
            params=extraction,
            reconstruction=reconstruction,
            overwrite=args.overwrite,
            progress=not args.quiet,
            tile_m=args.tile_m or None,
            margin_m=DEFAULT_MARGIN_M if args.margin_m is None else args.margin_m,
            cluster=cluster,
            client=client,
        )
        del warming  # their work is done (a warm-up that failed leaves it to the tiles)
    counts = info.counts
    crops = counts.crops
    print(
        f"{counts.segments} segments from {counts.segment_points} of {counts.points} "
        f"points ({counts.road_points} road surface, {counts.off_road_points} far from the road)"
    )
    print(
        f"crops: {crops.ok} ok, {crops.no_image} with no image that holds all their points, "
        f"{crops.too_small} too small to crop; the CNN asked for {crops.asked} of the "
        f"{crops.ok} (the shape decided the others)"
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
    processing = info.processing
    if processing is not None:
        print(
            f"{len(processing.tiles)} tile(s) on {processing.scheduler} "
            f"({processing.workers} worker(s)) in {processing.seconds:.1f} s"
        )
        for tile in processing.failed:
            print(
                f"error: tile {tile.number} (stations {tile.station_m[0]:g}..{tile.station_m[1]:g}"
                f" m) failed, its points are marked unprocessed: {tile.error}",
                file=sys.stderr,
            )
    print(f"wrote {args.out}")
    return 1 if processing is not None and processing.failed else 0
