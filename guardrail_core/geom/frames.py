"""Frames and rotations shared by the drive format, the simulator and the pipeline.

Conventions (also in ``docs/drive-format.md``):

* The vehicle frame: x forward, y left, z up; its origin is the trajectory's reference point.
* Attitude is (roll, pitch, yaw) in radians, applied as ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``
  (aerospace Z-Y-X order), mapping vehicle vectors to world vectors: ``R_world_vehicle``.
* A camera frame is OpenCV's: x right, y down, z forward along the optical axis.
* ``T_a_b`` is the 4x4 transform mapping coordinates in frame b to frame a.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt


def rotation_from_euler(
    roll: npt.ArrayLike, pitch: npt.ArrayLike, yaw: npt.ArrayLike
) -> np.ndarray:
    """``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` for arrays of angles (radians).

    Returns ``(..., 3, 3)`` float64, the broadcast shape of the inputs followed by (3, 3).
    """
    roll, pitch, yaw = np.broadcast_arrays(
        np.asarray(roll, np.float64), np.asarray(pitch, np.float64), np.asarray(yaw, np.float64)
    )
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    r = np.empty(roll.shape + (3, 3))
    r[..., 0, 0] = cy * cp
    r[..., 0, 1] = cy * sp * sr - sy * cr
    r[..., 0, 2] = cy * sp * cr + sy * sr
    r[..., 1, 0] = sy * cp
    r[..., 1, 1] = sy * sp * sr + cy * cr
    r[..., 1, 2] = sy * sp * cr - cy * sr
    r[..., 2, 0] = -sp
    r[..., 2, 1] = cp * sr
    r[..., 2, 2] = cp * cr
    return r


def make_transform(rotation: npt.ArrayLike, translation: npt.ArrayLike) -> np.ndarray:
    """A 4x4 transform from a rotation (3, 3) and a translation (3,)."""
    t = np.eye(4)
    t[:3, :3] = rotation
    t[:3, 3] = translation
    return t


def invert_transform(t: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform."""
    r = t[:3, :3]
    return make_transform(r.T, -r.T @ t[:3, 3])


def transform_points(t: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to points (N, 3)."""
    return points @ t[:3, :3].T + t[:3, 3]


def euler_from_rotation(rotation: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) radians (..., 3) of rotations (..., 3, 3): the inverse of
    :func:`rotation_from_euler` for pitch within (-pi/2, pi/2)."""
    r = np.asarray(rotation, np.float64)
    roll = np.arctan2(r[..., 2, 1], r[..., 2, 2])
    pitch = -np.arcsin(np.clip(r[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(r[..., 1, 0], r[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)
