"""Picking segments in the scene: viser gives a click ray or a screen rectangle, not points."""

from __future__ import annotations

import numpy as np


def pick_along_ray(
    xyz: np.ndarray,
    origin: np.ndarray,
    direction: np.ndarray,
    *,
    radius_m: float = 0.15,
    radius_per_m: float = 0.004,
) -> int | None:
    """The point a click ray hits first.

    A point is hit when it lies within ``radius_m + radius_per_m * depth`` of the ray (the
    allowance grows with depth, as a rendered point's footprint shrinks); the nearest hit along
    the ray wins.

    Parameters
    ----------
    xyz : (N, 3) float64, metres, the candidate points
    origin, direction : (3,) the ray, in the same frame (direction need not be unit length)

    Returns
    -------
    The index into ``xyz`` of the hit point, or None when the ray misses every point.
    """
    direction = np.asarray(direction, np.float64)
    direction = direction / np.linalg.norm(direction)
    offset = np.asarray(xyz, np.float64) - np.asarray(origin, np.float64)
    depth = offset @ direction
    miss = np.linalg.norm(offset - depth[:, None] * direction, axis=1)
    hit = np.flatnonzero((depth > 0) & (miss <= radius_m + radius_per_m * depth))
    if len(hit) == 0:
        return None
    return int(hit[np.argmin(depth[hit])])


def project_to_screen(
    xyz: np.ndarray,
    T_world_camera: np.ndarray,
    fov_y: float,
    aspect: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Screen coordinates of points seen by a pinhole camera (OpenCV convention, +z forward).

    Parameters
    ----------
    xyz : (N, 3) float64, world metres
    T_world_camera : (4, 4) camera pose
    fov_y : vertical field of view, radians
    aspect : width / height

    Returns
    -------
    uv : (N, 2) float64, 0..1 from the upper-left corner (viser's screen coordinates)
    in_front : (N,) bool
    """
    T_camera_world = np.linalg.inv(T_world_camera)
    p = np.asarray(xyz, np.float64) @ T_camera_world[:3, :3].T + T_camera_world[:3, 3]
    in_front = p[:, 2] > 1e-6
    z = np.where(in_front, p[:, 2], 1.0)
    half_h = np.tan(fov_y / 2.0)
    u = 0.5 + p[:, 0] / z / (2.0 * half_h * aspect)
    v = 0.5 + p[:, 1] / z / (2.0 * half_h)
    return np.stack([u, v], axis=1), in_front


def in_rectangle(
    uv: np.ndarray, in_front: np.ndarray, corner_min: np.ndarray, corner_max: np.ndarray
) -> np.ndarray:
    """(N,) bool: points in front of the camera whose screen position is inside the rectangle."""
    lo, hi = np.minimum(corner_min, corner_max), np.maximum(corner_min, corner_max)
    return in_front & np.all((uv >= lo) & (uv <= hi), axis=1)
