"""Import a mobile-mapping delivery (LAS/LAZ points, trajectory, images, calibration) as a drive.

A delivery from a mapping vehicle's processing software comes as

* one or more LAS/LAZ point clouds with ``gps_time`` on every point, in map coordinates;
* a trajectory CSV with the seven columns of the drive's ``trajectory.csv`` in any order;
* optionally an image list CSV (``file, camera, gps_time``) and the camera calibration
  (:mod:`guardrail_core.importers.calibration`);
* the scanner's rates, epoch and mounting, from which every point's scan lattice follows (§3.1).

The files are read by :mod:`guardrail_core.importers.delivery_sources` and the scanner's lattice
comes from :mod:`guardrail_core.importers.delivery_scanner`; this module checks that the parts
fit together (every time covered by the trajectory, every camera calibrated, the image sizes
those of their calibration), then writes an ordinary drive folder through a staging folder
(:func:`guardrail_core.formats.atomic.staged_folder`), so a failure leaves nothing behind and no
input is ever deleted. The formats are documented in ``docs/import.md``.

The points stream: the files' headers and first and last points give the origin, the time span
and the scanner's epoch before any point is written; then the points of all files pass in
GPS-time order, chunk by chunk, through the lattice into a
:class:`~guardrail_core.formats.drive_tiles.TiledPointWriter` (drive format 2.0 tiles). Memory
is one tile plus a chunk per file open at once, whatever the size of the delivery.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from guardrail_core.errors import (
    InvalidOptionError,
    MissingCalibrationError,
    SourceFormatError,
)
from guardrail_core.formats.atomic import check_output, staged_folder
from guardrail_core.formats.drive import ImageRecord
from guardrail_core.formats.drive_tiles import DEFAULT_DRIVE_TILE_M, TiledPointWriter
from guardrail_core.formats.drive_writer import write_drive_metadata
from guardrail_core.geom.frames import make_transform
from guardrail_core.importers.calibration import read_calibrations, require_file
from guardrail_core.importers.delivery_scanner import (
    OFF_GRID_NOTE_FRACTION,
    read_scanner_file,
    scan_lattice,
    scanner_params,
)
from guardrail_core.importers.delivery_sources import (
    DeliveryFile,
    PathLike,
    SourceImage,
    check_coverage,
    check_reach,
    check_span,
    drive_origin,
    las_crs,
    read_image_list,
    read_time_ordered,
    read_trajectory_table,
    scan_delivery,
    to_week_seconds,
    week_time_note,
)
from guardrail_core.progress import progress_bar
from guardrail_core.sensors.camera import Camera
from guardrail_core.sensors.scanner import ScannerParams
from guardrail_core.sensors.trajectory import Trajectory

__all__ = [
    "DEFAULT_CHUNK_POINTS",
    "DEFAULT_REFERENCE_HEIGHT_M",
    "DEFAULT_TILE_M",
    "LasImport",
    "drive_origin",
    "import_las_delivery",
    "las_crs",
    "read_image_list",
    "read_scanner_file",
    "read_time_ordered",
    "read_trajectory_table",
    "scan_delivery",
    "scanner_params",
    "to_week_seconds",
]

#: Height of the trajectory's reference point above the road, as the simulator's vehicle has it.
DEFAULT_REFERENCE_HEIGHT_M = 1.8
#: Metres of driving per tile of the imported drive.
DEFAULT_TILE_M = DEFAULT_DRIVE_TILE_M
#: Points read from a LAS/LAZ file at a time: about 40 MB of arrays in flight per chunk.
DEFAULT_CHUNK_POINTS = 250_000


@dataclass(frozen=True)
class LasImport:
    """What :func:`import_las_delivery` wrote.

    Attributes
    ----------
    out : the drive folder
    n_points, n_images, n_tiles : int
    cameras : names of the calibrated cameras
    crs : str, as written to ``drive.json``; ``crs_from`` says where it came from
        (``"LAS file"``, ``"--crs option"`` or ``"none"``)
    origin : (3,) float64, map coordinates of the local frame's origin
    scanner : the scanner parameters (with the ``t0`` used)
    off_grid_fraction : float, share of points whose time is off the scanner's pulse grid
    notes : things the user should know (a time conversion, a CRS override, an off-grid lattice)
    """

    out: Path
    n_points: int
    n_images: int
    n_tiles: int
    cameras: list[str]
    crs: str
    crs_from: str
    origin: np.ndarray
    scanner: ScannerParams
    off_grid_fraction: float
    notes: list[str]


# ------------------------------------------------------------------------------------ images


def _check_images(images: list[SourceImage], cameras: dict[str, Camera], where: Path) -> None:
    """Every image's camera is calibrated and its file exists; the first image of every camera is
    decoded and must have the calibrated size (else the calibration or camera name is wrong)."""
    for image in images:
        if image.camera not in cameras:
            raise MissingCalibrationError(
                f"{where}, line {image.line}: camera {image.camera!r} has no calibration "
                f"(calibrated: {', '.join(sorted(cameras)) or 'none'})"
            )
        require_file(image.path, "image")
    checked: set[str] = set()
    for image in images:
        if image.camera in checked:
            continue
        pixels = cv2.imread(str(image.path), cv2.IMREAD_UNCHANGED)
        if pixels is None:
            raise SourceFormatError(f"{image.path}: not a readable image")
        camera = cameras[image.camera]
        if pixels.shape[:2] != (camera.height, camera.width):
            raise SourceFormatError(
                f"{image.path}: {pixels.shape[1]} x {pixels.shape[0]} pixels, but camera "
                f"{camera.name!r} is calibrated for {camera.width} x {camera.height}"
            )
        checked.add(image.camera)


def _image_records(
    images: list[SourceImage],
    cameras: dict[str, Camera],
    trajectory: Trajectory,
    where: Path,
) -> list[tuple[Path, ImageRecord]]:
    """Source path and drive record (file in the drive, pose in the local frame) of every image,
    ordered by time."""
    ordered = sorted(images, key=lambda i: (i.gps_time, i.camera))
    rotation, position = trajectory.poses(np.array([i.gps_time for i in ordered]))
    records: list[tuple[Path, ImageRecord]] = []
    taken: dict[str, Path] = {}
    for image, r, p in zip(ordered, rotation, position, strict=True):
        file = f"images/{image.camera}/{image.path.name}"
        if file in taken:
            raise SourceFormatError(
                f"{where}, line {image.line}: {image.path} and {taken[file]} would both be "
                f"{file}; images of one camera need distinct file names"
            )
        taken[file] = image.path
        pose = make_transform(r, p) @ cameras[image.camera].T_vehicle_camera
        records.append((image.path, ImageRecord(file, image.camera, image.gps_time, pose)))
    return records


# ------------------------------------------------------------------------------------ points


@dataclass(frozen=True)
class _Streamed:
    points: int
    off_grid: int
    tiles: int


def _stream_points(
    folder: Path,
    files: list[DeliveryFile],
    *,
    origin: np.ndarray,
    trajectory: Trajectory,
    table: np.ndarray,
    scanner: ScannerParams,
    week_time: bool,
    tile_m: float | None,
    compress: bool,
    chunk_points: int,
    progress: bool,
) -> _Streamed:
    """Write the points of ``files`` as tiles into ``folder``, chunk by chunk in GPS-time order:
    times to seconds of the week (``week_time``), coordinates to the local frame, the lattice
    from the times (§3.1). Each chunk is checked as the whole delivery was before: covered by the
    trajectory, within reach of the origin, on a lattice the epoch allows."""
    where = ", ".join(str(f.path) for f in files)
    writer = TiledPointWriter(
        folder, origin=origin, trajectory=trajectory, tile_m=tile_m, compress=compress
    )
    written = off_grid = 0
    with progress_bar(
        total=sum(f.points for f in files),
        desc="importing points",
        unit="pt",
        unit_scale=True,
        enabled=progress,
        leave=False,
    ) as bar:
        for chunk in read_time_ordered(files, chunk_points):
            gps_time = to_week_seconds(chunk.gps_time) if week_time else chunk.gps_time
            check_coverage(gps_time, table, "points", where)
            check_reach(chunk.xyz, origin)
            rotation, phase, off = scan_lattice(scanner, gps_time)
            writer.append(chunk.xyz - origin, gps_time, chunk.intensity, rotation, phase)
            written, off_grid = written + len(chunk), off_grid + off
            bar.update(len(chunk))
    return _Streamed(written, off_grid, len(writer.close()))


def import_las_delivery(
    points: PathLike | Sequence[PathLike],
    trajectory: PathLike,
    out: PathLike,
    *,
    scanner: ScannerParams | Mapping | PathLike,
    images_csv: PathLike | None = None,
    calibration: PathLike | Sequence[PathLike] | None = None,
    crs: str | None = None,
    reference_height_m: float = DEFAULT_REFERENCE_HEIGHT_M,
    trajectory_degrees: bool = False,
    tile_m: float | None = DEFAULT_TILE_M,
    chunk_points: int = DEFAULT_CHUNK_POINTS,
    compress: bool = True,
    overwrite: bool = False,
    progress: bool = False,
) -> LasImport:
    """Import a LAS/LAZ delivery into the drive folder ``out``, streaming its points.

    Parameters
    ----------
    points : one LAS/LAZ file or several, in any order, any point format with ``gps_time``; each
        file lists its points in GPS-time order; files may overlap in time (they are merged)
    trajectory : CSV with a header naming time, x, y, z, roll, pitch, yaw (any order); GPS s, map
        coordinates (metres), radians (degrees with ``trajectory_degrees``)
    out : drive folder to write; must be absent or empty unless ``overwrite``
    scanner : the scanner: :class:`ScannerParams` as is, or a mapping / a JSON or YAML file of its
        fields (:func:`scanner_params`: ``t0`` defaults to the first point's whole second)
    images_csv : image list CSV (``file, camera, gps_time``), or None for no images
    calibration : calibration file(s) for the images' cameras (OpenCV YAML, YAML or JSON)
    crs : the map CRS; overrides the one the LAS file declares. Default: the file's, else
        ``"unknown"``
    reference_height_m : metres of the trajectory's reference point above the road
    tile_m : metres of driving per tile of the drive's points; None: one tile
    chunk_points : points read from a file at a time (memory, not the result, depends on it)
    compress : write LAZ tiles (True) or LAS
    progress : show progress bars while copying images and importing points

    Returns
    -------
    LasImport
        What was written, and notes worth telling the user.

    Raises
    ------
    MissingSourceFileError, SourceFormatError, MissingGpsTimeError, PointsOutOfTimeOrderError,
    TrajectoryCoverageError, MissingCalibrationError, ImportSourceError
        Each names the input file and what is wrong; nothing is written.
    InvalidOptionError
        Scanner rates missing, an epoch ``t0`` after the first point, a tile length or chunk size
        not positive.
    OutputExistsError
        ``out`` is not empty and ``overwrite`` is False.
    InputInsideOutputError
        ``out`` is, holds or would replace one of the input files (images included); raised
        before the points are read.
    """
    out = Path(out)
    point_paths = (
        [Path(points)] if isinstance(points, str | os.PathLike) else [Path(p) for p in points]
    )
    if not point_paths:
        raise InvalidOptionError("no point cloud given")
    if tile_m is not None and not tile_m > 0:
        raise InvalidOptionError(f"tiles must be longer than 0 m, got {tile_m}")
    if not chunk_points >= 1:
        raise InvalidOptionError(f"chunks must hold at least 1 point, got {chunk_points}")
    calibration_paths = (
        []
        if calibration is None
        else [Path(calibration)]
        if isinstance(calibration, str | os.PathLike)
        else [Path(c) for c in calibration]
    )
    trajectory_path = Path(trajectory)
    scanner_path = Path(scanner) if isinstance(scanner, str | os.PathLike) else None
    inputs = [*point_paths, trajectory_path, *calibration_paths]
    inputs += [Path(p) for p in (images_csv, scanner_path) if p is not None]
    check_output(out, folder=True, overwrite=overwrite, inputs=inputs)  # before heavy reading
    for path in point_paths:
        require_file(path, "point cloud")
    notes: list[str] = []

    # Everything small first, so a bad calibration or image list fails before the points load.
    cameras = read_calibrations(calibration_paths)
    source_images = read_image_list(images_csv) if images_csv is not None else []
    if source_images and not cameras:
        raise MissingCalibrationError(
            f"{images_csv}: {len(source_images)} images but no camera calibration; give the "
            "calibration of their cameras (--calibration)"
        )
    if source_images:
        _check_images(source_images, cameras, Path(str(images_csv)))
        inputs += [image.path for image in source_images]
        check_output(out, folder=True, overwrite=overwrite, inputs=inputs)
    scanner_where = str(scanner_path or "scanner")
    scanner_fields: Mapping | None = None
    if scanner_path is not None:
        scanner_fields = read_scanner_file(scanner_path)
    elif isinstance(scanner, Mapping):
        scanner_fields = scanner
    if scanner_fields is not None:  # its rates checked before the points load; t0 comes later
        scanner_params(scanner_fields, 0.0, scanner_where)
    table = read_trajectory_table(trajectory_path, degrees=trajectory_degrees)
    if source_images:
        check_coverage(
            np.array([i.gps_time for i in source_images]), table, "images", str(images_csv)
        )

    # The points' headers and first and last points: their span, origin and CRS.
    files = scan_delivery(point_paths)
    with_points = [f for f in files if f.points]
    recorded = (min(f.first_time for f in with_points), max(f.last_time for f in with_points))
    converted = week_time_note(
        recorded, (float(table[0, 0]), float(table[-1, 0])), any(f.standard_time for f in files)
    )
    if converted:
        notes.append(converted)
    first, last = (
        float(t) for t in (to_week_seconds(np.array(recorded)) if converted else recorded)
    )
    check_span(first, last, table, "points", ", ".join(str(p) for p in point_paths))
    origin = drive_origin(
        np.min([f.bounds_min for f in with_points], axis=0),
        np.max([f.bounds_max for f in with_points], axis=0),
    )

    if scanner_fields is not None:
        params = scanner_params(scanner_fields, first, scanner_where)
    elif isinstance(scanner, ScannerParams):
        params = scanner
    else:
        raise InvalidOptionError(
            f"scanner: expected ScannerParams, a mapping or a file, got {scanner!r}"
        )
    scan_lattice(params, np.array([first, last]))  # a wrong epoch fails before any writing

    declared = next((f.crs for f in files if f.crs is not None), None)
    if crs is not None:
        crs_from = "--crs option"
        if declared is not None and declared != crs:
            notes.append(f"--crs {crs} replaces the CRS the LAS file declares ({declared})")
    elif declared is not None:
        crs, crs_from = declared, "LAS file"
    else:
        crs, crs_from = "unknown", "none"
        notes.append("the LAS file declares no CRS and --crs was not given: CRS 'unknown'")

    local_trajectory = Trajectory(
        time=table[:, 0],
        position=table[:, 1:4] - origin,
        attitude=table[:, 4:7],
        reference_height_m=float(reference_height_m),
    )
    images = _image_records(source_images, cameras, local_trajectory, Path(images_csv or "images"))

    with staged_folder(out, overwrite=overwrite, inputs=inputs) as staging:
        for source_path, record in progress_bar(
            images, desc="copying images", unit="image", enabled=progress, leave=False
        ):
            (staging / record.file).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(source_path, staging / record.file)
        streamed = _stream_points(
            staging,
            files,
            origin=origin,
            trajectory=local_trajectory,
            table=table,
            scanner=params,
            week_time=converted is not None,
            tile_m=tile_m,
            compress=compress,
            chunk_points=chunk_points,
            progress=progress,
        )
        off_grid = streamed.off_grid / streamed.points
        if off_grid > OFF_GRID_NOTE_FRACTION:
            notes.append(
                f"{100 * off_grid:.0f}% of the points' times lie off the scanner's pulse grid "
                f"({params.measurement_rate_hz:g} Hz from t0 {params.t0_s:.6f} s): check the "
                "scanner's rates and epoch, or the lattice joins points that are not neighbours"
            )
        source = {
            "importer": "las",
            "points": [str(p.resolve()) for p in point_paths],
            "trajectory": str(trajectory_path.resolve()),
            "images": str(Path(images_csv).resolve()) if images_csv is not None else None,
            "calibration": [str(p.resolve()) for p in calibration_paths],
            "crs_from": crs_from,
            "gps_time": converted or "as recorded",
            "lattice_off_grid_fraction": off_grid,
            "tile_m": tile_m,
        }
        write_drive_metadata(
            staging,
            crs=crs,
            origin=origin,
            scanner=params,
            trajectory=local_trajectory,
            cameras=list(cameras.values()),
            images=[record for _, record in images],
            objects=None,
            source=source,
        )
    return LasImport(
        out=out,
        n_points=streamed.points,
        n_images=len(images),
        n_tiles=streamed.tiles,
        cameras=list(cameras),
        crs=crs,
        crs_from=crs_from,
        origin=origin,
        scanner=params,
        off_grid_fraction=off_grid,
        notes=notes,
    )
