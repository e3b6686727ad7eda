"""Track coordinates: where a point lies along, beside and above the vehicle's trajectory.

Road removal (§3.1) needs each point's height above the road, and slicing (§3.1) needs its station
along the trajectory so that section planes stand perpendicular to it. Both come from projecting
the point onto the trajectory's horizontal path, parametrised by arc length.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from guardrail_core.errors import InvalidOptionError
from guardrail_core.sensors.trajectory import Trajectory

#: Trajectory samples closer than this to the previous one are the vehicle standing still.
_MIN_STEP_M = 1e-6
#: Beyond the path's ends the road goes on at the grade of its last metres: a line fitted to
#: the road heights within this many metres of each end, its grade held within MAX_END_GRADE
#: (a single frame's path spans a few metres, and a lidar sits a degree off level or so).
END_FIT_M = 10.0
MAX_END_GRADE = 0.12
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
    height : (N,) float64, metres above the road surface estimated from the trajectory (beyond
        its ends, the road goes on at its end grades)
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
    A vehicle that never moved gives a straight path along its heading, its road rising at the
    grade its pitch gives (nose up, road up).
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
        grade = float(np.clip(-np.tan(trajectory.attitude[0, 1]), -MAX_END_GRADE, MAX_END_GRADE))
        road = road[[0, 0]] + np.array([0.0, grade])
        return sample_arc, np.array([0.0, 1.0]), path_xy, tangent, np.zeros(2), road
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
    grade_start, grade_end = end_grades(arc, road)
    station, lateral, height = _project(
        xyz[:, 0].copy(),
        xyz[:, 1].copy(),
        xyz[:, 2].copy(),
        np.interp(gps_time, trajectory.time, sample_arc),
        arc,
        path_xy[:, 0].copy(),
        path_xy[:, 1].copy(),
        tangent[:, 0].copy(),
        tangent[:, 1].copy(),
        curvature,
        road,
        grade_start,
        grade_end,
        int(iterations),
        _MIN_BEND,
    )
    return TrackCoordinates(station=station, lateral=lateral, height=height)


def end_grades(arc: np.ndarray, road: np.ndarray) -> tuple[float, float]:
    """The road's grade (rise per metre along the path) at its start and its end: a line fitted
    to the road heights (K,) within :data:`END_FIT_M` of each end of ``arc`` (K,), held within
    :data:`MAX_END_GRADE`."""
    grades = []
    for near in (arc <= arc[0] + END_FIT_M, arc >= arc[-1] - END_FIT_M):
        a, h = arc[near], road[near]
        grade = np.polyfit(a - a.mean(), h, 1)[0] if len(a) >= 2 else 0.0
        grades.append(float(np.clip(grade, -MAX_END_GRADE, MAX_END_GRADE)))
    return grades[0], grades[1]


# Compiled: each Newton step is a few dozen flops on values interpolated from the path, which
# numpy ran as some 40 passes over the points (2.1 s for a 2.5 M point window, now 0.6 s, with
# the same results to the bit). Points are stepped in turn inside each iteration so that the CPU
# overlaps neighbouring points' divisions; error_model="numpy" drops Python's zero-division
# checks (a zero span cannot occur: arc length strictly increases).
@numba.njit(cache=True, nogil=True, error_model="numpy")
def _project(
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    station: np.ndarray,
    arc: np.ndarray,
    path_x: np.ndarray,
    path_y: np.ndarray,
    tangent_x: np.ndarray,
    tangent_y: np.ndarray,
    curvature: np.ndarray,
    road: np.ndarray,
    grade_start: float,
    grade_end: float,
    iterations: int,
    min_bend: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Newton steps of every point's foot on the path sampled at ``arc`` (K,), from the starting
    ``station`` (N,); returns (N,) station, lateral and height. Beyond the path's ends the path
    continues straight along its end tangents and the road at its end grades; values between
    samples are linear in arc length."""
    n, k = len(x), len(arc)
    station = station.copy()
    lateral = np.empty(n)
    height = np.empty(n)
    # Sample before each point's station: searched once, then moved a step or searched again.
    lower = np.searchsorted(arc, np.minimum(np.maximum(station, arc[0]), arc[k - 1]), "right")
    lower = np.minimum(np.maximum(lower, 1), k - 1) - 1
    for step in range(iterations + 1):
        for i in range(n):
            s = station[i]
            inside = min(max(s, arc[0]), arc[k - 1])
            j = lower[i]
            if arc[j] > inside or (j < k - 2 and arc[j + 1] <= inside):
                if j < k - 3 and arc[j + 1] <= inside < arc[j + 2]:
                    j += 1
                elif j > 0 and arc[j - 1] <= inside < arc[j]:
                    j -= 1
                else:
                    j = min(max(np.searchsorted(arc, inside, "right"), 1), k - 1) - 1
                lower[i] = j
            w = (inside - arc[j]) / (arc[j + 1] - arc[j])
            tx = tangent_x[j] + w * (tangent_x[j + 1] - tangent_x[j])
            ty = tangent_y[j] + w * (tangent_y[j + 1] - tangent_y[j])
            norm = np.hypot(tx, ty)
            tx /= norm
            ty /= norm
            beyond = s - inside
            dx = x[i] - (path_x[j] + w * (path_x[j + 1] - path_x[j]) + beyond * tx)
            dy = y[i] - (path_y[j] + w * (path_y[j + 1] - path_y[j]) + beyond * ty)
            if step == iterations:
                lateral[i] = tx * dy - ty * dx
                grade = grade_end if beyond > 0 else grade_start
                height[i] = z[i] - (road[j] + w * (road[j + 1] - road[j]) + beyond * grade)
            else:
                # Newton step: on a curve the foot point moves 1 / (1 - curvature * lateral)
                # times as fast as the point's tangential offset.
                bend = 1.0 - (curvature[j] + w * (curvature[j + 1] - curvature[j])) * (
                    tx * dy - ty * dx
                )
                station[i] = s + (dx * tx + dy * ty) / max(bend, min_bend)
    return station, lateral, height
