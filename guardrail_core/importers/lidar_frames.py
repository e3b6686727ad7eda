"""One frame (one turn) of a spinning LiDAR from a file: PCD, LAS/LAZ or a KITTI ``.bin``.

PCD (ascii, binary or binary_compressed) is read by Open3D, LAS and LAZ by laspy; the fields
a frame may carry besides x, y, z, by the names drivers give them (the first found is taken):

=============  ==============================================================================
ring           ``ring``, ``channel``, ``laser_id``, ``laser_number``, ``beam``, ``line``
time           ``time``, ``timestamp``, ``t``, ``time_offset``, ``offset_time``; LAS
               ``gps_time``. Integers are nanoseconds, floats seconds; values from 1e5 s up are
               absolute, smaller ones offsets from the frame's time
intensity      ``intensity``, ``reflectivity``, ``signal``; scaled to 16 bits from its range
               (0-1, 0-255 or 0-65535)
=============  ==============================================================================

A KITTI ``.bin`` holds float32 x, y, z, reflectance (0-1) and nothing else. Points with a
non-finite coordinate (the holes of an organised cloud) and points at the origin (no return)
are dropped.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import laspy
import numpy as np

from guardrail_core.errors import MissingSourceFileError, SourceFormatError

RING_FIELDS = ("ring", "channel", "laser_id", "laser_number", "beam", "line")
TIME_FIELDS = ("time", "timestamp", "t", "time_offset", "offset_time", "gps_time")
INTENSITY_FIELDS = ("intensity", "reflectivity", "signal")
#: Point times from this many seconds up are absolute (GPS, Unix); below, offsets in the turn.
ABSOLUTE_TIME_S = 1e5
#: The file kinds read, by suffix.
FRAME_SUFFIXES = (".pcd", ".las", ".laz", ".bin")


@dataclass(frozen=True)
class LidarFrame:
    """The points of one turn, in the sensor's frame.

    Attributes
    ----------
    path : the file
    xyz : (N, 3) float64, metres, sensor frame (x forward, y left, z up)
    intensity : (N,) uint16
    ring : (N,) int64 as the file numbers its beams, or None without a ring field
    time : (N,) float64 seconds, or None without a time field
    time_is_offset : the times are offsets from the frame's time, not absolute
    """

    path: Path
    xyz: np.ndarray
    intensity: np.ndarray
    ring: np.ndarray | None
    time: np.ndarray | None
    time_is_offset: bool


def _first(fields: dict[str, np.ndarray], names: tuple[str, ...]) -> tuple[str, np.ndarray] | None:
    lowered = {name.lower(): name for name in fields}
    for name in names:
        if name in lowered:
            return lowered[name], np.asarray(fields[lowered[name]]).reshape(
                len(fields[lowered[name]]), -1
            )[:, 0]
    return None


def _intensity16(values: np.ndarray | None, n: int) -> np.ndarray:
    """(n,) uint16 from an intensity of any of the usual ranges (0 where there is none)."""
    if values is None:
        return np.zeros(n, np.uint16)
    v = np.nan_to_num(np.asarray(values, np.float64), nan=0.0)
    top = float(v.max(initial=0.0))
    scale = 65535.0 if top <= 1.0 else 257.0 if top <= 255.0 else 1.0
    return np.clip(np.rint(v * scale), 0, 65535).astype(np.uint16)


def _read_pcd(path: Path) -> dict[str, np.ndarray]:
    import open3d as o3d  # Open3D's import is slow; only a PCD needs it

    head = path.read_bytes()[:4096]
    if b"FIELDS" not in head or b"DATA" not in head:
        raise SourceFormatError(f"{path}: not a PCD file (no FIELDS or DATA line in its header)")
    cloud = o3d.t.io.read_point_cloud(os.fspath(path), remove_nan_points=False)  # type: ignore[arg-type]
    if "positions" not in cloud.point or len(cloud.point.positions) == 0:
        raise SourceFormatError(
            f"{path}: Open3D reads no points from this PCD (a damaged file, or fields other "
            "than x, y, z)"
        )
    fields = {name: cloud.point[name].numpy() for name in cloud.point}
    xyz = fields.pop("positions")
    return {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], **fields}


def _read_las(path: Path) -> dict[str, np.ndarray]:
    try:
        las = laspy.read(path)
    except (laspy.errors.LaspyException, OSError, ValueError) as exc:
        raise SourceFormatError(f"{path}: not a readable LAS/LAZ file ({exc})") from exc
    fields = {"x": np.asarray(las.x), "y": np.asarray(las.y), "z": np.asarray(las.z)}
    for name in las.point_format.dimension_names:
        if name.lower() in (*RING_FIELDS, *TIME_FIELDS, *INTENSITY_FIELDS):
            fields[name] = np.asarray(las[name])
    return fields


def _read_bin(path: Path) -> dict[str, np.ndarray]:
    size = path.stat().st_size
    if size == 0 or size % 16:
        raise SourceFormatError(
            f"{path}: {size} bytes is not a KITTI scan (float32 x, y, z, reflectance: 16 bytes "
            "a point)"
        )
    scan = np.fromfile(path, dtype="<f4").reshape(-1, 4)
    return {"x": scan[:, 0], "y": scan[:, 1], "z": scan[:, 2], "intensity": scan[:, 3]}


def read_lidar_frame(path: str | os.PathLike) -> LidarFrame:
    """Read one frame (module docstring for the formats and fields).

    Raises
    ------
    MissingSourceFileError
        No such file.
    SourceFormatError
        Not a file of a known kind, unreadable, or without a point.
    """
    path = Path(path)
    if not path.is_file():
        raise MissingSourceFileError(f"{path}: LiDAR frame file is missing")
    suffix = path.suffix.lower()
    readers = {".pcd": _read_pcd, ".las": _read_las, ".laz": _read_las, ".bin": _read_bin}
    if suffix not in readers:
        raise SourceFormatError(
            f"{path}: expected a LiDAR frame as {', '.join(FRAME_SUFFIXES)}, got {suffix!r}"
        )
    fields = readers[suffix](path)
    xyz = np.stack([fields.pop(k) for k in "xyz"], axis=1).astype(np.float64)
    keep = np.all(np.isfinite(xyz), axis=1) & np.any(xyz != 0, axis=1)
    if not keep.any():
        raise SourceFormatError(f"{path}: the frame holds no point with a return")
    ring = _first(fields, RING_FIELDS)
    time = _first(fields, TIME_FIELDS)
    intensity = _first(fields, INTENSITY_FIELDS)
    seconds = None
    offset = False
    if time is not None:
        raw = time[1][keep]
        seconds = raw.astype(np.float64) * (1e-9 if np.issubdtype(raw.dtype, np.integer) else 1.0)
        if not np.all(np.isfinite(seconds)):
            raise SourceFormatError(f"{path}: the point times ({time[0]}) hold NaN or infinity")
        offset = bool(np.median(seconds) < ABSOLUTE_TIME_S)
    rings = None
    if ring is not None:
        values = ring[1][keep]
        if not np.issubdtype(values.dtype, np.integer) and not np.all(values == np.round(values)):
            raise SourceFormatError(f"{path}: the ring field {ring[0]!r} holds non-integers")
        rings = values.astype(np.int64)
    return LidarFrame(
        path=path,
        xyz=xyz[keep],
        intensity=_intensity16(None if intensity is None else intensity[1][keep], int(keep.sum())),
        ring=rings,
        time=seconds,
        time_is_offset=offset,
    )
