"""A short human-readable account of a drive folder: where it is and what is in it.

The points are counted tile by tile (:func:`count_points`), so describing a survey of any
length holds one point tile at a time.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from guardrail_core.classes import GUARDRAIL_CLASSES, TruthClass
from guardrail_core.formats.drive import DriveSource
from guardrail_core.sensors.scanner import MULTIBEAM


@dataclass(frozen=True)
class PointCounts:
    """What a drive's point tiles hold.

    Attributes
    ----------
    points : the drive's points
    by_class : (len(TruthClass),) int64 points per truth class (synthetic drives), else None
    """

    points: int
    by_class: np.ndarray | None


def count_points(source: DriveSource) -> PointCounts:
    """Read every point tile of ``source``, one at a time, and count its points (and truth).

    Reading is validating: a tile that is missing, unreadable, holds another number of points
    than the index says or lies outside the trajectory's times raises its named
    :class:`~guardrail_core.errors.DriveError`. Memory holds one tile.
    """
    total = 0
    by_class = np.zeros(len(TruthClass), np.int64) if source.has_truth else None
    for tile in range(len(source.tiles)):
        points, truth = source.read_tiles([tile])
        total += len(points)
        if by_class is not None and truth is not None:
            by_class += np.bincount(truth.point_class, minlength=len(TruthClass))
        del points, truth  # before the next tile is read, not after
    return PointCounts(total, by_class)


def _scanner_line(source: DriveSource) -> str:
    scanner = source.scanner
    if scanner.kind == MULTIBEAM:
        return (
            f"a multi-beam scanner: {scanner.rings} rings x {scanner.points_per_rotation} azimuth "
            f"bins, {scanner.rotation_rate_hz:g} turns/s"
        )
    return (
        f"{scanner.rotation_rate_hz:g} rotations/s x {scanner.points_per_rotation} phases "
        f"({scanner.measurement_rate_hz:,.0f} pulses/s)"
    )


def describe_drive(source: DriveSource, counts: PointCounts | None = None) -> str:
    """Lines describing the drive's extent, sensors, files, point tiles and (for synthetic
    drives) truth. ``counts``: :func:`count_points` of ``source``, counted here when not given."""
    counts = counts if counts is not None else count_points(source)
    traj = source.trajectory
    length = float(np.sum(np.linalg.norm(np.diff(traj.position, axis=0), axis=1)))
    duration = float(traj.time[-1] - traj.time[0])
    size_mb = sum(p.stat().st_size for p in source.root.rglob("*") if p.is_file()) / 1e6
    per_camera = Counter(record.camera for record in source.images)
    n_tiles = len(source.tiles)
    lines = [
        f"drive      {source.root.resolve()}  ({size_mb:.1f} MB)",
        f"CRS        {source.crs}, local origin {', '.join(f'{v:.3f}' for v in source.origin)}",
        f"trajectory {length:.1f} m in {duration:.1f} s ({length / max(duration, 1e-9):.1f} m/s mean), "
        f"{len(traj)} poses",
        f"points     {counts.points:,} from {_scanner_line(source)}",
        *(
            [f"tiles      {n_tiles}, {length / n_tiles:.1f} m of driving each on average"]
            if n_tiles
            else []
        ),
        f"images     {len(source.images)}: "
        + ", ".join(
            f"{name} {n} ({source.cameras[name].width}x{source.cameras[name].height})"
            for name, n in per_camera.items()
        ),
    ]
    if counts.by_class is not None:
        runs = [o for o in source.objects if o.get("kind") == "guardrail"]
        others = Counter(o.get("kind") for o in source.objects if o.get("kind") != "guardrail")
        on_rails = int(counts.by_class[list(GUARDRAIL_CLASSES)].sum())
        lines.append(
            f"truth      {len(runs)} guardrail runs ({', '.join(sorted({r['design'] for r in runs}))}), "
            f"{on_rails:,} guardrail points ({100 * on_rails / max(counts.points, 1):.1f}%)"
        )
        lines.append(
            "           others: " + ", ".join(f"{k} {n}" for k, n in sorted(others.items()))
        )
        lines.append(
            "           points by class: "
            + ", ".join(
                f"{TruthClass(i).name.lower()} {n:,}" for i, n in enumerate(counts.by_class) if n
            )
        )
    return "\n".join(lines)
