"""The drive's points and the run's per-point segments, read tile by tile as the app asks for them.

The review app holds nothing per point over the whole drive: a survey of hundreds of kilometres
has billions of points. It holds the run's per-segment table (a few hundred bytes a segment) and
reads the drive tiles and the run's point tiles (``points/NNNNNN.npz``, one per drive tile) that
a request needs, keeping the most recent ones within a point budget:

- the *points* of a tile (coordinates, GPS time, the vehicle's station, segment, truth class)
  for the 3D window and the camera images;
- the *segments* of a tile (segment and truth class only: no LAS file is read) for labelling,
  a segment's points and its truth.

A segment's points lie in the tiles its GPS time range (``segments.npz`` ``time``) overlaps,
so a segment is found without reading anything else. Drive point indices (those of the label
store) are the tile's offset plus the point's index in its tile.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from guardrail_core.classes import GUARDRAIL_CLASSES
from guardrail_core.errors import RunFolderError
from guardrail_core.formats.drive import DriveSource
from guardrail_core.formats.drive_tiles import vehicle_station
from guardrail_core.formats.run_folder_paths import RunFolder

#: Points of drive tiles kept in memory (about 45 bytes a point: some 270 MB).
POINTS_KEPT = 6_000_000
#: Points of run tiles' segments (and truth classes) kept (5 bytes a point: some 80 MB).
SEGMENT_POINTS_KEPT = 16_000_000

T = TypeVar("T")


@dataclass(frozen=True)
class TilePoints:
    """The points of some drive tiles (one tile, or a window of several).

    Attributes
    ----------
    index : (K,) int64, drive point indices (those of the label store), ascending
    xyz : (K, 3) float64, metres, the drive's local frame
    gps_time : (K,) float64, seconds
    station : (K,) float64, metres the vehicle had driven when the point was scanned
    segment : (K,) int32, the run's segment of each point (negative: road -1, off the road -2,
        not processed -3)
    point_class : (K,) uint8 truth class (synthetic drives), else None
    """

    index: np.ndarray
    xyz: np.ndarray
    gps_time: np.ndarray
    station: np.ndarray
    segment: np.ndarray
    point_class: np.ndarray | None

    def __len__(self) -> int:
        return len(self.index)

    def take(self, keep: np.ndarray) -> TilePoints:
        """The points at ``keep`` ((M,) int ascending, or (K,) bool)."""
        return TilePoints(
            self.index[keep],
            self.xyz[keep],
            self.gps_time[keep],
            self.station[keep],
            self.segment[keep],
            None if self.point_class is None else self.point_class[keep],
        )

    @staticmethod
    def concatenate(parts: Sequence[TilePoints]) -> TilePoints:
        classes = [p.point_class for p in parts]
        return TilePoints(
            np.concatenate([p.index for p in parts]) if parts else np.zeros(0, np.int64),
            np.concatenate([p.xyz for p in parts]) if parts else np.zeros((0, 3)),
            np.concatenate([p.gps_time for p in parts]) if parts else np.zeros(0),
            np.concatenate([p.station for p in parts]) if parts else np.zeros(0),
            np.concatenate([p.segment for p in parts]) if parts else np.zeros(0, np.int32),
            None if not parts or any(c is None for c in classes) else np.concatenate(classes),  # type: ignore[arg-type]
        )


@dataclass(frozen=True)
class TileSegments:
    """The run's segment (and the truth class) of every point of one drive tile."""

    offset: int  # drive index of the tile's first point
    segment: np.ndarray  # (n,) int32
    point_class: np.ndarray | None  # (n,) uint8, synthetic drives


class RunTiles:
    """A drive and its run folder, read a tile at a time.

    Parameters
    ----------
    source : the drive, opened without its points (:func:`~guardrail_core.formats.drive.open_drive`)
    folder : the run folder made from it
    segment_time : (S, 2) float64, first and last GPS second of each segment's points
    points_kept, segment_points_kept : the point budgets of the two tile caches

    Raises
    ------
    RunFolderError
        The run was made from a drive of another number of points or tiles.

    Thread-safe: the app's request threads and the 3D scene's share one.
    """

    def __init__(
        self,
        source: DriveSource,
        folder: RunFolder,
        segment_time: np.ndarray,
        *,
        points_kept: int = POINTS_KEPT,
        segment_points_kept: int = SEGMENT_POINTS_KEPT,
    ) -> None:
        self.source = source
        self.folder = folder
        info = folder.info()
        n = source.tiles.points
        if info.drive.points != n:
            raise RunFolderError(
                f"{folder.root}: made from a drive of {info.drive.points} points, but "
                f"{source.root} has {n}; serve the run with the drive it was made from"
            )
        if folder.point_tiles() != len(source.tiles):
            raise RunFolderError(
                f"{folder.root}: holds {folder.point_tiles()} point tiles, but {source.root} has "
                f"{len(source.tiles)} tiles; serve the run with the drive it was made from"
            )
        self.n_points = n
        self.offsets = source.tiles.offsets()  # (T + 1,)
        records = source.tiles.tiles
        self._tile_first = np.array([r.gps_time[0] for r in records])  # (T,) s
        self._tile_last = np.array([r.gps_time[1] for r in records])
        self._tile_points = np.array([r.points for r in records], np.int64)
        self.segment_time = np.asarray(segment_time, np.float64).reshape(-1, 2)
        self._points_kept = int(points_kept)
        self._segment_points_kept = int(segment_points_kept)
        self._points: OrderedDict[int, TilePoints] = OrderedDict()
        self._segments: OrderedDict[int, TileSegments] = OrderedDict()
        self._truth = np.full(len(self.segment_time), -1, np.int8)  # (S,) -1 not yet known
        self._lock = threading.RLock()

    @property
    def has_truth(self) -> bool:
        return self.source.has_truth

    def __len__(self) -> int:
        return len(self.offsets) - 1

    # -- which tiles ------------------------------------------------------------------------

    def tiles_between(self, t0: float, t1: float) -> np.ndarray:
        """(K,) int64 ascending: the tiles with points scanned between GPS seconds t0 and t1."""
        hit = (self._tile_first <= t1) & (self._tile_last >= t0) & (self._tile_points > 0)
        return np.flatnonzero(hit)

    def tiles_of_segments(self, segments: np.ndarray) -> np.ndarray:
        """(K,) int64 ascending: the tiles holding any point of ``segments``."""
        times = self.segment_time[np.asarray(segments, np.int64)]
        if len(times) == 0:
            return np.zeros(0, np.int64)
        # Tiles follow each other in time: a segment's tiles run from the first whose last point
        # is not before its first to the last whose first point is not after its last.
        lo = np.searchsorted(self._tile_last, times[:, 0], side="left")
        hi = np.searchsorted(self._tile_first, times[:, 1], side="right")
        tiles = [np.arange(a, b) for a, b in zip(lo.tolist(), hi.tolist(), strict=True)]
        found = np.unique(np.concatenate(tiles)) if tiles else np.zeros(0, np.int64)
        return found[self._tile_points[found] > 0].astype(np.int64)

    # -- a tile's contents ------------------------------------------------------------------

    def tile_points(self, tile: int) -> TilePoints:
        """Every point of drive tile ``tile``, with its segment and station (cached)."""
        return self._cached(self._points, tile, self._read_points, self._points_kept)

    def tile_segments(self, tile: int) -> TileSegments:
        """The segment and truth class of every point of ``tile`` (cached; no LAS read)."""
        with self._lock:
            if tile in self._points:  # the larger cache has them
                points = self._points[tile]
                return TileSegments(int(self.offsets[tile]), points.segment, points.point_class)
        return self._cached(self._segments, tile, self._read_segments, self._segment_points_kept)

    def _cached(
        self, cache: OrderedDict[int, T], tile: int, read: Callable[[int], T], kept: int
    ) -> T:
        with self._lock:  # one reader at a time: two asking for a tile read it once
            if tile in cache:
                cache.move_to_end(tile)
                return cache[tile]
            value = read(tile)
            cache[tile] = value
            while len(cache) > 1 and self._tile_points[list(cache)].sum() > kept:
                cache.popitem(last=False)
            return value

    def _read_points(self, tile: int) -> TilePoints:
        points, truth = self.source.read_tiles([tile])
        segment = self._read_segment(tile)
        offset = int(self.offsets[tile])
        return TilePoints(
            index=np.arange(offset, offset + len(points), dtype=np.int64),
            xyz=points.xyz,
            gps_time=points.gps_time,
            station=vehicle_station(self.source.trajectory, points.gps_time),
            segment=segment,
            point_class=None if truth is None else truth.point_class,
        )

    def _read_segments(self, tile: int) -> TileSegments:
        segment = self._read_segment(tile)
        point_class = self.source.read_truth_tile(tile) if self.has_truth else None
        return TileSegments(int(self.offsets[tile]), segment, point_class)

    def _read_segment(self, tile: int) -> np.ndarray:
        segment = self.folder.point_segment_tile(tile)
        if len(segment) != self._tile_points[tile]:
            raise RunFolderError(
                f"{self.folder.point_tile_path(tile)}: holds {len(segment)} points, the drive's "
                f"tile {tile} has {self._tile_points[tile]}; serve the run with its drive"
            )
        return segment.astype(np.int32, copy=False)

    # -- windows ----------------------------------------------------------------------------

    def window(self, station_lo: float, station_hi: float) -> TilePoints:
        """The points scanned while the vehicle drove from ``station_lo`` to ``station_hi``
        metres (half-open), from the tiles scanned meanwhile."""
        trajectory = self.source.trajectory
        station = vehicle_station(trajectory, trajectory.time)  # (T,) non-decreasing
        # The trajectory samples either side of the window bound the times of its points.
        first = max(int(np.searchsorted(station, station_lo, side="left")) - 1, 0)
        last = min(int(np.searchsorted(station, station_hi, side="left")), len(station) - 1)
        parts = []
        for tile in self.tiles_between(trajectory.time[first], trajectory.time[last]):
            points = self.tile_points(int(tile))
            keep = (points.station >= station_lo) & (points.station < station_hi)
            parts.append(points.take(np.flatnonzero(keep)))
        return TilePoints.concatenate(parts)

    def scanned_between(self, t0: float, t1: float) -> TilePoints:
        """The points scanned between GPS seconds ``t0`` and ``t1`` (closed)."""
        parts = []
        for tile in self.tiles_between(t0, t1):
            points = self.tile_points(int(tile))
            inside = (points.gps_time >= t0) & (points.gps_time <= t1)
            parts.append(points.take(np.flatnonzero(inside)))
        return TilePoints.concatenate(parts)

    # -- segments and points ----------------------------------------------------------------

    def segment_points(self, segments: Sequence[int] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The points of ``segments``: (K,) int64 drive indices, ascending, and (K,) int32 the
        segment of each."""
        ids = np.unique(np.asarray(segments, np.int64))
        points, owner = [np.zeros(0, np.int64)], [np.zeros(0, np.int32)]
        for tile in self.tiles_of_segments(ids):
            part = self.tile_segments(int(tile))
            mine = np.flatnonzero(np.isin(part.segment, ids))
            points.append(mine + part.offset)
            owner.append(part.segment[mine])
        return np.concatenate(points), np.concatenate(owner)

    def points_of(self, segments: Sequence[int] | np.ndarray) -> np.ndarray:
        """(K,) int64 ascending drive indices of the points of ``segments``."""
        return self.segment_points(segments)[0]

    def segment_of(self, points: np.ndarray) -> np.ndarray:
        """(K,) int32 segment of each drive point of ``points`` (K,) (negative: in none)."""
        points = np.asarray(points, np.int64)
        out = np.empty(len(points), np.int32)
        tile = np.searchsorted(self.offsets, points, side="right") - 1
        for t in np.unique(tile):
            mine = tile == t
            part = self.tile_segments(int(t))
            out[mine] = part.segment[points[mine] - part.offset]
        return out

    def segments_of(self, points: np.ndarray) -> np.ndarray:
        """(K,) int64 sorted unique segments holding any of ``points`` (points in none skipped)."""
        segment = self.segment_of(points)
        return np.unique(segment[segment >= 0]).astype(np.int64)

    def truth(self, segments: Sequence[int] | np.ndarray) -> np.ndarray | None:
        """(K,) bool true class of ``segments`` (guardrail when most of its points are), or
        None for a drive without truth; worked out from the segments' tiles once each."""
        if not self.has_truth:
            return None
        ids = np.asarray(segments, np.int64)
        with self._lock:
            missing = np.unique(ids[self._truth[ids] < 0])
            if len(missing):
                n_guardrail = np.zeros(len(missing))
                n_points = np.zeros(len(missing))
                guardrail = np.array(sorted(GUARDRAIL_CLASSES))
                for tile in self.tiles_of_segments(missing):
                    part = self.tile_segments(int(tile))
                    assert part.point_class is not None  # the drive has truth
                    where = np.searchsorted(missing, part.segment)
                    where = np.minimum(where, len(missing) - 1)
                    mine = missing[where] == part.segment
                    at = where[mine]
                    n_points += np.bincount(at, minlength=len(missing))
                    is_guardrail = np.isin(part.point_class[mine], guardrail)
                    n_guardrail += np.bincount(at, weights=is_guardrail, minlength=len(missing))
                self._truth[missing] = 2 * n_guardrail > n_points
            return self._truth[ids] == 1

    def operator_labels(
        self, points: np.ndarray, labels: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The segments' operator labels from labelled points.

        Parameters
        ----------
        points : (L,) int64 drive indices of labelled points
        labels : (L,) int, their labels (0 other, 1 guardrail; negative ones are skipped)

        Returns
        -------
        segments : (K,) int64 sorted, the segments holding any of those points
        label : (K,) int8, the majority label of each segment's labelled points (ties: guardrail)
        """
        points = np.asarray(points, np.int64)
        labels = np.asarray(labels)
        labelled = labels >= 0
        segment = self.segment_of(points[labelled])
        labels = labels[labelled]
        inside = segment >= 0
        segments, at = np.unique(segment[inside], return_inverse=True)
        n_guardrail = np.bincount(at, weights=labels[inside] == 1, minlength=len(segments))
        n_labelled = np.bincount(at, minlength=len(segments))
        return segments.astype(np.int64), (2 * n_guardrail >= n_labelled).astype(np.int8)
