"""Camera calibration and scanner parameters from OpenCV YAML, plain YAML or JSON files.

A calibration file holds one camera or several. Several: a top-level mapping from camera name to
a block. One: the block itself at the top level, named by its ``camera_name`` (or ``name``) key,
else by the file's stem. A JSON file may also be a list of blocks with ``name`` (the drive's own
``cameras.json``). A block has

==========================================  ==========================================================
``camera_matrix`` (or ``K``)                 3 x 3 intrinsics, pixels
``distortion_coefficients`` (or ``dist``)    Brown-Conrady k1, k2, p1, p2[, k3[, ...]] in OpenCV order;
                                             beyond the fifth, coefficients must be zero
``image_width``, ``image_height``            pixels (or ``width``, ``height``)
``T_vehicle_camera``                         4 x 4, camera frame (OpenCV) to vehicle frame; or one
                                             of the mountings on a LiDAR below
``distortion_model`` (optional)              ``plumb_bob``, ``radtan`` or ``brown-conrady...``
==========================================  ==========================================================

A matrix may be an ``!!opencv-matrix`` (as ``cv2.FileStorage`` writes it), a ``{rows, cols,
data}`` mapping (as ROS ``camera_info`` YAML has it), a nested list or a flat list.

For frames of one LiDAR (``guardrail import lidar``) the vehicle frame is the LiDAR's, and a
camera's mounting may be given as calibration tools write it: ``T_lidar_camera`` (camera to
LiDAR, the same as ``T_vehicle_camera``), or ``T_camera_lidar``, ``lidar_to_camera`` or
``T_cam_velo`` (LiDAR to camera: a LiDAR point ``p`` lands at ``T @ p`` in the camera's frame;
4 x 4, or 3 x 4 as KITTI's ``Tr``). One of them, once.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import yaml

from guardrail_core.errors import MissingSourceFileError, SourceFormatError
from guardrail_core.geom.frames import invert_transform, make_transform, rotation_from_euler
from guardrail_core.sensors.camera import Camera

#: Camera names become folder names under ``images/``.
CAMERA_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
#: Distortion models that are the Brown-Conrady polynomial of :class:`Camera` (lower case).
BROWN_CONRADY_MODELS = ("plumb_bob", "radtan", "radial-tangential", "opencv", "brown")
_ALIASES = {
    "K": ("camera_matrix", "K"),
    "dist": ("distortion_coefficients", "dist"),
    "width": ("image_width", "width"),
    "height": ("image_height", "height"),
}
#: A rotation block of a 4 x 4 transform may be off orthonormal by this much (calibrations are
#: often written with six decimals); a transposed or scaled matrix is far off.
ROTATION_TOLERANCE = 1e-3


def require_file(path: str | os.PathLike, what: str) -> Path:
    """``path`` as a Path if it is a file, else :class:`MissingSourceFileError` naming ``what``."""
    path = Path(path)
    if not path.is_file():
        raise MissingSourceFileError(f"{path}: {what} file is missing")
    return path


# ------------------------------------------------------------------------------- YAML / JSON


class _OpenCvLoader(yaml.SafeLoader):
    """PyYAML's safe loader that also reads OpenCV's ``!!opencv-matrix`` nodes."""


def _opencv_matrix(loader: yaml.SafeLoader, node: yaml.Node) -> np.ndarray:
    if not isinstance(node, yaml.MappingNode):
        raise yaml.constructor.ConstructorError(
            None, None, "an !!opencv-matrix must be a mapping", node.start_mark
        )
    fields = loader.construct_mapping(node, deep=True)
    try:
        shape = (
            tuple(int(v) for v in fields["sizes"])
            if "sizes" in fields
            else (int(fields["rows"]), int(fields["cols"]))
        )
        return np.asarray(fields["data"], np.float64).reshape(shape)
    except (KeyError, TypeError, ValueError) as exc:
        raise yaml.constructor.ConstructorError(
            None, None, f"a malformed !!opencv-matrix ({exc})", node.start_mark
        ) from exc


_OpenCvLoader.add_constructor("tag:yaml.org,2002:opencv-matrix", _opencv_matrix)
_OpenCvLoader.add_constructor("tag:yaml.org,2002:opencv-nd-matrix", _opencv_matrix)


def read_structured_file(path: str | Path, what: str) -> object:
    """Parse a JSON (``.json``) or YAML file, OpenCV's ``cv2.FileStorage`` YAML included.

    Raises
    ------
    MissingSourceFileError, SourceFormatError
    """
    path = require_file(path, what)
    try:
        text = path.read_text()
    except UnicodeDecodeError as exc:
        raise SourceFormatError(f"{path}: {what} file is not text ({exc})") from exc
    try:
        if path.suffix.lower() == ".json":
            return json.loads(text)
        # OpenCV writes "%YAML:1.0" (not YAML syntax) or "%YAML 1.2" (a version PyYAML refuses).
        text = re.sub(r"\A\s*%YAML[:\s][^\n]*\n", "", text)
        return yaml.load(text, Loader=_OpenCvLoader)  # noqa: S506 (a SafeLoader subclass)
    except (json.JSONDecodeError, yaml.YAMLError) as exc:
        raise SourceFormatError(f"{path}: {what} file is not valid JSON/YAML ({exc})") from exc


def as_matrix(value: object, shape: tuple[int, ...], where: str) -> np.ndarray:
    """A float64 array of ``shape`` from a matrix, a ``{rows, cols, data}`` mapping, a nested or
    a flat list; :class:`SourceFormatError` naming ``where`` otherwise."""
    if isinstance(value, Mapping) and "data" in value:
        value = value["data"]
    try:
        array = np.asarray(value, np.float64)
    except (TypeError, ValueError) as exc:
        raise SourceFormatError(f"{where}: expected numbers of shape {shape}") from exc
    if array.size != int(np.prod(shape)):
        raise SourceFormatError(f"{where}: expected shape {shape}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise SourceFormatError(f"{where}: contains NaN or infinity")
    return array.reshape(shape)


def _flat_numbers(value: object, message: str) -> np.ndarray:
    """(K,) float64 of a matrix, a ``{rows, cols, data}`` mapping or a list; else
    :class:`SourceFormatError` with ``message``."""
    if isinstance(value, Mapping) and "data" in value:
        value = value["data"]
    try:
        return np.asarray(value, np.float64).ravel()
    except (TypeError, ValueError) as exc:
        raise SourceFormatError(message) from exc


def as_rigid_transform(value: object, where: str) -> np.ndarray:
    """A 4 x 4 rigid transform; its last row must be (0, 0, 0, 1) and its rotation orthonormal."""
    t = as_matrix(value, (4, 4), where)
    r = t[:3, :3]
    if (
        not np.allclose(t[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9)
        or np.abs(r.T @ r - np.eye(3)).max() > ROTATION_TOLERANCE
        or np.linalg.det(r) < 0
    ):
        raise SourceFormatError(
            f"{where}: not a rigid transform (last row must be 0 0 0 1, the 3 x 3 block a rotation)"
        )
    return t


def mount_transform(value: object, where: str) -> np.ndarray:
    """A mounting ``T_vehicle_sensor`` (4, 4) from 16 numbers (a 4 x 4 matrix, row-major) or six:
    x, y, z (metres, vehicle frame), roll, pitch, yaw (degrees, ``Rz(yaw) Ry(pitch) Rx(roll)``)."""
    if isinstance(value, str):
        value = [v for v in re.split(r"[\s,]+", value.strip()) if v]
    flat = _flat_numbers(value, f"{where}: expected 6 or 16 numbers")
    if flat.size == 16:
        return as_rigid_transform(flat, where)
    if flat.size != 6 or not np.all(np.isfinite(flat)):
        raise SourceFormatError(
            f"{where}: expected 16 numbers (4 x 4) or 6 (x, y, z m, roll, pitch, yaw degrees), "
            f"got {flat.size}"
        )
    rotation = rotation_from_euler(*np.deg2rad(flat[3:]))
    return make_transform(rotation, flat[:3])


# ----------------------------------------------------------------------------------- cameras


def _field(block: Mapping, key: str, where: str) -> object:
    for name in _ALIASES[key]:
        if name in block:
            return block[name]
    raise SourceFormatError(f"{where}: lacks {' or '.join(repr(n) for n in _ALIASES[key])}")


def _positive_int(value: object, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | float | str | np.number):
        raise SourceFormatError(f"{where}: expected a whole number, got {value!r}")
    try:
        number = float(value)
    except ValueError as exc:
        raise SourceFormatError(f"{where}: expected a whole number, got {value!r}") from exc
    if not number.is_integer() or number <= 0:
        raise SourceFormatError(f"{where}: expected a positive whole number, got {value!r}")
    return int(number)


def _is_camera_block(value: object) -> bool:
    return isinstance(value, Mapping) and any(k in value for k in _ALIASES["K"])


def camera_from_block(name: str, block: Mapping, where: str) -> Camera:
    """A :class:`Camera` from one calibration block (keys in the module docstring)."""
    where = f"{where}: camera {name!r}"
    if not CAMERA_NAME.match(name):
        raise SourceFormatError(
            f"{where}: a camera name may hold letters, digits, '_', '.', '-' (it names a folder)"
        )
    model = str(block.get("distortion_model", "plumb_bob")).lower()
    if not any(model.startswith(m) for m in BROWN_CONRADY_MODELS):
        raise SourceFormatError(
            f"{where}: distortion_model {model!r} is not the Brown-Conrady (plumb_bob) model"
        )
    K = as_matrix(_field(block, "K", where), (3, 3), f"{where}: camera_matrix")
    if not (K[0, 0] > 0 and K[1, 1] > 0 and np.allclose(K[2], [0.0, 0.0, 1.0])):
        raise SourceFormatError(f"{where}: camera_matrix needs fx, fy > 0 and a last row 0 0 1")
    coefficients = _flat_numbers(
        _field(block, "dist", where), f"{where}: distortion_coefficients are not numbers"
    )
    if coefficients.size not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(coefficients)):
        raise SourceFormatError(
            f"{where}: expected 4, 5, 8, 12 or 14 finite distortion coefficients, got "
            f"{coefficients.size}"
        )
    if np.any(coefficients[5:] != 0):
        raise SourceFormatError(
            f"{where}: only k1, k2, p1, p2, k3 are supported; coefficients beyond the fifth "
            f"(rational or thin-prism model) must be zero, got {coefficients[5:].tolist()}"
        )
    dist = np.zeros(5)
    dist[: min(5, coefficients.size)] = coefficients[:5]
    width = _positive_int(_field(block, "width", where), f"{where}: image_width")
    height = _positive_int(_field(block, "height", where), f"{where}: image_height")
    return Camera(name, width, height, K, dist, _camera_mounting(block, where))


#: A camera's mounting keys: True where the matrix maps the vehicle (LiDAR) into the camera.
_MOUNTINGS = {
    "T_vehicle_camera": False,
    "T_lidar_camera": False,
    "T_camera_lidar": True,
    "lidar_to_camera": True,
    "T_cam_velo": True,
}


def _camera_mounting(block: Mapping, where: str) -> np.ndarray:
    """(4, 4) ``T_vehicle_camera`` from whichever mounting key the block has (module docstring)."""
    given = [key for key in _MOUNTINGS if key in block]
    if len(given) != 1:
        raise SourceFormatError(
            f"{where}: expected one of {', '.join(repr(k) for k in _MOUNTINGS)}, got "
            f"{given or 'none'}"
        )
    key = given[0]
    flat = _flat_numbers(block[key], f"{where}: {key} is not numbers")
    if flat.size == 12:  # 3 x 4, as KITTI's Tr
        flat = np.concatenate([flat, [0.0, 0.0, 0.0, 1.0]])
    transform = as_rigid_transform(flat, f"{where}: {key}")
    return invert_transform(transform) if _MOUNTINGS[key] else transform


def read_calibration(path: str | Path) -> list[Camera]:
    """The cameras of one calibration file (OpenCV YAML, plain YAML or JSON; module docstring).

    Raises
    ------
    MissingSourceFileError
        The file is missing.
    SourceFormatError
        It is not JSON/YAML, or a camera lacks a key, has a matrix of the wrong shape, an
        unsupported distortion model or a bad name.
    """
    path = Path(path)
    data = read_structured_file(path, "camera calibration")
    where = str(path)
    if isinstance(data, list):
        blocks: list[tuple[str, object]] = []
        for i, item in enumerate(data):
            if not isinstance(item, Mapping) or "name" not in item:
                raise SourceFormatError(f"{where}[{i}]: expected a camera with a 'name'")
            blocks.append((str(item["name"]), item))
    elif _is_camera_block(data):
        assert isinstance(data, Mapping)
        name = data.get("camera_name", data.get("name", path.stem))
        blocks = [(str(name), data)]
    elif isinstance(data, Mapping) and data:
        blocks = [(str(name), block) for name, block in data.items()]
    else:
        raise SourceFormatError(
            f"{where}: expected a camera block, a mapping camera name -> block, or a list of cameras"
        )
    cameras = []
    for name, block in blocks:
        if not isinstance(block, Mapping):
            raise SourceFormatError(f"{where}: camera {name!r} is not a mapping of keys")
        cameras.append(camera_from_block(name, block, where))
    return cameras


def read_calibrations(paths: Sequence[str | Path]) -> dict[str, Camera]:
    """The cameras of several calibration files by name; a name given twice is an error."""
    cameras: dict[str, Camera] = {}
    origin: dict[str, Path] = {}
    for path in paths:
        for camera in read_calibration(path):
            if camera.name in cameras:
                raise SourceFormatError(
                    f"{path}: camera {camera.name!r} is calibrated again (first in "
                    f"{origin[camera.name]})"
                )
            cameras[camera.name] = camera
            origin[camera.name] = Path(path)
    return cameras
