"""The README's picture of a real scan: KITTI sequence 01, frame 280 (a German motorway), imported,
processed with the default model and reconstructed.

    .venv/bin/python docs/make_kitti_figure.py [--sequence ../shared/realdata/kitti-odometry/sequences/01]

Writes docs/images/kitti_motorway.png: a top view of the +-40 m window with the points found to
be guardrail in red, and a view from the road of the right shoulder's reconstructed W-beam and
posts over its points, from the road and in section.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import trimesh
from matplotlib.collections import PolyCollection

from guardrail_core.extract.classify.model_folder import DEFAULT_MODEL_DIR, load_model
from guardrail_core.formats.drive import load_drive
from guardrail_core.formats.run_folder import load_run
from guardrail_core.importers.kitti import import_kitti
from guardrail_core.process import process_drive

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SEQUENCE = ROOT.parent / "shared" / "realdata" / "kitti-odometry" / "sequences" / "01"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sequence", type=Path, default=DEFAULT_SEQUENCE)
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images" / "kitti_motorway.png")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        import_kitti(args.sequence, Path(tmp) / "drive", frames=[280])
        drive = load_drive(Path(tmp) / "drive")
        process_drive(drive, load_model(DEFAULT_MODEL_DIR), Path(tmp) / "run")
        run = load_run(Path(tmp) / "run")
        meshes = {
            p.stem: trimesh.load(p, force="mesh")
            for p in run.folder.reconstruction.mesh_files("ply").values()
        }
        # Read now: the run folder's tables load when first asked for, and it goes with `tmp`.
        xyz = drive.points.xyz
        segment = run.point_segment
        found = np.zeros(len(xyz), bool)
        found[segment >= 0] = run.segments["label"][segment[segment >= 0]]
    window = (np.abs(xyz[:, 0]) < 40) & (np.abs(xyz[:, 1]) < 22)

    fig = plt.figure(figsize=(14, 8.5))
    top = fig.add_axes((0.04, 0.52, 0.92, 0.44))
    rest = window & ~found & (segment != -1)
    top.scatter(xyz[rest, 0], xyz[rest, 1], s=0.3, c="0.55", linewidths=0)
    road = window & (segment == -1)
    top.scatter(xyz[road, 0], xyz[road, 1], s=0.3, c="0.85", linewidths=0)
    top.scatter(xyz[found & window, 0], xyz[found & window, 1], s=1.2, c="#d62728", linewidths=0)
    top.set_aspect("equal")
    top.set_xlim(-40, 40)
    top.set_ylim(-22, 22)
    top.set_xlabel("x (m, forward)")
    top.set_ylabel("y (m, left)")
    top.set_title(
        "KITTI sequence 01, frame 280: points found to be guardrail (red); road light grey",
        fontsize=11,
    )

    shoulder = [
        m for m in meshes.values() if -7 < m.vertices[:, 1].mean() < -2.5
    ]  # the right shoulder's run
    near = (xyz[:, 1] > -7) & (xyz[:, 1] < -2.5) & (np.abs(xyz[:, 0]) < 20)
    near &= xyz[:, 2] > -1.9
    side = fig.add_axes((0.05, 0.06, 0.6, 0.36))
    for mesh in shoulder:
        triangles = mesh.vertices[mesh.faces]
        keep = np.abs(triangles[:, :, 0]).min(axis=1) < 20  # the axes clip the rest
        side.add_collection(
            PolyCollection(
                triangles[keep][:, :, [0, 2]], facecolor="#1f77b4", edgecolor="none", alpha=0.35
            )
        )
    side.scatter(xyz[near & ~found, 0], xyz[near & ~found, 2], s=1, c="0.55", linewidths=0)
    side.scatter(xyz[near & found, 0], xyz[near & found, 2], s=1.5, c="#d62728", linewidths=0)
    side.set_xlim(-20, 20)
    side.set_ylim(-1.9, -0.7)
    side.set_xlabel("x (m)")
    side.set_ylabel("z (m; road at -1.72)")
    side.set_title(
        "right shoulder from the road: the reconstructed beam and posts (blue)", fontsize=11
    )

    section = fig.add_axes((0.72, 0.06, 0.25, 0.36))
    band = near & (np.abs(xyz[:, 0]) < 10)
    section.scatter(xyz[band & ~found, 1], xyz[band & ~found, 2], s=1, c="0.55", linewidths=0)
    section.scatter(xyz[band & found, 1], xyz[band & found, 2], s=1.5, c="#d62728", linewidths=0)
    for mesh in shoulder:
        for x in (-6.0, -2.0, 2.0, 6.0):
            cut = mesh.section(plane_origin=(x, 0, 0), plane_normal=(1, 0, 0))
            if cut is None:
                continue
            for line in cut.discrete:
                section.plot(line[:, 1], line[:, 2], c="#1f77b4", lw=1)
    section.set_aspect("equal")
    section.set_xlim(-5.6, -3.8)
    section.set_ylim(-1.9, -0.7)
    section.set_xlabel("y (m)")
    section.set_title("sections of the model (blue) over\nthe points of |x| < 10 m", fontsize=11)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=90)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
