"""Reading a LAS/LAZ delivery's files: the trajectory and image-list CSVs and the point clouds,
with their times brought to the drive's seconds of the GPS week and their coordinates to a local
origin. The formats are documented in ``docs/import.md``; every reader names the file and line
of what is wrong (:class:`~guardrail_core.errors.ImportSourceError` subclasses).

A delivery's points are never read whole: :func:`scan_delivery` reads each file's header and its
first and last point, and :func:`read_time_ordered` streams the points of all files in GPS-time
order, chunk by chunk (laspy's chunked reading).
"""

from __future__ import annotations

import csv
import math
import os
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import laspy
import numpy as np
from laspy.vlrs.known import GeoKeyDirectoryVlr, WktCoordinateSystemVlr

from guardrail_core.errors import (
    ImportSourceError,
    MissingGpsTimeError,
    PointsOutOfTimeOrderError,
    SourceFormatError,
    TrajectoryCoverageError,
)
from guardrail_core.formats.drive import TRAJECTORY_COLUMNS
from guardrail_core.importers.calibration import require_file
from guardrail_core.io.las import LAS_READ_ERRORS, SCALE_M

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


def las_crs(header: laspy.LasHeader) -> str | None:
    """The CRS a LAS header declares, as a string, without pyproj.

    An OGC WKT record (LAS 1.4) gives ``EPSG:<code>`` when its outermost element ends in an EPSG
    authority, else the WKT itself; GeoTIFF keys give ``EPSG:<projected or geographic code>``,
    ``+<vertical code>`` when a vertical CRS is named too. ``None`` when the file has neither.
    """
    records = list(header.vlrs) + list(getattr(header, "evlrs", None) or [])
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
class DeliveryFile:
    """One LAS/LAZ file of a delivery, as its header and its first and last points describe it.

    Attributes
    ----------
    path : the file
    given : its position among the files as given (orders files that start at the same time)
    points : int, point count from the header
    bounds_min, bounds_max : (3,) float64 map coordinates from the header
    first_time, last_time : float, GPS s (as recorded) of its first and last point; the bounds of
        all its times once :func:`read_time_ordered` has checked that they do not decrease
    crs : the CRS it declares (:func:`las_crs`), or None
    standard_time : its header declares (adjusted) standard GPS time
    """

    path: Path
    given: int
    points: int
    bounds_min: np.ndarray
    bounds_max: np.ndarray
    first_time: float
    last_time: float
    crs: str | None
    standard_time: bool


#: Why a file out of time order is refused, and what to do.
_SORT_ADVICE = (
    "the importer streams each file in the order its points are stored, which must be GPS-time "
    "order (as a mobile-mapping system records them): sort the file by time first (e.g. "
    "LAStools' lassort -gps_time)"
)


def _point_time(reader: laspy.LasReader, index: int) -> float:
    reader.seek(index)
    return float(reader.read_points(1).gps_time[0])


def scan_delivery_file(path: PathLike, given: int = 0) -> DeliveryFile:
    """Describe a delivery's LAS/LAZ file from its header and its first and last points, without
    reading the others (a seek, also in LAZ through its chunk table).

    Raises
    ------
    MissingSourceFileError, SourceFormatError
        The file is missing, is not LAS/LAZ, or its first or last time is not finite.
    MissingGpsTimeError
        Its point format has no ``gps_time``, or the time is zero at its first and last point.
    PointsOutOfTimeOrderError
        Its last point is earlier than its first.
    """
    path = require_file(path, "point cloud")
    try:
        with laspy.open(str(path)) as reader:
            header = reader.header
            has_time = "gps_time" in header.point_format.dimension_names
            count = int(header.point_count)
            times = (
                (_point_time(reader, 0), _point_time(reader, count - 1))
                if has_time and count
                else (0.0, 0.0)
            )
    except LAS_READ_ERRORS as exc:
        raise SourceFormatError(f"{path}: not a readable LAS/LAZ file ({exc})") from exc
    if not has_time:
        raise MissingGpsTimeError(
            f"{path}: LAS point format {header.point_format.id} has no gps_time, so its points "
            "cannot be placed on the trajectory or the scan lattice; export the cloud with a "
            "point format that has it (1, 3-10)"
        )
    if not all(math.isfinite(t) for t in times):
        raise SourceFormatError(f"{path}: its first or last point has a non-finite gps_time")
    scales, offsets = np.asarray(header.scales, np.float64), np.asarray(header.offsets, np.float64)
    if not (np.isfinite(scales).all() and (scales != 0).all() and np.isfinite(offsets).all()):
        # Every coordinate is integer * scale + offset: none of them would be a number.
        raise SourceFormatError(
            f"{path}: the header's coordinate scales {scales.tolist()} and offsets "
            f"{offsets.tolist()} must be finite numbers, the scales not zero"
        )
    if count and times == (0.0, 0.0):
        raise MissingGpsTimeError(
            f"{path}: gps_time is zero at its first and its last point (never filled in)"
        )
    if times[1] < times[0]:
        raise PointsOutOfTimeOrderError(
            f"{path}: its last point (GPS time {times[1]:.6f} s) is earlier than its first "
            f"({times[0]:.6f} s); {_SORT_ADVICE}"
        )
    return DeliveryFile(
        path=path,
        given=given,
        points=count,
        bounds_min=np.asarray(header.mins, np.float64),
        bounds_max=np.asarray(header.maxs, np.float64),
        first_time=times[0],
        last_time=times[1],
        crs=las_crs(header),
        standard_time=header.global_encoding.gps_time_type == laspy.header.GpsTimeType.STANDARD,
    )


def scan_delivery(paths: Sequence[PathLike]) -> list[DeliveryFile]:
    """:func:`scan_delivery_file` of every file, in the order given.

    Raises
    ------
    MissingSourceFileError, SourceFormatError, MissingGpsTimeError
        As :func:`scan_delivery_file`; also when the files hold no point at all or declare
        different CRSs.
    """
    files = [scan_delivery_file(path, given) for given, path in enumerate(paths)]
    if sum(f.points for f in files) == 0:
        raise SourceFormatError(f"{', '.join(str(p) for p in paths)}: no points")
    crss = {str(f.path): f.crs for f in files if f.crs is not None}
    if len(set(crss.values())) > 1:
        raise SourceFormatError(
            "the point clouds declare different CRSs: "
            + "; ".join(f"{path}: {crs}" for path, crs in crss.items())
        )
    return files


@dataclass(frozen=True)
class DeliveryChunk:
    """Points of a delivery ordered by GPS time.

    Attributes
    ----------
    xyz : (N, 3) float64 map coordinates, metres
    gps_time : (N,) float64 seconds, as recorded
    intensity : (N,) uint16
    """

    xyz: np.ndarray
    gps_time: np.ndarray
    intensity: np.ndarray

    def __len__(self) -> int:
        return len(self.gps_time)

    def split(self, cut: int) -> tuple[DeliveryChunk, DeliveryChunk]:
        """The first ``cut`` points and the rest."""
        head = DeliveryChunk(self.xyz[:cut], self.gps_time[:cut], self.intensity[:cut])
        tail = DeliveryChunk(self.xyz[cut:], self.gps_time[cut:], self.intensity[cut:])
        return head, tail

    @staticmethod
    def join(chunks: Sequence[DeliveryChunk]) -> DeliveryChunk:
        """The chunks' points one after the other (``chunks`` not empty)."""
        if len(chunks) == 1:
            return chunks[0]
        return DeliveryChunk(
            np.concatenate([c.xyz for c in chunks]),
            np.concatenate([c.gps_time for c in chunks]),
            np.concatenate([c.intensity for c in chunks]),
        )


_NO_POINTS = DeliveryChunk(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.uint16))


def _check_time_order(path: Path, gps_time: np.ndarray, previous: float, start: int) -> None:
    """Raise unless ``gps_time`` (the points from number ``start`` on) follows ``previous`` and
    never decreases."""
    times = np.concatenate([[previous], gps_time])
    back = np.flatnonzero(np.diff(times) < 0)
    if back.size:
        i = int(back[0])
        raise PointsOutOfTimeOrderError(
            f"{path}: point {start + i:,} (GPS time {times[i + 1]:.6f} s) comes after a point at "
            f"{times[i]:.6f} s; {_SORT_ADVICE}"
        )


def read_file_chunks(file: DeliveryFile, chunk_points: int) -> Iterator[DeliveryChunk]:
    """The points of ``file`` in chunks of ``chunk_points`` (laspy's chunked reading): only one
    chunk is in memory at a time.

    Raises
    ------
    SourceFormatError
        A chunk cannot be read or holds a non-finite time.
    PointsOutOfTimeOrderError
        A point's time is earlier than the time of the point before it.
    """
    with laspy.open(str(file.path)) as reader:
        chunks = reader.chunk_iterator(chunk_points)
        start, previous = 0, -math.inf
        while True:
            try:
                points = next(chunks)
            except StopIteration:
                return
            except LAS_READ_ERRORS as exc:
                raise SourceFormatError(
                    f"{file.path}: the points from number {start:,} on cannot be read ({exc})"
                ) from exc
            if len(points) == 0:
                return
            gps_time = np.asarray(points.gps_time, np.float64)
            if not np.all(np.isfinite(gps_time)):
                raise SourceFormatError(
                    f"{file.path}: {int((~np.isfinite(gps_time)).sum())} points from number "
                    f"{start:,} on have a non-finite gps_time"
                )
            _check_time_order(file.path, gps_time, previous, start)
            names = points.point_format.dimension_names
            yield DeliveryChunk(
                np.column_stack([np.asarray(points.x), np.asarray(points.y), np.asarray(points.z)]),
                gps_time,
                np.asarray(points.intensity, np.uint16)
                if "intensity" in names
                else np.zeros(len(gps_time), np.uint16),
            )
            start, previous = start + len(gps_time), float(gps_time[-1])


class _FileStream:
    """One file being merged: its chunks, and the points read from it but not yet passed on."""

    def __init__(self, file: DeliveryFile, chunk_points: int) -> None:
        self.file = file
        self._chunks = read_file_chunks(file, chunk_points)
        self.pending = _NO_POINTS
        self.done = False

    def read_until_two_times(self) -> None:
        """Read on until the pending points span two distinct times (or the file ends), so that
        those before the last time can be passed on."""
        while not self.done and (
            len(self.pending) == 0 or self.pending.gps_time[0] == self.pending.gps_time[-1]
        ):
            chunk = next(self._chunks, None)
            if chunk is None:
                self.done = True
            else:
                self.pending = DeliveryChunk.join([p for p in (self.pending, chunk) if len(p)])

    @property
    def horizon(self) -> float:
        """Every point this file has yet to give lies at this time or later."""
        return math.inf if self.done else float(self.pending.gps_time[-1])

    def take_before(self, limit: float) -> DeliveryChunk:
        head, self.pending = self.pending.split(
            int(np.searchsorted(self.pending.gps_time, limit, side="left"))
        )
        return head


def read_time_ordered(files: Sequence[DeliveryFile], chunk_points: int) -> Iterator[DeliveryChunk]:
    """All points of the delivery ``files`` in GPS-time order, chunk by chunk, whatever the order
    the files come in.

    Each file must list its points in time order; files may overlap in time (spatial tiles of one
    pass, one file per scanner). Files are merged like sorted runs: a file is opened when the
    merge reaches its first time, and every open file holds about one chunk of pending points,
    so memory is ``chunk_points`` times the number of files that overlap in time, never the whole
    delivery. Points at equal times keep the order of their files (by first time, then as given)
    and their order within a file.

    Raises
    ------
    SourceFormatError, PointsOutOfTimeOrderError
        As :func:`read_file_chunks`.
    """
    waiting = sorted((f for f in files if f.points), key=lambda f: (f.first_time, f.given))
    open_streams: list[_FileStream] = []
    while waiting or open_streams:
        for stream in open_streams:
            stream.read_until_two_times()
        open_streams = [s for s in open_streams if len(s.pending)]
        horizon = min((s.horizon for s in open_streams), default=math.inf)
        if waiting and waiting[0].first_time <= horizon:  # it may hold points before the horizon
            open_streams.append(_FileStream(waiting.pop(0), chunk_points))
            open_streams.sort(key=lambda s: (s.file.first_time, s.file.given))
            continue
        # Every point before the horizon has been read: pass those on, in time order.
        parts = [s.take_before(horizon) for s in open_streams]
        parts = [p for p in parts if len(p)]
        if not parts:  # cannot happen: the file that sets the horizon has a point before it
            continue
        merged = DeliveryChunk.join(parts)
        if len(parts) > 1:
            order = np.argsort(merged.gps_time, kind="stable")
            merged = DeliveryChunk(
                merged.xyz[order], merged.gps_time[order], merged.intensity[order]
            )
        yield merged


def week_time_note(
    point_span: tuple[float, float], span: tuple[float, float], standard_declared: bool
) -> str | None:
    """Whether the points' times (first, last GPS s as recorded) need :func:`to_week_seconds` to
    fit the trajectory's ``span``: the note that says they were converted, or None.

    The drive format counts GPS seconds of the week. Many LAS 1.4 files carry (adjusted) standard
    GPS time instead. When the trajectory is in seconds of the week and the points' times cannot
    be, they are reduced modulo a week (:func:`to_week_seconds`). A delivery across the week's
    end (Sunday 00:00 GPS) cannot be converted this way.
    """
    lo, hi = point_span
    inside = lo >= span[0] and hi <= span[1]
    if inside or lo < GPS_WEEK_S or span[1] > GPS_WEEK_S:
        return None
    kind = "adjusted standard" if hi < 1e9 else "standard"
    declared = "" if standard_declared else " (the LAS header says week time, its values do not)"
    return f"point times converted from {kind} GPS time to seconds of the week{declared}"


def to_week_seconds(gps_time: np.ndarray) -> np.ndarray:
    """(Adjusted) standard GPS times (N,) s as seconds of the GPS week (N,) float64: adjusted
    standard time (below 1e9 s) first gets its 1e9 s back."""
    # Added before the modulo so the sum stays near 4e8 s, where float64 resolves 60 ns.
    adjusted = gps_time < 1e9
    return np.mod(gps_time + np.where(adjusted, ADJUSTED_STANDARD_WEEK_OFFSET_S, 0.0), GPS_WEEK_S)


def check_span(lo: float, hi: float, trajectory: np.ndarray, what: str, where: str) -> None:
    """Raise unless GPS times ``lo``..``hi`` lie within the trajectory's (N, 7) time span."""
    t_lo, t_hi = float(trajectory[0, 0]), float(trajectory[-1, 0])
    if lo < t_lo or hi > t_hi:
        raise TrajectoryCoverageError(
            f"{where}: {what} span GPS time {lo:.6f}..{hi:.6f} s but the trajectory covers only "
            f"{t_lo:.6f}..{t_hi:.6f} s; a trajectory must cover every point and image"
        )


def check_coverage(times: np.ndarray, trajectory: np.ndarray, what: str, where: str) -> None:
    """Raise unless every time (N,) GPS s lies within the trajectory's (N, 7) time span; the
    error counts those outside."""
    t_lo, t_hi = float(trajectory[0, 0]), float(trajectory[-1, 0])
    outside = int(((times < t_lo) | (times > t_hi)).sum())
    if outside:
        try:
            check_span(float(times.min()), float(times.max()), trajectory, what, where)
        except TrajectoryCoverageError as exc:
            raise TrajectoryCoverageError(
                f"{exc} ({outside:,} of {len(times):,} {what} outside)"
            ) from None


def drive_origin(bounds_min: np.ndarray, bounds_max: np.ndarray) -> np.ndarray:
    """The local origin (3,) float64 for map points within ``bounds_min``..``bounds_max`` (3,):
    the bounding-box centre, x and y rounded to :data:`ORIGIN_ROUNDING_M`, z to 1 m, so local
    coordinates are small and round.

    Raises
    ------
    ImportSourceError
        The box reaches further from the origin than a drive's LAS tiles can hold.
    """
    lo, hi = np.asarray(bounds_min, np.float64), np.asarray(bounds_max, np.float64)
    centre = (lo + hi) / 2
    origin = np.round(centre / ORIGIN_ROUNDING_M) * ORIGIN_ROUNDING_M
    origin[2] = np.round(centre[2])
    check_reach(np.stack([lo, hi]), origin)
    return origin


def check_reach(xyz: np.ndarray, origin: np.ndarray) -> None:
    """Raise unless map points (N, 3) lie within :data:`MAX_EXTENT_M` of ``origin`` (3,)."""
    reach = float(np.abs(xyz - origin).max(initial=0.0))
    if reach > MAX_EXTENT_M:
        raise ImportSourceError(
            f"points reach {reach / 1000:.0f} km from the drive origin; a drive's LAS file holds "
            f"at most {MAX_EXTENT_M / 1000:.0f} km either way: split the delivery"
        )
