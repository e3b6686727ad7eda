"""Make the README's picture of a green roadside: the scene ``green_roadside`` simulated, one
left-camera image beside the laser points it sees, coloured by truth class.

Usage::

    .venv/bin/python docs/make_roadside_figure.py [--drive /tmp/green_roadside] [--out docs/images]

Simulates the scene (seed 1, a camera shot every 10 m) into ``--drive`` when that folder does not
exist, then writes ``green_roadside.png``: the image with the most vegetation and guardrail
points in view, and the points within 25 m projected into it (guardrail red and orange,
vegetation light green, other classes by the palette of ``docs/make_figures.py``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "docs"))

from make_figures import (  # noqa: E402
    PALETTE,
    camera_points,
    class_name,
    legend_strip,
    palette_lut,
    put_label,
    write_png,
)

from guardrail_core.classes import GUARDRAIL_CLASSES, TruthClass  # noqa: E402
from guardrail_core.formats.drive import Drive, load_drive  # noqa: E402
from guardrail_core.synth.scene import load_scene_spec  # noqa: E402
from guardrail_core.synth.simulate import SimulationOptions, simulate_drive  # noqa: E402

SHOWN = (
    TruthClass.GUARDRAIL,
    TruthClass.GUARDRAIL_POLE,
    TruthClass.VEGETATION,
    TruthClass.TERRAIN,
    TruthClass.TREE,
    TruthClass.SIDEWALK,
    TruthClass.ROAD,
)


def ensure_drive(path: Path) -> Drive:
    if not (path / "drive.json").is_file():
        simulate_drive(
            load_scene_spec("green_roadside"),
            path,
            seed=1,
            options=SimulationOptions(image_every_m=10.0),
            progress=True,
        )
    return load_drive(path)


def make_figure(drive: Drive, out: Path) -> None:
    assert drive.truth is not None
    classes = drive.truth.point_class
    wanted = np.isin(classes, [TruthClass.VEGETATION, *GUARDRAIL_CLASSES])
    records = [r for r in drive.images if r.camera == "left"]
    record = max(records, key=lambda r: int(wanted[camera_points(drive, r)[0]].sum()))
    image = drive.read_image(record)
    idx, uv, depth = camera_points(drive, record)
    cls = classes[idx]
    colours = palette_lut()[cls]
    px = np.round(uv).astype(np.int32)
    points = (0.35 * image).astype(np.uint8)
    for i in np.argsort(-depth):  # far first, so near points win
        cv2.circle(points, (int(px[i, 0]), int(px[i, 1])), 1, tuple(int(c) for c in colours[i]), -1)
    gap = np.full((image.shape[0], 12, 3), 255, np.uint8)
    both = np.concatenate([image, gap, points], axis=1)
    scale = 1400 / both.shape[1]
    both = cv2.resize(both, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    x_right = int(round((image.shape[1] + gap.shape[1]) * scale))
    put_label(both, f"scene green_roadside, left camera ({Path(record.file).name})", (8, 8), 0.55)
    put_label(both, "its laser points within 25 m, by truth class", (x_right + 8, 8), 0.55)
    strip = legend_strip(both.shape[1], [(class_name(c), PALETTE[c]) for c in SHOWN])
    write_png(out / "green_roadside.png", np.concatenate([both, strip], axis=0))
    print(f"green_roadside.png: {record.file}, {len(idx):,} points in view")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--drive", type=Path, default=Path("/tmp/green_roadside"))
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images")
    args = parser.parse_args(argv)
    make_figure(ensure_drive(args.drive), args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
