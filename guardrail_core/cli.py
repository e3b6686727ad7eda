"""The ``guardrail`` command line."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from guardrail_core.errors import GuardrailError

DEMO_SCENE = "sample"


def _size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(
            f"expected WIDTHxHEIGHT, e.g. 1024x768, got {text!r}"
        ) from exc
    if not (64 <= width <= 8192 and 64 <= height <= 8192):
        raise argparse.ArgumentTypeError("image sides must lie within 64..8192 pixels")
    return width, height


def _simulate(args: argparse.Namespace) -> int:
    from guardrail_core.drive import load_drive
    from guardrail_core.drive_summary import describe_drive
    from guardrail_core.synth.scene import load_scene_spec, random_scene_spec
    from guardrail_core.synth.simulate import SimulationOptions, simulate_drive

    if args.scene:
        spec = load_scene_spec(args.scene)
        if args.length is not None:
            print(
                "note: --length is ignored with --scene (the spec sets the drive)", file=sys.stderr
            )
    else:
        designs = args.designs.split(",") if args.designs else None
        spec = random_scene_spec(
            args.seed, args.length if args.length is not None else 100.0, designs=designs
        )
    if args.scanner:
        spec["scanner"] = {**(spec.get("scanner") or {}), "kind": args.scanner}
        if args.frame_every is not None:
            spec["scanner"]["frame_every_m"] = args.frame_every
    options = SimulationOptions(
        image_every_m=args.image_every, image_size=args.image_size, compress=not args.las
    )
    summary = simulate_drive(
        spec,
        args.out,
        seed=args.seed,
        options=options,
        overwrite=args.overwrite,
        progress=not args.quiet,
    )
    timing = ", ".join(f"{k} {v:.1f} s" for k, v in summary.seconds.items())
    print(f"simulated {summary.length_m:.1f} m in {sum(summary.seconds.values()):.1f} s ({timing})")
    print(describe_drive(load_drive(summary.out)))
    return 0


def _info(args: argparse.Namespace) -> int:
    from guardrail_core.drive import load_drive
    from guardrail_core.drive_summary import describe_drive

    print(describe_drive(load_drive(args.drive)))
    return 0


def _train(args: argparse.Namespace) -> int:
    from guardrail_core.extract.classify import ClassifierParams
    from guardrail_core.extract.model_store import save_model
    from guardrail_core.training import train_from_drives

    params = ClassifierParams(mode=args.mode, seed=args.seed)
    if bool(args.drives) == bool(args.run):
        from guardrail_core.errors import InvalidOptionError

        raise InvalidOptionError(
            "give either DRIVE... (labels from their truth/) or --run RUN_DIR (labels from the "
            "review app's label store), not both or neither"
        )
    if args.run:
        model = _train_from_labels(args, params)
    else:
        model = train_from_drives(args.drives, params=params, progress=not args.quiet)
    save_model(model, args.out, overwrite=args.overwrite)
    print(f"trained a {model.mode} model {model.version} into {args.out}")
    print(_held_out_report(model.info))
    return 0


def _train_from_labels(args: argparse.Namespace, params):
    from guardrail_core.label_store import LabelStore, default_store_path
    from guardrail_core.review_training import train_from_run
    from guardrail_core.run_folder import load_run

    run = load_run(args.run)
    path = args.labels or default_store_path(Path(run.info["drive"]["path"]))
    if not Path(path).is_file():
        from guardrail_core.errors import LabelStoreError

        raise LabelStoreError(f"{path}: no label store there; give it with --labels")
    with LabelStore(path, n_points=len(run.point_segment)) as store:
        labels = store.point_labels().copy()
    counts = int((labels >= 0).sum())
    print(f"{counts:,} operator-labelled points from {path}")
    return train_from_run(
        run, labels, params=params, include_unreviewed=not args.reviewed_only
    ).model


def _held_out_report(info: dict) -> str:
    metrics = info.get("metrics", {})
    trained = info.get("trained_on", {})
    lines = [
        f"trained on {trained.get('segments', '?')} segments, {trained.get('crops', '?')} with a "
        f"crop ({trained.get('guardrail', '?')} guardrail, {trained.get('other', '?')} other)"
    ]
    for key, what in (("held_out", "segments"), ("held_out_crops", "crops alone")):
        held = metrics.get(key)
        if not held:
            continue
        lines.append(f"held out {held['n_held_out']} {what}:")
        for name in ("guardrail", "other"):
            m = held.get(name)
            if m and m["f1"] is not None:
                lines.append(
                    f"  {name:10s} recall {100 * m['recall']:5.1f}%  precision "
                    f"{100 * m['precision']:5.1f}%  F {100 * m['f1']:5.1f}%  (n={m['n']})"
                )
    return "\n".join(lines)


def _process(args: argparse.Namespace) -> int:
    from guardrail_core.drive import load_drive
    from guardrail_core.extract.model_store import DEFAULT_MODEL_DIR, load_model
    from guardrail_core.pipeline import process_drive

    model = load_model(args.model or DEFAULT_MODEL_DIR)
    if args.model is None:
        print(f"model: the default model shipped with guardrail ({model.version})")
    drive = load_drive(args.drive, with_truth=False)
    info = process_drive(drive, model, args.out, overwrite=args.overwrite, progress=not args.quiet)
    counts = info["counts"]
    crops = counts["crops"]
    print(
        f"{counts['segments']} segments from {counts['segment_points']} of {counts['points']} "
        f"points ({counts['road_points']} road surface, {counts['off_road_points']} far from the road)"
    )
    print(
        f"crops: {crops['ok']} ok, {crops['no_image']} with no image that holds all their points, "
        f"{crops['too_small']} too small to crop"
    )
    if crops["ok"] == 0 and counts["segments"]:
        if model.segment_head is not None:
            print("note: no segment has a usable image: all were classified by their geometry")
        else:
            print(
                "warning: no segment has a usable image, and this model classifies crops only, "
                "so nothing could be classified",
                file=sys.stderr,
            )
    print(
        f"guardrail segments: {counts['guardrail_segments_raw']} raw, "
        f"{counts['guardrail_segments']} after label correction "
        f"({counts['guardrail_points']} points)"
    )
    if "reconstruction" in info:
        print(_reconstruction_summary(info["reconstruction"]))
    print(f"wrote {args.out}")
    return 0


def _reconstruction_params(args: argparse.Namespace):
    import json

    from guardrail_core.errors import InvalidOptionError
    from guardrail_core.reconstruction import ReconstructionParams

    params = ReconstructionParams()
    if getattr(args, "params", None):
        try:
            data = json.loads(Path(args.params).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise InvalidOptionError(f"--params {args.params}: cannot read it ({exc})") from exc
        params = ReconstructionParams.from_json(data.get("params", data))
    return params.with_settings(getattr(args, "set", None) or [])


def _reconstruct(args: argparse.Namespace) -> int:
    from guardrail_core.drive import load_drive
    from guardrail_core.reconstruction import reconstruct_into
    from guardrail_core.run_folder import load_run

    params = _reconstruction_params(args)
    run = load_run(args.run_dir)
    drive = load_drive(args.drive or run.info["drive"]["path"], with_truth=False)
    if len(drive.points) != len(run.point_segment):
        from guardrail_core.errors import RunFolderError

        raise RunFolderError(
            f"{args.run_dir}: made from a drive of {len(run.point_segment)} points, but "
            f"{drive.root} has {len(drive.points)}; give the right drive with --drive"
        )
    summary = reconstruct_into(
        Path(args.run_dir),
        drive.points.xyz,
        run.point_segment,
        run.segments["label"],
        drive.trajectory.position,
        origin=drive.origin,
        crs=drive.crs,
        params=params,
        progress=not args.quiet,
    )
    print(_reconstruction_summary(summary))
    print(f"wrote {Path(args.run_dir) / 'reconstruction'}")
    return 0


def _reconstruction_summary(summary: dict) -> str:
    return (
        f"guardrail runs: {summary['runs']} ({summary['reconstructed']} reconstructed, "
        f"{summary['poles_only']} poles only, {summary['not_reconstructed']} not reconstructed) "
        f"in {summary['seconds']:.1f} s"
    )


def _evaluate(args: argparse.Namespace) -> int:
    import json

    from guardrail_core.drive import load_drive
    from guardrail_core.evaluate import evaluate_run, format_report
    from guardrail_core.run_folder import load_run

    drive, run = load_drive(args.drive), load_run(args.run)
    result = evaluate_run(drive, run)
    sweep = None
    if args.units_sweep:
        from guardrail_core.units_sweep import (
            format_units_sweep,
            parse_units,
            plot_units_sweep,
            units_sweep,
        )

        units = parse_units(args.units_sweep)
        sweep = units_sweep(
            drive, run, units, params=_reconstruction_params(args), progress=not args.quiet
        )
        plot = plot_units_sweep(sweep, args.plot or Path(args.run) / "units_sweep.png")
        result["units_sweep"] = {**sweep, "plot": str(plot)}
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(format_report(result))
        if sweep is not None:
            print()
            print(format_units_sweep(sweep))
            print(f"plot: {result['units_sweep']['plot']}")
    return 0


def _demo(args: argparse.Namespace) -> int:
    from guardrail_core.drive import load_drive
    from guardrail_core.drive_summary import describe_drive
    from guardrail_core.synth.scene import load_scene_spec
    from guardrail_core.synth.simulate import simulate_drive

    out = Path(args.out)
    if (out / "drive.json").is_file() and not args.fresh:
        print(f"the sample drive is already there (--fresh to simulate it again): {out}")
    else:
        simulate_drive(
            load_scene_spec(DEMO_SCENE), out, seed=7, overwrite=True, progress=not args.quiet
        )
        print(f"simulated the sample drive into {out}")
    print(describe_drive(load_drive(out)))

    from guardrail_core.evaluate import evaluate_run, format_report
    from guardrail_core.extract.classify import ClassifierParams
    from guardrail_core.extract.model_store import save_model
    from guardrail_core.pipeline import process_drive
    from guardrail_core.run_folder import load_run
    from guardrail_core.training import train_from_drives

    model_dir, run_dir = out.parent / "model", out.parent / "run"
    print(f"\ntraining a fast model on the sample drive's truth into {model_dir}")
    model = train_from_drives([out], params=ClassifierParams(mode="fast"), progress=not args.quiet)
    save_model(model, model_dir, overwrite=True)
    print(_held_out_report(model.info))
    print(f"\nprocessing the sample drive into {run_dir}")
    drive = load_drive(out)
    process_drive(drive, model, run_dir, overwrite=True, progress=not args.quiet)
    print("\nthe model was trained on this drive, so these figures are in-sample:")
    print(format_report(evaluate_run(drive, load_run(run_dir))))
    return 0


def _add_reconstruction_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--params",
        type=Path,
        metavar="JSON",
        help="reconstruction parameters: a JSON object {stage: {name: value}} (or a "
        "reconstruction/models.json, whose parameters are used)",
    )
    parser.add_argument(
        "--set",
        action="append",
        metavar="STAGE.NAME=VALUE",
        help="one reconstruction parameter, e.g. pipes.slice_interval_m=0.02 (repeatable)",
    )


def _export(args: argparse.Namespace) -> int:
    from guardrail_core.io.las_export import export_run_las, format_summary

    summary = export_run_las(args.run_dir, args.las, drive_dir=args.drive, overwrite=args.overwrite)
    for line in summary.warnings:
        print(f"warning: {line}", file=sys.stderr)
    print(format_summary(summary))
    return 0


def _add_import_commands(sub: argparse._SubParsersAction) -> None:
    """``guardrail import las|kitti``: data from elsewhere into an ordinary drive folder."""
    imp = sub.add_parser(
        "import",
        help="import a LAS/LAZ mobile-mapping delivery or KITTI scans as a drive folder",
        description="Turn data recorded elsewhere into a drive folder that every other command "
        "reads.",
    )
    sources = imp.add_subparsers(dest="source", required=True, metavar="SOURCE")
    _add_import_las(sources)
    _add_import_kitti(sources)


def _add_import_las(sources: argparse._SubParsersAction) -> None:
    """``guardrail import las``: a LAS/LAZ delivery (points, trajectory, images, calibration)."""
    from guardrail_core.importers.las_delivery import DEFAULT_REFERENCE_HEIGHT_M

    las = sources.add_parser(
        "las",
        help="a LAS/LAZ delivery: points with GPS time, trajectory, images and calibration",
        description="Turn a mobile-mapping delivery into a drive folder: LAS/LAZ points (any "
        "point format with gps_time, map coordinates), a trajectory CSV (time, x, y, z, roll, "
        "pitch, yaw), optionally an image list CSV (file, camera, gps_time) with the cameras' "
        "calibration (OpenCV YAML or JSON), and the scanner's rates for the scan lattice. "
        "Formats: docs/import.md.",
    )
    las.add_argument("points", type=Path, nargs="+", metavar="POINTS", help="LAS/LAZ file(s)")
    las.add_argument("--trajectory", type=Path, required=True, metavar="CSV", help="trajectory CSV")
    las.add_argument("--out", type=Path, required=True, help="drive folder to write")
    las.add_argument(
        "--trajectory-degrees",
        action="store_true",
        help="the trajectory's roll, pitch, yaw are in degrees (default radians)",
    )
    las.add_argument(
        "--reference-height",
        type=float,
        default=DEFAULT_REFERENCE_HEIGHT_M,
        metavar="METRES",
        help="height of the trajectory's reference point above the road "
        f"(default {DEFAULT_REFERENCE_HEIGHT_M})",
    )
    las.add_argument("--images", type=Path, metavar="CSV", help="image list: file,camera,gps_time")
    las.add_argument(
        "--calibration",
        type=Path,
        nargs="+",
        action="extend",
        metavar="FILE",
        help="camera calibration: OpenCV YAML (cv2.FileStorage), YAML or JSON; one file per "
        "camera or one for several",
    )
    las.add_argument(
        "--scanner",
        type=Path,
        metavar="FILE",
        help="scanner parameters, JSON or YAML with the keys of drive.json's scanner block",
    )
    las.add_argument("--rotations-per-second", type=float, metavar="HZ", help="mirror rotations")
    las.add_argument("--measurements-per-second", type=float, metavar="HZ", help="pulse rate")
    las.add_argument(
        "--t0",
        type=float,
        metavar="SECONDS",
        help="GPS time of pulse 0, the lattice's epoch (default: the first point's whole second)",
    )
    las.add_argument(
        "--scanner-mount",
        metavar="NUMBERS",
        help="T_vehicle_scanner: x,y,z,roll,pitch,yaw (metres, degrees) or 16 numbers of the "
        "4x4 matrix, row by row; write --scanner-mount=-0.6,... when it starts with a minus "
        "(default: the simulator's mount)",
    )
    las.add_argument(
        "--crs",
        help="map CRS, e.g. EPSG:6677 (default: the one the LAS file declares, else 'unknown'); "
        "replaces the file's",
    )
    las.add_argument(
        "--las", action="store_true", help="write uncompressed points.las instead of points.laz"
    )
    las.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    las.add_argument("--quiet", action="store_true", help="no progress bars")
    las.set_defaults(func=_import_las)


def _import_las(args: argparse.Namespace) -> int:
    from guardrail_core.drive import load_drive
    from guardrail_core.drive_summary import describe_drive
    from guardrail_core.importers.las_delivery import import_las_delivery, read_scanner_file

    # Options override the scanner file's values, one by one.
    fields = read_scanner_file(args.scanner) if args.scanner else {}
    for key, value in (
        ("rotations_per_second", args.rotations_per_second),
        ("measurements_per_second", args.measurements_per_second),
        ("t0", args.t0),
        ("T_vehicle_scanner", args.scanner_mount),
    ):
        if value is not None:
            fields[key] = value
    result = import_las_delivery(
        args.points,
        args.trajectory,
        args.out,
        scanner=fields,
        images_csv=args.images,
        calibration=args.calibration,
        crs=args.crs,
        reference_height_m=args.reference_height,
        trajectory_degrees=args.trajectory_degrees,
        compress=not args.las,
        overwrite=args.overwrite,
        progress=not args.quiet,
    )
    for note in result.notes:
        print(f"note: {note}", file=sys.stderr)
    crs_from = "none declared" if result.crs_from == "none" else f"from the {result.crs_from}"
    print(
        f"imported {result.n_points:,} points and {result.n_images} images into {result.out} "
        f"(CRS {result.crs}, {crs_from}; scanner t0 {result.scanner.t0:.6f} s)"
    )
    print(describe_drive(load_drive(result.out)))
    return 0


def _import_kitti(args: argparse.Namespace) -> int:
    from guardrail_core.drive import load_drive
    from guardrail_core.drive_summary import describe_drive
    from guardrail_core.importers.kitti import import_kitti, parse_frames

    frames = parse_frames(args.frames) if args.frames else None
    result = import_kitti(
        args.sequence_dir,
        args.out,
        frames=frames,
        sensor_height_m=args.sensor_height,
        overwrite=args.overwrite,
        progress=not args.quiet,
    )
    print(
        f"imported {len(result.frames)} frames ({result.n_points:,} points, {result.rings} rings, "
        f"{result.n_images} images) into {result.out}"
    )
    print(describe_drive(load_drive(result.out)))
    return 0


def _add_import_kitti(sources: argparse._SubParsersAction) -> None:
    """``guardrail import kitti``: frames of a KITTI odometry sequence."""
    from guardrail_core.importers.kitti import KITTI_SENSOR_HEIGHT_M

    kitti = sources.add_parser(
        "kitti",
        help="frames of a KITTI odometry sequence, merged with their poses",
        description="Merge frames of a KITTI odometry sequence folder (velodyne/NNNNNN.bin, "
        "calib.txt, poses.txt, times.txt, optional image_2/) into a drive folder: points in "
        "the world of the sequence's frame 0, the scan lattice as ring x azimuth (rings "
        "recovered from the point order and elevation), the trajectory from the poses, "
        "image_2 as a calibrated camera.",
    )
    kitti.add_argument("sequence_dir", type=Path, metavar="SEQUENCE_DIR")
    kitti.add_argument(
        "--frames",
        metavar="LIST",
        help="frames to merge: 280,281 or 270-290 or a mix (default: every frame with a scan)",
    )
    kitti.add_argument("--out", type=Path, required=True, help="drive folder to write")
    kitti.add_argument(
        "--sensor-height",
        type=float,
        default=KITTI_SENSOR_HEIGHT_M,
        metavar="METRES",
        help=f"the scanner's height above the road (default {KITTI_SENSOR_HEIGHT_M}, KITTI's car)",
    )
    kitti.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    kitti.add_argument("--quiet", action="store_true", help="no progress bars")
    kitti.set_defaults(func=_import_kitti)


def _add_export_command(sub: argparse._SubParsersAction) -> None:
    """``guardrail export RUN_DIR --las OUT.laz``: the drive's points with the run's result."""
    export = sub.add_parser(
        "export",
        help="write a run's result onto the drive's points as LAS/LAZ for GIS tools",
        description="Write every point of the run's drive in map coordinates (LAS 1.4, the "
        "drive's CRS) with the run's result: class 64 guardrail, 65 guardrail pole, 11 road "
        "surface (where the drive left points unclassified), and the extra dimensions "
        "segment_id, guardrail_probability and run_id. See docs/run-folder.md.",
    )
    export.add_argument(
        "run_dir", type=Path, metavar="RUN_DIR", help="run folder (guardrail process)"
    )
    export.add_argument(
        "--las",
        type=Path,
        required=True,
        metavar="OUT",
        help="file to write: OUT.laz (compressed) or OUT.las",
    )
    export.add_argument(
        "--drive", type=Path, help="the drive of the run (default: the path in run.json)"
    )
    export.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    export.set_defaults(func=_export)


def _add_plugin_commands(sub: argparse._SubParsersAction) -> None:
    """Commands other packages register under the ``guardrail.commands`` entry points (the
    review app's ``serve``): the library never imports the app, the app plugs into the CLI."""
    from importlib.metadata import entry_points

    for entry in sorted(entry_points(group="guardrail.commands"), key=lambda e: e.name):
        entry.load()(sub)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="guardrail",
        description="Find, reconstruct and review guardrails in mobile-mapping point clouds and images.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    sim = sub.add_parser(
        "simulate",
        help="simulate a mapping drive with exact ground truth",
        description="Simulate a mobile-mapping drive (profile laser scanner, cameras, trajectory) "
        "through a random street from --seed, or through the scene of --scene, into the drive folder OUT.",
    )
    sim.add_argument(
        "out", type=Path, help="drive folder to write (must not exist, or use --overwrite)"
    )
    sim.add_argument(
        "--seed", type=int, default=0, help="random seed: same seed, same drive (default 0)"
    )
    sim.add_argument(
        "--length", type=float, default=None, help="metres to drive in a random scene (default 100)"
    )
    sim.add_argument(
        "--scene", help="scene spec YAML (a path, or the name of one in data_samples/scenes)"
    )
    sim.add_argument(
        "--designs",
        metavar="NAME,...",
        help="guardrail designs a random scene may use (default: every shipped design)",
    )
    sim.add_argument(
        "--image-every",
        type=float,
        default=5.0,
        metavar="METRES",
        help="camera trigger spacing (default 5)",
    )
    sim.add_argument(
        "--image-size",
        type=_size,
        default=(1024, 768),
        metavar="WxH",
        help="image size (default 1024x768)",
    )
    sim.add_argument(
        "--scanner",
        choices=("profile", "multibeam"),
        help="profile: the RIEGL VQ-250 profile scanner of the paper's vehicle (the default); "
        "multibeam: a Velodyne HDL-64E as on the KITTI car, one frame every --frame-every metres",
    )
    sim.add_argument(
        "--frame-every",
        type=float,
        metavar="METRES",
        help="with --scanner multibeam: metres between frames (default 60)",
    )
    sim.add_argument(
        "--las", action="store_true", help="write uncompressed points.las instead of points.laz"
    )
    sim.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    sim.add_argument("--quiet", action="store_true", help="no progress bars")
    sim.set_defaults(func=_simulate)

    info = sub.add_parser(
        "info",
        help="describe a drive folder",
        description="Validate a drive folder and describe it.",
    )
    info.add_argument("drive", type=Path)
    info.set_defaults(func=_info)

    train = sub.add_parser(
        "train",
        help="train the guardrail classifier on labelled drives or on operators' labels",
        description="Extract the segments of each DRIVE, label their crops from truth/, and "
        "fine-tune the ImageNet-pretrained EfficientNet-Lite0 (two classes: guardrail, other). "
        "With --run RUN_DIR instead, train on that run's segments labelled by operators in the "
        "review app (`guardrail serve`).",
    )
    train.add_argument("drives", type=Path, nargs="*", metavar="DRIVE")
    train.add_argument(
        "--run",
        type=Path,
        metavar="RUN_DIR",
        help="train from a run folder and the operators' labels instead of drives' truth",
    )
    train.add_argument(
        "--labels",
        type=Path,
        help="the label store (default: DRIVE/review/labels.sqlite of the run's drive)",
    )
    train.add_argument(
        "--reviewed-only",
        action="store_true",
        help="with --run: only segments an operator labelled (default: the others keep the "
        "run's corrected labels)",
    )
    train.add_argument("--out", type=Path, required=True, help="model folder to write")
    train.add_argument(
        "--mode",
        choices=("fast", "full"),
        default="fast",
        help="fast: frozen backbone and a small head, seconds; full: the whole network, minutes "
        "(default fast)",
    )
    train.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    train.add_argument("--overwrite", action="store_true", help="replace the model folder")
    train.add_argument("--quiet", action="store_true", help="no progress bars")
    train.set_defaults(func=_train)

    process = sub.add_parser(
        "process",
        help="extract guardrail segments from a drive",
        description="Remove the road, cut the rest into 0.5 m segments, crop each segment's "
        "image, classify it and correct the labels; write everything into the run folder.",
    )
    process.add_argument("drive", type=Path)
    process.add_argument(
        "--model",
        type=Path,
        help="model folder (guardrail train; default: the model shipped with guardrail, trained "
        "on simulated drives of a profile and a multi-beam scanner)",
    )
    process.add_argument("--out", type=Path, required=True, help="run folder to write")
    process.add_argument("--overwrite", action="store_true", help="replace the run folder")
    process.add_argument("--quiet", action="store_true", help="no progress bars")
    process.set_defaults(func=_process)

    evaluate = sub.add_parser(
        "evaluate",
        help="compare a run with the drive's truth",
        description="Print the paper's Table 1 (segments per class) and Table 2 (recall, "
        "precision, F-measure per class) before and after label correction.",
    )
    evaluate.add_argument("drive", type=Path)
    evaluate.add_argument("--run", type=Path, required=True, help="run folder (guardrail process)")
    evaluate.add_argument("--json", action="store_true", help="print one JSON object instead")
    evaluate.add_argument(
        "--units-sweep",
        metavar="K,...",
        help="also reconstruct every run from only its first K units, for each K, and report "
        "the pipes found per design (the experiment of §5.2), e.g. 1,2,4,8,16,32",
    )
    evaluate.add_argument(
        "--plot",
        type=Path,
        help="PNG of the units sweep (default RUN/units_sweep.png)",
    )
    _add_reconstruction_options(evaluate)
    evaluate.add_argument("--quiet", action="store_true", help="no progress bars")
    evaluate.set_defaults(func=_evaluate)

    reconstruct = sub.add_parser(
        "reconstruct",
        help="reconstruct the guardrails of a run folder again, with other parameters",
        description="Reconstruct the guardrail runs of RUN_DIR (poles, unit shapes superimposed "
        "with ICP, pipes or beam sections, meshes and inventory) and replace "
        "RUN_DIR/reconstruction. `guardrail process` already did this with the defaults.",
    )
    reconstruct.add_argument("run_dir", type=Path, metavar="RUN_DIR")
    reconstruct.add_argument(
        "--drive", type=Path, help="the drive of the run (default: the path in run.json)"
    )
    _add_reconstruction_options(reconstruct)
    reconstruct.add_argument("--quiet", action="store_true", help="no progress bars")
    reconstruct.set_defaults(func=_reconstruct)

    _add_import_commands(sub)
    _add_export_command(sub)
    _add_plugin_commands(sub)

    demo = sub.add_parser(
        "demo",
        help="simulate the sample drive, train on it and process it",
        description="The end-to-end demo: simulate the sample drive "
        "(data_samples/scenes/sample.yaml) into --out, train a fast model on it (model/ beside "
        "it), process it (run/ beside it) and evaluate the run.",
    )
    demo.add_argument("--out", type=Path, default=Path("demo_output/sample_drive"))
    demo.add_argument(
        "--fresh", action="store_true", help="simulate again even if the drive exists"
    )
    demo.add_argument("--quiet", action="store_true")
    demo.set_defaults(func=_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except GuardrailError as exc:
        print(f"guardrail: error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("guardrail: interrupted; nothing half-written was kept", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
