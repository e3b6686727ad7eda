"""Track coordinates: where a point lies along, beside and above the vehicle's trajectory.

Road removal (§3.1) needs each point's height above the road, and slicing (§3.1) needs its station
along the trajectory so that section planes stand perpendicular to it. Both come from projecting
the point onto the trajectory's horizontal path, parametrised by arc length.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from guardrail_core.errors import InvalidOptionError
from guardrail_core.sensors.trajectory import Trajectory

#: Trajectory samples closer than this to the previous one are the vehicle standing still.
_MIN_STEP_M = 1e-6
#: Newton steps divide by the bend factor ``1 - curvature * lateral``; a point near or beyond the
#: centre of curvature (a factor near 0 or below) takes at most 5 times its tangential offset.
_MIN_BEND = 0.2


@dataclass(frozen=True)
class TrackCoordinates:
    """Points in the trajectory's frame.

    Attributes
    ----------
    station : (N,) float64, metres along the trajectory's horizontal path from its first sample
    lateral : (N,) float64, metres to the left of the path (negative: right)
    height : (N,) float64, metres above the road surface estimated from the trajectory
    """

    station: np.ndarray
    lateral: np.ndarray
    height: np.ndarray

    def take(self, index: np.ndarray) -> TrackCoordinates:
        """The coordinates of the points at ``index`` ((M,) int or (N,) bool)."""
        return TrackCoordinates(self.station[index], self.lateral[index], self.height[index])


def _path(
    trajectory: Trajectory,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The trajectory's horizontal path parametrised by arc length.

    Returns the arc length of every trajectory sample (M,), then arc length (K,), positions
    (K, 2), unit tangents (K, 2), signed curvature (K,) 1/m (positive turning left) and road
    heights (K,) of the samples where the vehicle moved, so that arc length strictly increases.
    """
    xy = trajectory.position[:, :2]
    step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    sample_arc = np.concatenate([[0.0], np.cumsum(step)])
    keep = np.concatenate([[True], step > _MIN_STEP_M])
    road = trajectory.position[keep, 2] - trajectory.reference_height_m
    if keep.sum() < 2:
        # A vehicle that never moved: a straight path along its heading.
        yaw = float(trajectory.attitude[0, 2])
        direction = np.array([np.cos(yaw), np.sin(yaw)])
        path_xy = np.stack([xy[0], xy[0] + direction])
        tangent = np.stack([direction] * 2)
        return sample_arc, np.array([0.0, 1.0]), path_xy, tangent, np.zeros(2), road[[0, 0]]
    arc = sample_arc[keep]
    path_xy = xy[keep]
    tangent = np.gradient(path_xy, arc, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    curvature = np.gradient(np.unwrap(np.arctan2(tangent[:, 1], tangent[:, 0])), arc)
    return sample_arc, arc, path_xy, tangent, curvature, road


def track_coordinates(
    xyz: np.ndarray, gps_time: np.ndarray, trajectory: Trajectory, *, iterations: int = 4
) -> TrackCoordinates:
    """Project points onto the trajectory's path.

    Parameters
    ----------
    xyz : (N, 3) float64, metres, local frame
    gps_time : (N,) float64, seconds; the station of the vehicle when the point was scanned
        starts the search, so a path that comes back near itself is not confused.
    trajectory : the drive's trajectory
    iterations : Newton steps of the projection; each moves the foot point along the local
        tangent; four bring the station within millimetres.

    Returns
    -------
    TrackCoordinates with (N,) station, lateral and height. Beyond the ends of the path the
    station continues along the end tangents.

    References
    ----------
    Matsumoto et al. 2019, §3.1 (road height from the trajectory; section planes perpendicular
    to the trajectory).
    """
    xyz = np.asarray(xyz, np.float64)
    gps_time = np.asarray(gps_time, np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or gps_time.shape != (len(xyz),):
        raise InvalidOptionError(
            f"track_coordinates: expected xyz (N, 3) and gps_time (N,), got {xyz.shape} and "
            f"{gps_time.shape}"
        )
    sample_arc, arc, path_xy, tangent, curvature, road = _path(trajectory)
    station = np.interp(gps_time, trajectory.time, sample_arc)
    x, y = xyz[:, 0], xyz[:, 1]
    for _ in range(iterations):
        at = _PathPoint(station, arc)
        foot_x, foot_y, tx, ty = at.foot(path_xy, tangent)
        # Newton step: on a curve the foot point moves 1 / (1 - curvature * lateral) times as
        # fast as the point's tangential offset.
        dx, dy = x - foot_x, y - foot_y
        bend = 1.0 - at.value(curvature) * (tx * dy - ty * dx)
        station = station + (dx * tx + dy * ty) / np.maximum(bend, _MIN_BEND)
    at = _PathPoint(station, arc)
    foot_x, foot_y, tx, ty = at.foot(path_xy, tangent)
    lateral = tx * (y - foot_y) - ty * (x - foot_x)
    height = xyz[:, 2] - at.value(road)
    return TrackCoordinates(station=station, lateral=lateral, height=height)


class _PathPoint:
    """Where stations (N,) fall on the path sampled at ``arc`` (K,): one binary search serves
    every quantity interpolated there; straight beyond the ends."""

    def __init__(self, station: np.ndarray, arc: np.ndarray) -> None:
        self.station = station
        self.inside = np.clip(station, arc[0], arc[-1])
        upper = np.searchsorted(arc, self.inside, side="right")
        np.clip(upper, 1, len(arc) - 1, out=upper)
        self.lower = upper - 1
        self.upper = upper
        self.weight = (self.inside - arc[self.lower]) / (arc[upper] - arc[self.lower])

    def value(self, samples: np.ndarray) -> np.ndarray:
        """(N,) ``samples`` (K,) interpolated linearly (held beyond the ends)."""
        low = samples[self.lower]
        return low + self.weight * (samples[self.upper] - low)

    def foot(
        self, path_xy: np.ndarray, tangent: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Foot point (x, y) and unit tangent (tx, ty), continued along the end tangents."""
        tx = self.value(tangent[:, 0])
        ty = self.value(tangent[:, 1])
        norm = np.hypot(tx, ty)
        tx /= norm
        ty /= norm
        beyond = self.station - self.inside
        foot_x = self.value(path_xy[:, 0]) + beyond * tx
        foot_y = self.value(path_xy[:, 1]) + beyond * ty
        return foot_x, foot_y, tx, ty
