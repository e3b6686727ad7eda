"""Picking segments in the scene: viser gives a click ray or a screen rectangle, not points."""

from __future__ import annotations

import numpy as np
import viser
import viser.transforms as vtf


def camera_pose(camera: viser.CameraHandle) -> np.ndarray:
    """(4, 4) T_world_camera of a browser's camera."""
    T = np.eye(4)
    T[:3, :3] = vtf.SO3(np.asarray(camera.wxyz)).as_matrix()
    T[:3, 3] = camera.position
    return T


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


def in_polygon(uv: np.ndarray, in_front: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(N,) bool: points in front of the camera whose screen position (N, 2) lies inside the
    closed ``polygon`` (V, 2) of screen positions (V >= 3; the even-odd rule, so a lasso that
    crosses itself leaves out what it wound round twice)."""
    polygon = np.asarray(polygon, np.float64).reshape(-1, 2)
    inside = np.zeros(len(uv), bool)
    if len(polygon) < 3:
        return inside
    u, v = uv[:, 0], uv[:, 1]
    for (u0, v0), (u1, v1) in zip(polygon, np.roll(polygon, -1, axis=0), strict=True):
        if v0 == v1:
            continue  # a horizontal edge crosses no horizontal ray
        crosses = (v0 > v) != (v1 > v)
        at = u0 + (v - v0) * (u1 - u0) / (v1 - v0)
        inside ^= crosses & (u < at)
    return in_front & inside
