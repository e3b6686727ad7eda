"""Make the README figures of the extraction from the demo's run.

Usage::

    .venv/bin/python docs/make_extraction_figures.py [--drive demo_output/sample_drive]
        [--run demo_output/run] [--out docs/images]

Needs the run that ``make demo`` writes. Writes into ``--out``:

``extraction_segments.png``
    the sample street from above and behind: road surface removed (dark), far points faint, and
    every sliced segment coloured by its corrected label against the truth (guardrail found in
    red, other in blue, false detections in magenta, missed guardrail in yellow), with slice
    boundaries visible as alternating shades;
``extraction_crops.png``
    crops of guardrail and other segments as the classifier saw them, with its probability.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from make_figures import (  # noqa: E402
    draw_legend,
    eye_dome,
    overview_pose,
    put_label,
    splat,
    write_png,
)

from guardrail_core.extract.crops import CROP_OK  # noqa: E402
from guardrail_core.extract.segment_truth import segment_truth  # noqa: E402
from guardrail_core.formats.drive import Drive, load_drive  # noqa: E402
from guardrail_core.formats.run_folder import Run, load_run  # noqa: E402
from guardrail_core.review.run_crops import read_crops  # noqa: E402

FOUND = (235, 30, 30)
OTHER = (70, 130, 220)
FALSE = (230, 60, 230)
MISSED = (250, 220, 40)


def make_segments(drive: Drive, run: Run, out: Path, size: tuple[int, int] = (1400, 800)) -> None:
    assert drive.truth is not None
    truth = segment_truth(drive.truth.point_class, run.point_segment, len(run))
    label = run.segments["label"]
    colour = np.empty((len(run), 3), np.float64)
    colour[truth & label] = FOUND
    colour[~truth & ~label] = OTHER
    colour[~truth & label] = FALSE
    colour[truth & ~label] = MISSED
    # Alternate shades by slice so the 0.5 m cuts show.
    shade = np.where(run.segments["slice_index"] % 2 == 0, 1.0, 0.72)
    colour *= shade[:, None]

    seg = run.point_segment
    rgb = np.zeros((len(seg), 3), np.float64)
    rgb[seg == -1] = (45, 45, 52)
    rgb[seg == -2] = (95, 95, 105)
    inside = seg >= 0
    rgb[inside] = colour[seg[inside]]

    eye, pose = overview_pose(drive)
    xyz = drive.points.xyz
    near = np.linalg.norm(xyz[:, :2] - eye[:2], axis=1) < 90.0
    image, depth = splat(
        xyz[near], rgb[near].clip(0, 255).astype(np.uint8), pose, size, 0.62 * size[0], radius=1
    )
    image = eye_dome(image, depth)
    counts = (
        f"{int((truth & label).sum())} found, {int((~truth & label).sum())} false, "
        f"{int((truth & ~label).sum())} missed of {int(truth.sum())} guardrail segments"
    )
    put_label(image, f"sliced segments after label correction: {counts}", (10, 10))
    draw_legend(
        image,
        [
            ("guardrail, found", FOUND),
            ("other", OTHER),
            ("false guardrail", FALSE),
            ("missed guardrail", MISSED),
            ("road surface (removed)", (45, 45, 52)),
            ("far from the road (removed)", (95, 95, 105)),
        ],
        (10, size[1] - 20 * 6 - 20),
    )
    write_png(out / "extraction_segments.png", image)


def make_crops(drive: Drive, run: Run, out: Path, per_row: int = 10, rows: int = 2) -> None:
    assert drive.truth is not None
    truth = segment_truth(drive.truth.point_class, run.point_segment, len(run))
    ok = run.segments["crop_status"] == CROP_OK
    big = run.segments["n_points"] >= 30
    rng = np.random.default_rng(3)
    bands = []
    for title, pick in (("true guardrail", truth & ok & big), ("true other", ~truth & ok & big)):
        chosen = rng.choice(np.flatnonzero(pick), size=per_row * rows, replace=False)
        tiles = []
        for s in chosen:
            tile = read_crops(run, np.array([s]), 128, drive_root=drive.root)[0]  # as classified
            tile = cv2.resize(tile, (160, 160), interpolation=cv2.INTER_LINEAR)
            p = float(run.segments["probability"][s])
            colour = FOUND if run.segments["raw_label"][s] else OTHER
            cv2.rectangle(tile, (0, 0), (159, 159), colour, 4)
            put_label(tile, f"p={p:.2f}", (6, 132), 0.45)
            tiles.append(tile)
        grid = np.concatenate(
            [np.concatenate(tiles[r * per_row : (r + 1) * per_row], axis=1) for r in range(rows)]
        )
        header = np.full((30, grid.shape[1], 3), 30, np.uint8)
        put_label(header, f"{title} segments: crop and probability of guardrail", (6, 4), 0.55)
        bands += [header, grid]
    write_png(out / "extraction_crops.png", np.concatenate(bands))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Make the README figures of the extraction.")
    parser.add_argument("--drive", type=Path, default=Path("demo_output/sample_drive"))
    parser.add_argument("--run", type=Path, default=Path("demo_output/run"))
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "images")
    args = parser.parse_args(argv)
    drive, run = load_drive(args.drive), load_run(args.run)
    args.out.mkdir(parents=True, exist_ok=True)
    make_segments(drive, run, args.out)
    make_crops(drive, run, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
