"""Import frames of any spinning multi-beam LiDAR as a drive folder (``guardrail import lidar``).

A frame is one turn of the sensor in a file of its own (:mod:`~guardrail_core.importers.
lidar_frames`: PCD, LAS/LAZ, KITTI ``.bin``). One frame makes a drive by itself; several are
merged with their poses (:mod:`~guardrail_core.importers.lidar_poses`). As for KITTI
(:mod:`~guardrail_core.importers.kitti`), the drive's world is the sensor frame of the first
frame and its vehicle frame the sensor's: the trajectory is the sensor's pose at every frame,
``sensor_height_m`` above the road.

The scan lattice is ring x azimuth bin, one block of rows per frame. The ring of a point comes
from the file's ring field where it has one; else from its elevation, the beam of the nearest
elevation in the sensor's beam table (a preset or a table given); else, for a KITTI ``.bin`` in
its original order, from the order (a step back in azimuth starts the next ring); else from the
elevations the frame's own far points cluster at
(:mod:`~guardrail_core.sensors.lidar_models`). Rows are ordered by elevation, highest first,
whatever the file numbers its beams.

Points are placed with their frame's pose (no motion compensation within a turn).
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from guardrail_core.errors import MissingSourceFileError, SourceFormatError
from guardrail_core.formats.atomic import check_output, staged_folder
from guardrail_core.formats.drive import ImageRecord, PointCloud
from guardrail_core.formats.drive_writer import write_drive_files
from guardrail_core.geom.frames import euler_from_rotation, invert_transform
from guardrail_core.importers.calibration import read_calibrations
from guardrail_core.importers.kitti import MAX_SWEEPS, recover_rings
from guardrail_core.importers.lidar_frames import FRAME_SUFFIXES, LidarFrame, read_lidar_frame
from guardrail_core.importers.lidar_poses import read_frame_poses, read_frame_times
from guardrail_core.progress import progress_bar
from guardrail_core.sensors.camera import Camera
from guardrail_core.sensors.lidar_models import (
    beams_from_points,
    lidar_model,
    read_beam_table,
    rings_from_elevation,
    rows_by_elevation,
)
from guardrail_core.sensors.scanner import azimuth_phase, imported_multibeam
from guardrail_core.sensors.trajectory import Trajectory

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
#: Turns per second when neither the sensor preset nor the caller says.
DEFAULT_ROTATION_HZ = 10.0
#: The road is looked for between these horizontal distances from the sensor (metres): beyond
#: the car's own body, near enough to be under it.
GROUND_RANGE_M = (3.0, 20.0)
#: The road's 15 cm layer holds at least this share of the points below the sensor there.
GROUND_SHARE = 0.15
#: A sensor height estimated outside this range (metres) is not believed.
SENSOR_HEIGHT_RANGE_M = (0.3, 5.0)


@dataclass(frozen=True)
class LidarImport:
    """What :func:`import_lidar` wrote."""

    out: Path
    frames: int
    n_points: int
    n_images: int
    rings: int
    rings_from: str
    sensor_height_m: float
    sensor_height_estimated: bool


def frame_files(paths: Sequence[str | os.PathLike]) -> list[Path]:
    """The frame files of ``paths`` (files, or folders whose frame files are taken in name
    order); :class:`MissingSourceFileError` where there are none."""
    found: list[Path] = []
    for given in map(Path, paths):
        if given.is_dir():
            found += sorted(p for p in given.iterdir() if p.suffix.lower() in FRAME_SUFFIXES)
        elif given.exists():
            found.append(given)
        else:
            raise MissingSourceFileError(f"{given}: no such LiDAR frame file or folder")
    if not found:
        raise MissingSourceFileError(
            f"{', '.join(map(str, paths)) or 'nothing'}: no LiDAR frames ({', '.join(FRAME_SUFFIXES)})"
        )
    return found


def estimate_sensor_height(xyz: np.ndarray) -> float:
    """The sensor's height above the road, metres: the median of the densest 15 cm layer of the
    points below it, between :data:`GROUND_RANGE_M` from it, which must hold
    :data:`GROUND_SHARE` of them.

    Parameters
    ----------
    xyz : (N, 3) float, metres, sensor frame (z up)

    Raises
    ------
    SourceFormatError
        No ground found within :data:`SENSOR_HEIGHT_RANGE_M`: give the height.
    """
    reach = np.hypot(xyz[:, 0], xyz[:, 1])
    near = (reach >= GROUND_RANGE_M[0]) & (reach <= GROUND_RANGE_M[1])
    z = xyz[near, 2]
    z = z[(z <= -SENSOR_HEIGHT_RANGE_M[0]) & (z >= -SENSOR_HEIGHT_RANGE_M[1])]
    if len(z) < 50:
        raise SourceFormatError(
            "no road found under the sensor to measure its height from; give --sensor-height"
        )
    edges = np.arange(-SENSOR_HEIGHT_RANGE_M[1], -SENSOR_HEIGHT_RANGE_M[0] + 0.05, 0.05)
    counts, _ = np.histogram(z, edges)
    layer = int(np.argmax(counts))
    inside = z[(z >= edges[layer] - 0.05) & (z < edges[layer + 1] + 0.05)]
    if len(inside) < GROUND_SHARE * len(z):  # no flat layer: walls, slopes, a car park's ramps
        raise SourceFormatError(
            "no flat road under the sensor to measure its height from; give --sensor-height"
        )
    return float(-np.median(inside))


def fit_road(xyz: np.ndarray, height_m: float) -> tuple[float, float]:
    """The road around the sensor: its rise per metre along the sensor's x axis (forward), from
    a plane fitted to the road's returns (within :data:`GROUND_RANGE_M` and 4 m to each side,
    0.25 m of ``height_m`` below the sensor, refitted on those within 5 cm), and its depth under
    the sensor (metres): the median of the returns 3-10 m away and within 2 m to each side, the
    grade taken off (the road's crown bends a plane across the carriageway). Where too few are
    found: no grade and ``height_m``.

    A lidar sits a degree or so off level, which puts the road 0.35 m off at 20 m, and the
    densest layer of returns (:func:`estimate_sensor_height`) then lies a few centimetres off
    the road under the sensor (KITTI frame 280: the layer 1.69 m, this 1.75 m).
    """
    x, y, z = xyz.T
    reach = np.hypot(x, y)
    level = np.abs(z + height_m) < 0.25
    near = (reach >= GROUND_RANGE_M[0]) & (reach <= GROUND_RANGE_M[1]) & (np.abs(y) < 4.0)
    near &= level
    for _ in range(3):
        if near.sum() < 50 or np.ptp(x[near]) < 5.0:
            return 0.0, height_m
        design = np.c_[x[near], y[near], np.ones(int(near.sum()))]
        coef = np.linalg.lstsq(design, z[near], rcond=None)[0]
        near &= np.abs(z - (coef[0] * x + coef[1] * y + coef[2])) < 0.05
    grade = float(coef[0])
    under = level & (reach >= GROUND_RANGE_M[0]) & (reach <= 10.0) & (np.abs(y) < 2.0)
    depth = z[under] - grade * x[under]
    if len(depth) < 20:
        return grade, height_m
    depth = depth[np.abs(depth - np.median(depth)) < 0.05]
    return grade, float(-np.median(depth))


def _rings(frame: LidarFrame, table: np.ndarray | None) -> tuple[np.ndarray, int, str]:
    """(N,) row of every point of a frame, the number of rows, and where they came from."""
    if frame.ring is not None:
        ring, count = rows_by_elevation(frame.ring, frame.xyz)
        return ring, count, "ring field"
    if table is not None:
        return rings_from_elevation(frame.xyz, table), len(table), "beam table"
    if frame.path.suffix.lower() == ".bin":
        ring, count = recover_rings(frame.xyz)
        if count <= MAX_SWEEPS:
            return ring, count, "point order"
    found = beams_from_points(frame.xyz)
    return rings_from_elevation(frame.xyz, found), len(found), "elevations found in the frame"


def _point_times(frame: LidarFrame, frame_time: float, turn_s: float) -> np.ndarray:
    """(N,) GPS-like seconds of a frame's points: their own (absolute, or offsets from the
    frame's time) or the frame's; offsets beyond a turn are refused."""
    if frame.time is None:
        return np.full(len(frame.xyz), frame_time)
    if not frame.time_is_offset:
        return frame.time
    span = float(frame.time.max() - min(frame.time.min(), 0.0))
    if span > 2 * turn_s:
        raise SourceFormatError(
            f"{frame.path}: point time offsets span {span:.3f} s, more than a turn of "
            f"{turn_s:.3f} s (are they in another unit?)"
        )
    return frame_time + frame.time


def _frame_times(frames: list[LidarFrame], given: np.ndarray | None, turn_s: float) -> np.ndarray:
    """(F,) each frame's time: given, else its points' absolute times' start, else one turn
    after the other."""
    if given is not None:
        return np.asarray(given, np.float64)
    absolute = [f.time is not None and not f.time_is_offset for f in frames]
    if all(absolute):
        times = np.array([float(f.time.min()) for f in frames if f.time is not None])
        if np.all(np.diff(times) > 0):
            return times
    return np.arange(len(frames)) * turn_s


def _trajectory(
    T_drive_sensor: np.ndarray,
    times: np.ndarray,
    turn_s: float,
    height_m: float,
    grade: float = 0.0,
) -> Trajectory:
    """The sensor's poses at its frames, a turn before the first and after the last held still,
    so that every point's time lies within; ``grade``: a frame without poses stands pitched as
    the road under it rises (its path goes on at that grade: ``sensors.track``)."""
    poses = np.concatenate([T_drive_sensor[:1], T_drive_sensor, T_drive_sensor[-1:]])
    times = np.concatenate([[times[0] - turn_s], times, [times[-1] + 2 * turn_s]])
    attitude = euler_from_rotation(poses[:, :3, :3])
    attitude[:, 1] -= np.arctan(grade)  # nose up (a negative pitch) where the road rises
    return Trajectory(
        time=times,
        position=poses[:, :3, 3],
        attitude=attitude,
        reference_height_m=height_m,
    )


def _image_of(folder: Path, camera: str, stem: str, one_camera: bool) -> Path | None:
    places = [folder / camera] + ([folder] if one_camera else [])
    for place in places:
        for suffix in IMAGE_SUFFIXES:
            if (place / f"{stem}{suffix}").is_file():
                return place / f"{stem}{suffix}"
    return None


def _copy_images(
    cameras: dict[str, Camera],
    folder: Path | None,
    paths: list[Path],
    T_drive_sensor: np.ndarray,
    times: np.ndarray,
    staging: Path,
) -> list[ImageRecord]:
    """Copy each frame's image of each camera (``folder/<camera>/<frame stem>.png``, or
    ``folder/<stem>.png`` for one camera) into ``staging``, with its pose."""
    if not cameras:
        return []
    if folder is None or not folder.is_dir():
        raise MissingSourceFileError(f"{folder}: the cameras' images folder is missing (--images)")
    records = []
    for name, camera in cameras.items():
        out = staging / "images" / name
        out.mkdir(parents=True)
        for block, path in enumerate(paths):
            image = _image_of(folder, name, path.stem, len(cameras) == 1)
            if image is None:
                raise MissingSourceFileError(
                    f"{folder}: no image of camera {name!r} for frame {path.name} (expected "
                    f"{name}/{path.stem}.png or .jpg)"
                )
            pixels = cv2.imread(str(image), cv2.IMREAD_UNCHANGED)
            if pixels is None:
                raise SourceFormatError(f"{image}: not a readable image")
            if pixels.shape[:2] != (camera.height, camera.width):
                raise SourceFormatError(
                    f"{image}: {pixels.shape[1]} x {pixels.shape[0]} px, but camera {name!r} is "
                    f"calibrated for {camera.width} x {camera.height}"
                )
            shutil.copyfile(image, out / image.name)
            records.append(
                ImageRecord(
                    f"images/{name}/{image.name}",
                    name,
                    float(times[block]),
                    T_drive_sensor[block] @ camera.T_vehicle_camera,
                )
            )
    return records


def import_lidar(
    frames: Sequence[str | os.PathLike],
    out: str | os.PathLike,
    *,
    sensor: str | None = None,
    beams: str | os.PathLike | None = None,
    poses: str | os.PathLike | None = None,
    times: str | os.PathLike | None = None,
    kitti_calib: str | os.PathLike | None = None,
    sensor_height_m: float | None = None,
    calibrations: Sequence[str | os.PathLike] = (),
    images: str | os.PathLike | None = None,
    rotation_hz: float | None = None,
    overwrite: bool = False,
    progress: bool = False,
) -> LidarImport:
    """Import LiDAR frames as a drive folder (module docstring).

    Parameters
    ----------
    frames : frame files, or folders of them (taken in name order)
    out : the drive folder to write; written whole or not at all
    sensor : a preset of :data:`~guardrail_core.sensors.lidar_models.LIDAR_MODELS` (its beam
        table and turn rate)
    beams : a beam table file instead (one elevation a beam, degrees)
    poses, times, kitti_calib : the frames' poses and times
        (:func:`~guardrail_core.importers.lidar_poses.read_frame_poses`); several frames need
        poses
    sensor_height_m : the sensor's height above the road, metres; None: estimated from the
        first frame (:func:`estimate_sensor_height`, then :func:`fit_road`)
    calibrations : camera calibration files (:mod:`~guardrail_core.importers.calibration`;
        the vehicle frame is the sensor's)
    images : the folder of the cameras' images, one a frame and camera, named as the frame
    rotation_hz : turns per second (default: the preset's, else 10)
    overwrite : replace an existing drive folder
    progress : show a progress bar

    Raises
    ------
    MissingSourceFileError, SourceFormatError, FrameRangeError
        An input is missing or malformed; the message names it. Nothing is written.
    OutputExistsError, InputInsideOutputError
        ``out`` is not empty (without ``overwrite``), or is, holds or would replace an input.
    """
    paths = frame_files(frames)
    given = [
        Path(p) for p in (beams, poses, times, kitti_calib, images, *calibrations) if p is not None
    ]
    check_output(Path(out), folder=True, overwrite=overwrite, inputs=[*paths, *given])
    if sensor is not None and beams is not None:
        raise SourceFormatError("give --sensor or --beams, not both")
    model = lidar_model(sensor) if sensor is not None else None
    table = (
        np.asarray(model.elevations_deg)
        if model is not None
        else read_beam_table(beams)
        if beams is not None
        else None
    )
    rate = rotation_hz or (model.rotation_hz if model is not None else DEFAULT_ROTATION_HZ)
    if not rate > 0:
        raise SourceFormatError(f"--rotation-hz must be positive, got {rate}")
    turn_s = 1.0 / rate
    frame_poses = read_frame_poses(paths, poses, times=times, calib=kitti_calib)
    if frame_poses is None and len(paths) > 1:
        raise SourceFormatError(
            f"{len(paths)} frames and no --poses: several frames are merged by their poses"
        )
    given_times = (
        frame_poses.times
        if frame_poses is not None
        else read_frame_times(paths, times)
        if times is not None
        else None
    )
    cameras = read_calibrations([Path(c) for c in calibrations]) if calibrations else {}
    if sensor_height_m is not None and not sensor_height_m > 0:
        raise SourceFormatError(f"--sensor-height must be positive, got {sensor_height_m} m")

    read = [
        read_lidar_frame(p) for p in progress_bar(paths, desc="reading frames", enabled=progress)
    ]
    estimated = sensor_height_m is None
    if sensor_height_m is None:  # the densest layer of returns, then the road's plane there
        height = fit_road(read[0].xyz, estimate_sensor_height(read[0].xyz))[1]
    else:
        height = sensor_height_m
    frame_times = _frame_times(read, given_times, turn_s)
    T_world_sensor = frame_poses.T_world_sensor if frame_poses is not None else np.eye(4)[None]
    T_drive_sensor = invert_transform(T_world_sensor[0]) @ T_world_sensor
    rings_of = [_rings(frame, table) for frame in read]
    rings = max(count for _, count, _ in rings_of)
    sources = sorted({source for _, _, source in rings_of})
    rows_per_frame = rings + 1  # one empty row keeps frames apart on the lattice
    parts = []
    for block, (frame, (ring, _, _)) in enumerate(zip(read, rings_of, strict=True)):
        pose = T_drive_sensor[block]
        parts.append(
            (
                frame.xyz @ pose[:3, :3].T + pose[:3, 3],
                _point_times(frame, float(frame_times[block]), turn_s),
                frame.intensity,
                block * rows_per_frame + ring,
                azimuth_phase(frame.xyz),
            )
        )
    xyz, gps_time, intensity, rotation, phase = (
        np.concatenate(column) for column in zip(*parts, strict=True)
    )
    order = np.argsort(gps_time, kind="stable")
    points = PointCloud(
        xyz[order], gps_time[order], intensity[order], rotation[order], phase[order]
    )
    # One frame without poses: the road's grade in it, as the path a moving vehicle gives.
    grade = fit_road(read[0].xyz, height)[0] if frame_poses is None else 0.0
    trajectory = _trajectory(T_drive_sensor, frame_times, turn_s, height, grade)
    if gps_time.min() < trajectory.time[0] or gps_time.max() > trajectory.time[-1]:
        raise SourceFormatError(
            "the points' own times lie outside their frames' times by more than a turn: the "
            "frame times (--times, --poses) and the points' times are on different clocks"
        )
    scanner = imported_multibeam(rate, float(trajectory.time[0]), rings, max_range_m=250.0)
    with staged_folder(Path(out), overwrite=overwrite, inputs=[*paths, *given]) as staging:
        records = _copy_images(
            cameras,
            None if images is None else Path(images),
            paths,
            T_drive_sensor,
            frame_times,
            staging,
        )
        write_drive_files(
            staging,
            crs=f"local: the sensor frame of {paths[0].name} (x forward, y left, z up)",
            origin=np.zeros(3),
            scanner=scanner,
            trajectory=trajectory,
            points=points,
            cameras=list(cameras.values()),
            images=records,
            truth=None,
            source={
                "importer": "lidar",
                "frames": [str(p.resolve()) for p in paths],
                "sensor": sensor,
                "rings_from": sources,
                "T_world_drive": T_world_sensor[0].tolist(),
                "sensor_height_m": height,
                "sensor_height_estimated": estimated,
            },
        )
    return LidarImport(
        Path(out),
        len(paths),
        len(points),
        len(records),
        rings,
        ", ".join(sources),
        height,
        estimated,
    )
