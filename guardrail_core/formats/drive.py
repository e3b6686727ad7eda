"""The drive folder: what a mapping vehicle recorded, and for synthetic drives, the truth.

Layout (documented in ``docs/drive-format.md``)::

    drive.json        format version, CRS, float64 local origin, scanner, file names
    points/           LAS 1.4 tiles along the trajectory (gps_time, intensity, extra dims
                      rotation, phase) and their index.json (formats/drive_tiles.py)
    trajectory.csv    time, x, y, z (map coordinates), roll, pitch, yaw (radians)
    cameras.json      intrinsics, Brown-Conrady distortion, T_vehicle_camera per camera
    images.json       one record per image: file, camera, gps_time, T_world_camera (map frame)
    images/<camera>/<n>.jpg
    truth/            synthetic drives only: points/<tile>.npz (class, object_id per point),
                      masks/<camera>/<n>.png (class per pixel), objects.json (exact geometry)

:func:`load_drive` validates everything and raises a named :class:`~guardrail_core.errors.DriveError`
subclass that says what is wrong. Producers (the simulator, the importers) call
:func:`~guardrail_core.formats.drive_writer.write_drive_files` inside
:func:`~guardrail_core.formats.atomic.staged_folder`, so a failed write never leaves a
half-written drive and never deletes one of their inputs.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from guardrail_core.errors import (
    DriveDimensionError,
    DriveFormatError,
    MissingDriveFileError,
    NonFiniteCoordinatesError,
    TimestampMismatchError,
)
from guardrail_core.formats.drive_tiles import INDEX_FILE, TileIndex, read_tile_index
from guardrail_core.io.las import read_points
from guardrail_core.sensors.camera import Camera
from guardrail_core.sensors.scanner import ScannerParams
from guardrail_core.sensors.trajectory import Trajectory

FORMAT_NAME = "guardrail-drive"
FORMAT_VERSION = "2.0"
#: The major version this reader reads (its minors only add keys). 0.2.0, the first release, reads
#: no 1.x drive (one points file, written before the point tiles): those are refused by name.
READS_MAJOR = FORMAT_VERSION.split(".")[0]
TRAJECTORY_COLUMNS = ("time", "x", "y", "z", "roll", "pitch", "yaw")


@dataclass(frozen=True)
class PointCloud:
    """Points of a drive, ordered by GPS time.

    Attributes
    ----------
    xyz : (N, 3) float64, metres, local frame (drive origin subtracted)
    gps_time : (N,) float64, seconds
    intensity : (N,) uint16
    rotation, phase : (N,) int64, the scan lattice (§3.1)
    """

    xyz: np.ndarray
    gps_time: np.ndarray
    intensity: np.ndarray
    rotation: np.ndarray
    phase: np.ndarray

    def __len__(self) -> int:
        return int(self.xyz.shape[0])

    def take(self, index: np.ndarray) -> PointCloud:
        """The points at ``index`` ((M,) int or (N,) bool), in that order."""
        return PointCloud(*(getattr(self, name)[index] for name in _CLOUD_FIELDS))


@dataclass(frozen=True)
class ImageRecord:
    """One camera exposure.

    Attributes
    ----------
    file : str, path relative to the drive folder
    camera : str, name of a camera in ``cameras.json``
    gps_time : float, seconds (mid-exposure)
    T_world_camera : (4, 4) float64, camera pose in the local frame
    """

    file: str
    camera: str
    gps_time: float
    T_world_camera: np.ndarray


@dataclass(frozen=True)
class Truth:
    """Ground truth of a synthetic drive.

    Attributes
    ----------
    point_class : (N,) uint8, :class:`~guardrail_core.classes.TruthClass` of every point
    point_object : (N,) int32, object id of every point (ids of ``objects``; 0 = scenery)
    objects : list of dict, ``truth/objects.json`` (coordinates in the local frame)
    mask_files : dict image file -> mask file (relative to the drive folder)
    """

    point_class: np.ndarray
    point_object: np.ndarray
    objects: list[dict]
    mask_files: dict[str, str]


@dataclass
class Drive:
    """A drive folder in memory. Images and masks stay on disk until asked for."""

    root: Path
    crs: str
    origin: np.ndarray
    scanner: ScannerParams
    trajectory: Trajectory
    points: PointCloud
    cameras: dict[str, Camera]
    images: list[ImageRecord]
    truth: Truth | None = None
    source: dict = field(default_factory=dict)
    #: the point tiles the points came from (None: one tile of all the points)
    tiles: TileIndex | None = None

    def tile_offsets(self) -> np.ndarray:
        """(T + 1,) int64: the index of each point tile's first point, then the total."""
        if self.tiles is None or self.tiles.points != len(self.points):
            return np.array([0, len(self.points)], np.int64)
        return self.tiles.offsets()

    def read_image(self, record: ImageRecord) -> np.ndarray:
        """The image (H, W, 3) uint8 RGB of a record."""
        return read_rgb_image(self.root, record)

    def read_mask(self, record: ImageRecord) -> np.ndarray:
        """The truth class mask (H, W) uint8 of a record (synthetic drives only)."""
        if self.truth is None:
            raise MissingDriveFileError(f"{self.root}: this drive has no truth/ folder")
        return _read_image(self.root / self.truth.mask_files[record.file], cv2.IMREAD_UNCHANGED)


def read_rgb_image(root: Path, record: ImageRecord) -> np.ndarray:
    """The image (H, W, 3) uint8 RGB of a record of the drive folder ``root``."""
    return _read_image(root / record.file, cv2.IMREAD_COLOR)[:, :, ::-1].copy()


def _read_image(path: Path, flags: int) -> np.ndarray:
    if not path.is_file():
        raise MissingDriveFileError(f"{path}: image file is missing")
    image = cv2.imread(str(path), flags)
    if image is None:
        raise DriveFormatError(f"{path}: not a readable image")
    return image


# ----------------------------------------------------------------------------------- loading


def _require(path: Path, what: str) -> Path:
    if not path.is_file():
        raise MissingDriveFileError(f"{path.parent}: {what} {path.name!r} is missing")
    return path


def _read_json(path: Path, what: str) -> object:
    _require(path, what)
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DriveFormatError(f"{path}: not valid JSON ({exc})") from exc


def _matrix(value: object, shape: tuple[int, ...], where: str) -> np.ndarray:
    try:
        array = np.asarray(value, np.float64)
    except (TypeError, ValueError) as exc:
        raise DriveFormatError(f"{where}: expected numbers of shape {shape}") from exc
    if array.shape != shape:
        raise DriveDimensionError(f"{where}: expected shape {shape}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise NonFiniteCoordinatesError(f"{where}: contains NaN or infinity")
    return array


def read_trajectory_csv(path: Path, origin: np.ndarray, reference_height_m: float) -> Trajectory:
    """Read ``trajectory.csv`` (columns ``TRAJECTORY_COLUMNS``; map coordinates) to a local Trajectory."""
    _require(path, "trajectory")
    with path.open(newline="") as handle:
        header = next(csv.reader([handle.readline()]), None)
        if header is None or tuple(h.strip() for h in header) != TRAJECTORY_COLUMNS:
            raise DriveDimensionError(
                f"{path}: expected the header {','.join(TRAJECTORY_COLUMNS)}, got {header}"
            )
        try:  # NumPy's C reader: a survey's trajectory has millions of rows
            with warnings.catch_warnings():  # no rows: refused below, by name
                warnings.simplefilter("ignore", UserWarning)
                data = np.loadtxt(handle, delimiter=",", dtype=np.float64, comments=None, ndmin=2)
        except ValueError as exc:
            raise DriveFormatError(
                f"{path}: a row is malformed or a value is not a number ({exc})"
            ) from exc
    if data.ndim != 2 or data.shape[1] != 7 or data.shape[0] < 2:
        raise DriveDimensionError(
            f"{path}: expected at least 2 rows of 7 columns, got shape {data.shape}"
        )
    if not np.all(np.isfinite(data)):
        bad = np.flatnonzero(~np.isfinite(data).all(axis=1))
        raise NonFiniteCoordinatesError(f"{path}: rows {bad[:5].tolist()} contain NaN or infinity")
    if np.any(np.diff(data[:, 0]) <= 0):
        raise TimestampMismatchError(f"{path}: times must be strictly increasing")
    return Trajectory(
        time=data[:, 0],
        position=data[:, 1:4] - origin,
        attitude=data[:, 4:7],
        reference_height_m=reference_height_m,
    )


def _camera_from_json(item: dict, where: str) -> Camera:
    try:
        name = str(item["name"])
        width, height = int(item["width"]), int(item["height"])
        return Camera(
            name=name,
            width=width,
            height=height,
            K=_matrix(item["K"], (3, 3), f"{where}: {name}.K"),
            dist=_matrix(item["dist"], (5,), f"{where}: {name}.dist"),
            T_vehicle_camera=_matrix(
                item["T_vehicle_camera"], (4, 4), f"{where}: {name}.T_vehicle_camera"
            ),
        )
    except KeyError as exc:
        raise DriveFormatError(f"{where}: a camera lacks the key {exc.args[0]!r}") from exc


@dataclass
class DriveSource:
    """A drive folder opened without reading its points: everything but the point tiles, which
    :meth:`read_tiles` reads on demand (survey-scale drives do not fit in memory whole).

    Attributes
    ----------
    tiles : the point tiles in time order
    has_truth : the drive has truth (and truth was asked for)
    objects : ``truth/objects.json`` (synthetic drives; empty otherwise)
    """

    root: Path
    crs: str
    origin: np.ndarray
    scanner: ScannerParams
    trajectory: Trajectory
    cameras: dict[str, Camera]
    images: list[ImageRecord]
    tiles: TileIndex
    has_truth: bool
    objects: list[dict]
    source: dict = field(default_factory=dict)

    def read_tiles(self, ids: Sequence[int]) -> tuple[PointCloud, Truth | None]:
        """The points of tiles ``ids`` (ascending), concatenated, and their truth.

        Raises
        ------
        MissingDriveFileError, DriveFormatError, DriveDimensionError, NonFiniteCoordinatesError,
        TimestampMismatchError
            Naming the tile file that is missing or wrong.
        """
        parts = [self._read_tile(int(i)) for i in ids]
        if not parts:
            empty = PointCloud(
                np.zeros((0, 3)),
                np.zeros(0),
                np.zeros(0, np.uint16),
                *([np.zeros(0, np.int64)] * 2),
            )
            truth_arrays = (np.zeros(0, np.uint8), np.zeros(0, np.int32))
            parts = [(empty, truth_arrays if self.has_truth else None)]
        clouds = [p for p, _ in parts]
        points = PointCloud(
            *(np.concatenate([getattr(c, name) for c in clouds]) for name in _CLOUD_FIELDS)
        )
        truth = None
        if self.has_truth:
            truth = Truth(
                np.concatenate([t[0] for _, t in parts if t is not None]),
                np.concatenate([t[1] for _, t in parts if t is not None]),
                self.objects,
                _mask_files(self.images),
            )
        return points, truth

    def read_truth_tile(self, i: int) -> np.ndarray:
        """(n,) uint8 truth class of every point of tile ``i`` (its LAS file is not read).

        Raises
        ------
        MissingDriveFileError
            The drive has no truth (or it was not asked for), or the tile's truth file is missing.
        DriveFormatError, DriveDimensionError
            The truth file is damaged or does not hold one class per point of the tile.
        """
        record = self.tiles.tiles[i]
        if not self.has_truth or record.truth is None:
            raise MissingDriveFileError(f"{self.root}: tile {record.file} has no truth file")
        return _load_truth_arrays(self.root / record.truth, record.points)[0]

    def read_image(self, record: ImageRecord) -> np.ndarray:
        """The image (H, W, 3) uint8 RGB of a record."""
        return read_rgb_image(self.root, record)

    def drive(self, points: PointCloud, truth: Truth | None = None) -> Drive:
        """A :class:`Drive` of these points (a window of this drive, or all of it)."""
        return Drive(
            root=self.root,
            crs=self.crs,
            origin=self.origin,
            scanner=self.scanner,
            trajectory=self.trajectory,
            points=points,
            cameras=self.cameras,
            images=self.images,
            truth=truth,
            source=self.source,
        )

    def _read_tile(self, i: int) -> tuple[PointCloud, tuple[np.ndarray, np.ndarray] | None]:
        record = self.tiles.tiles[i]
        points = _load_points(self.root / record.file, self.origin, self.scanner)
        if len(points) != record.points:
            raise DriveDimensionError(
                f"{self.root / record.file}: holds {len(points)} points, the tile index says "
                f"{record.points}"
            )
        t_lo, t_hi = self.trajectory.time[0], self.trajectory.time[-1]
        if len(points) and (points.gps_time.min() < t_lo or points.gps_time.max() > t_hi):
            raise TimestampMismatchError(
                f"{self.root / record.file}: points span GPS time {points.gps_time.min():.6f}.."
                f"{points.gps_time.max():.6f} s but the trajectory covers only "
                f"{t_lo:.6f}..{t_hi:.6f} s"
            )
        truth = None
        if self.has_truth:
            if record.truth is None:
                raise MissingDriveFileError(f"{self.root}: tile {record.file} has no truth file")
            truth = _load_truth_arrays(self.root / record.truth, len(points))
        return points, truth


_CLOUD_FIELDS = ("xyz", "gps_time", "intensity", "rotation", "phase")


def check_format_version(meta: dict, path: Path) -> None:
    """Refuse a ``drive.json`` (``meta``, read from ``path``) of a major version other than
    :data:`READS_MAJOR`.

    Raises
    ------
    DriveFormatError
        Saying what to do: an older drive (1.x) is imported or simulated again, a newer one needs
        a newer version of guardrail.
    """
    version = str(meta.get("format_version"))
    major = version.split(".")[0]
    if major == READS_MAJOR:
        return
    if major.isdigit() and int(major) < int(READS_MAJOR):
        hint = "import or simulate the drive again with this version of guardrail"
    else:
        hint = "it was written by a newer version of guardrail"
    raise DriveFormatError(
        f"{path}: format_version {version} is not readable by this version (reads "
        f"{READS_MAJOR}.x); {hint}"
    )


def open_drive(root: str | os.PathLike, *, with_truth: bool = True) -> DriveSource:
    """Open and validate a drive folder, reading everything but its points.

    Reads format 2.x (point tiles with ``points/index.json``); other major versions are refused
    (:func:`check_format_version`).

    Raises
    ------
    MissingDriveFileError, DriveFormatError, DriveDimensionError, TimestampMismatchError,
    NonFiniteCoordinatesError
        Each names the file and what is wrong with it.
    """
    root = Path(root)
    if not root.is_dir():
        raise MissingDriveFileError(f"{root}: no such drive folder")
    meta = _read_json(root / "drive.json", "drive description")
    if not isinstance(meta, dict) or meta.get("format") != FORMAT_NAME:
        raise DriveFormatError(f"{root / 'drive.json'}: not a {FORMAT_NAME} description")
    check_format_version(meta, root / "drive.json")
    try:
        origin = _matrix(meta["origin"], (3,), "drive.json: origin")
        crs = str(meta["crs"])
        scanner = ScannerParams.from_json(meta["scanner"])
        files = meta["files"]
        reference_height = float(meta["trajectory"]["reference_height_m"])
    except KeyError as exc:
        raise DriveFormatError(f"{root / 'drive.json'}: lacks the key {exc.args[0]!r}") from exc

    trajectory = read_trajectory_csv(root / files["trajectory"], origin, reference_height)
    has_truth = bool(with_truth and meta.get("truth"))
    truth_dir = str(meta.get("truth") or "truth")
    tiles = read_tile_index(root, files["points"])
    t_lo, t_hi = trajectory.time[0], trajectory.time[-1]

    camera_list = _read_json(root / files["cameras"], "camera calibration")
    if not isinstance(camera_list, list):
        raise DriveFormatError(f"{root / files['cameras']}: expected a list of cameras")
    cameras = {
        c.name: c for c in (_camera_from_json(item, files["cameras"]) for item in camera_list)
    }
    images = _load_images(root, files["images"], cameras, origin, (t_lo, t_hi))
    objects: list[dict] = []
    if has_truth:
        loaded = _read_json(root / truth_dir / "objects.json", "truth geometry")
        if not isinstance(loaded, list):
            raise DriveFormatError(
                f"{root / truth_dir / 'objects.json'}: expected a list of objects"
            )
        objects = list(loaded)
    return DriveSource(
        root=root,
        crs=crs,
        origin=origin,
        scanner=scanner,
        trajectory=trajectory,
        cameras=cameras,
        images=images,
        tiles=tiles,
        has_truth=has_truth,
        objects=objects,
        source=meta.get("source", {}),
    )


def load_drive(root: str | os.PathLike, *, with_truth: bool = True) -> Drive:
    """Load and validate a drive folder with all of its points (see :func:`open_drive`).

    Raises
    ------
    MissingDriveFileError, DriveFormatError, DriveDimensionError, TimestampMismatchError,
    NonFiniteCoordinatesError
        Each names the file and what is wrong with it.
    """
    source = open_drive(root, with_truth=with_truth)
    points, truth = source.read_tiles(range(len(source.tiles)))
    return dataclasses.replace(source.drive(points, truth), tiles=source.tiles)


def _load_points(path: Path, origin: np.ndarray, scanner: ScannerParams) -> PointCloud:
    _require(path, "point cloud")
    data = read_points(path, origin)
    if "rotation" in data and "phase" in data:
        rotation, phase = data["rotation"], data["phase"]
    else:  # §3.1: the lattice follows from GPS time and the scanner parameters.
        rotation, phase = scanner.lattice_from_gps_time(data["gps_time"])
    return PointCloud(data["xyz"], data["gps_time"], data["intensity"], rotation, phase)


def _load_images(
    root: Path, name: str, cameras: dict[str, Camera], origin: np.ndarray, span: tuple[float, float]
) -> list[ImageRecord]:
    items = _read_json(root / name, "image list")
    if not isinstance(items, list):
        raise DriveFormatError(f"{root / name}: expected a list of image records")
    images = []
    for i, item in enumerate(items):
        where = f"{name}[{i}]"
        try:
            file, camera, gps_time = str(item["file"]), str(item["camera"]), float(item["gps_time"])
            pose = _matrix(item["T_world_camera"], (4, 4), f"{where}.T_world_camera")
        except KeyError as exc:
            raise DriveFormatError(f"{where}: lacks the key {exc.args[0]!r}") from exc
        except (TypeError, ValueError) as exc:
            raise DriveFormatError(f"{where}: gps_time is not a number ({exc})") from exc
        if camera not in cameras:
            raise DriveFormatError(f"{where}: camera {camera!r} has no calibration in cameras.json")
        if Path(file).is_absolute() or ".." in Path(file).parts:
            raise DriveFormatError(f"{where}: file {file!r} must be a path inside the drive folder")
        if not np.isfinite(gps_time):
            raise NonFiniteCoordinatesError(f"{where}: gps_time is not finite")
        if not span[0] <= gps_time <= span[1]:
            raise TimestampMismatchError(
                f"{where}: image time {gps_time:.6f} s lies outside the trajectory "
                f"{span[0]:.6f}..{span[1]:.6f} s"
            )
        _require(root / file, "image")
        pose = pose.copy()
        pose[:3, 3] -= origin
        images.append(ImageRecord(file, camera, gps_time, pose))
    return images


def _load_truth_arrays(path: Path, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Class (N,) uint8 and object id (N,) int32 of a tile's points from its truth file."""
    _require(path, "truth of the points")
    try:
        with np.load(path, allow_pickle=False) as npz:
            if "class" not in npz or "object_id" not in npz:
                raise DriveFormatError(f"{path}: needs the arrays 'class' and 'object_id'")
            point_class, point_object = npz["class"], npz["object_id"]
    except (OSError, ValueError) as exc:
        raise DriveFormatError(f"{path}: not a readable truth file ({exc})") from exc
    if point_class.shape != (n_points,) or point_object.shape != (n_points,):
        raise DriveDimensionError(
            f"{path}: truth has {point_class.shape[0]} classes and {point_object.shape[0]} "
            f"object ids for {n_points} points"
        )
    return point_class.astype(np.uint8), point_object.astype(np.int32)


def _mask_files(images: list[ImageRecord]) -> dict[str, str]:
    """Image file -> its truth mask file (synthetic drives)."""
    mask_files = {}
    for record in images:
        mask = Path("truth") / "masks" / Path(record.file).relative_to("images").with_suffix(".png")
        mask_files[record.file] = str(mask)
    return mask_files


#: Folders of a drive besides the files ``drive.json`` names (``points/``: the tiles);
#: ``review/`` holds the review
#: app's labels (``formats.label_store``), which no command may delete either.
DRIVE_FOLDERS = ("points", "images", "truth", "review")
_DEFAULT_FILES = {
    "points": INDEX_FILE,
    "trajectory": "trajectory.csv",
    "cameras": "cameras.json",
    "images": "images.json",
}


def drive_parts(root: str | os.PathLike) -> list[Path]:
    """Every file and folder of the drive folder ``root``: ``drive.json``, the files it names
    (their usual names when it cannot be read) and :data:`DRIVE_FOLDERS`.

    A command that reads a drive lists these as its inputs
    (:func:`guardrail_core.formats.atomic.check_output`) rather than the folder itself: an output
    may then live inside the drive folder (``DRIVE/run``) but never replace a part of the drive.
    """
    root = Path(root)
    names = dict(_DEFAULT_FILES)
    try:
        meta = json.loads((root / "drive.json").read_text())
        names.update({key: str(value) for key, value in meta["files"].items()})
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        pass  # load_drive refuses a broken drive.json; here its parts keep their usual names
    return [root / "drive.json", *(root / name for name in names.values())] + [
        root / name for name in DRIVE_FOLDERS
    ]
