"""The drive format: round trip, and malformed drives rejected with named errors."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import laspy
import numpy as np
import pytest

from guardrail_core.cli import main
from guardrail_core.errors import (
    DriveDimensionError,
    DriveFormatError,
    MissingDriveFileError,
    NonFiniteCoordinatesError,
    TimestampMismatchError,
)
from guardrail_core.export.drive_points import read_drive_points
from guardrail_core.formats.drive import Drive, load_drive, open_drive
from tests.drive_files import drive_las, tile_file, truth_file


@pytest.fixture
def copy(drive_path: Path, tmp_path: Path) -> Path:
    """A private copy of the session's drive, to break."""
    out = tmp_path / "drive"
    shutil.copytree(drive_path, out)
    return out


def _edit_json(path: Path, edit) -> None:
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))


def test_loaded_drive_holds_every_part(drive: Drive) -> None:
    assert len(drive.points) > 100_000
    assert drive.points.xyz.dtype == np.float64 and np.isfinite(drive.points.xyz).all()
    assert np.all(np.diff(drive.points.gps_time) > 0)  # ordered by time, one return per pulse
    assert drive.origin.dtype == np.float64 and abs(drive.origin[1]) > 10_000  # map coordinates
    assert np.abs(drive.points.xyz).max() < 500  # local coordinates stay small
    assert drive.crs.startswith("EPSG:")
    assert set(drive.cameras) == {"front", "left", "right"}
    image = drive.read_image(drive.images[0])
    camera = drive.cameras[drive.images[0].camera]
    assert image.shape == (camera.height, camera.width, 3) and image.dtype == np.uint8
    assert drive.trajectory.time[0] <= drive.points.gps_time[0]
    # The trajectory's road height is the road under the vehicle (flat test road at z = 0).
    assert np.abs(drive.trajectory.road_height(drive.points.gps_time[:1000])).max() < 0.1


def test_points_keep_sub_millimetre_precision_in_map_coordinates(drive: Drive) -> None:
    las = drive_las(drive.root)
    assert las.header.version.minor == 4
    assert {"gps_time", "rotation", "phase"} <= set(las.point_format.dimension_names)
    world = np.stack([las.x, las.y, las.z], axis=1)
    np.testing.assert_allclose(world - drive.origin, drive.points.xyz, atol=1e-9)
    assert las.header.scales[0] <= 1e-4


def test_missing_drive_folder(tmp_path: Path) -> None:
    with pytest.raises(MissingDriveFileError, match="no such drive folder"):
        load_drive(tmp_path / "nowhere")


@pytest.mark.parametrize(
    "name", ["drive.json", "points/index.json", "trajectory.csv", "cameras.json", "images.json"]
)
def test_missing_file_is_named(copy: Path, name: str) -> None:
    (copy / name).unlink()
    with pytest.raises(MissingDriveFileError, match=re.escape(Path(name).name)):
        load_drive(copy)


def test_missing_point_tile_is_named(copy: Path) -> None:
    tile = tile_file(copy)
    tile.unlink()
    with pytest.raises(MissingDriveFileError, match=re.escape(tile.name)):
        load_drive(copy)


def test_missing_image_file_is_named(copy: Path) -> None:
    (copy / "images" / "left" / "000001.jpg").unlink()
    with pytest.raises(MissingDriveFileError, match="000001.jpg"):
        load_drive(copy)


def test_newer_major_format_version_is_refused(copy: Path) -> None:
    _edit_json(copy / "drive.json", lambda d: d.update(format_version="3.0"))
    with pytest.raises(DriveFormatError, match="format_version 3.0 .* newer version of guardrail"):
        load_drive(copy)


@pytest.mark.parametrize("version", ["1.0", "1.1"])
def test_a_format_1_drive_is_refused_and_says_to_import_it_again(
    copy: Path, version: str, capsys: pytest.CaptureFixture[str]
) -> None:
    # 1.x (one points.laz, before the point tiles) was written only before 0.2.0, the first
    # release: every reader refuses it by name instead of reading it as one tile.
    _edit_json(
        copy / "drive.json",
        lambda d: d.update(format_version=version, files={**d["files"], "points": "points.laz"}),
    )
    message = (
        rf"drive\.json: format_version {re.escape(version)} is not readable by this version "
        r"\(reads 2\.x\); import or simulate the drive again"
    )
    with pytest.raises(DriveFormatError, match=message):
        open_drive(copy)
    with pytest.raises(DriveFormatError, match=message):
        read_drive_points(copy)  # the LAS export's reader
    assert main(["info", str(copy)]) == 2
    assert re.search(f"DriveFormatError: .*{message}", capsys.readouterr().err)


def test_broken_json_is_a_format_error(copy: Path) -> None:
    (copy / "cameras.json").write_text("[{")
    with pytest.raises(DriveFormatError, match="not valid JSON"):
        load_drive(copy)


def test_wrong_trajectory_columns(copy: Path) -> None:
    path = copy / "trajectory.csv"
    lines = path.read_text().splitlines()
    path.write_text(
        "\n".join(["time,x,y,z"] + [",".join(line.split(",")[:4]) for line in lines[1:]])
    )
    with pytest.raises(DriveDimensionError, match="header"):
        load_drive(copy)


@pytest.mark.parametrize(
    "rows, error, match",
    [
        ([], DriveDimensionError, "at least 2 rows"),  # the header alone
        (["1,2,3,4,5,6,7", "2,3,4,5,6,7"], DriveFormatError, "malformed"),  # a short row
        (["1,2,3,4,5,6,7", "2,x,4,5,6,7,8"], DriveFormatError, "not a number"),
        (["1,2,3,4,5,6,7", "# 2,3,4,5,6,7,8"], DriveFormatError, "not a number"),  # no comments
    ],
)
def test_malformed_trajectory_rows_are_refused_by_name(
    copy: Path, rows: list[str], error: type[Exception], match: str
) -> None:
    (copy / "trajectory.csv").write_text("\n".join(["time,x,y,z,roll,pitch,yaw", *rows]) + "\n")
    with pytest.raises(error, match=match):
        load_drive(copy)


def test_non_finite_trajectory(copy: Path) -> None:
    path = copy / "trajectory.csv"
    lines = path.read_text().splitlines()
    fields = lines[5].split(",")
    fields[2] = "nan"
    lines[5] = ",".join(fields)
    path.write_text("\n".join(lines))
    with pytest.raises(NonFiniteCoordinatesError, match="rows \\[4\\]"):
        load_drive(copy)


def test_trajectory_that_does_not_cover_the_points(copy: Path) -> None:
    path = copy / "trajectory.csv"
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[: len(lines) // 2]))
    end = float(lines[len(lines) // 2 - 1].split(",")[0])
    # The images stay inside it, so what is refused is the points.
    images = json.loads((copy / "images.json").read_text())
    (copy / "images.json").write_text(json.dumps([r for r in images if r["gps_time"] <= end]))
    with pytest.raises(TimestampMismatchError, match="trajectory covers only"):
        load_drive(copy)


def test_image_time_outside_the_trajectory(copy: Path) -> None:
    _edit_json(copy / "images.json", lambda d: d[0].update(gps_time=d[0]["gps_time"] + 3600))
    with pytest.raises(TimestampMismatchError, match=r"images.json\[0\]"):
        load_drive(copy)


def test_image_of_an_uncalibrated_camera(copy: Path) -> None:
    _edit_json(copy / "cameras.json", lambda d: d.pop(0))
    with pytest.raises(DriveFormatError, match="has no calibration"):
        load_drive(copy)


def test_camera_matrix_of_the_wrong_shape(copy: Path) -> None:
    _edit_json(copy / "cameras.json", lambda d: d[0].update(K=[[1, 0], [0, 1]]))
    with pytest.raises(DriveDimensionError, match=r"\.K: expected shape \(3, 3\)"):
        load_drive(copy)


def test_non_finite_camera_pose(copy: Path) -> None:
    def poison(records: list) -> None:
        records[2]["T_world_camera"][0][3] = float("inf")

    path = copy / "images.json"
    data = json.loads(path.read_text())
    poison(data)
    path.write_text(json.dumps(data).replace("Infinity", "1e999"))
    with pytest.raises(NonFiniteCoordinatesError, match="T_world_camera"):
        load_drive(copy)


def test_las_without_gps_time(copy: Path) -> None:
    las = laspy.read(str(tile_file(copy)))
    plain = laspy.LasData(laspy.LasHeader(point_format=2, version="1.2"))
    plain.header.offsets, plain.header.scales = las.header.offsets, las.header.scales
    plain.x, plain.y, plain.z = las.x, las.y, las.z
    plain.write(str(tile_file(copy)))
    with pytest.raises(DriveDimensionError, match="no gps_time"):
        load_drive(copy)


def test_non_finite_gps_time(copy: Path) -> None:
    las = laspy.read(str(tile_file(copy)))
    times = np.array(las.gps_time)
    times[10] = np.nan
    las.gps_time = times
    las.write(str(tile_file(copy)))
    with pytest.raises(NonFiniteCoordinatesError, match="gps_time"):
        load_drive(copy)


def test_not_a_las_file(copy: Path) -> None:
    tile_file(copy).write_bytes(b"this is no point cloud")
    with pytest.raises(DriveFormatError, match="not a readable LAS"):
        load_drive(copy)


def test_lattice_is_recovered_when_the_extra_dimensions_are_absent(
    copy: Path, drive: Drive
) -> None:
    las = laspy.read(str(tile_file(copy)))
    plain = laspy.LasData(laspy.LasHeader(point_format=6, version="1.4"))
    plain.header.offsets, plain.header.scales = las.header.offsets, las.header.scales
    plain.x, plain.y, plain.z, plain.gps_time = las.x, las.y, las.z, las.gps_time
    plain.write(str(tile_file(copy)))
    again = load_drive(copy, with_truth=False)
    np.testing.assert_array_equal(again.points.rotation, drive.points.rotation)
    np.testing.assert_array_equal(again.points.phase, drive.points.phase)


def test_truth_of_the_wrong_length(copy: Path) -> None:
    with np.load(truth_file(copy)) as npz:
        cls, obj = npz["class"][:-1], npz["object_id"][:-1]
    np.savez(truth_file(copy), **{"class": cls, "object_id": obj})
    with pytest.raises(DriveDimensionError, match="truth has"):
        load_drive(copy)
    assert load_drive(copy, with_truth=False).truth is None
