"""Import a mobile-mapping delivery (LAS/LAZ points, trajectory, images, calibration) as a drive.

A delivery from a mapping vehicle's processing software comes as

* one or more LAS/LAZ point clouds with ``gps_time`` on every point, in map coordinates;
* a trajectory CSV with the seven columns of the drive's ``trajectory.csv`` in any order;
* optionally an image list CSV (``file, camera, gps_time``) and the camera calibration
  (:mod:`guardrail_core.importers.calibration`);
* the scanner's rates, epoch and mounting, from which every point's scan lattice follows (§3.1).

:func:`import_las_delivery` checks that the parts fit together (every time covered by the
trajectory, every camera calibrated, the image sizes those of their calibration), then writes an
ordinary drive folder through a staging folder, so a failure leaves nothing behind. The formats
are documented in ``docs/import.md``.
"""

from __future__ import annotations

import csv
import math
import os
import re
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import laspy
import numpy as np
from laspy.vlrs.known import GeoKeyDirectoryVlr, WktCoordinateSystemVlr
from tqdm import tqdm

from guardrail_core.camera_model import Camera
from guardrail_core.drive import (
    TRAJECTORY_COLUMNS,
    ImageRecord,
    PointCloud,
    atomic_folder,
    commit_folder,
    write_drive_files,
)
from guardrail_core.errors import (
    DriveFormatError,
    ImportSourceError,
    InvalidOptionError,
    MissingCalibrationError,
    MissingGpsTimeError,
    OutputExistsError,
    SourceFormatError,
    TrajectoryCoverageError,
)
from guardrail_core.geometry import make_transform
from guardrail_core.importers.calibration import (
    mount_transform,
    read_calibrations,
    read_structured_file,
    require_file,
)
from guardrail_core.io.las import SCALE_M
from guardrail_core.scanner_model import ScannerParams, scanner_mounting
from guardrail_core.trajectory import Trajectory

PathLike = str | os.PathLike

#: Height of the trajectory's reference point above the road, as the simulator's vehicle has it.
DEFAULT_REFERENCE_HEIGHT_M = 1.8
#: x and y of the drive origin are the points' bounding-box centre rounded to this; z to 1 m.
ORIGIN_ROUNDING_M = 100.0
#: LAS stores coordinates as int32 multiples of the scale around the origin (about 214 km).
MAX_EXTENT_M = 0.95 * (2**31 - 1) * SCALE_M
IMAGE_COLUMNS = ("file", "camera", "gps_time")
GPS_WEEK_S = 604_800.0
#: Adjusted standard GPS time = standard GPS time - 1e9 s, and 1e9 s = 1653 weeks + 265600 s.
ADJUSTED_STANDARD_WEEK_OFFSET_S = 1e9 % GPS_WEEK_S
#: A point is off the scanner's measurement grid when its time lies further than this (in
#: measurement intervals) from the nearest pulse; more than OFF_GRID_NOTE_FRACTION such points
#: suggest wrong scanner rates or epoch.
OFF_GRID_TOLERANCE = 0.25
OFF_GRID_NOTE_FRACTION = 0.05
#: GeoTIFF keys of the EPSG codes a LAS header may carry.
_PROJECTED_CRS_KEY, _GEOGRAPHIC_CRS_KEY, _VERTICAL_CRS_KEY = 3072, 2048, 4096
_SCANNER_FLOAT_KEYS = ("range_noise_m", "min_range_m", "max_range_m")


@dataclass(frozen=True)
class LasImport:
    """What :func:`import_las_delivery` wrote.

    Attributes
    ----------
    out : the drive folder
    n_points, n_images : int
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
    cameras: list[str]
    crs: str
    crs_from: str
    origin: np.ndarray
    scanner: ScannerParams
    off_grid_fraction: float
    notes: list[str]


# ----------------------------------------------------------------------------------- CSV files


def _read_table(path: Path, what: str, required: Sequence[str]) -> tuple[list[list[str]], dict]:
    """Rows of a delimited text file with a header naming ``required`` (any order, any case).

    The delimiter is a comma, semicolon or tab (whichever the header holds), else white space;
    blank lines and lines starting with ``#`` are skipped. Returns the data rows (with their line
    numbers as the first field) and the column index of every required name.
    """
    require_file(path, what)
    try:
        lines = [
            (number, line.strip())
            for number, line in enumerate(path.read_text().splitlines(), start=1)
            if line.strip() and not line.lstrip().startswith("#")
        ]
    except UnicodeDecodeError as exc:
        raise SourceFormatError(f"{path}: {what} is not a text file ({exc})") from exc
    if not lines:
        raise SourceFormatError(f"{path}: {what} is empty (expected a header {','.join(required)})")
    header_line = lines[0][1]
    delimiter = next((d for d in (",", ";", "\t") if d in header_line), None)
    texts = [line for _, line in lines]
    split = (
        (line.split() for line in texts)
        if delimiter is None
        else (
            [field.strip() for field in fields] for fields in csv.reader(texts, delimiter=delimiter)
        )
    )
    header = [name.strip().lower() for name in next(split)]
    missing = [name for name in required if name not in header]
    doubled = sorted({name for name in required if header.count(name) > 1})
    if missing or doubled:
        problem = f"lacks the columns {missing}" if missing else f"repeats the columns {doubled}"
        raise SourceFormatError(
            f"{path}: the header {header_line!r} {problem}; a {what} needs a header naming "
            f"{', '.join(required)} (any order)"
        )
    rows = []
    for (number, _), fields in zip(lines[1:], split, strict=True):
        if len(fields) != len(header):
            raise SourceFormatError(
                f"{path}, line {number}: {len(fields)} fields where the header has {len(header)}"
            )
        rows.append([str(number), *fields])
    return rows, {name: header.index(name) + 1 for name in required}


def read_trajectory_table(path: PathLike, *, degrees: bool = False) -> np.ndarray:
    """A delivery's trajectory CSV as (N, 7) float64: time (GPS s), x, y, z (map, metres), roll,
    pitch, yaw (radians; converted from degrees when ``degrees``).

    Raises
    ------
    MissingSourceFileError
        The file is missing.
    SourceFormatError
        A column is missing, a value is not a finite number, there are fewer than 2 rows, times
        do not increase, or the attitude looks like degrees without ``degrees``.
    """
    path = Path(path)
    rows, column = _read_table(path, "trajectory", TRAJECTORY_COLUMNS)
    data = np.empty((len(rows), 7))
    for i, row in enumerate(rows):
        try:
            data[i] = [float(row[column[name]]) for name in TRAJECTORY_COLUMNS]
        except ValueError as exc:
            raise SourceFormatError(f"{path}, line {row[0]}: not a number ({exc})") from exc
        if not np.all(np.isfinite(data[i])):
            raise SourceFormatError(f"{path}, line {row[0]}: NaN or infinity")
    if len(data) < 2:
        raise SourceFormatError(f"{path}: a trajectory needs at least 2 rows, got {len(data)}")
    steps = np.flatnonzero(np.diff(data[:, 0]) <= 0)
    if len(steps):
        raise SourceFormatError(
            f"{path}, line {rows[steps[0] + 1][0]}: time {data[steps[0] + 1, 0]:.6f} does not "
            f"follow {data[steps[0], 0]:.6f}; times must be strictly increasing"
        )
    if degrees:
        data[:, 4:7] = np.deg2rad(data[:, 4:7])
    else:
        tilt = float(np.abs(data[:, 4:6]).max())
        if tilt > math.pi / 2:  # a road vehicle never rolls or pitches past 90 degrees
            raise SourceFormatError(
                f"{path}: roll or pitch reaches {tilt:.3f}, more than pi/2 radians; if the "
                "attitude is in degrees, say so (--trajectory-degrees)"
            )
    return data


@dataclass(frozen=True)
class _SourceImage:
    path: Path
    camera: str
    gps_time: float
    line: str


def read_image_list(path: PathLike) -> list[_SourceImage]:
    """The image list CSV: ``file`` (relative to the CSV's folder, or absolute), ``camera`` and
    ``gps_time`` (GPS s, the trajectory's time system) columns, in any order.

    Raises
    ------
    MissingSourceFileError, SourceFormatError
    """
    path = Path(path)
    rows, column = _read_table(path, "image list", IMAGE_COLUMNS)
    images = []
    for row in rows:
        file, camera = row[column["file"]], row[column["camera"]]
        try:
            gps_time = float(row[column["gps_time"]])
        except ValueError as exc:
            raise SourceFormatError(f"{path}, line {row[0]}: gps_time is not a number") from exc
        if not file or not camera or not math.isfinite(gps_time):
            raise SourceFormatError(
                f"{path}, line {row[0]}: needs a file, a camera and a finite gps_time"
            )
        source = Path(file) if Path(file).is_absolute() else path.parent / file
        images.append(_SourceImage(source, camera, gps_time, row[0]))
    return images


# ---------------------------------------------------------------------------------- LAS files


def las_crs(las: laspy.LasData) -> str | None:
    """The CRS a LAS file declares, as a string, without pyproj.

    An OGC WKT record (LAS 1.4) gives ``EPSG:<code>`` when its outermost element ends in an EPSG
    authority, else the WKT itself; GeoTIFF keys give ``EPSG:<projected or geographic code>``,
    ``+<vertical code>`` when a vertical CRS is named too. ``None`` when the file has neither.
    """
    records = list(las.header.vlrs) + list(getattr(las.header, "evlrs", None) or [])
    for record in records:
        if isinstance(record, WktCoordinateSystemVlr) and record.string.strip("\0 \n"):
            wkt = " ".join(record.string.strip("\0").split())
            match = re.search(
                r'(?:AUTHORITY|ID)\[\s*"EPSG"\s*,\s*"?(\d+)"?\s*\]\s*\]\s*$', wkt, re.IGNORECASE
            )
            return f"EPSG:{match.group(1)}" if match else wkt
    for record in records:
        if isinstance(record, GeoKeyDirectoryVlr):
            # Codes 1024..32766 are EPSG codes; 32767 is "user-defined", not passable as a string.
            codes = {
                key.id: key.value_offset
                for key in record.geo_keys
                if key.tiff_tag_location == 0 and 1024 <= key.value_offset <= 32766
            }
            horizontal = codes.get(_PROJECTED_CRS_KEY, codes.get(_GEOGRAPHIC_CRS_KEY))
            if horizontal is not None:
                vertical = codes.get(_VERTICAL_CRS_KEY)
                return f"EPSG:{horizontal}" + (f"+{vertical}" if vertical else "")
    return None


@dataclass(frozen=True)
class _Points:
    xyz: np.ndarray  # (N, 3) float64 map coordinates
    gps_time: np.ndarray  # (N,) float64
    intensity: np.ndarray  # (N,) uint16
    crs: str | None
    standard_time: bool  # a header declared (adjusted) standard GPS time


def read_delivery_points(paths: Sequence[PathLike]) -> _Points:
    """Read and concatenate LAS/LAZ files (any point format with ``gps_time``).

    Raises
    ------
    MissingSourceFileError, SourceFormatError
        A file is missing, is not LAS, has no points, non-finite times, or files name different
        CRSs.
    MissingGpsTimeError
        A file's point format has no ``gps_time``.
    """
    xyz, times, intensity, crss, standard = [], [], [], {}, False
    for name in paths:
        path = require_file(name, "point cloud")
        try:
            las = laspy.read(str(path))
        except (laspy.errors.LaspyException, OSError, ValueError) as exc:
            raise SourceFormatError(f"{path}: not a readable LAS/LAZ file ({exc})") from exc
        dimensions = set(las.point_format.dimension_names)
        if "gps_time" not in dimensions:
            raise MissingGpsTimeError(
                f"{path}: LAS point format {las.point_format.id} has no gps_time, so its points "
                "cannot be placed on the trajectory or the scan lattice; export the cloud with a "
                "point format that has it (1, 3-10)"
            )
        gps_time = np.asarray(las.gps_time, np.float64)
        if not np.all(np.isfinite(gps_time)):
            raise SourceFormatError(
                f"{path}: {int((~np.isfinite(gps_time)).sum())} points have a non-finite gps_time"
            )
        if len(gps_time) and not np.any(gps_time):
            raise MissingGpsTimeError(f"{path}: gps_time is zero on every point (never filled in)")
        xyz.append(np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)]))
        times.append(gps_time)
        intensity.append(
            np.asarray(las.intensity, np.uint16)
            if "intensity" in dimensions
            else np.zeros(len(gps_time), np.uint16)
        )
        crs = las_crs(las)
        if crs is not None:
            crss[str(path)] = crs
        standard |= bool(
            las.header.global_encoding.gps_time_type == laspy.header.GpsTimeType.STANDARD
        )
    points = _Points(
        np.concatenate(xyz).astype(np.float64, copy=False),
        np.concatenate(times),
        np.concatenate(intensity),
        next(iter(crss.values()), None),
        standard,
    )
    if len(points.gps_time) == 0:
        raise SourceFormatError(f"{', '.join(str(p) for p in paths)}: no points")
    if len(set(crss.values())) > 1:
        raise SourceFormatError(
            "the point clouds declare different CRSs: "
            + "; ".join(f"{path}: {crs}" for path, crs in crss.items())
        )
    return points


def to_week_seconds(
    gps_time: np.ndarray, span: tuple[float, float], standard_declared: bool
) -> tuple[np.ndarray, str | None]:
    """Point times in the trajectory's time system (N,) float64, and a note if they were converted.

    The drive format counts GPS seconds of the week. Many LAS 1.4 files carry (adjusted) standard
    GPS time instead. When the trajectory is in seconds of the week and the points' times cannot
    be, they are reduced modulo a week: adjusted standard time (below 1e9 s) first gets its 1e9 s
    back. A delivery across the week's end (Sunday 00:00 GPS) cannot be converted this way.
    """
    inside = gps_time.min() >= span[0] and gps_time.max() <= span[1]
    if inside or gps_time.min() < GPS_WEEK_S or span[1] > GPS_WEEK_S:
        return gps_time, None
    # Added before the modulo so the sum stays near 4e8 s, where float64 resolves 60 ns.
    adjusted = gps_time < 1e9
    week = np.mod(gps_time + np.where(adjusted, ADJUSTED_STANDARD_WEEK_OFFSET_S, 0.0), GPS_WEEK_S)
    kind = "adjusted standard" if adjusted.all() else "standard"
    declared = "" if standard_declared else " (the LAS header says week time, its values do not)"
    return week, f"point times converted from {kind} GPS time to seconds of the week{declared}"


def _check_coverage(times: np.ndarray, trajectory: np.ndarray, what: str, where: str) -> None:
    t_lo, t_hi = float(trajectory[0, 0]), float(trajectory[-1, 0])
    lo, hi = float(times.min()), float(times.max())
    if lo < t_lo or hi > t_hi:
        outside = int(((times < t_lo) | (times > t_hi)).sum())
        raise TrajectoryCoverageError(
            f"{where}: {what} span GPS time {lo:.6f}..{hi:.6f} s but the trajectory covers only "
            f"{t_lo:.6f}..{t_hi:.6f} s ({outside:,} of {len(times):,} {what} outside); a "
            "trajectory must cover every point and image"
        )


def drive_origin(xyz: np.ndarray) -> np.ndarray:
    """The local origin (3,) float64 for map points (N, 3): the bounding-box centre, x and y
    rounded to :data:`ORIGIN_ROUNDING_M`, z to 1 m, so local coordinates are small and round."""
    centre = (xyz.min(axis=0) + xyz.max(axis=0)) / 2
    origin = np.round(centre / ORIGIN_ROUNDING_M) * ORIGIN_ROUNDING_M
    origin[2] = np.round(centre[2])
    reach = float(np.abs(xyz - origin).max())
    if reach > MAX_EXTENT_M:
        raise ImportSourceError(
            f"points reach {reach / 1000:.0f} km from the drive origin; a drive's LAS file holds "
            f"at most {MAX_EXTENT_M / 1000:.0f} km either way: split the delivery"
        )
    return origin


# ----------------------------------------------------------------------------------- scanner


def read_scanner_file(path: PathLike) -> dict:
    """Scanner parameters from JSON or YAML: the keys of ``ScannerParams.to_json`` (a drive's
    ``drive.json`` works too: its ``scanner`` block is used)."""
    path = Path(path)
    data = read_structured_file(path, "scanner parameters")
    if isinstance(data, Mapping) and isinstance(data.get("scanner"), Mapping):
        data = data["scanner"]
    if not isinstance(data, Mapping):
        raise SourceFormatError(f"{path}: expected a mapping of scanner parameters")
    return dict(data)


def scanner_params(fields: Mapping, first_gps_time: float, where: str = "scanner") -> ScannerParams:
    """:class:`ScannerParams` of a profile scanner from a mapping of its fields.

    ``rotations_per_second`` and ``measurements_per_second`` (Hz) are required. ``t0`` (GPS s)
    defaults to ``first_gps_time`` rounded down to a whole second: the epoch of a scanner whose
    mirror is synchronised to the GPS pulse per second (and whose rotations per second are whole).
    ``T_vehicle_scanner`` is 16 or 6 numbers (:func:`mount_transform`), default the simulator's
    mount. ``range_noise_m``, ``min_range_m``, ``max_range_m`` default to ScannerParams'.
    """
    kind = str(fields.get("kind", "profile"))
    if kind != "profile":
        raise SourceFormatError(
            f"{where}: a {kind} scanner's lattice does not follow from GPS time; a LAS delivery "
            "needs a profile scanner (kind: profile)"
        )
    missing = [
        key
        for key in ("rotations_per_second", "measurements_per_second")
        if fields.get(key) is None
    ]
    if missing:
        raise InvalidOptionError(
            f"{where}: the scan lattice needs the scanner's {' and '.join(missing)}; give them "
            "in a scanner file (--scanner) or as --rotations-per-second and "
            "--measurements-per-second"
        )
    try:
        rotations = float(fields["rotations_per_second"])
        measurements = float(fields["measurements_per_second"])
        t0 = fields.get("t0")
        epoch = float(t0) if t0 is not None else float(math.floor(first_gps_time))
        # Absent ranges keep ScannerParams' defaults (class attributes of the dataclass).
        ranges = {k: float(fields.get(k, getattr(ScannerParams, k))) for k in _SCANNER_FLOAT_KEYS}
    except (TypeError, ValueError) as exc:
        raise SourceFormatError(f"{where}: a scanner parameter is not a number ({exc})") from exc
    mount = fields.get("T_vehicle_scanner")
    transform = (
        scanner_mounting()
        if mount is None
        else mount_transform(mount, f"{where}: T_vehicle_scanner")
    )
    try:
        return ScannerParams(
            rotations_per_second=rotations,
            measurements_per_second=measurements,
            t0=epoch,
            range_noise_m=ranges["range_noise_m"],
            min_range_m=ranges["min_range_m"],
            max_range_m=ranges["max_range_m"],
            T_vehicle_scanner=transform,
        )
    except DriveFormatError as exc:
        raise SourceFormatError(f"{where}: {exc}") from exc


def _lattice(scanner: ScannerParams, gps_time: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Rotation (N,), phase (N,) and the share of points off the pulse grid."""
    rotation, phase = scanner.lattice_from_gps_time(gps_time)
    if rotation.min() < 0 or rotation.max() >= 2**32:
        raise InvalidOptionError(
            f"scanner t0 {scanner.t0:.6f} s gives rotations {int(rotation.min())}.."
            f"{int(rotation.max())}: the epoch must lie at or before the first point "
            f"({float(gps_time.min()):.6f} s) and within 2^32 rotations of the last"
        )
    pulses = (gps_time - scanner.t0) * scanner.measurements_per_second
    off_grid = float(np.mean(np.abs(pulses - np.rint(pulses)) > OFF_GRID_TOLERANCE))
    return rotation, phase, off_grid


# ------------------------------------------------------------------------------------ images


def _check_images(images: list[_SourceImage], cameras: dict[str, Camera], where: Path) -> None:
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
    images: list[_SourceImage],
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


# -------------------------------------------------------------------------------------- import


def _check_output(out: Path, overwrite: bool, inputs: list[Path]) -> None:
    """Refuse an output that exists (before any heavy reading) or that holds an input."""
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out}: exists and is not a folder")
    if out.exists() and any(out.iterdir()):
        if not overwrite:
            raise OutputExistsError(
                f"{out}: exists and is not empty (use --overwrite to replace it)"
            )
        _refuse_inputs_inside(out, inputs)


def _refuse_inputs_inside(out: Path, inputs: list[Path]) -> None:
    """Replacing ``out`` must not delete an input."""
    if not out.exists():
        return
    resolved = out.resolve()
    for path in inputs:
        if resolved in path.resolve().parents:
            raise InvalidOptionError(
                f"{out}: holds the input {path}; replacing it would delete the input"
            )


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
    compress: bool = True,
    overwrite: bool = False,
    progress: bool = False,
) -> LasImport:
    """Import a LAS/LAZ delivery into the drive folder ``out``.

    Parameters
    ----------
    points : one LAS/LAZ file or several (concatenated), any point format with ``gps_time``
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
    compress : write ``points.laz`` (True) or ``points.las``
    progress : show a progress bar while copying images

    Returns
    -------
    LasImport
        What was written, and notes worth telling the user.

    Raises
    ------
    MissingSourceFileError, SourceFormatError, MissingGpsTimeError, TrajectoryCoverageError,
    MissingCalibrationError, ImportSourceError
        Each names the input file and what is wrong; nothing is written.
    InvalidOptionError
        Scanner rates missing, or an epoch ``t0`` after the first point.
    OutputExistsError
        ``out`` is not empty and ``overwrite`` is False.
    """
    out = Path(out)
    point_paths = (
        [Path(points)] if isinstance(points, str | os.PathLike) else [Path(p) for p in points]
    )
    if not point_paths:
        raise InvalidOptionError("no point cloud given")
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
    _check_output(out, overwrite, inputs)
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
        _refuse_inputs_inside(out, [image.path for image in source_images])
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
        _check_coverage(
            np.array([i.gps_time for i in source_images]), table, "images", str(images_csv)
        )

    cloud = read_delivery_points(point_paths)
    gps_time, converted = to_week_seconds(
        cloud.gps_time, (float(table[0, 0]), float(table[-1, 0])), cloud.standard_time
    )
    if converted:
        notes.append(converted)
    _check_coverage(gps_time, table, "points", ", ".join(str(p) for p in point_paths))
    order = np.argsort(gps_time, kind="stable")  # the drive's points are ordered by GPS time
    gps_time = gps_time[order]
    origin = drive_origin(cloud.xyz)

    if scanner_fields is not None:
        params = scanner_params(scanner_fields, float(gps_time[0]), scanner_where)
    elif isinstance(scanner, ScannerParams):
        params = scanner
    else:
        raise InvalidOptionError(
            f"scanner: expected ScannerParams, a mapping or a file, got {scanner!r}"
        )
    rotation, phase, off_grid = _lattice(params, gps_time)
    if off_grid > OFF_GRID_NOTE_FRACTION:
        notes.append(
            f"{100 * off_grid:.0f}% of the points' times lie off the scanner's pulse grid "
            f"({params.measurements_per_second:g} Hz from t0 {params.t0:.6f} s): check the "
            "scanner's rates and epoch, or the lattice joins points that are not neighbours"
        )

    if crs is not None:
        crs_from = "--crs option"
        if cloud.crs is not None and cloud.crs != crs:
            notes.append(f"--crs {crs} replaces the CRS the LAS file declares ({cloud.crs})")
    elif cloud.crs is not None:
        crs, crs_from = cloud.crs, "LAS file"
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
    point_cloud = PointCloud(
        xyz=cloud.xyz[order] - origin,
        gps_time=gps_time,
        intensity=cloud.intensity[order],
        rotation=rotation,
        phase=phase,
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
    }

    with atomic_folder(out, overwrite=overwrite) as staging_name:
        staging = Path(staging_name)
        for source_path, record in tqdm(
            images, desc="copying images", unit="image", disable=not progress, leave=False
        ):
            (staging / record.file).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(source_path, staging / record.file)
        write_drive_files(
            staging,
            crs=crs,
            origin=origin,
            scanner=params,
            trajectory=local_trajectory,
            points=point_cloud,
            cameras=list(cameras.values()),
            images=[record for _, record in images],
            truth=None,
            source=source,
            compress=compress,
        )
        commit_folder(staging, out)
    return LasImport(
        out=out,
        n_points=len(point_cloud),
        n_images=len(images),
        cameras=list(cameras),
        crs=crs,
        crs_from=crs_from,
        origin=origin,
        scanner=params,
        off_grid_fraction=off_grid,
        notes=notes,
    )
