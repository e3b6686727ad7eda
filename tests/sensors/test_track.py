"""Track coordinates (§3.1): station, lateral offset and height of points along a trajectory.

Every trajectory here is built analytically, so the expected coordinates are exact.
"""

from __future__ import annotations

import numpy as np
import pytest

from guardrail_core.errors import GuardrailError
from guardrail_core.sensors.track import TrackCoordinates, track_coordinates
from guardrail_core.sensors.trajectory import Trajectory

SPEED = 10.0  # m/s
ROAD_Z = 10.0  # road surface height in the local frame, metres


def straight_trajectory(
    heading: float, length: float = 100.0, step: float = 1.0, *, origin=(3.0, -2.0), grade=0.0
) -> Trajectory:
    """A vehicle driving straight along ``heading`` (radians) at SPEED, 1.8 m above the road."""
    s = np.arange(0.0, length + step / 2, step)
    direction = np.array([np.cos(heading), np.sin(heading)])
    position = np.empty((len(s), 3))
    position[:, :2] = np.asarray(origin) + s[:, None] * direction
    position[:, 2] = ROAD_Z + grade * s + 1.8
    attitude = np.zeros((len(s), 3))
    attitude[:, 2] = heading
    return Trajectory(time=s / SPEED, position=position, attitude=attitude)


def place(trajectory_origin, heading: float, station, lateral, height, *, grade=0.0) -> np.ndarray:
    """Points (N, 3) at given track coordinates of a straight trajectory."""
    d = np.array([np.cos(heading), np.sin(heading)])
    left = np.array([-d[1], d[0]])
    xyz = np.empty((len(station), 3))
    xyz[:, :2] = np.asarray(trajectory_origin) + station[:, None] * d + lateral[:, None] * left
    xyz[:, 2] = ROAD_Z + grade * station + height
    return xyz


def random_track(rng: np.random.Generator, n: int, lo: float, hi: float) -> tuple[np.ndarray, ...]:
    return rng.uniform(lo, hi, n), rng.uniform(-15.0, 15.0, n), rng.uniform(-1.0, 3.0, n)


def test_straight_trajectory_is_exact() -> None:
    rng = np.random.default_rng(1)
    heading = np.deg2rad(30.0)
    trajectory = straight_trajectory(heading)
    station, lateral, height = random_track(rng, 2000, 0.0, 100.0)
    xyz = place((3.0, -2.0), heading, station, lateral, height)
    # Scanned up to half a second before or after the vehicle passed the point's station.
    gps_time = station / SPEED + rng.uniform(-0.5, 0.5, len(station))

    track = track_coordinates(xyz, gps_time, trajectory)

    assert isinstance(track, TrackCoordinates)
    assert track.station.shape == track.lateral.shape == track.height.shape == (2000,)
    np.testing.assert_allclose(track.station, station, rtol=0, atol=1e-9)
    np.testing.assert_allclose(track.lateral, lateral, rtol=0, atol=1e-9)
    np.testing.assert_allclose(track.height, height, rtol=0, atol=1e-9)


def test_lateral_is_positive_to_the_left() -> None:
    trajectory = straight_trajectory(0.0, origin=(0.0, 0.0))  # heading +x: left is +y
    xyz = np.array([[50.0, 2.0, ROAD_Z], [50.0, -3.0, ROAD_Z + 1.0]])
    track = track_coordinates(xyz, np.array([5.0, 5.0]), trajectory)
    np.testing.assert_allclose(track.lateral, [2.0, -3.0], atol=1e-12)
    np.testing.assert_allclose(track.height, [0.0, 1.0], atol=1e-12)


def test_beyond_the_ends_continues_along_the_end_tangents() -> None:
    rng = np.random.default_rng(2)
    heading = np.deg2rad(-120.0)
    trajectory = straight_trajectory(heading, length=40.0)
    station = np.concatenate([rng.uniform(-20.0, -0.1, 200), rng.uniform(40.1, 60.0, 200)])
    lateral, height = rng.uniform(-10.0, 10.0, 400), rng.uniform(0.0, 2.0, 400)
    xyz = place((3.0, -2.0), heading, station, lateral, height)
    gps_time = np.clip(station / SPEED, 0.0, 4.0)  # scanned at the trajectory's ends

    track = track_coordinates(xyz, gps_time, trajectory)

    np.testing.assert_allclose(track.station, station, rtol=0, atol=1e-9)
    np.testing.assert_allclose(track.lateral, lateral, rtol=0, atol=1e-9)
    np.testing.assert_allclose(track.height, height, rtol=0, atol=1e-9)


@pytest.mark.parametrize("grade", [0.04, -0.03])
def test_beyond_the_ends_the_road_goes_on_at_its_grade(grade: float) -> None:
    """A drive's first and last points lie beyond its path; the road there goes on at the grade
    of its last metres (it used to stay flat: 0.4 m off 10 m out on a 4 % grade)."""
    rng = np.random.default_rng(3)
    heading = np.deg2rad(15.0)
    trajectory = straight_trajectory(heading, length=5.0, step=0.5, grade=grade)
    station = np.concatenate([rng.uniform(-40.0, -0.1, 200), rng.uniform(5.1, 45.0, 200)])
    lateral, height = rng.uniform(-10.0, 10.0, 400), rng.uniform(0.0, 2.0, 400)
    xyz = place((3.0, -2.0), heading, station, lateral, height, grade=grade)
    track = track_coordinates(xyz, np.clip(station / SPEED, 0.0, 0.5), trajectory)
    np.testing.assert_allclose(track.height, height, rtol=0, atol=1e-9)


def test_a_vehicle_standing_still_has_the_road_its_pitch_gives() -> None:
    """One frame of a spinning lidar without poses: the path is a line along the heading and the
    road rises along it as the vehicle's nose does (a negative pitch), within 12 %."""
    grade = 0.01
    trajectory = Trajectory(
        time=np.array([0.0, 0.1]),
        position=np.array([[3.0, -2.0, ROAD_Z + 1.8]] * 2),
        attitude=np.array([[0.0, -np.arctan(grade), 0.0]] * 2),
    )
    station = np.linspace(-60.0, 60.0, 121)
    xyz = place((3.0, -2.0), 0.0, station, np.full(121, 4.0), np.full(121, 0.5), grade=grade)
    track = track_coordinates(xyz, np.full(121, 0.05), trajectory)
    np.testing.assert_allclose(track.station, station, atol=1e-9)
    np.testing.assert_allclose(track.height, 0.5, atol=1e-9)
    steep = Trajectory(trajectory.time, trajectory.position, np.array([[0.0, -0.5, 0.0]] * 2))
    assert track_coordinates(xyz[-1:], np.array([0.05]), steep).height[0] == pytest.approx(
        0.5 + 60 * (grade - 0.12)
    )


def circular_trajectory(radius: float, angle: float, step: float) -> tuple[Trajectory, np.ndarray]:
    """A left turn along a circle about ``centre``; returns the trajectory and the centre."""
    centre = np.array([20.0, 60.0])
    phi = np.linspace(0.0, angle, int(round(radius * angle / step)) + 1)
    position = np.empty((len(phi), 3))
    # Starts at centre - (0, R) heading +x, turning left (anticlockwise) around the centre.
    position[:, 0] = centre[0] + radius * np.sin(phi)
    position[:, 1] = centre[1] - radius * np.cos(phi)
    position[:, 2] = ROAD_Z + 1.8
    attitude = np.zeros((len(phi), 3))
    attitude[:, 2] = phi
    return Trajectory(time=radius * phi / SPEED, position=position, attitude=attitude), centre


def test_circular_arc_within_millimetres() -> None:
    """Station is R * angle within 5 mm and lateral R - distance to the centre within 1 mm.

    The trajectory is sampled every 0.5 m; between samples the path is the chord, whose
    sagitta 0.5**2 / (8 * 60) = 0.5 mm bounds the lateral error.
    """
    rng = np.random.default_rng(3)
    radius, angle = 60.0, 1.0
    trajectory, centre = circular_trajectory(radius, angle, step=0.5)
    phi = rng.uniform(0.05, angle - 0.05, 3000)
    lateral = rng.uniform(-10.0, 10.0, len(phi))
    distance = radius - lateral
    xyz = np.stack(
        [
            centre[0] + distance * np.sin(phi),
            centre[1] - distance * np.cos(phi),
            ROAD_Z + rng.uniform(0.0, 2.0, len(phi)),
        ],
        axis=1,
    )
    gps_time = radius * phi / SPEED + rng.uniform(-0.3, 0.3, len(phi))

    track = track_coordinates(xyz, gps_time, trajectory)

    np.testing.assert_allclose(track.station, radius * phi, rtol=0, atol=5e-3)
    np.testing.assert_allclose(track.lateral, lateral, rtol=0, atol=1e-3)
    np.testing.assert_allclose(track.height, xyz[:, 2] - ROAD_Z, rtol=0, atol=1e-12)


def test_tight_curve_station_within_millimetres() -> None:
    """A 15 m radius turn (a roundabout), points 5 m aside, scanned when the vehicle was 2 m past them
    (the scan plane tilts back 45 degrees): the docstring's four steps should reach 5 mm."""
    rng = np.random.default_rng(8)
    radius, angle = 15.0, 1.5
    trajectory, centre = circular_trajectory(radius, angle, step=0.1)
    phi = rng.uniform(0.3, angle - 0.2, 1000)
    lateral = rng.uniform(-5.0, 5.0, len(phi))
    distance = radius - lateral
    xyz = np.stack(
        [
            centre[0] + distance * np.sin(phi),
            centre[1] - distance * np.cos(phi),
            np.full(len(phi), ROAD_Z),
        ],
        axis=1,
    )
    gps_time = (radius * phi + 2.0) / SPEED

    track = track_coordinates(xyz, gps_time, trajectory)

    np.testing.assert_allclose(track.lateral, lateral, rtol=0, atol=1e-3)
    np.testing.assert_allclose(track.station, radius * phi, rtol=0, atol=5e-3)


def test_circular_arc_beyond_its_end_follows_the_end_tangent() -> None:
    """Past the end of an arc sampled every 0.1 m, the path is the end tangent's straight line.

    The end tangent is a one-sided difference, off by at most 0.1 / (2 * 60) rad; over 5 m
    beyond the end and 5 m aside that moves a point by under 1 cm.
    """
    rng = np.random.default_rng(4)
    radius, angle = 60.0, 1.0
    trajectory, centre = circular_trajectory(radius, angle, step=0.1)
    end = centre + radius * np.array([np.sin(angle), -np.cos(angle)])
    tangent = np.array([np.cos(angle), np.sin(angle)])
    left = np.array([-tangent[1], tangent[0]])
    beyond, lateral = rng.uniform(0.1, 5.0, 300), rng.uniform(-5.0, 5.0, 300)
    xy = end + beyond[:, None] * tangent + lateral[:, None] * left
    xyz = np.column_stack([xy, np.full(300, ROAD_Z + 0.5)])
    gps_time = np.full(300, radius * angle / SPEED)

    track = track_coordinates(xyz, gps_time, trajectory)

    np.testing.assert_allclose(track.station, radius * angle + beyond, rtol=0, atol=1e-2)
    np.testing.assert_allclose(track.lateral, lateral, rtol=0, atol=1e-2)
    np.testing.assert_allclose(track.height, 0.5, rtol=0, atol=1e-12)


def test_a_path_that_comes_back_near_itself_is_told_apart_by_gps_time() -> None:
    """A hairpin: out along +x, a half circle of radius 4 m, back along -x at y = 8.

    A point at y = 2 is 2 m left of the outbound leg and 6 m left of the return leg; the time
    it was scanned says which pass saw it.
    """
    out = np.column_stack([np.arange(0.0, 50.0, 0.5), np.zeros(100)])
    phi = np.linspace(0.0, np.pi, 64)[1:-1]
    turn = np.column_stack([50.0 + 4.0 * np.sin(phi), 4.0 - 4.0 * np.cos(phi)])
    back = np.column_stack([np.arange(50.0, -0.25, -0.5), np.full(101, 8.0)])
    xy = np.concatenate([out, turn, back])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    position = np.column_stack([xy, np.full(len(xy), ROAD_Z + 1.8)])
    trajectory = Trajectory(time=arc / SPEED, position=position, attitude=np.zeros((len(xy), 3)))
    back_start = arc[len(out) + len(turn)]  # station where the return leg starts at x = 50

    xyz = np.array([[25.0, 2.0, ROAD_Z], [25.0, 2.0, ROAD_Z]])
    gps_time = np.array([25.0 / SPEED, (back_start + 25.0) / SPEED])
    track = track_coordinates(xyz, gps_time, trajectory)

    np.testing.assert_allclose(track.station, [25.0, back_start + 25.0], atol=1e-9)
    np.testing.assert_allclose(track.lateral, [2.0, 6.0], atol=1e-9)


def test_a_vehicle_that_stands_still_for_a_while() -> None:
    """Repeated positions (time runs on, the vehicle waits at a light) keep results exact."""
    rng = np.random.default_rng(5)
    heading = np.deg2rad(75.0)
    s = np.concatenate([np.arange(0.0, 20.0), np.full(15, 20.0), np.arange(21.0, 41.0)])
    time = np.arange(len(s)) * 0.1
    d = np.array([np.cos(heading), np.sin(heading)])
    position = np.column_stack([s[:, None] * d, np.full(len(s), ROAD_Z + 1.8)])
    attitude = np.column_stack([np.zeros((len(s), 2)), np.full(len(s), heading)])
    trajectory = Trajectory(time=time, position=position, attitude=attitude)
    station, lateral, height = random_track(rng, 500, 0.0, 40.0)
    xyz = place((0.0, 0.0), heading, station, lateral, height)
    # Many points are scanned while the vehicle waits.
    gps_time = rng.uniform(time[19], time[35], len(station))

    track = track_coordinates(xyz, gps_time, trajectory)

    assert np.isfinite(track.station).all()
    assert np.isfinite(track.lateral).all()
    assert np.isfinite(track.height).all()
    np.testing.assert_allclose(track.station, station, rtol=0, atol=1e-9)
    np.testing.assert_allclose(track.lateral, lateral, rtol=0, atol=1e-9)
    np.testing.assert_allclose(track.height, height, rtol=0, atol=1e-9)


def test_a_vehicle_that_never_moved_uses_its_heading() -> None:
    rng = np.random.default_rng(6)
    heading = np.deg2rad(30.0)
    position = np.tile([5.0, 7.0, ROAD_Z + 1.8], (10, 1))
    attitude = np.tile([0.0, 0.0, heading], (10, 1))
    trajectory = Trajectory(time=np.arange(10) * 0.1, position=position, attitude=attitude)
    station, lateral, height = random_track(rng, 100, -20.0, 20.0)
    xyz = place((5.0, 7.0), heading, station, lateral, height)

    track = track_coordinates(xyz, rng.uniform(0.0, 0.9, 100), trajectory)

    np.testing.assert_allclose(track.station, station, rtol=0, atol=1e-9)
    np.testing.assert_allclose(track.lateral, lateral, rtol=0, atol=1e-9)
    np.testing.assert_allclose(track.height, height, rtol=0, atol=1e-9)


def test_height_is_measured_from_the_road_under_the_point_on_a_grade() -> None:
    """On a 6 % grade the road under a point is the trajectory's z at its station less 1.8 m,
    not the road under the vehicle when the point was scanned."""
    rng = np.random.default_rng(7)
    heading, grade = np.deg2rad(200.0), 0.06
    trajectory = straight_trajectory(heading, grade=grade)
    station, lateral, height = random_track(rng, 1000, 0.0, 100.0)
    xyz = place((3.0, -2.0), heading, station, lateral, height, grade=grade)
    gps_time = station / SPEED + rng.uniform(-1.0, 1.0, len(station))  # up to 10 m away

    track = track_coordinates(xyz, gps_time, trajectory)

    np.testing.assert_allclose(track.station, station, rtol=0, atol=1e-9)
    np.testing.assert_allclose(track.height, height, rtol=0, atol=1e-9)


def test_reference_height_of_the_trajectory_is_used() -> None:
    base = straight_trajectory(0.0, origin=(0.0, 0.0))
    trajectory = Trajectory(base.time, base.position, base.attitude, reference_height_m=2.3)
    track = track_coordinates(np.array([[10.0, 0.0, ROAD_Z + 1.0]]), np.array([1.0]), trajectory)
    # The trajectory is 1.8 m above ROAD_Z; with a 2.3 m reference the road is 0.5 m lower.
    np.testing.assert_allclose(track.height, [1.5], atol=1e-12)


def test_no_points_give_empty_coordinates() -> None:
    track = track_coordinates(np.zeros((0, 3)), np.zeros(0), straight_trajectory(0.0))
    assert track.station.shape == track.lateral.shape == track.height.shape == (0,)


def test_gps_time_of_another_length_is_a_named_error() -> None:
    with pytest.raises(GuardrailError):
        track_coordinates(np.zeros((5, 3)), np.zeros(4), straight_trajectory(0.0))
