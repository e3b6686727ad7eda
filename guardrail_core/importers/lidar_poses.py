"""The poses and times of a sequence of LiDAR frames.

Poses are optional (one frame makes a drive by itself). Accepted shapes, one row a frame:

- KITTI ``poses.txt``: 12 numbers, a row-major 3 x 4 pose. With ``calib`` (KITTI
  ``calib.txt``, its ``Tr`` velodyne -> camera 0) the poses are camera 0's, as KITTI writes
  them, and the sensor's pose is ``pose @ Tr``; without, they are the sensor's.
- CSV (commas or spaces, an optional header line of words): 17 numbers, a time in seconds then
  a row-major 4 x 4 ``T_world_sensor``, or 16 numbers, the matrix alone.

Frame times: a ``times`` file (one number a line, KITTI ``times.txt``), else the poses' times.
Rows are matched to frames in order; where every frame file is named by a number
(``000280.pcd``) and the file has more rows than frames, by that number (a KITTI sequence's
poses cover all its frames).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from guardrail_core.errors import FrameRangeError, MissingSourceFileError, SourceFormatError

#: A pose's rotation may be off orthonormal by this much (poses are written with few decimals).
ROTATION_TOLERANCE = 1e-3


@dataclass(frozen=True)
class FramePoses:
    """Per frame: ``T_world_sensor`` (F, 4, 4) float64, and times (F,) float64 seconds or None."""

    T_world_sensor: np.ndarray
    times: np.ndarray | None


def _read_numbers(path: Path, what: str) -> np.ndarray:
    """The rows of numbers of a text table (commas or spaces; a first line of words skipped)."""
    if not path.is_file():
        raise MissingSourceFileError(f"{path}: {what} file is missing")
    rows: list[list[float]] = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        parts = line.split("#", 1)[0].replace(",", " ").split()
        if not parts:
            continue
        try:
            rows.append([float(v) for v in parts])
        except ValueError as exc:
            if number == 1:
                continue  # a header
            raise SourceFormatError(f"{path}:{number}: not a row of numbers ({exc})") from exc
    widths = {len(row) for row in rows}
    if not rows or len(widths) != 1:
        raise SourceFormatError(
            f"{path}: expected rows of the same count of numbers, got {sorted(widths) or 'none'}"
        )
    table = np.asarray(rows, np.float64)
    if not np.all(np.isfinite(table)):
        raise SourceFormatError(f"{path}: contains NaN or infinity")
    return table


def _kitti_tr(path: Path) -> np.ndarray:
    """(4, 4) ``Tr`` (velodyne -> camera 0) of a KITTI ``calib.txt``."""
    if not path.is_file():
        raise MissingSourceFileError(f"{path}: KITTI calibration file is missing")
    for line in path.read_text().splitlines():
        name, _, values = line.partition(":")
        if name.strip() == "Tr":
            try:
                matrix = np.array([float(v) for v in values.split()], np.float64)
            except ValueError as exc:
                raise SourceFormatError(f"{path}: Tr is not 12 numbers ({exc})") from exc
            if matrix.shape != (12,):
                raise SourceFormatError(f"{path}: Tr needs 12 numbers, got {matrix.size}")
            return np.vstack([matrix.reshape(3, 4), [0.0, 0.0, 0.0, 1.0]])
    raise SourceFormatError(f"{path}: lacks Tr, the velodyne -> camera 0 transform")


def _rows_of(frame_paths: list[Path], n_rows: int, where: Path) -> np.ndarray:
    """(F,) the row of every frame (module docstring)."""
    if n_rows == len(frame_paths):
        return np.arange(n_rows)
    stems = [p.stem for p in frame_paths]
    if n_rows > len(frame_paths) and all(s.isdigit() for s in stems):
        rows = np.array([int(s) for s in stems])
        if rows.max() >= n_rows:
            raise FrameRangeError(
                f"{where}: frame {rows.max()} has no row ({n_rows} rows, frames 0..{n_rows - 1})"
            )
        return rows
    raise SourceFormatError(
        f"{where}: {n_rows} rows for {len(frame_paths)} frames; give one row a frame, or name "
        "the frames by their number in the sequence (000280.pcd)"
    )


def read_frame_poses(
    frame_paths: list[Path],
    poses: str | os.PathLike | None,
    *,
    times: str | os.PathLike | None = None,
    calib: str | os.PathLike | None = None,
) -> FramePoses | None:
    """The frames' sensor poses and times (module docstring); None without a poses file.

    Raises
    ------
    MissingSourceFileError, SourceFormatError, FrameRangeError
        A file is missing or malformed, or a frame has no row; the message names it.
    """
    if poses is None:
        if calib is not None:
            raise SourceFormatError("--kitti-calib: the calibration turns poses; give --poses")
        return None
    path = Path(poses)
    table = _read_numbers(path, "poses")
    width = table.shape[1]
    pose_times = None
    if width == 12:
        matrices = np.concatenate(
            [table.reshape(-1, 3, 4), np.broadcast_to([0.0, 0.0, 0.0, 1.0], (len(table), 1, 4))],
            axis=1,
        )
    elif width in (16, 17):
        pose_times = table[:, 0] if width == 17 else None
        matrices = table[:, width - 16 :].reshape(-1, 4, 4)
    else:
        raise SourceFormatError(
            f"{path}: expected 12 numbers a row (KITTI), 16 (a 4 x 4 matrix) or 17 (a time and "
            f"the matrix), got {width}"
        )
    rotation = matrices[:, :3, :3]
    off = np.abs(np.einsum("nji,njk->nik", rotation, rotation) - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero(
        (off > ROTATION_TOLERANCE)
        | (np.linalg.det(rotation) < 0)
        | np.any(np.abs(matrices[:, 3] - [0, 0, 0, 1]) > 1e-9, axis=1)
    )
    if len(bad):
        raise SourceFormatError(
            f"{path}: row {bad[0] + 1} is not a rigid transform (a rotation and a translation)"
        )
    if calib is not None:
        matrices = matrices @ _kitti_tr(Path(calib))
    rows = _rows_of(frame_paths, len(matrices), path)
    frame_times = None
    if times is not None:
        frame_times = read_frame_times(frame_paths, times)
    elif pose_times is not None:
        frame_times = pose_times[rows]
        if np.any(np.diff(frame_times) <= 0):
            raise SourceFormatError(f"{path}: the frames' times must increase")
    return FramePoses(matrices[rows], frame_times)


def read_frame_times(frame_paths: list[Path], times: str | os.PathLike) -> np.ndarray:
    """(F,) float64 seconds: the frames' rows of a times file (one number a line).

    Raises
    ------
    MissingSourceFileError, SourceFormatError, FrameRangeError
    """
    path = Path(times)
    table = _read_numbers(path, "frame times")
    if table.shape[1] != 1:
        raise SourceFormatError(f"{path}: expected one time a line, got {table.shape[1]} numbers")
    frame_times = table[_rows_of(frame_paths, len(table), path), 0]
    if np.any(np.diff(frame_times) <= 0):
        raise SourceFormatError(f"{path}: the frames' times must increase")
    return frame_times
