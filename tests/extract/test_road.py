"""Road removal (§3.1) on a synthetic lattice scene whose every point's fate is known.

Each scan line (rotation r) is a profile across the road at x = 0.05 r; its pulses (phases) run
from right to left, 2 cm apart. Objects are separated along the scan line by depth jumps of at
least 0.5 m, wider than the normals' neighbour distance, so each object's normals come from its
own points. Track coordinates are given exactly: station = x, lateral = y, height = z.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from guardrail_core.errors import GuardrailError
from guardrail_core.extract.lattice import build_lattice
from guardrail_core.extract.road import OFF_ROAD, ROAD, RoadParams, remove_road
from guardrail_core.sensors.track import TrackCoordinates

KEPT = 0
LINE_SPACING_M = 0.05  # between scan lines
PULSE_SPACING_M = 0.02  # between pulses along a scan line


@dataclass(frozen=True)
class Part:
    """One object of the profile: its (y, z) points in firing order and its expected code."""

    name: str
    y: np.ndarray
    z: np.ndarray
    code: int


def vertical(y: float, z0: float, z1: float, step: float) -> tuple[np.ndarray, np.ndarray]:
    z = np.arange(z0, z1 + step / 2, step)
    return np.full(len(z), y), z


def horizontal(y0: float, y1: float, z: float, step: float) -> tuple[np.ndarray, np.ndarray]:
    y = np.arange(y0, y1 + step / 2, step)
    return y, np.full(len(y), z)


def profile() -> list[Part]:
    """The road scene across one scan line, right (negative y) to left."""
    step = PULSE_SPACING_M
    return [
        Part("building 10 m right", *vertical(-10.0, 0.0, 2.0, step), OFF_ROAD),
        Part("curb face 0.15 m high", *vertical(-4.8, 0.0, 0.15, 0.01), KEPT),
        Part("road", *horizontal(-4.0, 4.0, 0.0, step), ROAD),
        Part("sidewalk 0.1 m above the road", *horizontal(4.8, 6.0, 0.1, step), ROAD),
        Part("guardrail beam face", *vertical(6.5, 0.4, 1.0, step), KEPT),
        Part("guardrail pipe, one return", np.array([7.0]), np.array([0.5]), KEPT),
        Part("overhead wire 5 m up", np.array([3.0]), np.array([5.0]), OFF_ROAD),
        Part("building 30 m left", *vertical(30.0, 0.0, 2.0, step), OFF_ROAD),
    ]


@dataclass(frozen=True)
class Scene:
    xyz: np.ndarray
    rotation: np.ndarray
    phase: np.ndarray
    expected: np.ndarray  # (N,) uint8 code
    part: np.ndarray  # (N,) index into the profile
    phases: int


def make_scene(
    parts: list[Part], rotations: int = 120, *, rng: np.random.Generator, noise_m: float = 0.003
) -> Scene:
    """The profile repeated on every scan line, with range noise, in random point order."""
    y = np.concatenate([p.y for p in parts])
    z = np.concatenate([p.z for p in parts])
    code = np.concatenate([np.full(len(p.y), p.code, np.uint8) for p in parts])
    part = np.concatenate([np.full(len(p.y), i) for i, p in enumerate(parts)])
    phases = len(y)
    r, ph = np.meshgrid(np.arange(rotations), np.arange(phases), indexing="ij")
    r, ph = r.ravel(), ph.ravel()
    xyz = np.column_stack([LINE_SPACING_M * r, y[ph], z[ph]])
    xyz = xyz + rng.normal(0.0, noise_m, xyz.shape)
    order = rng.permutation(len(r))
    return Scene(xyz[order], r[order], ph[order], code[ph][order], part[ph][order], phases)


def classify(scene: Scene, params: RoadParams = RoadParams()) -> np.ndarray:
    track = TrackCoordinates(
        station=scene.xyz[:, 0], lateral=scene.xyz[:, 1], height=scene.xyz[:, 2]
    )
    lattice = build_lattice(scene.rotation, scene.phase, scene.phases)
    return remove_road(scene.xyz, track, lattice, params)


@pytest.fixture(scope="module")
def scene() -> Scene:
    return make_scene(profile(), rng=np.random.default_rng(20))


def test_every_point_gets_its_expected_code(scene: Scene) -> None:
    status = classify(scene)

    assert status.dtype == np.uint8 and status.shape == (len(scene.xyz),)
    for i, part in enumerate(profile()):
        mine = scene.part == i
        assert (status[mine] == part.code).all(), (part.name, np.bincount(status[mine]))
    np.testing.assert_array_equal(status, scene.expected)


def test_counts_equal_the_truth(scene: Scene) -> None:
    status = classify(scene)
    per_line = {code: sum(len(p.y) for p in profile() if p.code == code) for code in (0, 1, 2)}
    assert per_line == {KEPT: 16 + 31 + 1, ROAD: 401 + 61, OFF_ROAD: 101 + 1 + 101}
    counts = np.bincount(status, minlength=3)
    np.testing.assert_array_equal(counts, [120 * per_line[c] for c in (0, 1, 2)])


def test_thresholds_come_from_the_params(scene: Scene) -> None:
    status = classify(scene, RoadParams(max_height_m=6.0, max_lateral_m=40.0, edge_margin_m=30.0))
    expected = scene.expected.copy()
    expected[scene.expected == OFF_ROAD] = KEPT  # nothing is far any more
    np.testing.assert_array_equal(status, expected)
    # A lower road tolerance turns the 0.1 m sidewalk into kept points.
    status = classify(scene, RoadParams(height_tolerance_m=0.05))
    sidewalk = scene.part == 3
    assert (status[sidewalk] == KEPT).all()
    np.testing.assert_array_equal(status[~sidewalk], scene.expected[~sidewalk])


def test_a_raised_but_flat_patch_is_road_and_a_tilted_one_is_not() -> None:
    """A flat plateau 0.2 m up is road; a 0.2 m high ramp at 45 degrees is kept (its normal is
    tilted); a flat shelf 0.3 m up (above the 0.25 m tolerance) is kept; a lone low return,
    which has no normal, is a stray ground return."""
    t = np.arange(0.0, 0.2 + 0.005, 0.01)[::-1]  # down the ramp, towards the road
    parts = [
        Part("ramp at 45 degrees", -5.0 - t, t, KEPT),
        Part("road", *horizontal(-4.0, 4.0, 0.0, PULSE_SPACING_M), ROAD),
        Part("plateau 0.2 m up", *horizontal(4.8, 6.0, 0.2, PULSE_SPACING_M), ROAD),
        Part("shelf 0.3 m up", *horizontal(7.0, 8.0, 0.3, PULSE_SPACING_M), KEPT),
        Part("stray low return, no normal", np.array([9.0]), np.array([0.1]), ROAD),
    ]
    scene = make_scene(parts, rotations=60, rng=np.random.default_rng(21))
    np.testing.assert_array_equal(classify(scene), scene.expected)


def test_a_stretch_without_road_takes_its_neighbours_edges() -> None:
    """Scan lines 100..199 (stations 5..10 m, one whole edge bin) have no road (a bridge joint,
    say). A wall 10 m to the right is far from the road there too: the edges come from the
    stretches either side, not from the 15 m fallback."""
    rng = np.random.default_rng(22)
    wall_y, wall_z = vertical(-10.0, 0.5, 1.5, PULSE_SPACING_M)
    road_y, road_z = horizontal(-4.0, 4.0, 0.0, PULSE_SPACING_M)
    y = np.concatenate([wall_y, road_y])
    z = np.concatenate([wall_z, road_z])
    phases = len(y)
    r, ph = np.meshgrid(np.arange(300), np.arange(phases), indexing="ij")
    r, ph = r.ravel(), ph.ravel()
    present = ~((r >= 100) & (r < 200) & (ph >= len(wall_y)))
    r, ph = r[present], ph[present]
    xyz = np.column_stack([LINE_SPACING_M * r, y[ph], z[ph]])
    xyz = xyz + rng.normal(0.0, 0.003, (len(r), 3))
    track = TrackCoordinates(xyz[:, 0], xyz[:, 1], xyz[:, 2])

    status = remove_road(xyz, track, build_lattice(r, ph, phases))

    is_wall = ph < len(wall_y)
    assert (status[is_wall] == OFF_ROAD).all()
    assert (status[~is_wall] == ROAD).all()


def test_without_any_road_the_lateral_limit_decides() -> None:
    """No road-level ground at all: edges fall back to +-max_lateral_m, so only the hard limit
    removes points: a wall at 14 m is kept, one at 16 m is far."""
    rng = np.random.default_rng(23)
    parts = [
        Part("wall at 16 m right", *vertical(-16.0, 0.3, 1.2, PULSE_SPACING_M), OFF_ROAD),
        Part("wall at 14 m right", *vertical(-14.0, 0.3, 1.2, PULSE_SPACING_M), KEPT),
        Part("wall at 14 m left", *vertical(14.0, 0.3, 1.2, PULSE_SPACING_M), KEPT),
        Part("wall at 16 m left", *vertical(16.0, 0.3, 1.2, PULSE_SPACING_M), OFF_ROAD),
    ]
    scene = make_scene(parts, rotations=60, rng=rng)
    np.testing.assert_array_equal(classify(scene), scene.expected)


def test_no_points() -> None:
    track = TrackCoordinates(np.zeros(0), np.zeros(0), np.zeros(0))
    lattice = build_lattice(np.zeros(0, np.int64), np.zeros(0, np.int64), 8)
    status = remove_road(np.zeros((0, 3)), track, lattice)
    assert status.shape == (0,) and status.dtype == np.uint8


def test_track_of_another_length_is_a_named_error(scene: Scene) -> None:
    track = TrackCoordinates(np.zeros(5), np.zeros(5), np.zeros(5))
    lattice = build_lattice(scene.rotation, scene.phase, scene.phases)
    with pytest.raises(GuardrailError):
        remove_road(scene.xyz, track, lattice)
