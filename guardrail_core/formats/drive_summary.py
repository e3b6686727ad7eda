"""A short human-readable account of a drive folder: where it is and what is in it."""

from __future__ import annotations

from collections import Counter

import numpy as np

from guardrail_core.classes import GUARDRAIL_CLASSES, TruthClass
from guardrail_core.formats.drive import Drive
from guardrail_core.formats.drive_tiles import TileIndex
from guardrail_core.sensors.scanner import MULTIBEAM


def _scanner_line(drive: Drive) -> str:
    scanner = drive.scanner
    if scanner.kind == MULTIBEAM:
        return (
            f"a multi-beam scanner: {scanner.rings} rings x {scanner.points_per_rotation} azimuth "
            f"bins, {scanner.rotation_rate_hz:g} turns/s"
        )
    return (
        f"{scanner.rotation_rate_hz:g} rotations/s x {scanner.points_per_rotation} phases "
        f"({scanner.measurement_rate_hz:,.0f} pulses/s)"
    )


def describe_drive(drive: Drive, tiles: TileIndex | None = None) -> str:
    """Lines describing the drive's extent, sensors, files, point ``tiles`` (when given) and (for
    synthetic drives) truth."""
    points, traj = drive.points, drive.trajectory
    length = float(np.sum(np.linalg.norm(np.diff(traj.position, axis=0), axis=1)))
    duration = float(traj.time[-1] - traj.time[0])
    size_mb = sum(p.stat().st_size for p in drive.root.rglob("*") if p.is_file()) / 1e6
    per_camera = Counter(record.camera for record in drive.images)
    lines = [
        f"drive      {drive.root.resolve()}  ({size_mb:.1f} MB)",
        f"CRS        {drive.crs}, local origin {', '.join(f'{v:.3f}' for v in drive.origin)}",
        f"trajectory {length:.1f} m in {duration:.1f} s ({length / max(duration, 1e-9):.1f} m/s mean), "
        f"{len(traj)} poses",
        f"points     {len(points):,} from {_scanner_line(drive)}",
        *(
            [f"tiles      {len(tiles)}, {length / len(tiles):.1f} m of driving each on average"]
            if tiles is not None and len(tiles)
            else []
        ),
        f"images     {len(drive.images)}: "
        + ", ".join(
            f"{name} {n} ({drive.cameras[name].width}x{drive.cameras[name].height})"
            for name, n in per_camera.items()
        ),
    ]
    if drive.truth is not None:
        truth = drive.truth
        runs = [o for o in truth.objects if o.get("kind") == "guardrail"]
        others = Counter(o.get("kind") for o in truth.objects if o.get("kind") != "guardrail")
        on_rails = int(np.isin(truth.point_class, list(GUARDRAIL_CLASSES)).sum())
        lines.append(
            f"truth      {len(runs)} guardrail runs ({', '.join(sorted({r['design'] for r in runs}))}), "
            f"{on_rails:,} guardrail points ({100 * on_rails / max(len(points), 1):.1f}%)"
        )
        lines.append(
            "           others: " + ", ".join(f"{k} {n}" for k, n in sorted(others.items()))
        )
        counts = np.bincount(truth.point_class, minlength=len(TruthClass))
        lines.append(
            "           points by class: "
            + ", ".join(f"{TruthClass(i).name.lower()} {n:,}" for i, n in enumerate(counts) if n)
        )
    return "\n".join(lines)
