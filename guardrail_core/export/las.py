"""A run as a LAS 1.4 point cloud: every point of the drive, with what the run made of it.

``guardrail export RUN_DIR --las OUT.laz`` writes the drive's points in map coordinates for GIS
and point-cloud tools (QGIS, CloudCompare, PDAL), with the run's result as classes and extra
dimensions (documented in ``docs/run-folder.md``, *Exporting to LAS*):

* ``classification``: 64 guardrail, 65 guardrail pole, 11 road surface (where the drive had
  0 or 1), the drive's own class otherwise
* ``segment_id`` (int32): the point's segment; -1 road surface, -2 far from the road
* ``guardrail_probability`` (float32): the segment's probability of guardrail; -1 without one
* ``run_id`` (int32): the reconstructed guardrail run of a guardrail point; -1 if none

The drive's point tiles (``points/index.json``) are read as they are and converted to LAS 1.4
point format 6 (7 or 8 when they have colours or near infrared), so every dimension they had
(GPS time, intensity, returns, flags, the scan lattice, colours) is kept. A survey-scale drive
does not fit in memory, so the export goes tile by tile, twice: once for the guardrail points (the
runs are grouped over all of them) and the check that the run was made from this drive, once to
convert and append each tile to the output. The output is written to a hidden file beside
``OUT`` and renamed when complete (:func:`guardrail_core.formats.atomic.atomic_file`); it may
never be one of the files the export reads.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import date
from pathlib import Path
from typing import Any, BinaryIO

import laspy
import numpy as np
from scipy.spatial import cKDTree

from guardrail_core.errors import DriveFormatError, ExportError, RunFolderError
from guardrail_core.export.drive_points import DrivePoints, read_drive_points, read_point_file
from guardrail_core.formats.atomic import atomic_file, check_output
from guardrail_core.formats.drive import drive_parts
from guardrail_core.formats.run_folder_paths import RunFolder
from guardrail_core.io.las import SCALE_M  # 0.1 mm, as the drive writer stores points
from guardrail_core.reconstruct.pipeline import guardrail_mask
from guardrail_core.reconstruct.run_models import load_run_models
from guardrail_core.reconstruct.runs import group_runs

#: LAS 1.4 user-definable classes (64-255): points of segments the run labelled guardrail.
CLASS_GUARDRAIL = 64
#: Guardrail points on a reconstructed pole (see :data:`POLE_TOLERANCE_M`).
CLASS_GUARDRAIL_POLE = 65
#: ASPRS "road surface": the run's road points, where the drive had no class of its own.
CLASS_ROAD_SURFACE = 11
#: ASPRS "created, never classified" and "unclassified": the only classes the road may replace.
UNCLASSIFIED = (0, 1)
#: Metres. A guardrail point within a pole's radius + this of its axis (horizontally), and from
#: this below its ground to this above its top, is a pole point: the 5 mm range noise and the
#: fitted radius's error stay inside; a beam (90 mm before a 70 mm post's axis) or a baluster
#: (125 mm from the axis of the widest pole) stays out.
POLE_TOLERANCE_M = 0.03
#: ``guardrail_probability`` of points in no segment, or of a segment the model could not judge
#: (NaN in segments.npz): many tools choke on NaN, and -1 is never a probability.
NO_PROBABILITY = -1.0
#: ``run_id`` of points of no reconstructed run.
NO_RUN = -1
#: The extra dimensions the export adds (replacing same-named ones of the drive's file).
EXPORT_DIMENSIONS = ("segment_id", "guardrail_probability", "run_id")
SOFTWARE = "guardrail export"


_CRS_VLRS = (
    "WktCoordinateSystemVlr",
    "GeoKeyDirectoryVlr",
    "GeoAsciiParamsVlr",
    "GeoDoubleParamsVlr",
)


@dataclass(frozen=True)
class ExportSummary:
    """What :func:`export_run_las` wrote.

    Attributes
    ----------
    out : the LAS/LAZ file
    points : points written (every point of the drive)
    guardrail_points : points of class 64 or 65
    pole_points : points of class 65
    road_points : points given class 11 (road surface)
    run_points : guardrail points with a ``run_id`` (0 when the reconstruction is missing or
        does not match the run's labels)
    point_format : LAS point format id (6, 7 or 8)
    crs : the CRS written (the drive's ``crs``), or None when none was written
    warnings : what the export could not do (an unreadable CRS, a missing or outdated
        reconstruction); one line each
    """

    out: Path
    points: int
    guardrail_points: int
    pole_points: int
    road_points: int
    run_points: int
    point_format: int
    crs: str | None
    warnings: tuple[str, ...]


def export_run_las(
    run_dir: str | Path,
    out: str | Path,
    *,
    drive_dir: str | Path | None = None,
    overwrite: bool = False,
) -> ExportSummary:
    """Write every point of a run's drive, with the run's result, as LAS 1.4 (``.las``) or LAZ.

    Parameters
    ----------
    run_dir : a run folder (``guardrail process``)
    out : the file to write; ``.laz`` compresses (lazrs), ``.las`` does not
    drive_dir : the run's drive (default: ``run.json``'s ``drive.path``)
    overwrite : replace ``out`` if it exists

    Returns
    -------
    An :class:`ExportSummary`. Coordinates are map coordinates (local + the drive's origin) with
    the origin as LAS offset and a 0.1 mm scale; classes and extra dimensions as in the module
    docstring. The drive's points are held one tile at a time.

    Raises
    ------
    OutputExistsError
        ``out`` exists and ``overwrite`` is false.
    InputInsideOutputError
        ``out`` is one of the files the export reads or a part of the drive or the run folder
        (a point tile, ``reconstruction/models.json``), or replaces a file in one of their
        folders (``points/``, ``images/``, ``crops/``); checked before any work.
    OutputKindError
        ``out`` is a folder.
    ExportError
        ``out`` is not a ``.las``/``.laz`` path, or a point lies too far from the origin for
        32-bit LAS coordinates.
    RunFolderError
        The run folder cannot be read, or was made from another drive (another number of
        points, or other points).
    DriveError
        The drive's ``drive.json``, tile index or a point tile is missing or unreadable, a tile
        holds another number of points than the index says, or the tiles differ in point format.
    """
    out = Path(out)
    compress = _compression(out)
    folder = RunFolder(Path(run_dir))
    run_inputs = [*folder.parts(), folder.reconstruction.models_file]
    check_output(out, folder=False, overwrite=overwrite, inputs=run_inputs)

    run = folder.load()
    if drive_dir is None:
        drive_dir = Path(run.info.drive.path)
    drive = read_drive_points(Path(drive_dir))
    # The tiles before the drive's folders: an output that is a tile is "the input" itself.
    inputs = [*run_inputs, *(f.path for f in drive.files), *drive_parts(drive_dir)]
    check_output(out, folder=False, overwrite=overwrite, inputs=inputs)

    starts = drive.starts()
    n = int(starts[-1])
    segment = np.asarray(run.point_segment, np.int64)
    n_segments = len(run)
    if segment.shape != (n,):
        raise RunFolderError(
            f"{run.root}: made from a drive of {len(segment)} points, but {drive_dir} has {n}; "
            "give the run's drive with --drive"
        )
    if n and (segment.min() < -2 or segment.max() >= n_segments):
        raise RunFolderError(
            f"{run.root}: points.npz names segments outside -2..{n_segments - 1}; damaged run folder"
        )
    guardrail_index = np.flatnonzero(guardrail_mask(segment, run.segments["label"]))

    scan = _scan_tiles(drive, starts, segment, guardrail_index, n_segments)
    _check_same_drive(run.root, run.segments, segment, scan, Path(drive_dir))
    warnings: list[str] = []
    on_pole, run_of_guardrail = _reconstruction_labels(folder, scan.guardrail_xyz, warnings)
    probability = np.asarray(run.segments["probability"], np.float32)
    labels = _RunLabels(
        segment=segment,
        segment_probability=np.where(
            np.isnan(probability), np.float32(NO_PROBABILITY), probability
        ),
        guardrail_index=guardrail_index,
        on_pole=on_pole,
        run_of_guardrail=run_of_guardrail,
    )
    with atomic_file(out, overwrite=overwrite, inputs=inputs) as f:
        written = _write_tiles(f, drive, starts, scan.kept, labels, compress, out, warnings)
    return ExportSummary(
        out=out,
        points=n,
        guardrail_points=len(guardrail_index),
        pole_points=int(on_pole.sum()),
        road_points=written.road_points,
        run_points=int((run_of_guardrail >= 0).sum()),
        point_format=written.point_format,
        crs=written.crs,
        warnings=tuple(warnings),
    )


def format_summary(summary: ExportSummary) -> str:
    """The summary as the CLI prints it (warnings are printed apart)."""
    crs = summary.crs if summary.crs is not None else "none"
    return (
        f"{summary.points:,} points ({summary.guardrail_points:,} guardrail, "
        f"{summary.pole_points:,} of them on poles; {summary.road_points:,} road surface), "
        f"LAS 1.4 point format {summary.point_format}, CRS {crs}\n"
        f"wrote {summary.out}"
    )


# ------------------------------------------------------------------------------------ helpers


def _compression(out: Path) -> bool:
    suffix = out.suffix.lower()
    if suffix not in (".las", ".laz"):
        raise ExportError(f"{out}: give a .laz (compressed) or .las file name")
    return suffix == ".laz"


@dataclass(frozen=True)
class _Scan:
    """What the first pass over the tiles gathers.

    Attributes
    ----------
    guardrail_xyz : (M, 3) float64, metres, local frame: the guardrail points in drive order
    first, last : (S,) float64 GPS seconds: the time of each segment's first and last point
    kept : a one-tile drive's points, read once for both passes; None for more tiles
    """

    guardrail_xyz: np.ndarray
    first: np.ndarray
    last: np.ndarray
    kept: laspy.LasData | None


def _scan_tiles(
    drive: DrivePoints,
    starts: np.ndarray,
    segment: np.ndarray,
    guardrail_index: np.ndarray,
    n_segments: int,
) -> _Scan:
    """Read the tiles once for the guardrail points and each segment's time range.

    Parameters
    ----------
    starts : (T + 1,) int64, the drive-wide index of each tile's first point, then the total
    segment : (N,) int64, the segment of every drive point
    guardrail_index : (M,) int64, ascending: the drive's guardrail points
    """
    first = np.full(n_segments, np.inf)
    last = np.full(n_segments, -np.inf)
    parts = [np.zeros((0, 3))]
    src = None
    for file, start, stop in zip(drive.files, starts[:-1], starts[1:], strict=True):
        src = read_point_file(file)
        mine = segment[start:stop]
        inside = mine >= 0
        gps_time = np.asarray(src.gps_time, np.float64)
        np.minimum.at(first, mine[inside], gps_time[inside])
        np.maximum.at(last, mine[inside], gps_time[inside])
        lo, hi = np.searchsorted(guardrail_index, [start, stop])
        index = guardrail_index[lo:hi] - start
        parts.append(
            np.column_stack([src.X[index], src.Y[index], src.Z[index]])
            * np.asarray(src.header.scales, np.float64)
            + np.asarray(src.header.offsets, np.float64)
            - drive.origin
        )
    return _Scan(np.concatenate(parts), first, last, src if len(drive.files) == 1 else None)


def _check_same_drive(
    run_dir: Path, segments: dict[str, np.ndarray], segment: np.ndarray, scan: _Scan, drive: Path
) -> None:
    """Refuse a drive with as many points as the run's but other ones.

    Every segment must have its ``n_points`` and its first and last GPS time (``time``, (S, 2)
    seconds) among the drive's points: another drive, or the same drive's points reordered,
    fails this even with the same point count.
    """
    n_segments = len(segments["n_points"])
    count = np.bincount(segment[segment >= 0], minlength=n_segments)
    time = np.asarray(segments["time"], np.float64)
    if not (
        np.array_equal(count, np.asarray(segments["n_points"]))
        and np.allclose(scan.first, time[:, 0], rtol=0, atol=1e-6)
        and np.allclose(scan.last, time[:, 1], rtol=0, atol=1e-6)
    ):
        raise RunFolderError(
            f"{run_dir}: its segments do not match the points of the drive {drive} (other points "
            "or GPS times): the run was made from another drive; give the run's drive with --drive"
        )


@dataclass(frozen=True)
class _RunLabels:
    """What the run made of the drive's points.

    Attributes
    ----------
    segment : (N,) int64, the segment of every drive point (-1 road, -2 off road)
    segment_probability : (S,) float32, P(guardrail) of each segment (``NO_PROBABILITY``: none)
    guardrail_index : (M,) int64, ascending: the guardrail points
    on_pole : (M,) bool; run_of_guardrail : (M,) int32: their pole and reconstructed run
    """

    segment: np.ndarray
    segment_probability: np.ndarray
    guardrail_index: np.ndarray
    on_pole: np.ndarray
    run_of_guardrail: np.ndarray


@dataclass(frozen=True)
class _Written:
    """What :func:`_write_tiles` wrote: the LAS point format id, the CRS (None: none), and how
    many points became road surface."""

    point_format: int
    crs: str | None
    road_points: int


def _write_tiles(
    f: BinaryIO,
    drive: DrivePoints,
    starts: np.ndarray,
    kept: laspy.LasData | None,
    labels: _RunLabels,
    compress: bool,
    out: Path,
    warnings: list[str],
) -> _Written:
    """Convert and label the tiles one by one and append them to ``f``, a LAS 1.4 file whose
    header (CRS, point format, extra dimensions) is the first tile's."""
    writer: laspy.LasWriter | None = None
    written = _Written(point_format=6, crs=None, road_points=0)
    evlrs = None
    for k, file in enumerate(drive.files):
        las = _converted(kept if kept is not None else read_point_file(file), drive.origin, out)
        road = _label(las, labels, int(starts[k]), int(starts[k + 1]))
        if writer is None:
            crs = _set_crs(las.header, drive.crs, warnings)
            las.header.generating_software = SOFTWARE
            las.header.creation_date = date.today()
            written, evlrs = _Written(las.header.point_format.id, crs, 0), las.evlrs
            # Closed only when complete: after a failure atomic_file removes the partial file.
            writer = laspy.LasWriter(f, las.header, do_compress=compress, closefd=False)
        elif las.point_format != writer.header.point_format:
            raise DriveFormatError(
                f"{file.path}: point format {las.point_format.id} with extra dimensions "
                f"{list(las.point_format.extra_dimension_names)} differs from the first tile's "
                f"({drive.files[0].path}); the tiles of a drive share one point format"
            )
        if len(las.points):
            writer.write_points(las.points)
        written = _Written(written.point_format, written.crs, written.road_points + road)
    if writer is not None:  # read_drive_points refuses a drive without tiles
        if evlrs is not None:
            writer.write_evlrs(evlrs)
        writer.close()
    return written


def _converted(src: laspy.LasData, origin: np.ndarray, out: Path) -> laspy.LasData:
    """A tile as LAS 1.4 point format 6, 7 or 8 (:func:`_point_format`) in map coordinates with
    the drive's origin as offset."""
    las = laspy.convert(src, point_format_id=_point_format(src.point_format), file_version="1.4")
    if "scan_angle_rank" in src.point_format.dimension_names:
        # Formats 0-5 keep whole degrees in an int8; 6-10 keep 0.006 degree steps in an int16
        # under another name, which laspy's conversion does not carry over.
        las.scan_angle = np.round(np.asarray(src.scan_angle_rank, np.float64) / 0.006).astype(
            np.int16
        )
    _to_map_scaling(las, origin, out)
    return las


def _label(las: laspy.LasData, labels: _RunLabels, start: int, stop: int) -> int:
    """Give the tile of drive points ``start:stop`` the run's classes and extra dimensions;
    return how many became road surface."""
    segment = labels.segment[start:stop]
    lo, hi = np.searchsorted(labels.guardrail_index, [start, stop])
    guardrail_index = labels.guardrail_index[lo:hi] - start
    original = np.asarray(las.classification, np.uint8)
    classification = original.copy()
    road = (segment == -1) & np.isin(original, UNCLASSIFIED)
    classification[road] = CLASS_ROAD_SURFACE
    classification[guardrail_index] = CLASS_GUARDRAIL
    classification[guardrail_index[labels.on_pole[lo:hi]]] = CLASS_GUARDRAIL_POLE
    las.classification = classification

    probability = np.full(len(segment), NO_PROBABILITY, np.float32)
    inside = segment >= 0
    probability[inside] = labels.segment_probability[segment[inside]]
    run_id = np.full(len(segment), NO_RUN, np.int32)
    run_id[guardrail_index] = labels.run_of_guardrail[lo:hi]

    present = [d for d in EXPORT_DIMENSIONS if d in las.point_format.extra_dimension_names]
    if present:  # a drive imported from an earlier export: the run's values replace them
        las.remove_extra_dims(present)
    las.add_extra_dims(
        [
            laspy.ExtraBytesParams(
                "segment_id", np.int32, description="segment; -1 road, -2 off road"
            ),
            laspy.ExtraBytesParams(
                "guardrail_probability",
                np.float32,
                description="P(guardrail) of segment; -1 none",
                no_data=[NO_PROBABILITY],
            ),
            laspy.ExtraBytesParams(
                "run_id", np.int32, description="guardrail run; -1 none", no_data=[NO_RUN]
            ),
        ]
    )
    las.segment_id = segment.astype(np.int32)
    las.guardrail_probability = probability
    las.run_id = run_id
    return int(road.sum())


def _reconstruction_labels(
    run: RunFolder, local: np.ndarray, warnings: list[str]
) -> tuple[np.ndarray, np.ndarray]:
    """Which guardrail points lie on a reconstructed pole, and the run of each.

    Parameters
    ----------
    local : (M, 3) float64, metres, local frame: the guardrail points
    warnings : gets a line when the reconstruction is missing or does not match the labels

    Returns
    -------
    on_pole : (M,) bool
    run_id : (M,) int32, the reconstructed run (``NO_RUN`` for points in none)
    """
    on_pole = np.zeros(len(local), bool)
    run_id = np.full(len(local), NO_RUN, np.int32)
    if not run.reconstruction.exists():
        if len(local):
            warnings.append(
                "the run has no reconstruction: no pole points (class 65) and no run_id; run "
                f"`guardrail reconstruct {run.root}` first"
            )
        return on_pole, run_id
    models = load_run_models(run)
    runs = models.runs
    if len(local) == 0:
        return on_pole, run_id
    on_pole = pole_points(local, [p for r in runs for p in r.poles])

    # The runs are not stored per point: group the points again as the reconstruction did, and
    # trust the grouping only if every run has the very points the reconstruction had.
    group = group_runs(local, models.params.runs)
    counts = np.bincount(group[group >= 0], minlength=len(runs))
    expected = np.array([r.n_points for r in runs], np.int64)
    ids = np.array([r.run_id for r in runs], np.int64)
    if len(counts) == len(runs) and np.array_equal(counts, expected):
        run_id = np.where(group >= 0, ids[np.maximum(group, 0)], NO_RUN).astype(np.int32)
    else:
        warnings.append(
            "the reconstruction does not match the run's guardrail labels (made before they "
            "changed?): run_id is -1 everywhere and poles are those of the old labels; run "
            f"`guardrail reconstruct {run.root}`"
        )
    return on_pole, run_id


def pole_points(xyz: np.ndarray, poles: list[Any]) -> np.ndarray:
    """Which points lie on one of the poles.

    Parameters
    ----------
    xyz : (M, 3) float64, metres, local frame
    poles : :class:`~guardrail_core.reconstruct.model.Pole` (``position`` = ground point of the
        axis, ``radius``, ``height``; metres, local frame)

    Returns
    -------
    (M,) bool: horizontally within ``radius + POLE_TOLERANCE_M`` of a pole's axis, and from
    ``POLE_TOLERANCE_M`` below its ground to ``POLE_TOLERANCE_M`` above its top.
    """
    xyz = np.asarray(xyz, np.float64)
    out = np.zeros(len(xyz), bool)
    if len(xyz) == 0 or not poles:
        return out
    tree = cKDTree(xyz[:, :2])
    for pole in poles:
        position = np.asarray(pole.position, np.float64)
        index = np.asarray(
            tree.query_ball_point(position[:2], float(pole.radius) + POLE_TOLERANCE_M), np.int64
        )
        dz = xyz[index, 2] - position[2]
        inside = (dz >= -POLE_TOLERANCE_M) & (dz <= float(pole.height) + POLE_TOLERANCE_M)
        out[index[inside]] = True
    return out


def _point_format(source: laspy.PointFormat) -> int:
    """LAS 1.4 format 6, or 7 (RGB) / 8 (RGB + NIR) to keep the drive's colours.

    Waveform packets (formats 4, 5, 9, 10) point into data the export does not carry, so they
    are dropped.
    """
    names = set(source.dimension_names)
    if "nir" in names:
        return 8
    if "red" in names:
        return 7
    return 6


def _to_map_scaling(las: laspy.LasData, origin: np.ndarray, out: Path) -> None:
    """Re-quantise the coordinates at 0.1 mm with the drive's origin as the LAS offset."""
    if len(las.points):
        reach = max(
            float(np.max(np.abs(np.asarray(v, np.float64) - o)))
            for v, o in zip((las.x, las.y, las.z), origin, strict=True)
        )
        if reach / SCALE_M >= 2**31 - 1:
            raise ExportError(
                f"{out}: points lie {reach:.0f} m from the drive's origin, beyond what 32-bit "
                "LAS coordinates at 0.1 mm hold (214 km)"
            )
    las.change_scaling(scales=np.full(3, SCALE_M), offsets=np.asarray(origin, np.float64))


def _set_crs(header: laspy.LasHeader, crs: str, warnings: list[str]) -> str | None:
    """Write the drive's CRS as an OGC WKT VLR (and the WKT bit); any older CRS record goes.

    Returns the CRS written, or None (and a warning) when pyproj cannot read it.
    """
    import pyproj
    from pyproj.exceptions import CRSError

    for name in _CRS_VLRS:  # the drive's file may carry GeoTIFF keys, not allowed in 6-10
        header.vlrs.extract(name)
    try:
        parsed = pyproj.CRS.from_user_input(crs)
    except CRSError:
        header.global_encoding.wkt = False
        warnings.append(
            f"the drive's CRS {crs!r} is not one pyproj knows: the file has no CRS record "
            "(assign one in your GIS)"
        )
        return None
    header.add_crs(parsed)
    return crs
