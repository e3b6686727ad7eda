"""Import frames of a KITTI odometry sequence as a drive folder.

A KITTI sequence folder holds ``velodyne/NNNNNN.bin`` (float32 x, y, z, reflectance per point;
Velodyne HDL-64E, sensor frame x forward, y left, z up, metres), ``calib.txt`` (``P0``..``P3``,
the 3x4 projections of the rectified cameras, and ``Tr``, velodyne -> rectified camera 0),
``poses.txt`` (one row-major 3x4 ``T_world_cam0`` per frame, world = camera 0 of frame 0),
``times.txt`` (seconds per frame) and optionally ``image_2/NNNNNN.png`` (the left colour camera).

The drive's world is the velodyne frame of the first imported frame, and its vehicle frame is the
velodyne's: the trajectory is the sensor's pose at every frame, ``sensor_height_m`` above the road.
Frames are merged in that world with their poses. Not the sequence's world (camera 0 of frame 0):
its z axis drifts away from the vertical along a long sequence, which would tilt the road under
the imported frames; the sensor of an imported frame stands on that road. ``drive.json``'s
``source.T_sequence_drive`` maps the drive's coordinates back to the sequence's world.

The scan lattice of a spinning multi-beam scanner is ring x azimuth. A ``.bin`` carries no ring,
but the scanner writes each ring as one sweep of increasing azimuth: a step back in azimuth starts
the next ring. The rings are then ordered by their median elevation, so neighbouring lattice rows
are neighbouring beams, and the azimuth is binned into :data:`AZIMUTH_BINS` phases.
"""

from __future__ import annotations

import os
import re
import shutil
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from guardrail_core.errors import (
    FrameRangeError,
    MissingCalibrationError,
    MissingSourceFileError,
    SourceFormatError,
)
from guardrail_core.formats.atomic import check_output, staged_folder
from guardrail_core.formats.drive import ImageRecord, PointCloud
from guardrail_core.formats.drive_writer import write_drive_files
from guardrail_core.geom.frames import euler_from_rotation, invert_transform, make_transform
from guardrail_core.importers.calibration import require_file
from guardrail_core.progress import progress_bar
from guardrail_core.sensors.camera import Camera
from guardrail_core.sensors.lidar_models import rows_by_elevation
from guardrail_core.sensors.scanner import azimuth_phase, imported_multibeam
from guardrail_core.sensors.trajectory import Trajectory

#: Height of the Velodyne above the road on the KITTI car (Geiger et al. 2013, Fig. 3).
KITTI_SENSOR_HEIGHT_M = 1.73
#: The HDL-64E's beams.
KITTI_RINGS = 64
#: The HDL-64E turns at 10 Hz.
ROTATIONS_PER_SECOND = 10.0
#: A step back in azimuth larger than this (radians) ends a ring. Within a ring the azimuth only
#: grows, by about 3 mrad per point.
RING_BREAK_RAD = 0.05
#: A scan cut where the camera looks splits the beam swept at the cut into two sweeps, so a scan
#: has 64 or 65 of them; far more means the points are not in the scanner's order.
MAX_SWEEPS = 2 * KITTI_RINGS
CAMERA_NAME = "image_2"


@dataclass(frozen=True)
class KittiSequence:
    """What a sequence folder holds (matrices as in ``calib.txt`` and ``poses.txt``).

    Attributes
    ----------
    root : the sequence folder
    calib : name -> (3, 4) float64 matrix (``P0``..``P3``, ``Tr``)
    poses : (F, 4, 4) float64, ``T_world_cam0`` per frame
    times : (F,) float64, seconds per frame
    """

    root: Path
    calib: dict[str, np.ndarray]
    poses: np.ndarray
    times: np.ndarray

    @property
    def n_frames(self) -> int:
        return len(self.times)

    @property
    def T_cam0_velo(self) -> np.ndarray:
        """(4, 4) velodyne -> rectified camera 0."""
        return np.vstack([self.calib["Tr"], [0.0, 0.0, 0.0, 1.0]])

    def T_sequence_velo(self, frames: np.ndarray) -> np.ndarray:
        """(K, 4, 4) sensor poses of ``frames`` in the sequence's world (camera 0 of frame 0)."""
        return self.poses[np.asarray(frames)] @ self.T_cam0_velo

    def scan_path(self, frame: int) -> Path:
        return self.root / "velodyne" / f"{frame:06d}.bin"

    def image_path(self, frame: int) -> Path:
        return self.root / CAMERA_NAME / f"{frame:06d}.png"


@dataclass(frozen=True)
class KittiImport:
    """What :func:`import_kitti` wrote."""

    out: Path
    frames: list[int]
    n_points: int
    n_images: int
    rings: int


def read_calib(path: Path) -> dict[str, np.ndarray]:
    """``calib.txt``: ``NAME: 12 numbers`` per line -> name -> (3, 4) float64."""
    require_file(path, "KITTI calibration")
    calib = {}
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        name, _, values = line.partition(":")
        try:
            matrix = np.array([float(v) for v in values.split()], np.float64)
        except ValueError as exc:
            raise SourceFormatError(f"{path}:{number}: not a list of numbers ({exc})") from exc
        if matrix.shape != (12,) or not np.all(np.isfinite(matrix)):
            raise SourceFormatError(
                f"{path}:{number}: {name.strip()!r} needs 12 finite numbers (a 3x4 matrix), got "
                f"{matrix.size}"
            )
        calib[name.strip()] = matrix.reshape(3, 4)
    if "Tr" not in calib:
        raise MissingCalibrationError(
            f"{path}: lacks Tr, the velodyne -> camera 0 transform that places scans in the world"
        )
    return calib


def _read_rows(path: Path, what: str, columns: int) -> np.ndarray:
    require_file(path, what)
    try:
        data = np.loadtxt(path, dtype=np.float64, ndmin=2)
    except ValueError as exc:
        raise SourceFormatError(f"{path}: not a table of numbers ({exc})") from exc
    if data.shape[1] != columns or len(data) == 0:
        raise SourceFormatError(
            f"{path}: expected rows of {columns} numbers, got shape {data.shape}"
        )
    if not np.all(np.isfinite(data)):
        raise SourceFormatError(f"{path}: contains NaN or infinity")
    return data


def sequence_parts(root: str | os.PathLike) -> list[Path]:
    """The files and folders of a sequence that :func:`import_kitti` reads: the inputs its
    output must never be, hold or replace (the sequence folder itself may hold the output)."""
    root = Path(root)
    names = ("calib.txt", "poses.txt", "times.txt", "velodyne", CAMERA_NAME)
    return [root / name for name in names]


def read_sequence(root: str | os.PathLike) -> KittiSequence:
    """Read a sequence folder's calibration, poses and times.

    Raises
    ------
    MissingSourceFileError, SourceFormatError, MissingCalibrationError
        A file is missing or malformed; the message names it.
    """
    root = Path(root)
    if not root.is_dir():
        raise MissingSourceFileError(f"{root}: no such KITTI sequence folder")
    calib = read_calib(root / "calib.txt")
    poses = _read_rows(root / "poses.txt", "KITTI poses", 12).reshape(-1, 3, 4)
    times = _read_rows(root / "times.txt", "KITTI frame times", 1)[:, 0]
    if len(poses) != len(times):
        raise SourceFormatError(
            f"{root}: poses.txt has {len(poses)} frames but times.txt has {len(times)}"
        )
    if np.any(np.diff(times) <= 0):
        raise SourceFormatError(f"{root / 'times.txt'}: times must increase strictly")
    bottom = np.broadcast_to([0.0, 0.0, 0.0, 1.0], (len(poses), 1, 4))
    return KittiSequence(root, calib, np.concatenate([poses, bottom], axis=1), times)


def parse_frames(text: str) -> list[int]:
    """``"280,281"``, ``"270-290"`` or a mix (``"1,5-7"``) -> sorted distinct frame numbers."""
    frames: set[int] = set()
    for part in text.split(","):
        match = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", part)
        if match is None:
            raise FrameRangeError(
                f"--frames: {part!r} is not a frame number or a range like 270-290"
            )
        first = int(match.group(1))
        last = int(match.group(2)) if match.group(2) is not None else first
        if last < first:
            raise FrameRangeError(f"--frames: the range {part.strip()!r} runs backwards")
        frames.update(range(first, last + 1))
    return sorted(frames)


def read_scan(path: Path) -> np.ndarray:
    """``velodyne/NNNNNN.bin`` -> (N, 4) float32 x, y, z (metres, sensor frame), reflectance."""
    require_file(path, "scan")
    size = path.stat().st_size
    if size % 16:
        raise SourceFormatError(
            f"{path}: {size} bytes is not a whole number of points (16 bytes: 4 float32 each)"
        )
    if size == 0:
        raise SourceFormatError(f"{path}: the scan is empty (no points)")
    scan = np.fromfile(path, dtype="<f4").reshape(-1, 4)
    if not np.all(np.isfinite(scan)):
        raise SourceFormatError(f"{path}: contains NaN or infinity")
    return scan


def recover_rings(xyz: np.ndarray) -> tuple[np.ndarray, int]:
    """The ring (beam) of every point of one Velodyne scan, from point order and elevation.

    Parameters
    ----------
    xyz : (N, 3) float, metres, sensor frame, in the scan's own order

    Returns
    -------
    ring : (N,) int64, 0 for the highest sweep, increasing downward
    rings : the number of sweeps found: a beam with no return is not counted, and a beam the
        scan's cut splits in two counts twice (KITTI scans have 64 or 65)
    """
    n = len(xyz)
    if n == 0:
        return np.zeros(0, np.int64), 0
    azimuth = np.arctan2(xyz[:, 1], xyz[:, 0])
    breaks = np.flatnonzero(np.diff(azimuth) < -RING_BREAK_RAD) + 1
    run = np.zeros(n, np.int64)
    run[breaks] = 1
    return rows_by_elevation(np.cumsum(run), xyz)


def camera_from_calib(calib: dict[str, np.ndarray], width: int, height: int) -> Camera:
    """The rectified left colour camera (``P2``) as a drive camera on the velodyne frame.

    ``P2 = K [I | t]`` projects camera-0 coordinates, so camera 2 sits at ``t`` in camera 0's
    frame and ``T_cam2_velo = [I | t] @ Tr``. Rectified images have no distortion.
    """
    if "P2" not in calib:
        raise MissingCalibrationError(
            "calib.txt: the sequence has image_2/ but no P2, the projection of its camera"
        )
    p2 = calib["P2"]
    k = p2[:, :3]
    offset = np.linalg.solve(k, p2[:, 3])
    t_cam2_velo = make_transform(np.eye(3), offset) @ np.vstack([calib["Tr"], [0, 0, 0, 1]])
    return Camera(
        name=CAMERA_NAME,
        width=width,
        height=height,
        K=k.copy(),
        dist=np.zeros(5),
        T_vehicle_camera=invert_transform(t_cam2_velo),
    )


def _trajectory(
    sequence: KittiSequence, frames: list[int], sensor_height_m: float, T_drive_sequence: np.ndarray
) -> Trajectory:
    """The sensor's poses at the frames and their neighbours in the sequence (which give the
    direction of travel even for a single frame); a sequence of one pose stands still."""
    rows = sorted(
        {f for frame in frames for f in (frame - 1, frame, frame + 1) if 0 <= f < sequence.n_frames}
    )
    poses = T_drive_sequence @ sequence.T_sequence_velo(np.array(rows))
    times = sequence.times[rows]
    if len(rows) == 1:
        half = 0.5 / ROTATIONS_PER_SECOND
        poses = np.concatenate([poses, poses])
        times = np.array([times[0] - half, times[0] + half])
    return Trajectory(
        time=times,
        position=poses[:, :3, 3],
        attitude=euler_from_rotation(poses[:, :3, :3]),
        reference_height_m=sensor_height_m,
    )


def import_kitti(
    sequence_dir: str | os.PathLike,
    out: str | os.PathLike,
    *,
    frames: Iterable[int] | None = None,
    sensor_height_m: float = KITTI_SENSOR_HEIGHT_M,
    overwrite: bool = False,
    progress: bool = False,
) -> KittiImport:
    """Merge frames of a KITTI odometry sequence into a drive folder.

    Parameters
    ----------
    sequence_dir : the sequence folder (``velodyne/``, ``calib.txt``, ``poses.txt``,
        ``times.txt``, optional ``image_2/``)
    out : the drive folder to write; written whole or not at all
    frames : frame numbers (default: every frame with a scan in ``velodyne/``)
    sensor_height_m : the Velodyne's height above the road, metres (the trajectory's reference
        height, from which road removal estimates the road)
    overwrite : replace an existing drive folder
    progress : show a progress bar

    Raises
    ------
    MissingSourceFileError, SourceFormatError, MissingCalibrationError, FrameRangeError
        The message names the file or frame.
    OutputExistsError
        ``out`` is not empty and ``overwrite`` is False.
    InputInsideOutputError
        ``out`` is, holds or would replace a part of the sequence (``out`` may lie inside the
        sequence folder, beside its files); raised before anything is read.
    """
    out = Path(out)
    inputs = sequence_parts(sequence_dir)
    check_output(out, folder=True, overwrite=overwrite, inputs=inputs)
    sequence = read_sequence(sequence_dir)
    if frames is None:
        found = sorted(
            int(p.stem) for p in (sequence.root / "velodyne").glob("*.bin") if p.stem.isdigit()
        )
        chosen = [f for f in found if f < sequence.n_frames]
        if not chosen:
            raise MissingSourceFileError(f"{sequence.root / 'velodyne'}: no scans (NNNNNN.bin)")
    else:
        chosen = sorted(set(int(f) for f in frames))
    if not chosen:
        raise FrameRangeError("no frames asked for")
    bad = [f for f in chosen if not 0 <= f < sequence.n_frames]
    if bad:
        raise FrameRangeError(
            f"{sequence.root}: frames {bad[:5]} are out of range; the sequence has frames "
            f"0..{sequence.n_frames - 1}"
        )
    if not sensor_height_m > 0:
        raise SourceFormatError(f"sensor height must be positive, got {sensor_height_m} m")
    for frame in chosen:  # every file is checked before anything is written
        require_file(sequence.scan_path(frame), "scan")

    T_sequence_drive = sequence.T_sequence_velo(np.array(chosen[:1]))[0]
    T_drive_sequence = invert_transform(T_sequence_drive)
    sensor = T_drive_sequence @ sequence.T_sequence_velo(np.array(chosen))
    origin = np.zeros(3)
    scans = [
        read_scan(sequence.scan_path(f))
        for f in progress_bar(chosen, desc="reading scans", enabled=progress)
    ]
    rings_of = [recover_rings(scan[:, :3]) for scan in scans]
    rings = max(found for _, found in rings_of)
    if rings > MAX_SWEEPS:
        raise SourceFormatError(
            f"{sequence.root / 'velodyne'}: a scan splits into {rings} azimuth sweeps, far more "
            f"than the HDL-64E's {KITTI_RINGS} beams; is it a KITTI scan in its original point "
            "order?"
        )
    rows_per_frame = rings + 1  # one empty row keeps frames apart on the lattice
    parts = []
    for block, (frame, scan, (ring, _)) in enumerate(zip(chosen, scans, rings_of, strict=True)):
        xyz = scan[:, :3].astype(np.float64) @ sensor[block, :3, :3].T + sensor[block, :3, 3]
        parts.append(
            (
                xyz,
                np.full(len(scan), sequence.times[frame]),
                np.clip(np.rint(scan[:, 3] * 65535), 0, 65535).astype(np.uint16),
                block * rows_per_frame + ring,
                azimuth_phase(scan[:, :3]),
            )
        )
    xyz, gps_time, intensity, rotation, phase = (
        np.concatenate(c) for c in zip(*parts, strict=True)
    )
    points = PointCloud(xyz, gps_time, intensity, rotation, phase)
    trajectory = _trajectory(sequence, chosen, sensor_height_m, T_drive_sequence)
    scanner = imported_multibeam(
        ROTATIONS_PER_SECOND, float(sequence.times[0]), rings, max_range_m=120.0
    )

    with staged_folder(out, overwrite=overwrite, inputs=inputs) as staging:
        cameras, images = _copy_images(sequence, chosen, sensor, staging)
        write_drive_files(
            staging,
            crs=f"local: the velodyne frame of KITTI frame {chosen[0]} (x forward, y left, z up)",
            origin=origin,
            scanner=scanner,
            trajectory=trajectory,
            points=points,
            cameras=cameras,
            images=images,
            truth=None,
            source={
                "importer": "kitti",
                "sequence": str(sequence.root.resolve()),
                "frames": chosen,
                "T_sequence_drive": T_sequence_drive.tolist(),
                "sensor_height_m": sensor_height_m,
                "time": "seconds of the sequence's times.txt; every point has its frame's time",
            },
        )
    return KittiImport(out, chosen, len(points), len(images), rings)


def _copy_images(
    sequence: KittiSequence,
    frames: list[int],
    sensor: np.ndarray,
    staging: Path,
) -> tuple[list[Camera], list[ImageRecord]]:
    """Copy the frames' ``image_2`` images into ``staging`` and record their poses."""
    if not (sequence.root / CAMERA_NAME).is_dir():
        return [], []
    paths = [sequence.image_path(f) for f in frames]
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        raise MissingSourceFileError(
            f"{sequence.root / CAMERA_NAME}: the images of {len(missing)} frames are missing, "
            f"e.g. {missing[0]}"
        )
    first = cv2.imread(str(paths[0]), cv2.IMREAD_UNCHANGED)
    if first is None:
        raise SourceFormatError(f"{paths[0]}: not a readable image")
    camera = camera_from_calib(sequence.calib, first.shape[1], first.shape[0])
    folder = staging / "images" / CAMERA_NAME
    folder.mkdir(parents=True)
    records = []
    for block, (frame, path) in enumerate(zip(frames, paths, strict=True)):
        shutil.copyfile(path, folder / path.name)
        pose = sensor[block] @ camera.T_vehicle_camera
        records.append(
            ImageRecord(
                f"images/{CAMERA_NAME}/{path.name}",
                CAMERA_NAME,
                float(sequence.times[frame]),
                pose,
            )
        )
    return [camera], records
