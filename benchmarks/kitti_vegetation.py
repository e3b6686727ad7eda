"""Guardrail points on roadside vegetation in the real KITTI frames, with a model (the default).

Usage::

    .venv/bin/python benchmarks/kitti_vegetation.py [--model DIR] [--set STAGE.NAME=VALUE ...] [--json]

The frames are unlabelled, so the vegetation is placed by where it stands in the sensor frame
(seen on plots of the scan; ``../shared/realdata/README.md``). In frame 280 of sequence 01 (the
German motorway; road at z = -1.72 m):

- the **median hedge**: the foliage between the median barrier's two rails (the near one at
  y = 6.3-6.5 m, the far one, facing the opposite carriageway 0.35 m higher, at 7.6-8.3 m):
  y in [6.65, 7.55] m and more than 0.25 m above the road;
- the **far roadside**: bushes and trees behind the far-side guardrail, y > 20.5 m and more
  than 0.3 m above the road;

both within 40 m of the car along x. Reported: the points of each zone, how many the model's
run labels guardrail, and the guardrail points off every barrier band (the share the KITTI test
bounds at 1 %). The Karlsruhe street (raw 2011_09_26, frame 0) has no guardrail: every point
labelled guardrail there is a false alarm, and is counted too.
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
from guardrail_core.extract.classify.model_folder import DEFAULT_MODEL_DIR, load_model  # noqa: E402
from guardrail_core.formats.drive import load_drive  # noqa: E402
from guardrail_core.formats.run_folder import load_run  # noqa: E402
from guardrail_core.importers.kitti import import_kitti  # noqa: E402
from guardrail_core.process import process_drive  # noqa: E402

SEQUENCES = ROOT.parent / "shared" / "realdata" / "kitti-odometry" / "sequences"
ROAD_Z_M = -1.72
WINDOW_M = 40.0
#: Barrier bands of frame 280 (y, metres): shoulder W-beam, median barrier, far-side guardrail.
BARRIERS = ((-5.5, -3.5), (5.5, 9.0), (18.0, 21.0))


def _guardrail_points(
    sequence: Path, frame: int, model, work: Path, settings: list[str]
) -> tuple[np.ndarray, ...]:
    """The frame's points (N, 3) in the sensor frame and whether each was labelled guardrail."""
    import_kitti(sequence, work / "drive", frames=[frame])
    drive = load_drive(work / "drive")
    extraction, reconstruction = process_params(settings)
    process_drive(drive, model, work / "run", params=extraction, reconstruction=reconstruction)
    run = load_run(work / "run")
    segment = run.point_segment
    found = np.zeros(len(segment), bool)
    inside = segment >= 0
    found[inside] = run.segments["label"][segment[inside]]
    return drive.points.xyz, found


def measure(model_dir: Path, settings: list[str]) -> dict:
    model = load_model(model_dir)
    with tempfile.TemporaryDirectory() as tmp:
        xyz, found = _guardrail_points(
            SEQUENCES / "01", 280, model, Path(tmp) / "motorway", settings
        )
        x, y, z = xyz.T
        height = z - ROAD_Z_M
        window = np.abs(x) < WINDOW_M
        zones = {
            "median hedge": window & (y > 6.65) & (y < 7.55) & (height > 0.25),
            "far roadside": window & (y > 20.5) & (height > 0.3),
        }
        barriers = np.zeros(len(y), bool)
        for lo, hi in BARRIERS:
            barriers |= (y > lo) & (y < hi)
        street_xyz, street_found = _guardrail_points(
            SEQUENCES / "raw_2011_09_26_f0000", 0, model, Path(tmp) / "street", settings
        )
    return {
        "model": str(model_dir),
        "settings": settings,
        "motorway_frame_280": {
            "guardrail_points": int(found.sum()),
            "off_the_barriers": int((found & ~barriers).sum()),
            "vegetation": {
                name: {"points": int(mask.sum()), "labelled_guardrail": int((mask & found).sum())}
                for name, mask in zones.items()
            },
        },
        "karlsruhe_street_frame_0": {
            "points": len(street_xyz),
            "labelled_guardrail": int(street_found.sum()),
        },
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, default=DEFAULT_MODEL_DIR)
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="STAGE.NAME=VALUE",
        help="a parameter as `guardrail process --set` takes it (repeatable)",
    )
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = parser.parse_args(argv)
    if not (SEQUENCES / "01" / "calib.txt").is_file():
        parser.error(f"the real KITTI data is not at {SEQUENCES}")
    result = measure(args.model, args.set)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    motorway = result["motorway_frame_280"]
    print(f"model: {result['model']}")
    print(
        f"motorway, frame 280: {motorway['guardrail_points']:,} guardrail points, "
        f"{motorway['off_the_barriers']:,} off the barriers"
    )
    for name, zone in motorway["vegetation"].items():
        print(
            f"  {name}: {zone['labelled_guardrail']:,} of {zone['points']:,} points "
            "labelled guardrail"
        )
    street = result["karlsruhe_street_frame_0"]
    print(
        f"Karlsruhe street, frame 0 (no guardrail): {street['labelled_guardrail']:,} of "
        f"{street['points']:,} points labelled guardrail"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
