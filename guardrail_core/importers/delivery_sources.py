"""Reading a LAS/LAZ delivery's files: the trajectory and image-list CSVs and the point clouds,
with their times brought to the drive's seconds of the GPS week and their coordinates to a local
origin. The formats are documented in ``docs/import.md``; every reader names the file and line
of what is wrong (:class:`~guardrail_core.errors.ImportSourceError` subclasses).
"""

from __future__ import annotations

import csv
import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import laspy
import numpy as np
from laspy.vlrs.known import GeoKeyDirectoryVlr, WktCoordinateSystemVlr

from guardrail_core.errors import (
    ImportSourceError,
    MissingGpsTimeError,
    SourceFormatError,
    TrajectoryCoverageError,
)
from guardrail_core.formats.drive import TRAJECTORY_COLUMNS
from guardrail_core.importers.calibration import require_file
from guardrail_core.io.las import SCALE_M

PathLike = str | os.PathLike

#: x and y of the drive origin are the points' bounding-box centre rounded to this; z to 1 m.
ORIGIN_ROUNDING_M = 100.0
#: LAS stores coordinates as int32 multiples of the scale around the origin (about 214 km).
MAX_EXTENT_M = 0.95 * (2**31 - 1) * SCALE_M
IMAGE_COLUMNS = ("file", "camera", "gps_time")
GPS_WEEK_S = 604_800.0
#: Adjusted standard GPS time = standard GPS time - 1e9 s, and 1e9 s = 1653 weeks + 265600 s.
ADJUSTED_STANDARD_WEEK_OFFSET_S = 1e9 % GPS_WEEK_S
#: GeoTIFF keys of the EPSG codes a LAS header may carry.
_PROJECTED_CRS_KEY, _GEOGRAPHIC_CRS_KEY, _VERTICAL_CRS_KEY = 3072, 2048, 4096


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
class SourceImage:
    path: Path
    camera: str
    gps_time: float
    line: str


def read_image_list(path: PathLike) -> list[SourceImage]:
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
        images.append(SourceImage(source, camera, gps_time, row[0]))
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
class DeliveryPoints:
    xyz: np.ndarray  # (N, 3) float64 map coordinates
    gps_time: np.ndarray  # (N,) float64
    intensity: np.ndarray  # (N,) uint16
    crs: str | None
    standard_time: bool  # a header declared (adjusted) standard GPS time


def read_delivery_points(paths: Sequence[PathLike]) -> DeliveryPoints:
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
    points = DeliveryPoints(
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


def check_coverage(times: np.ndarray, trajectory: np.ndarray, what: str, where: str) -> None:
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
