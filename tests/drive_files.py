"""The files of a drive folder (format 2.x: point tiles with an index), for tests that poke them,
and drives written anew from one in memory."""

from __future__ import annotations

import shutil
from pathlib import Path

import laspy
import numpy as np

from guardrail_core.formats.drive import Drive, PointCloud, Truth
from guardrail_core.formats.drive_tiles import INDEX_FILE, read_tile_index
from guardrail_core.formats.drive_writer import write_drive_files


def tile_file(root: Path, k: int = 0) -> Path:
    """The LAS/LAZ file of tile ``k`` of the drive folder ``root``, as its index names it."""
    return root / read_tile_index(root).tiles[k].file


def truth_file(root: Path, k: int = 0) -> Path:
    """The truth file (class and object id per point) of tile ``k``."""
    truth = read_tile_index(root).tiles[k].truth
    assert truth is not None, f"{root / INDEX_FILE}: tile {k} has no truth"
    return root / truth


def drive_las(root: Path) -> laspy.LasData:
    """Every point of the drive as the LAS records of its tiles, concatenated in time order
    (the tiles share point format, scales and offsets)."""
    tiles = [laspy.read(str(root / t.file)) for t in read_tile_index(root).tiles]
    las = tiles[0]
    las.points = laspy.ScaleAwarePointRecord(
        np.concatenate([t.points.array for t in tiles]),
        las.point_format,
        las.header.scales,
        las.header.offsets,
    )
    return las


def write_drive_copy(
    drive: Drive,
    folder: Path,
    *,
    tile_m: float | None = None,
    points: PointCloud | None = None,
    truth: Truth | None = None,
) -> Path:
    """Write ``drive`` (its images and masks copied) into the new ``folder`` with
    :func:`write_drive_files`, in tiles of ``tile_m`` metres; ``points`` and ``truth`` replace
    the drive's own."""
    folder.mkdir(parents=True)
    shutil.copytree(drive.root / "images", folder / "images")
    if (drive.root / "truth" / "masks").is_dir():
        shutil.copytree(drive.root / "truth" / "masks", folder / "truth" / "masks")
    write_drive_files(
        folder,
        crs=drive.crs,
        origin=drive.origin,
        scanner=drive.scanner,
        trajectory=drive.trajectory,
        points=drive.points if points is None else points,
        cameras=list(drive.cameras.values()),
        images=drive.images,
        truth=drive.truth if truth is None else truth,
        source=drive.source,
        tile_m=tile_m,
    )
    return folder
