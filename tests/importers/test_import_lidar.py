"""``guardrail import lidar``: frames of spinning LiDARs as their drivers write them.

The frames are those of ``docs/examples/lidar_frames.py``: cut from simulated multi-beam drives
(a Hesai Pandar64 and an Ouster OS1-128 of the presets), put back into the sensor's own frame
point by point, shuffled, and written as a driver would: a PCD without a ring field with a
distorted camera calibrated on the LiDAR, and a LAS with a ring field numbered from the lowest
beam. Each imports and processes with one command.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from guardrail_core.classes import TruthClass
from guardrail_core.cli import main
from guardrail_core.errors import (
    FrameRangeError,
    MissingSourceFileError,
    OutputExistsError,
    SourceFormatError,
)
from guardrail_core.formats.drive import load_drive
from guardrail_core.formats.run_folder import load_run
from guardrail_core.geom.frames import invert_transform
from guardrail_core.importers.lidar import (
    estimate_sensor_height,
    fit_road,
    import_lidar,
)
from guardrail_core.importers.lidar_frames import read_lidar_frame
from guardrail_core.sensors.lidar_models import LIDAR_MODELS, rings_from_elevation
from guardrail_core.synth.scene import MULTIBEAM_HEIGHT_M

EXAMPLE = Path(__file__).resolve().parents[2] / "docs" / "examples" / "lidar_frames.py"


def _by_position(xyz: np.ndarray) -> np.ndarray:
    """The order of points (N, 3) by their position on the 0.1 mm grid."""
    grid = np.rint(np.asarray(xyz) * 1e4).astype(np.int64)
    return np.lexsort((grid[:, 2], grid[:, 1], grid[:, 0]))


@pytest.fixture(scope="module")
def examples():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("lidar_frames", EXAMPLE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def pandar(examples, tmp_path_factory: pytest.TempPathFactory) -> dict:  # type: ignore[no-untyped-def]
    """A Pandar64 frame as a binary_compressed PCD without a ring field, its front camera's
    image and calibration (docs/examples/lidar_frames.py)."""
    written = examples.write_pandar64_frame(tmp_path_factory.mktemp("pandar"))
    assert b"DATA binary_compressed" in written["pcd"].read_bytes()[:1000]
    return written


@pytest.fixture(scope="module")
def ouster(examples, tmp_path_factory: pytest.TempPathFactory) -> dict:  # type: ignore[no-untyped-def]
    """An OS1-128 frame as LAS 1.4 with a ring field numbered from the lowest beam up."""
    return examples.write_os1_frame(tmp_path_factory.mktemp("ouster"))


def test_a_pandar64_pcd_frame_with_its_distorted_camera_imports_and_processes(
    pandar: dict, tmp_path: Path
) -> None:
    out = tmp_path / "drive"
    command = ["import", "lidar", str(pandar["pcd"]), "--sensor", "pandar64", "--out", str(out)]
    camera = [
        "--camera",
        str(pandar["root"] / "front.json"),
        "--images",
        str(pandar["root"] / "images"),
    ]
    assert main([*command, *camera, "--quiet"]) == 0
    drive = load_drive(out)
    frame = pandar["frame"]
    assert len(drive.points) == len(frame["xyz"])
    assert drive.scanner.kind == "multibeam" and drive.scanner.rings == 64
    mine, theirs = _by_position(drive.points.xyz), _by_position(frame["xyz"])
    np.testing.assert_allclose(drive.points.xyz[mine], frame["xyz"][theirs], atol=1e-6)
    # One frame alone: its points' own times, and every ring recovered from elevation alone.
    np.testing.assert_array_equal(drive.points.gps_time[mine], frame["time"][theirs])
    np.testing.assert_array_equal(drive.points.rotation[mine], frame["ring"][theirs])
    assert abs(drive.trajectory.reference_height_m - MULTIBEAM_HEIGHT_M) < 0.05
    # The camera keeps its distortion; a point lands where OpenCV projects it.
    (record,) = drive.images
    lens = drive.cameras["front"]
    np.testing.assert_array_equal(lens.dist, pandar["camera"]["distortion_coefficients"])
    T_camera_lidar = np.asarray(pandar["camera"]["T_camera_lidar"])
    uv, valid = lens.project(drive.points.xyz, record.T_world_camera)
    seen = valid & lens.inside(uv)
    assert seen.sum() > 1000
    expected, _ = cv2.projectPoints(
        drive.points.xyz[seen],
        cv2.Rodrigues(T_camera_lidar[:3, :3])[0],
        T_camera_lidar[:3, 3],
        np.asarray(pandar["camera"]["camera_matrix"]),
        np.asarray(pandar["camera"]["distortion_coefficients"]),
    )
    np.testing.assert_allclose(uv[seen], expected[:, 0], atol=1e-6)

    run = tmp_path / "run"
    assert main(["process", str(out), "--out", str(run), "--workers", "1", "--quiet"]) == 0
    _guardrail_found(load_run(run), frame, mine, theirs)


def _guardrail_found(run, frame: dict, mine: np.ndarray, theirs: np.ndarray) -> None:  # type: ignore[no-untyped-def]
    """Most of the frame's guardrail points are called guardrail, and few others are."""
    label = np.zeros(len(frame["xyz"]), bool)
    in_segment = run.point_segment[mine] >= 0
    label[theirs[in_segment]] = run.segments["label"][run.point_segment[mine][in_segment]]
    rail = np.isin(frame["class"], [TruthClass.GUARDRAIL, TruthClass.GUARDRAIL_POLE])
    assert label[rail].mean() >= 0.5, label[rail].mean()
    assert (label & ~rail).sum() <= 0.25 * label.sum()


def test_an_os1_las_frame_with_a_ring_field_imports_and_processes(
    ouster: dict, tmp_path: Path
) -> None:
    out = tmp_path / "drive"
    assert main(["import", "lidar", str(ouster["las"]), "--out", str(out), "--quiet"]) == 0
    drive = load_drive(out)
    frame = ouster["frame"]
    assert drive.scanner.rings == 128
    mine, theirs = _by_position(drive.points.xyz), _by_position(frame["xyz"])
    np.testing.assert_allclose(drive.points.xyz[mine], frame["xyz"][theirs], atol=1e-6)
    np.testing.assert_array_equal(drive.points.gps_time[mine], frame["time"][theirs])
    # The ring field's numbering (lowest beam 0) becomes rows by elevation (highest 0).
    np.testing.assert_array_equal(drive.points.rotation[mine], frame["ring"][theirs])
    run = tmp_path / "run"
    assert main(["process", str(out), "--out", str(run), "--workers", "1", "--quiet"]) == 0
    _guardrail_found(load_run(run), frame, mine, theirs)


def test_rings_from_a_beam_table_survive_a_calibration_off_the_datasheet() -> None:
    """A unit whose beams all lie 0.1 degrees above the datasheet's, give or take 0.02 (its
    fine beams 0.167 degrees apart): the nearest nominal beam is the wrong one for theirs, so
    the table is first moved to the beams the frame shows."""
    rng = np.random.default_rng(4)
    table = np.asarray(LIDAR_MODELS["pandar64"].elevations_deg)
    unit = table + 0.1 + rng.uniform(-0.02, 0.02, len(table))
    ring = rng.integers(0, len(table), 50_000)
    reach = rng.uniform(3, 60, len(ring))
    azimuth = rng.uniform(-np.pi, np.pi, len(ring))
    xyz = np.stack(
        [reach * np.cos(azimuth), reach * np.sin(azimuth), reach * np.tan(np.radians(unit[ring]))],
        axis=1,
    )
    nearest_nominal = np.argmin(np.abs(unit[ring][:, None] - table[None, :]), axis=1)
    assert (nearest_nominal != ring).mean() > 0.5  # the fine beams' points, most of them
    np.testing.assert_array_equal(rings_from_elevation(xyz, table), ring)


def test_the_sensor_height_is_measured_from_the_road_under_it() -> None:
    rng = np.random.default_rng(5)
    road = np.column_stack(
        [rng.uniform(-20, 20, 5000), rng.uniform(-8, 8, 5000), rng.normal(-1.95, 0.01, 5000)]
    )
    wall = np.column_stack(
        [rng.uniform(-20, 20, 3000), np.full(3000, 9.0), rng.uniform(-1.9, 3, 3000)]
    )
    assert estimate_sensor_height(np.concatenate([road, wall])) == pytest.approx(1.95, abs=0.01)
    with pytest.raises(SourceFormatError, match="--sensor-height"):
        estimate_sensor_height(wall)
    # A sensor pitched 0.6 degree nose down sees the road rise 1 % ahead; a wall changes nothing.
    tilted = road.copy()
    tilted[:, 2] += 0.01 * tilted[:, 0]
    # The layer guessed 3 cm high: the plane still finds the road 1.95 m under the sensor.
    grade, height = fit_road(np.concatenate([tilted, wall]), 1.92)
    assert grade == pytest.approx(0.01, abs=5e-4) and height == pytest.approx(1.95, abs=2e-3)
    assert fit_road(wall, 1.95) == (0.0, 1.95)


def _write(path: Path, text: str | bytes) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(text.encode() if isinstance(text, str) else text)
    return path


def test_malformed_inputs_are_named_and_nothing_is_written(pandar: dict, tmp_path: Path) -> None:
    pcd = pandar["pcd"]
    out = tmp_path / "drive"
    cases = [
        ([_write(tmp_path / "a.pcd", "not a pcd at all")], {}, SourceFormatError, "not a PCD"),
        ([_write(tmp_path / "a.xyz", "1 2 3")], {}, SourceFormatError, "expected a LiDAR frame"),
        ([_write(tmp_path / "a.bin", b"\0" * 15)], {}, SourceFormatError, "not a KITTI scan"),
        ([_write(tmp_path / "b.las", b"LASF garbage")], {}, SourceFormatError, "LAS/LAZ"),
        ([tmp_path / "missing.pcd"], {}, MissingSourceFileError, "missing.pcd"),
        ([pcd, pcd], {}, SourceFormatError, "no --poses"),
        ([pcd], {"sensor": "hdl64"}, SourceFormatError, "unknown LiDAR 'hdl64'"),
        ([pcd], {"sensor": "pandar64", "beams": pcd}, SourceFormatError, "not both"),
        (
            [pcd],
            {"beams": _write(tmp_path / "beams.csv", "elevation\n1\nx\n")},
            SourceFormatError,
            "beams.csv:3",
        ),
        ([pcd], {"beams": _write(tmp_path / "one.csv", "1\n")}, SourceFormatError, "two or more"),
        (
            [pcd],
            {"poses": _write(tmp_path / "p.txt", "1 0 0 0 0 1 0 0 0 0 1\n")},
            SourceFormatError,
            "12 numbers",
        ),
        (
            [pcd],
            {"poses": _write(tmp_path / "q.txt", "2 0 0 0 0 1 0 0 0 0 1 0\n")},
            SourceFormatError,
            "not a rigid",
        ),
        (
            [_write(tmp_path / "000007.pcd", pcd.read_bytes())],
            {"poses": _write(tmp_path / "r.txt", "1 0 0 0 0 1 0 0 0 0 1 0\n" * 3)},
            FrameRangeError,
            "frame 7 has no row",
        ),
        ([pcd], {"sensor_height_m": -1.0}, SourceFormatError, "positive"),
        (
            [pcd],
            {"calibrations": [pandar["root"] / "front.json"]},
            MissingSourceFileError,
            "images",
        ),
    ]
    for frames, options, error, message in cases:
        with pytest.raises(error, match=message):
            import_lidar(frames, out, **options)
        assert not out.exists(), message
    # A calibration with two mountings, and an image of another size.
    both = {**pandar["camera"], "T_lidar_camera": np.eye(4).tolist()}
    with pytest.raises(SourceFormatError, match="expected one of"):
        import_lidar([pcd], out, calibrations=[_write(tmp_path / "c.json", json.dumps(both))])
    small = tmp_path / "small"
    cv2.imwrite(str(_write(small / "000000.png", b"")), np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(SourceFormatError, match="calibrated for 480 x 360"):
        import_lidar([pcd], out, calibrations=[pandar["root"] / "front.json"], images=small)
    assert not out.exists()
    # The output is never an input, nor is an existing folder replaced without asking.
    with pytest.raises(OutputExistsError):
        import_lidar([pcd], pcd.parent)
    assert read_lidar_frame(pcd).xyz.shape == pandar["frame"]["xyz"].shape


def test_a_sequence_of_kitti_bins_is_merged_with_its_poses(
    examples, pandar: dict, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    """Two frames as KITTI .bin files, their poses in a CSV of times and 4 x 4 matrices: each
    frame's points land where its pose puts them, in the first frame's sensor frame."""
    drive = load_drive(pandar["root"] / "sim")
    rows, poses = [], []
    for k in range(2):
        frame = examples.sensor_frame(drive, k, seed=k)
        scan = np.column_stack([frame["xyz"], frame["intensity"] / 65535.0]).astype("<f4")
        scan.tofile(tmp_path / f"{k:06d}.bin")
        pose = examples.T_world_sensor(drive, frame["t_mid"])
        poses.append([frame["t_mid"], *pose.ravel()])
        rows.append((frame, pose))
    np.savetxt(tmp_path / "poses.csv", poses, delimiter=",", header="time,m00..m33")
    out = tmp_path / "drive"
    frames = [str(tmp_path / "000000.bin"), str(tmp_path / "000001.bin")]
    command = ["import", "lidar", *frames, "--poses", str(tmp_path / "poses.csv")]
    assert main([*command, "--sensor", "pandar64", "--out", str(out), "--quiet"]) == 0
    merged = load_drive(out)
    block = merged.points.rotation // (merged.scanner.rings + 1)
    first = rows[0][1]
    for k, (frame, pose) in enumerate(rows):
        mine = np.flatnonzero(block == k)
        T = invert_transform(first) @ pose
        xyz = frame["xyz"].astype(np.float32).astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        a, b = _by_position(merged.points.xyz[mine]), _by_position(xyz)
        np.testing.assert_allclose(merged.points.xyz[mine][a], xyz[b], atol=2e-4)
        np.testing.assert_array_equal(merged.points.rotation[mine][a] % 65, frame["ring"][b])
        assert np.all(merged.points.gps_time[mine] == frame["t_mid"])  # a .bin has no times
    assert len(merged.trajectory) == 4  # the two frames, held still a turn before and after
