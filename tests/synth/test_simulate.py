"""The simulator against its own truth: geometry, lattice, cameras, and the paper's sparsity."""

from __future__ import annotations

import filecmp
import shutil
from pathlib import Path

import numpy as np
import pytest

from guardrail_core.classes import GUARDRAIL_CLASSES, TruthClass
from guardrail_core.cli import main
from guardrail_core.errors import InputInsideOutputError, OutputExistsError, SceneSpecError
from guardrail_core.formats.drive import Drive, load_drive
from guardrail_core.synth.raycast import SceneRaycaster
from guardrail_core.synth.scene import SCENES_DIR, load_scene_spec
from guardrail_core.synth.simulate import rebuild_scene, simulate_drive
from tests.conftest import SMALL_OPTIONS, TEST_SEED
from tests.file_tree import file_tree


def _distance_to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Distance (N,) from points (N, 3) to a polyline (K, 3)."""
    a, b = polyline[:-1], polyline[1:]
    ab = b - a
    t = np.einsum("nkj,kj->nk", points[:, None, :] - a[None], ab) / np.einsum("kj,kj->k", ab, ab)
    closest = a[None] + np.clip(t, 0, 1)[..., None] * ab[None]
    return np.linalg.norm(points[:, None, :] - closest, axis=2).min(axis=1)


def _pipe_run(drive: Drive) -> dict:
    return next(o for o in drive.truth.objects if o["kind"] == "guardrail" and o["type"] == "pipe")


def _pipe_points(drive: Drive) -> tuple[np.ndarray, np.ndarray, list[dict]]:
    """Pipe points of the pipe run, the distance of each to every pipe surface, and the pipes."""
    run = _pipe_run(drive)
    on_run = (drive.truth.point_object == run["id"]) & (
        drive.truth.point_class == TruthClass.GUARDRAIL
    )
    pts = drive.points.xyz[on_run]
    pipes = run["pipes"]
    surface = np.stack(
        [_distance_to_polyline(pts, np.asarray(p["axis"])) - p["radius"] for p in pipes], axis=1
    )
    return pts, surface, pipes


def test_points_on_pipes_lie_at_their_radius_within_the_noise(drive: Drive) -> None:
    _, surface, _ = _pipe_points(drive)
    residual = np.abs(surface).min(axis=1)  # to the nearest pipe surface
    sigma = drive.scanner.range_noise_m
    assert len(residual) > 500
    # Noise is along the beam: its radial part is at most the range error; the 12-gon tube
    # stands up to r (1 - cos 15 deg) < 1 mm inside the true circle.
    assert np.median(residual) < 0.8 * sigma + 0.001
    assert np.quantile(residual, 0.99) < 3.5 * sigma + 0.001
    assert np.std(np.abs(surface).min(axis=1)) > 0.2 * sigma  # the noise is there at all


def test_lattice_recovered_from_gps_time_equals_the_simulated_one(drive: Drive) -> None:
    rotation, phase = drive.scanner.lattice_from_gps_time(drive.points.gps_time)
    np.testing.assert_array_equal(rotation, drive.points.rotation)
    np.testing.assert_array_equal(phase, drive.points.phase)
    assert phase.max() < drive.scanner.points_per_rotation
    # Each rotation holds one profile: times within a rotation span at most 10 ms.
    spans = np.bincount(rotation - rotation.min(), weights=drive.points.gps_time)
    assert spans.size == rotation.max() - rotation.min() + 1
    np.testing.assert_allclose(
        drive.scanner.gps_time_of(drive.points.rotation, drive.points.phase),
        drive.points.gps_time,
        atol=1e-9,
    )


def test_truth_guardrail_points_project_onto_guardrail_pixels(drive: Drive) -> None:
    scene = rebuild_scene(drive)
    raycaster = SceneRaycaster(scene.mesh)
    is_rail = np.isin(drive.truth.point_class, list(GUARDRAIL_CLASSES))
    pts = drive.points.xyz[is_rail]
    hits = near = total = 0
    for record in drive.images:
        camera = drive.cameras[record.camera]
        uv, front = camera.project(pts, record.T_world_camera)
        inside = front & camera.inside(uv)
        if not inside.any():
            continue
        centre = record.T_world_camera[:3, 3]
        rays = pts[inside] - centre
        dist = np.linalg.norm(rays, axis=1)
        seen = raycaster.cast(centre, rays / dist[:, None]).t > dist - 0.03  # nothing in between
        mask = drive.read_mask(record)
        pix = np.rint(uv[inside][seen]).astype(int)
        labels = mask[pix[:, 1], pix[:, 0]]
        hits += int(np.isin(labels, list(GUARDRAIL_CLASSES)).sum())
        total += len(labels)
        # Within one pixel: the 5 mm range noise moves points off thin pipes by about a pixel.
        window = np.lib.stride_tricks.sliding_window_view(np.pad(mask, 1), (3, 3))
        near_rail = np.isin(window[pix[:, 1], pix[:, 0]], list(GUARDRAIL_CLASSES)).any(axis=(1, 2))
        near += int(near_rail.sum())
    assert total > 10_000
    assert hits / total >= 0.95
    assert near / total >= 0.995


def test_diagonal_pipes_along_the_scan_lines_get_far_fewer_points(drive: Drive) -> None:
    """The paper's Fig. 21: diagonals almost parallel to the scan lines are sparse.

    Scan lines on a vertical roadside plane rise toward the rear of the vehicle at 45 degrees
    (the scanner's tilt), so the diagonals that fall along the run lie along them: a unit's
    diagonal is either missed by every line or hit by one; a horizontal pipe is crossed by every
    line. Per unit, the typical (median) diagonal gets almost nothing.
    """
    pts, surface, pipes = _pipe_points(drive)
    nearest = np.argmin(np.abs(surface), axis=1)
    on_pipe = np.abs(surface[np.arange(len(surface)), nearest]) < 0.02
    poles = _pipe_run(drive)["poles"]
    run_dir = np.asarray(poles[-1]["position"]) - np.asarray(poles[0]["position"])
    density: dict[str, list[float]] = {"horizontal": [], "rising": [], "falling": []}
    coverage: dict[str, list[float]] = {"horizontal": [], "rising": [], "falling": []}
    for i, pipe in enumerate(pipes):
        a, b = np.asarray(pipe["axis"])[[0, -1]]
        kind = pipe["kind"]
        if kind == "diagonal":
            kind = "falling" if np.dot(b - a, run_dir) * (b[2] - a[2]) < 0 else "rising"
        length = float(np.linalg.norm(b - a))
        mine = pts[on_pipe & (nearest == i)]
        density[kind].append(len(mine) / length)
        # Coverage: the share of 10 cm stretches of the pipe with at least one point.
        t = np.clip((mine - a) @ (b - a) / length**2, 0, 1 - 1e-9)
        stretches = max(1, int(length / 0.1))
        coverage[kind].append(np.unique((t * stretches).astype(int)).size / stretches)
    median = {k: float(np.median(v)) for k, v in density.items()}
    share = {k: float(np.mean(v)) for k, v in coverage.items()}
    assert min(len(v) for v in density.values()) >= 10  # units of the run
    assert median["falling"] < 0.1 * median["horizontal"], median
    assert median["rising"] > 0.3 * median["horizontal"], median
    assert share["horizontal"] > 0.95 and share["rising"] > 0.95, share
    assert share["falling"] < 0.7, share


def test_same_seed_same_drive(tmp_path: Path) -> None:
    first, again = tmp_path / "first", tmp_path / "again"
    for out in (first, again):
        simulate_drive(
            load_scene_spec("test_straight"),
            out,
            seed=TEST_SEED,
            options=SMALL_OPTIONS,
            progress=False,
        )
    tiles = [
        p.relative_to(first).as_posix()
        for folder in ("points", "truth/points")
        for p in sorted((first / folder).iterdir())
    ]
    assert "points/index.json" in tiles and "points/000000.laz" in tiles
    for name in (
        *tiles,
        "trajectory.csv",
        "images.json",
        "cameras.json",
        "truth/objects.json",
        "images/left/000002.jpg",
        "truth/masks/front/000002.png",
    ):
        assert filecmp.cmp(first / name, again / name, shallow=False), name


def test_a_different_seed_gives_a_different_drive(drive: Drive, tmp_path: Path) -> None:
    other = tmp_path / "other"
    simulate_drive(
        load_scene_spec("test_straight"),
        other,
        seed=TEST_SEED + 1,
        options=SMALL_OPTIONS,
        progress=False,
    )
    assert len(load_drive(other).points) != len(drive.points)


def test_simulation_refuses_to_overwrite_and_leaves_nothing_on_error(
    drive_path: Path, tmp_path: Path
) -> None:
    with pytest.raises(OutputExistsError):
        simulate_drive(load_scene_spec("test_straight"), drive_path, seed=1, progress=False)
    spec = load_scene_spec("test_straight")
    spec["guardrails"][0]["design"] = "no_such_design"
    with pytest.raises(SceneSpecError, match="no_such_design"):
        simulate_drive(spec, tmp_path / "bad", seed=1, progress=False)
    assert list(tmp_path.iterdir()) == []


def test_a_scene_file_inside_the_output_is_refused_and_survives(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    out.mkdir()
    scene = out / "street.yaml"
    shutil.copyfile(SCENES_DIR / "test_straight.yaml", scene)
    before = file_tree(out)
    with pytest.raises(InputInsideOutputError, match="holds the input"):
        simulate_drive(load_scene_spec(scene), out, inputs=[scene], overwrite=True, progress=False)
    assert main(["simulate", str(out), "--scene", str(scene), "--overwrite", "--quiet"]) == 2
    assert "InputInsideOutputError" in capsys.readouterr().err
    assert file_tree(out) == before  # the scene byte for byte, and no staging folder
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_truth_covers_every_point_and_every_image(drive: Drive) -> None:
    truth = drive.truth
    assert truth.point_class.shape == (len(drive.points),)
    assert (truth.point_class != TruthClass.NONE).all()
    ids = {o["id"] for o in truth.objects}
    assert set(np.unique(truth.point_object)) - {0} <= ids
    kinds = {o["kind"] for o in truth.objects}
    assert {"guardrail", "tree", "bollard", "parked_car", "facade"} <= kinds
    for record in drive.images:
        mask = drive.read_mask(record)
        camera = drive.cameras[record.camera]
        assert mask.shape == (camera.height, camera.width)
    assert len({r.camera for r in drive.images}) >= 2
