"""Guardrails found on the labelled real frames, with a model (default: the shipped one).

Usage::

    .venv/bin/python benchmarks/real_frames.py [--model DIR ...] [--set STAGE.NAME=VALUE ...]
        [--json]

For every real frame of ``../shared/realdata`` labelled in ``tests/data/real_frames/`` (how:
``benchmarks/label_real_frames.py``), the frame is imported (``guardrail import kitti``, or
``--importer lidar``: ``guardrail import lidar`` on the frame alone, as any spinning lidar's)
and processed with each model, and reported:

- per labelled barrier, the metres of rail the scan sees and the metres found (1 m bins along
  the rail; a bin is found when at least half of its rail points are called guardrail:
  :func:`guardrail_core.evaluate.labelled_frames.rail_metres`);
- the share of the judged points called guardrail that are not guardrail;
- on a frame without guardrail, the points called guardrail.

A barrier farther from the sensor than ``road.max_lateral_m`` (15 m: a guardrail beyond the
opposite carriageway) is reported but not counted: extraction does not look there.

Goal (issue 76): on every labelled frame with guardrails, >= 90 % of the metres within reach
found and <= 10 % of the points called guardrail off guardrails.
Several ``--model`` are measured one after the other (the same recipe's models of several
seeds: a model ships when every one holds, not one lucky draw).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from guardrail_core.cli.common import process_params  # noqa: E402
from guardrail_core.evaluate.labelled_frames import (  # noqa: E402
    found_within,
    load_frame_labels,
    off_guardrail_share,
    rail_metres,
)
from guardrail_core.extract.classify.model_folder import DEFAULT_MODEL_DIR, load_model  # noqa: E402
from guardrail_core.formats.drive import load_drive  # noqa: E402
from guardrail_core.formats.run_folder import load_run  # noqa: E402
from guardrail_core.importers.kitti import import_kitti  # noqa: E402
from guardrail_core.importers.lidar import import_lidar  # noqa: E402
from guardrail_core.process import process_drive  # noqa: E402

SEQUENCES = ROOT.parent / "shared" / "realdata" / "kitti-odometry" / "sequences"
LABELS = ROOT / "tests" / "data" / "real_frames"
GOAL_FOUND = 0.90
GOAL_OFF = 0.10

#: name -> (sequence folder, frame, labels file)
FRAMES = {
    "KITTI 01/280 (motorway)": ("01", 280, "kitti01_000280.npz"),
    "KITTI raw 2011_09_26/0 (Karlsruhe street)": (
        "raw_2011_09_26_f0000",
        0,
        "kitti_raw_2011_09_26_000000.npz",
    ),
}


def found_points(drive_dir: Path, run_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """The drive's points (N, 3) and whether the run called each guardrail (N,) bool."""
    drive = load_drive(drive_dir, with_truth=False)
    run = load_run(run_dir)
    segment = run.point_segment
    found = np.zeros(len(segment), bool)
    inside = segment >= 0
    found[inside] = run.segments["label"][segment[inside]]
    return drive.points.xyz, found


def in_file_order(xyz: np.ndarray, scan: Path) -> np.ndarray:
    """(N,) the drive point of every point of the ``.bin`` ``scan`` (a drive imported from it
    alone, in the sensor's frame, its points in another order)."""
    from scipy.spatial import cKDTree

    original = np.fromfile(scan, dtype="<f4").reshape(-1, 4)[:, :3]
    distance, index = cKDTree(xyz).query(original)
    if len(xyz) != len(original) or distance.max() > 1e-3:
        raise SystemExit(f"{scan}: the imported points are not the file's")
    return index


def measure_frame(name: str, model, settings: list[str], work: Path, importer: str) -> dict:
    sequence, frame, labels_file = FRAMES[name]
    source = SEQUENCES / sequence
    scan = source / "velodyne" / f"{frame:06d}.bin"
    labels = load_frame_labels(LABELS / labels_file, scan)
    if importer == "kitti":
        import_kitti(source, work / "drive", frames=[frame])
    else:  # the frame alone, as any spinning lidar's: no poses, no calibration
        import_lidar([scan], work / "drive")
    extraction, reconstruction = process_params(settings)
    process_drive(
        load_drive(work / "drive"),
        model,
        work / "run",
        params=extraction,
        reconstruction=reconstruction,
    )
    xyz, found = found_points(work / "drive", work / "run")
    if importer == "lidar":
        order = in_file_order(xyz, scan)
        xyz, found = xyz[order], found[order]
    if len(xyz) != len(labels):
        raise SystemExit(f"{name}: {len(xyz)} points imported for {len(labels)} labelled")
    barriers = rail_metres(xyz[:, :2], labels, found)
    return {
        "barriers": [
            {
                "name": b.name,
                "seen_m": b.seen_m,
                "found_m": b.found_m,
                "lateral_m": round(b.lateral_m, 2),
                "within_reach": b.within,
            }
            for b in barriers
        ],
        "found_share": found_within(barriers),
        "points": len(found),
        "guardrail_points": int(found.sum()),
        "off_guardrail_share": off_guardrail_share(labels, found) if barriers else None,
    }


def measure(model_dir: Path, settings: list[str], importer: str = "kitti") -> dict:
    model = load_model(model_dir)
    frames = {}
    with tempfile.TemporaryDirectory() as tmp:
        for i, name in enumerate(FRAMES):
            frames[name] = measure_frame(name, model, settings, Path(tmp) / str(i), importer)
    holds = all(
        f["found_share"] is None
        or (f["found_share"] >= GOAL_FOUND and f["off_guardrail_share"] <= GOAL_OFF)
        for f in frames.values()
    )
    return {
        "model": str(model_dir),
        "importer": importer,
        "settings": settings,
        "frames": frames,
        "holds": holds,
    }


def print_table(result: dict) -> None:
    print(f"model: {result['model']}, imported by `guardrail import {result['importer']}`")
    for name, frame in result["frames"].items():
        share, called = frame["found_share"], frame["guardrail_points"]
        if share is None:
            print(
                f"  {name}: no guardrail; {called:,} of {frame['points']:,} points called guardrail"
            )
            continue
        print(
            f"  {name}: {share:.1%} of the metres within reach found; {called:,} points "
            f"called guardrail, {frame['off_guardrail_share']:.1%} of them off guardrails"
        )
        for barrier in frame["barriers"]:
            reach = "" if barrier["within_reach"] else " (beyond reach, not counted)"
            print(
                f"    {barrier['name']}: {barrier['found_m']:.0f} of {barrier['seen_m']:.0f} m"
                f" at {barrier['lateral_m']:.1f} m{reach}"
            )
    verdict = "holds" if result["holds"] else "does not hold"
    print(f"  goal (>= {GOAL_FOUND:.0%} found, <= {GOAL_OFF:.0%} off, every frame): {verdict}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, action="append", help="a model folder (repeatable)")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="STAGE.NAME=VALUE",
        help="a parameter as `guardrail process --set` takes it (repeatable)",
    )
    parser.add_argument(
        "--importer",
        choices=("kitti", "lidar", "both"),
        default="kitti",
        help="import the frames with `guardrail import kitti` (the sequence's poses and "
        "calibration), `guardrail import lidar` (the frame alone, as any spinning lidar's), or both",
    )
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = parser.parse_args(argv)
    if not (SEQUENCES / "01" / "calib.txt").is_file():
        parser.error(f"the real KITTI data is not at {SEQUENCES}")
    importers = ["kitti", "lidar"] if args.importer == "both" else [args.importer]
    results = [
        measure(model, args.set, importer)
        for model in args.model or [DEFAULT_MODEL_DIR]
        for importer in importers
    ]
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    for result in results:
        print_table(result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
