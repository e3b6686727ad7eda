"""Point clouds as LAS 1.4 (laspy, LAZ through lazrs) with the scan lattice as extra dimensions.

Coordinates are stored as scaled integers (0.1 mm) with the drive's origin as the LAS offset, so
map coordinates keep their precision and points come back as float64 local coordinates.
"""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np

from guardrail_core.errors import DriveDimensionError, DriveFormatError, NonFiniteCoordinatesError

#: LAS point format 6: LAS 1.4's base format with gps_time.
POINT_FORMAT = 6
SCALE_M = 1e-4
LATTICE_DIMENSIONS = ("rotation", "phase")


def write_points(
    path: Path,
    xyz_local: np.ndarray,
    origin: np.ndarray,
    gps_time: np.ndarray,
    intensity: np.ndarray,
    rotation: np.ndarray,
    phase: np.ndarray,
) -> None:
    """Write points to LAS 1.4 (``.laz`` compressed, ``.las`` plain).

    Parameters
    ----------
    xyz_local : (N, 3) float64, metres relative to ``origin`` (3,) float64 map coordinates
    gps_time : (N,) float64, seconds
    intensity : (N,) uint16
    rotation, phase : (N,) integer scan lattice (§3.1)
    """
    header = laspy.LasHeader(point_format=POINT_FORMAT, version="1.4")
    header.offsets = np.asarray(origin, np.float64)
    header.scales = np.array([SCALE_M] * 3)
    header.add_extra_dims(
        [
            laspy.ExtraBytesParams("rotation", np.uint32, description="scan lattice: rotation"),
            laspy.ExtraBytesParams("phase", np.uint16, description="scan lattice: phase"),
        ]
    )
    las = laspy.LasData(header)
    world = np.asarray(xyz_local, np.float64) + np.asarray(origin, np.float64)
    las.x, las.y, las.z = world[:, 0], world[:, 1], world[:, 2]
    las.gps_time = np.asarray(gps_time, np.float64)
    las.intensity = np.asarray(intensity, np.uint16)
    las.return_number = np.ones(len(world), np.uint8)
    las.number_of_returns = np.ones(len(world), np.uint8)
    las.rotation = np.asarray(rotation, np.uint32)
    las.phase = np.asarray(phase, np.uint16)
    las.write(str(path))


#: What laspy and lazrs raise on a file that is not LAS/LAZ or is cut short (lazrs: RuntimeError).
LAS_READ_ERRORS = (laspy.errors.LaspyException, OSError, ValueError, RuntimeError)


def read_points(path: Path, origin: np.ndarray) -> dict[str, np.ndarray]:
    """Read a drive's LAS/LAZ file.

    Returns a dict with ``xyz`` (N, 3) float64 local metres, ``gps_time`` (N,) float64,
    ``intensity`` (N,) uint16, and ``rotation``, ``phase`` (N,) int64 where the file has them.

    Raises
    ------
    DriveFormatError
        The file is not LAS.
    DriveDimensionError
        The point format has no ``gps_time``.
    NonFiniteCoordinatesError
        Coordinates or times are NaN or infinite.
    """
    try:
        las = laspy.read(str(path))
    except LAS_READ_ERRORS as exc:
        raise DriveFormatError(f"{path}: not a readable LAS/LAZ file ({exc})") from exc
    names = set(las.point_format.dimension_names)
    if "gps_time" not in names:
        raise DriveDimensionError(
            f"{path}: point format {las.point_format.id} has no gps_time; the drive format needs a "
            "GPS time on every point (LAS point formats 1, 3, 5, 6-10)"
        )
    xyz = np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], axis=1)
    xyz -= np.asarray(origin, np.float64)
    gps_time = np.asarray(las.gps_time, np.float64)
    if not np.all(np.isfinite(xyz)):
        raise NonFiniteCoordinatesError(
            f"{path}: {int((~np.isfinite(xyz)).any(axis=1).sum())} points have non-finite coordinates"
        )
    if not np.all(np.isfinite(gps_time)):
        raise NonFiniteCoordinatesError(
            f"{path}: {int((~np.isfinite(gps_time)).sum())} points have a non-finite gps_time"
        )
    out = {"xyz": xyz, "gps_time": gps_time, "intensity": np.asarray(las.intensity, np.uint16)}
    for name in LATTICE_DIMENSIONS:
        if name in names:
            out[name] = np.asarray(las[name], np.int64)
    return out
