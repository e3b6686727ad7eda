"""Simulating in tiles and windows: the same seed gives the same drive whatever the tile length,
and the scene near a stretch of the drive is all the scanner can reach from it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from guardrail_core.cli import main
from guardrail_core.errors import InvalidOptionError
from guardrail_core.formats.drive import Drive, load_drive, open_drive
from guardrail_core.formats.drive_tiles import vehicle_station
from guardrail_core.synth.mesh import MeshBuilder
from guardrail_core.synth.random_scene import random_scene_spec
from guardrail_core.synth.scene import build_scene, load_scene_spec, plan_scene
from guardrail_core.synth.scene_window import SceneWindows, drive_windows
from guardrail_core.synth.simulate import SimulationOptions, simulate_drive
from guardrail_core.synth.vehicle import drive_along

#: A short range, so that the windows of the 32 m test drive hold different parts of its scene.
SHORT_RANGE_M = 15.0
NO_IMAGES = SimulationOptions(image_every_m=1000.0)


def _spec(kind: str) -> dict:
    spec = load_scene_spec("test_straight")
    spec["scanner"] = {"kind": kind, "max_range_m": SHORT_RANGE_M}
    if kind == "multibeam":
        spec["scanner"]["frame_every_m"] = 4.0
    return spec


def _simulate(out: Path, kind: str, tile_m: float | None, window_m: float) -> Drive:
    options = SimulationOptions(image_every_m=1000.0, scene_window_m=window_m)
    simulate_drive(_spec(kind), out, seed=5, options=options, progress=False, tile_m=tile_m)
    return load_drive(out)


def _assert_same_points(a: Drive, b: Drive) -> None:
    for field in ("xyz", "gps_time", "intensity", "rotation", "phase"):
        np.testing.assert_array_equal(getattr(a.points, field), getattr(b.points, field), field)
    assert a.truth is not None and b.truth is not None
    np.testing.assert_array_equal(a.truth.point_class, b.truth.point_class)
    np.testing.assert_array_equal(a.truth.point_object, b.truth.point_object)
    assert a.truth.objects == b.truth.objects


@pytest.fixture(scope="module", params=["profile", "multibeam"])
def whole(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Drive:
    """The test drive in one tile, scanned against one build of its whole scene."""
    out = tmp_path_factory.mktemp("tiles") / request.param
    return _simulate(out, request.param, tile_m=None, window_m=1000.0)


def test_the_tile_length_does_not_change_the_points_or_the_truth(
    whole: Drive, tmp_path: Path
) -> None:
    assert len(open_drive(whole.root).tiles) == 1
    tiled = _simulate(tmp_path / "tiled", whole.scanner.kind, tile_m=8.0, window_m=1000.0)
    index = open_drive(tiled.root).tiles
    assert len(index) >= 4  # a 32 m drive in 8 m tiles
    assert index.points == len(whole.points) > 10_000
    _assert_same_points(whole, tiled)
    # Each tile holds the points scanned while the vehicle drove its 8 m.
    for record in index.tiles:
        driven = vehicle_station(whole.trajectory, np.array(record.gps_time))
        assert driven[1] - driven[0] <= 8.0 + 1e-6


def test_scanning_against_the_scene_near_each_window_gives_the_whole_scene_points(
    whole: Drive, tmp_path: Path
) -> None:
    # 5 m windows with a 15 m range: each window's scene lacks parts of the 60 m street.
    windowed = _simulate(tmp_path / "windowed", whole.scanner.kind, tile_m=10.0, window_m=5.0)
    _assert_same_points(whole, windowed)


def test_windows_leave_out_the_parts_beyond_reach_and_keep_the_rest() -> None:
    spec = random_scene_spec(2, 100.0)
    layout = plan_scene(spec, seed=4)
    reach = 15.0
    windows = SceneWindows(layout.parts, reach)
    built = [part.mesh() for part in layout.parts]
    assert windows.objects == [record for _, record in built if record is not None]
    positions = layout.road.point(np.linspace(50.0, 70.0, 21), np.zeros(21))
    near = set(windows.near(positions).tolist())
    assert 0 < len(near) < len(layout.parts) / 2
    for i, (mesh, _) in enumerate(built):
        gaps = np.linalg.norm(mesh.vertices[:, None, :2] - positions[None, :, :2], axis=2)
        if gaps.min() <= reach:
            assert i in near, layout.parts[i].name  # a vertex within reach: always held
    mesh = windows.mesh_near(positions)
    assert mesh.n_faces == sum(built[i][0].n_faces for i in near)


def test_a_part_is_the_same_alone_as_in_the_whole_scene() -> None:
    spec = load_scene_spec("test_straight")
    layout = plan_scene(spec, seed=9)
    whole = build_scene(spec, seed=9).mesh
    pieces = [part.mesh()[0] for part in layout.parts]
    np.testing.assert_array_equal(np.concatenate([p.vertices for p in pieces]), whole.vertices)
    np.testing.assert_array_equal(
        np.concatenate([p.face_object for p in pieces]), whole.face_object
    )
    # Built in another order (as a window would), each part keeps its faces.
    builder = MeshBuilder()
    for part in reversed(layout.parts):
        part.build(builder)
    again = builder.build()
    assert again.n_faces == whole.n_faces
    np.testing.assert_array_equal(again.vertices[: len(pieces[-1].vertices)], pieces[-1].vertices)


def test_windows_cover_every_chunk_once_in_time_order(tmp_path: Path) -> None:
    layout = plan_scene(load_scene_spec("test_straight"))
    trajectory = drive_along(
        layout.road,
        layout.vehicle,
        s_start=12.0,
        s_end=44.0,
        t0=1000.0,
        rng=np.random.default_rng(0),
    )
    spans = np.stack([np.arange(1000.0, 1003.0, 0.1), np.arange(1000.0, 1003.0, 0.1) + 0.09], 1)
    windows = drive_windows(trajectory, spans, 10.0)
    assert len(windows) >= 3
    assert [c for w in windows for c in w.chunks] == list(range(len(spans)))
    assert windows[0].span[0] == trajectory.time[0] and windows[-1].shots_before == np.inf
    for w, following in zip(windows[:-1], windows[1:], strict=True):
        assert w.shots_before == following.span[0] <= w.span[1]


def test_cli_writes_tiles_of_the_given_length(tmp_path: Path) -> None:
    out = tmp_path / "d"
    args = ["simulate", str(out), "--scene", "test_straight", "--tile-m", "12"]
    assert main([*args, "--image-every", "1000", "--quiet"]) == 0
    index = open_drive(out).tiles
    assert len(index) == 3  # 32 m of driving
    assert [t.file for t in index.tiles] == [f"points/{i:06d}.laz" for i in range(3)]
    assert main([*args[:-2], "--tile-m", "0", "--quiet"]) == 2


def test_a_tile_length_of_zero_is_refused(tmp_path: Path) -> None:
    with pytest.raises(InvalidOptionError, match="longer than 0 m"):
        simulate_drive(_spec("profile"), tmp_path / "x", options=NO_IMAGES, tile_m=0.0)
    with pytest.raises(InvalidOptionError, match="longer than 0 m"):
        SimulationOptions(scene_window_m=0.0)
    assert list(tmp_path.iterdir()) == []


def test_a_drive_too_short_for_a_frame_is_written_without_points(tmp_path: Path) -> None:
    spec = _spec("multibeam")
    spec["scanner"]["frame_every_m"] = 1000.0
    summary = simulate_drive(spec, tmp_path / "d", options=NO_IMAGES, progress=False, tile_m=10.0)
    assert summary.n_points == 0 and summary.points_by_class == {}
    assert len(load_drive(tmp_path / "d").points) == 0


def test_the_road_in_stretches_has_the_whole_roads_triangles() -> None:
    layout = plan_scene(random_scene_spec(2, 120.0), seed=1)
    builder = MeshBuilder()
    layout.road.build_mesh(builder)
    whole = builder.build()
    stretches = [part.mesh()[0] for part in layout.parts if part.name.startswith("road")]
    assert len(stretches) > 3

    def triangles(meshes: list) -> np.ndarray:
        """Each face as its corners and class, sorted (the order of faces is not kept)."""
        rows = np.concatenate(
            [
                np.column_stack([m.vertices[m.faces].reshape(len(m.faces), 9), m.face_class])
                for m in meshes
            ]
        )
        return rows[np.lexsort(rows.T[::-1])]

    np.testing.assert_array_equal(triangles(stretches), triangles([whole]))
