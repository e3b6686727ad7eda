"""The points of a drive as tiles along the trajectory, with an index (drive format 2.0).

Mobile-mapping points are recorded in time order, so a tile is a GPS-time range: the points
scanned while the vehicle drove from one station to the next (``tile_m`` metres of driving).
``points/index.json`` lists every tile (file, GPS-time range, station range, bounds, point
count), so a reader of a window of stations opens only the tiles that window touches::

    points/index.json      {"format": "guardrail-tiles", "format_version": 1, "tiles": [...]}
    points/000000.laz      LAS 1.4, one per tile
    truth/points/000000.npz   synthetic drives: class and object id of every point of the tile

A tile's ``station_m`` is the range of its points' stations (metres along the trajectory,
:func:`guardrail_core.sensors.track.track_coordinates`), so a reader of a window of stations
opens exactly the tiles that hold points in it (:meth:`TileIndex.touching`).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from guardrail_core.errors import DriveFormatError, MissingDriveFileError, TimestampMismatchError
from guardrail_core.io.las import write_points
from guardrail_core.sensors.track import track_coordinates
from guardrail_core.sensors.trajectory import Trajectory

TILES_FORMAT = "guardrail-tiles"
TILES_FORMAT_VERSION = 1
TILES_DIR = "points"
INDEX_FILE = "points/index.json"
TRUTH_TILES_DIR = "truth/points"
#: Metres of driving per tile the simulator and the importers write by default: a quarter of a
#: processing tile (``guardrail process --tile-m 100``), so a tile's window (its 100 m and a
#: 10 m margin either side) reads little more than itself (about 150 m of points).
DEFAULT_DRIVE_TILE_M = 25.0


@dataclass(frozen=True)
class TileRecord:
    """One tile of a drive's points.

    Attributes
    ----------
    file : str, the tile's LAS/LAZ file relative to the drive folder
    truth : str or None, its truth file (class and object id per point), synthetic drives only
    gps_time : (first, last) GPS seconds of its points
    station_m : (lowest, highest) metres: its points' stations along the trajectory
    bounds_min, bounds_max : (3,) float64 map coordinates of its points' bounding box
    points : int, number of points
    """

    file: str
    truth: str | None
    gps_time: tuple[float, float]
    station_m: tuple[float, float]
    bounds_min: tuple[float, float, float]
    bounds_max: tuple[float, float, float]
    points: int

    def to_json(self) -> dict:
        return {
            "file": self.file,
            "truth": self.truth,
            "gps_time": list(self.gps_time),
            "station_m": list(self.station_m),
            "bounds_min": list(self.bounds_min),
            "bounds_max": list(self.bounds_max),
            "points": self.points,
        }

    @classmethod
    def from_json(cls, item: object, where: str) -> TileRecord:
        if not isinstance(item, dict):
            raise DriveFormatError(f"{where}: expected a tile record, got {item!r}")
        try:
            return cls(
                file=str(item["file"]),
                truth=None if item.get("truth") is None else str(item["truth"]),
                gps_time=_pair(item["gps_time"], f"{where}.gps_time"),
                station_m=_pair(item["station_m"], f"{where}.station_m"),
                bounds_min=_triple(item["bounds_min"], f"{where}.bounds_min"),
                bounds_max=_triple(item["bounds_max"], f"{where}.bounds_max"),
                points=int(item["points"]),
            )
        except KeyError as exc:
            raise DriveFormatError(f"{where}: lacks the key {exc.args[0]!r}") from exc
        except (TypeError, ValueError) as exc:
            raise DriveFormatError(f"{where}: a value is not a number ({exc})") from exc


def _pair(value: object, where: str) -> tuple[float, float]:
    lo, hi = (float(v) for v in value)  # type: ignore[attr-defined]
    if not lo <= hi:  # NaN fails too
        raise DriveFormatError(f"{where}: expected first <= last, got {value!r}")
    return lo, hi


def _triple(value: object, where: str) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in value)  # type: ignore[attr-defined]
    return x, y, z


@dataclass(frozen=True)
class TileIndex:
    """The tiles of a drive in time order, and which of them a window of stations touches."""

    tiles: tuple[TileRecord, ...]

    def __len__(self) -> int:
        return len(self.tiles)

    @property
    def points(self) -> int:
        return sum(t.points for t in self.tiles)

    def offsets(self) -> np.ndarray:
        """(T + 1,) int64: the drive-wide index of each tile's first point, then the total."""
        return np.concatenate([[0], np.cumsum([t.points for t in self.tiles])]).astype(np.int64)

    def touching(self, station_lo: float, station_hi: float) -> list[int]:
        """Tiles holding points at stations in [``station_lo``, ``station_hi``)."""
        return [
            i
            for i, t in enumerate(self.tiles)
            if t.points and t.station_m[0] < station_hi and t.station_m[1] >= station_lo
        ]

    def to_json(self) -> dict:
        return {
            "format": TILES_FORMAT,
            "format_version": TILES_FORMAT_VERSION,
            "tiles": [t.to_json() for t in self.tiles],
        }


def read_tile_index(root: str | os.PathLike, name: str = INDEX_FILE) -> TileIndex:
    """Read and check ``points/index.json`` of the drive folder ``root``.

    Raises
    ------
    MissingDriveFileError, DriveFormatError
        The index is missing, is not a tile index, or its tiles overlap in time.
    """
    path = Path(root) / name
    if not path.is_file():
        raise MissingDriveFileError(f"{path.parent}: tile index {path.name!r} is missing")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DriveFormatError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(data, dict) or data.get("format") != TILES_FORMAT:
        raise DriveFormatError(f"{path}: not a {TILES_FORMAT} index")
    if data.get("format_version") != TILES_FORMAT_VERSION:
        raise DriveFormatError(
            f"{path}: tile index version {data.get('format_version')!r} is not readable by this "
            f"version (reads {TILES_FORMAT_VERSION})"
        )
    items = data.get("tiles")
    if not isinstance(items, list):
        raise DriveFormatError(f"{path}: expected a list of tiles")
    tiles = tuple(TileRecord.from_json(item, f"{path}: tiles[{i}]") for i, item in enumerate(items))
    for i in range(1, len(tiles)):
        if tiles[i].gps_time[0] < tiles[i - 1].gps_time[1]:
            raise TimestampMismatchError(
                f"{path}: tile {i} starts at {tiles[i].gps_time[0]:.6f} s, before tile {i - 1} "
                f"ends ({tiles[i - 1].gps_time[1]:.6f} s); tiles must follow each other in time"
            )
    return TileIndex(tiles)


def _travelled(trajectory: Trajectory) -> np.ndarray:
    """(T,) float64 metres: horizontal distance driven at each trajectory sample."""
    step = np.linalg.norm(np.diff(trajectory.position[:, :2], axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(step)])


def vehicle_station(trajectory: Trajectory, gps_time: np.ndarray) -> np.ndarray:
    """(N,) float64 metres: the vehicle's distance driven (horizontal) at ``gps_time`` (N,) s,
    from the trajectory's first sample; constant beyond its ends."""
    travelled = _travelled(trajectory)
    return np.interp(np.asarray(gps_time, np.float64), trajectory.time, travelled)


def tile_boundaries(trajectory: Trajectory, tile_m: float | None) -> np.ndarray:
    """(K - 1,) float64 GPS seconds at which the vehicle passes 1, 2, ... times ``tile_m``
    metres (the starts of tiles 1..K-1); empty for ``tile_m`` None (one tile)."""
    travelled = _travelled(trajectory)
    if tile_m is None or travelled[-1] <= tile_m:
        return np.zeros(0)
    marks = np.arange(tile_m, travelled[-1], tile_m)
    # The first time each mark is reached (np.interp needs strictly increasing x: skip halts).
    moving = np.concatenate([[True], np.diff(travelled) > 0])
    return np.interp(marks, travelled[moving], trajectory.time[moving])


class TiledPointWriter:
    """Write a drive's points tile by tile, as they are produced, in time order.

    ``append`` takes consecutive chunks of points (each sorted by GPS time, later than the
    previous chunk); a tile is written as soon as the vehicle has passed its end, so the writer
    holds at most one tile and one chunk. ``close`` writes the last tile and the index.

    Parameters
    ----------
    folder : the drive folder being written (a staging folder)
    origin : (3,) float64 map coordinates of the local frame
    trajectory : the whole drive's trajectory (local frame)
    tile_m : metres of driving per tile; None: one tile
    compress : LAZ (True) or LAS (False)
    with_truth : chunks carry truth (class, object id per point)
    """

    def __init__(
        self,
        folder: Path,
        *,
        origin: np.ndarray,
        trajectory: Trajectory,
        tile_m: float | None = None,
        compress: bool = True,
        with_truth: bool = False,
    ) -> None:
        if tile_m is not None and not tile_m > 0:
            raise DriveFormatError(f"tiles must be longer than 0 m, got {tile_m}")
        self.folder = Path(folder)
        self.origin = np.asarray(origin, np.float64)
        self.trajectory = trajectory
        self.compress = compress
        self.with_truth = with_truth
        self._cuts = tile_boundaries(trajectory, tile_m)
        self._pending: list[dict[str, np.ndarray]] = []
        self._last_time = -np.inf
        self.records: list[TileRecord] = []
        (self.folder / TILES_DIR).mkdir(parents=True, exist_ok=True)
        if with_truth:
            (self.folder / TRUTH_TILES_DIR).mkdir(parents=True, exist_ok=True)

    def append(
        self,
        xyz: np.ndarray,
        gps_time: np.ndarray,
        intensity: np.ndarray,
        rotation: np.ndarray,
        phase: np.ndarray,
        truth_class: np.ndarray | None = None,
        truth_object: np.ndarray | None = None,
    ) -> None:
        """Add a chunk of points: (N, 3) float64 local xyz, (N,) gps_time s, intensity, rotation,
        phase, and with truth (N,) class and object id."""
        gps_time = np.asarray(gps_time, np.float64)
        if len(gps_time) == 0:
            return
        if np.any(np.diff(gps_time) < 0) or gps_time[0] < self._last_time:
            raise TimestampMismatchError("points must be appended in GPS time order")
        if self.with_truth and (truth_class is None or truth_object is None):
            raise DriveFormatError("this drive has truth: every chunk needs its truth")
        self._last_time = float(gps_time[-1])
        chunk = {
            "xyz": np.asarray(xyz, np.float64),
            "gps_time": gps_time,
            "intensity": np.asarray(intensity, np.uint16),
            "rotation": np.asarray(rotation),
            "phase": np.asarray(phase),
        }
        if self.with_truth:
            chunk["class"] = np.asarray(truth_class, np.uint8)
            chunk["object_id"] = np.asarray(truth_object, np.int32)
        self._pending.append(chunk)
        # Write every tile the vehicle has passed the end of.
        while (
            len(self.records) < len(self._cuts) and self._last_time >= self._cuts[len(self.records)]
        ):
            self._flush(self._cuts[len(self.records)])

    def close(self) -> TileIndex:
        """Write the last tile and ``points/index.json``; return the index."""
        self._flush(np.inf)
        # Tiles the vehicle passed without a point (a gap) stay out of the index.
        index = TileIndex(tuple(self.records))
        (self.folder / INDEX_FILE).write_text(json.dumps(index.to_json(), indent=1) + "\n")
        return index

    def _flush(self, before: float) -> None:
        """Write the pending points earlier than ``before`` (GPS s) as the next tile."""
        data: dict[str, np.ndarray] = {}
        if self._pending:
            merged = {k: np.concatenate([c[k] for c in self._pending]) for k in self._pending[0]}
            cut = int(np.searchsorted(merged["gps_time"], before, side="left"))
            data = {k: v[:cut] for k, v in merged.items()}
            rest = {k: v[cut:] for k, v in merged.items()}
            self._pending = [rest] if len(rest["gps_time"]) else []
        n = len(data.get("gps_time", ()))
        number = len(self.records)
        if n == 0:
            # An empty tile keeps its number so tile k always starts at the k-th cut.
            self.records.append(self._record(number, None, 0))
            return
        self.records.append(self._record(number, data, n))

    def _record(self, number: int, data: dict[str, np.ndarray] | None, n: int) -> TileRecord:
        suffix = "laz" if self.compress else "las"
        file = f"{TILES_DIR}/{number:06d}.{suffix}"
        truth = f"{TRUTH_TILES_DIR}/{number:06d}.npz" if self.with_truth else None
        if data is None:
            data = {
                "xyz": np.zeros((0, 3)),
                "gps_time": np.zeros(0),
                "intensity": np.zeros(0, np.uint16),
                "rotation": np.zeros(0, np.int64),
                "phase": np.zeros(0, np.int64),
                "class": np.zeros(0, np.uint8),
                "object_id": np.zeros(0, np.int32),
            }
        write_points(
            self.folder / file,
            data["xyz"],
            self.origin,
            data["gps_time"],
            data["intensity"],
            data["rotation"],
            data["phase"],
        )
        if truth is not None:
            np.savez_compressed(
                self.folder / truth,
                **{"class": data["class"], "object_id": data["object_id"]},  # type: ignore[arg-type]
            )
        if n:
            track = track_coordinates(data["xyz"], data["gps_time"], self.trajectory)
            station = (float(track.station.min()), float(track.station.max()))
            world = data["xyz"] + self.origin
            lo, hi = world.min(axis=0), world.max(axis=0)
            times = (float(data["gps_time"][0]), float(data["gps_time"][-1]))
        else:
            cuts = np.concatenate(
                [[self.trajectory.time[0]], self._cuts, [self.trajectory.time[-1]]]
            )
            times = (float(cuts[number]), float(cuts[min(number + 1, len(cuts) - 1)]))
            at = vehicle_station(self.trajectory, np.array(times))
            station = (float(at[0]), float(at[1]))
            lo = hi = self.trajectory.position[0] + self.origin
        return TileRecord(
            file=file,
            truth=truth,
            gps_time=times,
            station_m=(float(station[0]), float(station[1])),
            bounds_min=(float(lo[0]), float(lo[1]), float(lo[2])),
            bounds_max=(float(hi[0]), float(hi[1]), float(hi[2])),
            points=n,
        )
