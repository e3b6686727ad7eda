"""The vehicle trajectory: time-stamped positions and attitudes, and poses between samples."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from guardrail_core.geom.frames import make_transform, rotation_from_euler


@dataclass(frozen=True)
class Trajectory:
    """Poses of the vehicle frame (x forward, y left, z up) in the local frame.

    Attributes
    ----------
    time : (N,) float64, GPS seconds, strictly increasing
    position : (N, 3) float64, metres, local frame (drive origin subtracted)
    attitude : (N, 3) float64, radians (roll, pitch, yaw), see :mod:`guardrail_core.geom.frames`
    reference_height_m : float, height of the vehicle origin above the road surface
    """

    time: np.ndarray
    position: np.ndarray
    attitude: np.ndarray
    reference_height_m: float = 1.8

    def __len__(self) -> int:
        return int(self.time.shape[0])

    def interpolate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position (M, 3) and attitude (M, 3) at times ``t`` (M,), linear between samples.

        Yaw is unwrapped before interpolating so a heading through +-pi does not spin.
        """
        t = np.asarray(t, np.float64)
        pos = np.stack([np.interp(t, self.time, self.position[:, i]) for i in range(3)], axis=1)
        att_unwrapped = self.attitude.copy()
        att_unwrapped[:, 2] = np.unwrap(att_unwrapped[:, 2])
        att = np.stack([np.interp(t, self.time, att_unwrapped[:, i]) for i in range(3)], axis=1)
        return pos, att

    def poses(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``R_world_vehicle`` (M, 3, 3) and ``p_world_vehicle`` (M, 3) at times ``t`` (M,)."""
        pos, att = self.interpolate(t)
        return rotation_from_euler(att[:, 0], att[:, 1], att[:, 2]), pos

    def T_world_vehicle(self, t: float) -> np.ndarray:
        """The 4x4 vehicle pose at one time ``t`` (s)."""
        rotation, position = self.poses(np.array([t]))
        return make_transform(rotation[0], position[0])

    def road_height(self, t: np.ndarray) -> np.ndarray:
        """Estimated road surface height (M,) metres under the vehicle at times ``t`` (§3.1)."""
        pos, _ = self.interpolate(t)
        return pos[:, 2] - self.reference_height_m
