"""The simulated multi-beam scanner (a Velodyne HDL-64E taking single frames): its frames, its
ring x azimuth lattice and its truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from guardrail_core.classes import TruthClass
from guardrail_core.errors import SceneSpecError
from guardrail_core.extract.lattice import build_lattice
from guardrail_core.formats.drive import Drive, load_drive
from guardrail_core.sensors.lidar_models import LIDAR_MODELS
from guardrail_core.sensors.scanner import MULTIBEAM
from guardrail_core.synth.scene import build_scene, load_scene_spec
from guardrail_core.synth.simulate import SimulationOptions, simulate_drive

FRAME_EVERY_M = 10.0


@pytest.fixture(scope="module")
def multibeam_drive(tmp_path_factory: pytest.TempPathFactory) -> Drive:
    spec = load_scene_spec("test_straight")
    spec["scanner"] = {"kind": "multibeam", "frame_every_m": FRAME_EVERY_M}
    out = tmp_path_factory.mktemp("drives") / "multibeam"
    simulate_drive(
        spec, out, seed=3, options=SimulationOptions(image_every_m=1000.0), progress=False
    )
    return load_drive(out)


def test_frames_and_rings(multibeam_drive: Drive) -> None:
    drive = multibeam_drive
    points = drive.points
    assert drive.scanner.kind == MULTIBEAM and drive.scanner.rings == 64
    rows = drive.scanner.rings + 1
    frame = points.rotation // rows
    ring = points.rotation % rows
    travelled = np.sum(np.linalg.norm(np.diff(drive.trajectory.position, axis=0), axis=1))
    assert frame.max() + 1 == int(np.floor((travelled - FRAME_EVERY_M / 2) / FRAME_EVERY_M)) + 1
    assert ring.max() < 64  # the spare row of every block stays empty
    assert np.all(np.diff(points.gps_time) >= 0)
    # A frame takes one turn (0.1 s); every point's ring is the beam it left on: its elevation
    # seen from the sensor's pose at its own time matches the beam's, within the noise.
    for f in np.unique(frame)[:2]:
        mine = frame == f
        t = points.gps_time[mine]
        assert t.max() - t.min() <= 0.1 + 1e-9
        rotation, position = drive.trajectory.poses(t)
        sensor = position + rotation @ drive.scanner.T_vehicle_scanner[:3, 3]
        local = np.einsum("nji,nj->ni", rotation, points.xyz[mine] - sensor)
        elevation = np.rad2deg(np.arctan2(local[:, 2], np.hypot(local[:, 0], local[:, 1])))
        expected = np.asarray(LIDAR_MODELS["hdl64e"].elevations_deg)[ring[mine]]
        assert np.median(np.abs(elevation - expected)) < 0.1


def test_lattice_neighbours_are_near(multibeam_drive: Drive) -> None:
    points = multibeam_drive.points
    lattice = build_lattice(
        points.rotation, points.phase, multibeam_drive.scanner.points_per_rotation
    )
    assert np.mean(lattice.cell >= 0) > 0.99  # two firings rarely share an azimuth bin
    for step in [(0, 1), (0, 2), (1, 0)]:
        other = lattice.neighbour(*step)
        ok = other >= 0
        gap = np.linalg.norm(points.xyz[ok] - points.xyz[other[ok]], axis=1)
        assert np.median(gap) < 0.3, step


def test_truth_covers_the_guardrails(multibeam_drive: Drive) -> None:
    truth = multibeam_drive.truth
    assert truth is not None
    assert np.count_nonzero(truth.point_class == TruthClass.GUARDRAIL) > 500
    assert np.count_nonzero(truth.point_class == TruthClass.ROAD) > 10_000


def test_bad_multibeam_spec_is_refused() -> None:
    spec = load_scene_spec("test_straight")
    spec["scanner"] = {"kind": "multibeam", "frame_every_m": 0}
    with pytest.raises(SceneSpecError, match="frame_every_m"):
        build_scene(spec)
    spec["scanner"] = {"kind": "spinning"}
    with pytest.raises(SceneSpecError, match="multibeam"):
        build_scene(spec)


def test_cli_simulates_multibeam(tmp_path: Path) -> None:
    from guardrail_core.cli import main

    out = tmp_path / "d"
    args = ["simulate", str(out), "--scene", "test_straight", "--scanner", "multibeam"]
    args += ["--frame-every", "20", "--image-every", "1000", "--quiet"]
    assert main(args) == 0
    assert load_drive(out).scanner.kind == MULTIBEAM
