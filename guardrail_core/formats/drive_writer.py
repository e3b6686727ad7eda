"""Writing a drive folder (the layout of :mod:`guardrail_core.formats.drive`): its metadata,
trajectory, cameras, image records, truth objects and, through a
:class:`~guardrail_core.formats.drive_tiles.TiledPointWriter`, its point tiles.

Producers call these inside :func:`guardrail_core.formats.atomic.staged_folder`, so a failed
write never leaves a half-written drive.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from guardrail_core.formats.drive import (
    FORMAT_NAME,
    FORMAT_VERSION,
    TRAJECTORY_COLUMNS,
    ImageRecord,
    PointCloud,
    Truth,
)
from guardrail_core.formats.drive_tiles import INDEX_FILE, TiledPointWriter
from guardrail_core.sensors.camera import Camera
from guardrail_core.sensors.scanner import ScannerParams
from guardrail_core.sensors.trajectory import Trajectory


def camera_to_json(camera: Camera) -> dict:
    return {
        "name": camera.name,
        "width": camera.width,
        "height": camera.height,
        "K": camera.K.tolist(),
        "dist": camera.dist.tolist(),
        "dist_model": "brown-conrady (k1, k2, p1, p2, k3), OpenCV order",
        "T_vehicle_camera": camera.T_vehicle_camera.tolist(),
    }


def write_trajectory_csv(path: Path, trajectory: Trajectory, origin: np.ndarray) -> None:
    world = trajectory.position + origin
    data = np.column_stack([trajectory.time, world, trajectory.attitude])
    with path.open("w", newline="") as handle:
        handle.write(",".join(TRAJECTORY_COLUMNS) + "\n")
        np.savetxt(
            handle,
            data,
            delimiter=",",
            fmt=["%.6f", "%.4f", "%.4f", "%.4f", "%.9f", "%.9f", "%.9f"],
        )


def write_drive_files(
    folder: Path,
    *,
    crs: str,
    origin: np.ndarray,
    scanner: ScannerParams,
    trajectory: Trajectory,
    points: PointCloud,
    cameras: list[Camera],
    images: list[ImageRecord],
    truth: Truth | None,
    source: dict,
    compress: bool = True,
    tile_m: float | None = None,
) -> None:
    """Write the metadata, trajectory and points (tiles of ``tile_m`` metres of driving; None:
    one tile) of a drive held in memory into ``folder``.

    Image and mask pixels are written by the producer as it goes (they do not fit in memory for
    long drives); ``images`` carries their records with poses in the local frame. Producers of
    long drives write their points through a :class:`TiledPointWriter` chunk by chunk instead,
    then call :func:`write_drive_metadata`.
    """
    writer = TiledPointWriter(
        folder,
        origin=origin,
        trajectory=trajectory,
        tile_m=tile_m,
        compress=compress,
        with_truth=truth is not None,
    )
    writer.append(
        points.xyz,
        points.gps_time,
        points.intensity,
        points.rotation,
        points.phase,
        None if truth is None else truth.point_class,
        None if truth is None else truth.point_object,
    )
    writer.close()
    write_drive_metadata(
        folder,
        crs=crs,
        origin=origin,
        scanner=scanner,
        trajectory=trajectory,
        cameras=cameras,
        images=images,
        objects=None if truth is None else truth.objects,
        source=source,
    )


def write_drive_metadata(
    folder: Path,
    *,
    crs: str,
    origin: np.ndarray,
    scanner: ScannerParams,
    trajectory: Trajectory,
    cameras: list[Camera],
    images: list[ImageRecord],
    objects: list[dict] | None,
    source: dict,
) -> None:
    """Write ``drive.json``, the trajectory, cameras, image records and (``objects`` given: a
    synthetic drive) ``truth/objects.json``; the point tiles and their index are written by a
    :class:`TiledPointWriter`."""
    meta = {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "units": {"length": "metre", "angle": "radian", "time": "GPS seconds"},
        "crs": crs,
        "origin": [float(v) for v in origin],
        "scanner": scanner.to_json(),
        "trajectory": {
            "reference_height_m": trajectory.reference_height_m,
            "attitude": "roll, pitch, yaw; R_world_vehicle = Rz(yaw) Ry(pitch) Rx(roll)",
            "vehicle_frame": "x forward, y left, z up",
        },
        "files": {
            "points": INDEX_FILE,
            "trajectory": "trajectory.csv",
            "cameras": "cameras.json",
            "images": "images.json",
        },
        "truth": "truth" if objects is not None else None,
        "source": source,
    }
    (folder / "drive.json").write_text(json.dumps(meta, indent=2))
    write_trajectory_csv(folder / "trajectory.csv", trajectory, origin)
    (folder / "cameras.json").write_text(json.dumps([camera_to_json(c) for c in cameras], indent=2))
    records = []
    for record in images:
        pose = record.T_world_camera.copy()
        pose[:3, 3] += origin
        records.append(
            {
                "file": record.file,
                "camera": record.camera,
                "gps_time": record.gps_time,
                "T_world_camera": pose.tolist(),
            }
        )
    (folder / "images.json").write_text(json.dumps(records, indent=1))
    if objects is not None:
        (folder / "truth").mkdir(exist_ok=True)
        (folder / "truth" / "objects.json").write_text(json.dumps(objects, indent=1))
