"""A drive's point files as the LAS export reads them: as they are, with every dimension, one
tile at a time.

The export needs the drive's CRS, origin and point files and nothing else, so it reads
``drive.json`` and the tile index (``points/index.json``, drive format 2.x) rather than opening
the whole drive with ``open_drive``, which would also demand the trajectory, cameras and images.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import laspy
import numpy as np

from guardrail_core.errors import DriveDimensionError, DriveFormatError, MissingDriveFileError
from guardrail_core.formats.drive import FORMAT_NAME, check_format_version
from guardrail_core.formats.drive_tiles import read_tile_index
from guardrail_core.io.las import LAS_READ_ERRORS


@dataclass(frozen=True)
class PointFile:
    """One point tile of a drive: its file and the number of points the drive says it holds."""

    path: Path
    points: int


@dataclass(frozen=True)
class DrivePoints:
    """What the export reads of a drive.

    Attributes
    ----------
    crs : the drive's ``crs``
    origin : (3,) float64, map coordinates of the local frame
    files : the point tiles in time order
    """

    crs: str
    origin: np.ndarray
    files: tuple[PointFile, ...]

    def starts(self) -> np.ndarray:
        """(T + 1,) int64: the drive-wide index of each tile's first point, then the total."""
        return np.concatenate([[0], np.cumsum([f.points for f in self.files])]).astype(np.int64)


def read_drive_points(root: Path) -> DrivePoints:
    """The CRS, origin and point tiles of the drive folder ``root``, every tile checked present.

    Raises
    ------
    MissingDriveFileError
        No ``drive.json`` (the message names ``--drive``), no tile index, or a tile is missing.
    DriveFormatError, TimestampMismatchError
        ``drive.json`` or the tile index is malformed, or of a major version this reader does
        not read.
    """
    path = root / "drive.json"
    if not path.is_file():
        raise MissingDriveFileError(
            f"{root}: not a drive folder (no drive.json); give the run's drive with --drive"
        )
    try:
        meta = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DriveFormatError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(meta, dict) or meta.get("format") != FORMAT_NAME:
        raise DriveFormatError(f"{path}: not a {FORMAT_NAME} description")
    check_format_version(meta, path)
    try:
        crs = str(meta["crs"])
        origin = np.asarray(meta["origin"], np.float64)
        points = str(meta["files"]["points"])
    except (KeyError, TypeError, ValueError) as exc:
        raise DriveFormatError(f"{path}: lacks the key or value {exc}") from exc
    if origin.shape != (3,) or not np.all(np.isfinite(origin)):
        raise DriveFormatError(f"{path}: origin must be three finite numbers")
    index = read_tile_index(root, points)
    if not index.tiles:
        raise DriveFormatError(f"{root / points}: lists no tiles")
    files = tuple(PointFile(root / t.file, t.points) for t in index.tiles)
    for file in files:  # before any work, not after an hour of it
        if not file.path.is_file():
            raise MissingDriveFileError(
                f"{file.path.parent}: point tile {file.path.name!r} is missing"
            )
    return DrivePoints(crs, origin, files)


def read_point_file(file: PointFile) -> laspy.LasData:
    """A point tile as it is (every dimension), with as many points as the drive says.

    Raises
    ------
    DriveFormatError
        Not LAS.
    DriveDimensionError
        Another number of points than the tile index gives, or no ``gps_time``.
    """
    try:
        las = laspy.read(str(file.path))
    except LAS_READ_ERRORS as exc:
        raise DriveFormatError(f"{file.path}: not a readable LAS/LAZ file ({exc})") from exc
    if len(las.points) != file.points:
        raise DriveDimensionError(
            f"{file.path}: holds {len(las.points)} points, the tile index says {file.points}"
        )
    if "gps_time" not in las.point_format.dimension_names:
        raise DriveDimensionError(
            f"{file.path}: point format {las.point_format.id} has no gps_time; the drive format "
            "needs a GPS time on every point"
        )
    return las
