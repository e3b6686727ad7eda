"""`guardrail import las`: a LAS/LAZ delivery exported from the simulated test drive comes back as
the same drive (points, lattice, image poses), and every bad input raises its named error and
leaves nothing behind."""

from __future__ import annotations

import csv
import filecmp
import gc
import json
import shutil
import tracemalloc
from dataclasses import astuple, dataclass
from pathlib import Path

import cv2
import laspy
import numpy as np
import pytest
from laspy.vlrs.known import GeoKeyDirectoryVlr, WktCoordinateSystemVlr

from guardrail_core.cli import main
from guardrail_core.errors import (
    InputInsideOutputError,
    InvalidOptionError,
    MissingCalibrationError,
    MissingGpsTimeError,
    MissingSourceFileError,
    OutputExistsError,
    PointsOutOfTimeOrderError,
    SourceFormatError,
    TrajectoryCoverageError,
)
from guardrail_core.formats.drive import TRAJECTORY_COLUMNS, Drive, load_drive, open_drive
from guardrail_core.formats.drive_tiles import vehicle_station
from guardrail_core.importers.calibration import read_calibration
from guardrail_core.importers.las_delivery import LasImport, import_las_delivery
from tests.file_tree import file_tree

WKT_6677 = (
    'PROJCS["JGD2011 / Japan Plane Rectangular CS IX",GEOGCS["JGD2011",DATUM["Japanese_Geodetic_'
    'Datum_2011",SPHEROID["GRS 1980",6378137,298.257222101]],PRIMEM["Greenwich",0],UNIT["degree",'
    '0.0174532925199433]],PROJECTION["Transverse_Mercator"],UNIT["metre",1],'
    'AUTHORITY["EPSG","6677"]]'
)
#: Adjusted standard GPS time of the start of a GPS week (week 2300: 2300 * 604800 - 1e9 s).
ADJUSTED_WEEK_START = 2300 * 604_800.0 - 1e9


@dataclass(frozen=True)
class Delivery:
    """Input files of a delivery exported from a drive, and the drive's points they hold."""

    folder: Path
    points: Path
    trajectory: Path
    images: Path
    calibration: Path
    scanner: Path
    keep: np.ndarray  # indices of the drive's points in the LAS file


def write_las(
    path: Path,
    drive: Drive,
    keep: np.ndarray,
    *,
    point_format: int = 3,
    version: str = "1.2",
    crs: str = "geokeys",
    gps_time: np.ndarray | None = None,
) -> None:
    """The drive's points ``keep`` as a plain LAS (no lattice dimensions), in map coordinates."""
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.offsets = np.round(drive.origin, -3)  # another offset than the drive's origin
    header.scales = np.array([1e-4] * 3)
    if crs == "geokeys":
        geokeys = GeoKeyDirectoryVlr()
        geokeys.geo_keys_header.key_directory_version = 1
        geokeys.geo_keys_header.key_revision = 1
        geokeys.geo_keys_header.number_of_keys = 1
        geokeys.geo_keys[0].id = 3072  # ProjectedCSTypeGeoKey
        geokeys.geo_keys[0].count = 1
        geokeys.geo_keys[0].value_offset = 6677
        header.vlrs.append(geokeys)
    elif crs == "wkt":
        header.vlrs.append(WktCoordinateSystemVlr(WKT_6677))
        header.global_encoding.wkt = True
    las = laspy.LasData(header)
    world = drive.points.xyz[keep] + drive.origin
    las.x, las.y, las.z = world[:, 0], world[:, 1], world[:, 2]
    if "gps_time" in las.point_format.dimension_names:
        las.gps_time = drive.points.gps_time[keep] if gps_time is None else gps_time
    las.intensity = drive.points.intensity[keep]
    las.write(str(path))


def write_calibration_yaml(path: Path, drive: Drive, cameras: list[str] | None = None) -> None:
    """The drive's cameras as OpenCV writes them: a mapping camera name -> block."""
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for name in cameras or list(drive.cameras):
        camera = drive.cameras[name]
        storage.startWriteStruct(name, cv2.FileNode_MAP)
        storage.write("camera_matrix", camera.K)
        storage.write("distortion_coefficients", camera.dist.reshape(1, 5))
        storage.write("image_width", camera.width)
        storage.write("image_height", camera.height)
        storage.write("T_vehicle_camera", camera.T_vehicle_camera)
        storage.endWriteStruct()
    storage.release()


def export_delivery(drive: Drive, folder: Path, keep: np.ndarray) -> Delivery:
    """Export a drive as a delivery: LAS 1.2 format 3, trajectory CSV, photos + list, YAML."""
    folder.mkdir(parents=True)
    write_las(folder / "cloud.las", drive, keep)
    shutil.copyfile(drive.root / "trajectory.csv", folder / "trajectory.csv")
    with (folder / "images.csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["camera", "gps_time", "file"])  # not the documented order on purpose
        for record in drive.images:
            target = folder / "photos" / record.camera / Path(record.file).name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(drive.root / record.file, target)
            writer.writerow([record.camera, repr(record.gps_time), target.relative_to(folder)])
    write_calibration_yaml(folder / "calibration.yaml", drive)
    (folder / "scanner.json").write_text(json.dumps(drive.scanner.to_json()))
    return Delivery(
        folder,
        folder / "cloud.las",
        folder / "trajectory.csv",
        folder / "images.csv",
        folder / "calibration.yaml",
        folder / "scanner.json",
        keep,
    )


@pytest.fixture(scope="module")
def delivery(drive: Drive, tmp_path_factory: pytest.TempPathFactory) -> Delivery:
    """Every point of the test drive."""
    folder = tmp_path_factory.mktemp("deliveries") / "full"
    return export_delivery(drive, folder, np.arange(len(drive.points)))


@pytest.fixture(scope="module")
def small(drive: Drive, tmp_path_factory: pytest.TempPathFactory) -> Delivery:
    """Every 50th point of the test drive: quick imports for the error cases."""
    folder = tmp_path_factory.mktemp("deliveries") / "small"
    return export_delivery(drive, folder, np.arange(0, len(drive.points), 50))


def run_import(
    d: Delivery,
    out: Path,
    *,
    points: Path | list[Path] | None = None,
    trajectory: Path | None = None,
    **kwargs,
) -> LasImport:
    """Import ``d`` into ``out``; keyword arguments replace its parts."""
    args = {"images_csv": d.images, "calibration": d.calibration, "scanner": d.scanner, **kwargs}
    return import_las_delivery(points or d.points, trajectory or d.trajectory, out, **args)


def assert_nothing_left(out: Path) -> None:
    assert not out.exists()
    assert not [p for p in out.parent.iterdir() if p.name.startswith(f".{out.name}.partial")]


# ------------------------------------------------------------------------------- round trip


def test_import_reproduces_the_drive(drive: Drive, delivery: Delivery, tmp_path: Path) -> None:
    out = tmp_path / "imported"
    result = import_las_delivery(
        delivery.points,
        delivery.trajectory,
        out,
        images_csv=delivery.images,
        calibration=delivery.calibration,
        scanner=delivery.scanner,
    )
    imported = load_drive(out)
    assert result.n_points == len(imported.points) == len(drive.points)
    assert imported.crs == "EPSG:6677" and result.crs_from == "LAS file"
    assert np.all(imported.origin[:2] % 100 == 0) and result.notes == []
    assert np.all(np.abs(imported.origin - drive.points.xyz.mean(axis=0) - drive.origin) < 1e3)

    # Points: map coordinates within 0.1 mm, same times, intensities and scan lattice.
    ours, theirs = imported.points, drive.points
    np.testing.assert_array_equal(ours.gps_time, theirs.gps_time)
    assert np.abs((ours.xyz + imported.origin) - (theirs.xyz + drive.origin)).max() <= 1e-4
    np.testing.assert_array_equal(ours.intensity, theirs.intensity)
    np.testing.assert_array_equal(ours.rotation, theirs.rotation)
    np.testing.assert_array_equal(ours.phase, theirs.phase)
    assert imported.scanner.to_json() == drive.scanner.to_json()

    # Trajectory and cameras.
    traj = imported.trajectory
    np.testing.assert_array_equal(traj.time, drive.trajectory.time)
    world = traj.position + imported.origin
    assert np.abs(world - (drive.trajectory.position + drive.origin)).max() <= 1e-4
    assert traj.reference_height_m == drive.trajectory.reference_height_m == 1.8
    assert sorted(imported.cameras) == sorted(drive.cameras)
    for name, camera in imported.cameras.items():
        np.testing.assert_array_equal(camera.K, drive.cameras[name].K)
        np.testing.assert_array_equal(camera.dist, drive.cameras[name].dist)
        np.testing.assert_array_equal(camera.T_vehicle_camera, drive.cameras[name].T_vehicle_camera)
        assert (camera.width, camera.height) == (
            drive.cameras[name].width,
            drive.cameras[name].height,
        )

    # Images: same files, and the poses the trajectory gives at their times.
    key = lambda r: (r.gps_time, r.camera)  # noqa: E731
    assert len(imported.images) == len(drive.images) == result.n_images
    for ours_image, theirs_image in zip(
        sorted(imported.images, key=key), sorted(drive.images, key=key), strict=True
    ):
        assert (ours_image.camera, ours_image.gps_time) == (
            theirs_image.camera,
            theirs_image.gps_time,
        )
        assert filecmp.cmp(out / ours_image.file, drive.root / theirs_image.file, shallow=False)
        pose = ours_image.T_world_camera.copy()
        pose[:3, 3] += imported.origin
        expected = (
            drive.trajectory.T_world_vehicle(theirs_image.gps_time)
            @ drive.cameras[theirs_image.camera].T_vehicle_camera
        )
        expected[:3, 3] += drive.origin
        np.testing.assert_allclose(pose, expected, rtol=0, atol=1e-6)
        # The stored pose came from the simulator's trajectory before trajectory.csv rounded it
        # to 0.1 mm: within that rounding.
        stored = theirs_image.T_world_camera.copy()
        stored[:3, 3] += drive.origin
        np.testing.assert_allclose(pose, stored, rtol=0, atol=1e-4)


def test_cli_imports_a_laz_with_wkt_reordered_trajectory_in_degrees(
    drive: Drive, small: Delivery, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    laz = tmp_path / "cloud.laz"
    write_las(laz, drive, small.keep, point_format=6, version="1.4", crs="wkt")
    trajectory = tmp_path / "trajectory_deg.csv"
    order = ["yaw", "x", "time", "pitch", "y", "roll", "z"]
    table = np.column_stack(
        [
            drive.trajectory.time,
            drive.trajectory.position + drive.origin,
            np.rad2deg(drive.trajectory.attitude),
        ]
    )
    columns = [table[:, TRAJECTORY_COLUMNS.index(name)] for name in order]
    np.savetxt(
        trajectory,
        np.column_stack(columns),
        delimiter=";",
        header=" ; ".join(order).upper(),
        comments="",
        fmt="%.10f",
    )
    scanner = drive.scanner
    mount = ",".join(f"{v:.17g}" for v in scanner.T_vehicle_scanner.ravel())
    out = tmp_path / "drive"
    code = main(
        [
            "import", "las", str(laz),
            "--trajectory", str(trajectory), "--trajectory-degrees",
            "--images", str(small.images),
            "--calibration", str(drive.root / "cameras.json"),
            "--rotations-per-second", str(scanner.rotation_rate_hz),
            "--measurements-per-second", str(scanner.measurement_rate_hz),
            f"--scanner-mount={mount}",
            "--reference-height", "1.7",
            "--out", str(out), "--quiet",
        ]
    )  # fmt: skip
    assert code == 0
    printed = capsys.readouterr().out
    assert "EPSG:6677, from the LAS file" in printed and f"t0 {scanner.t0_s:.6f}" in printed
    imported = load_drive(out)
    assert imported.crs == "EPSG:6677"
    assert imported.trajectory.reference_height_m == 1.7
    np.testing.assert_allclose(imported.trajectory.attitude, drive.trajectory.attitude, atol=1e-9)
    # t0 defaulted to the first point's whole second, the simulator's epoch.
    np.testing.assert_array_equal(imported.points.rotation, drive.points.rotation[small.keep])
    np.testing.assert_array_equal(imported.points.phase, drive.points.phase[small.keep])
    assert len(imported.images) == len(drive.images)
    assert main(["info", str(out)]) == 0


def test_cli_returns_2_on_a_bad_input(
    small: Delivery, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "drive"
    code = main(
        [
            "import", "las", str(small.points), "--trajectory", str(tmp_path / "missing.csv"),
            "--scanner", str(small.scanner), "--out", str(out),
        ]
    )  # fmt: skip
    assert code == 2
    assert "MissingSourceFileError" in capsys.readouterr().err
    assert_nothing_left(out)


def test_points_in_adjusted_standard_gps_time_are_converted(
    drive: Drive, small: Delivery, tmp_path: Path
) -> None:
    las = tmp_path / "standard.las"
    adjusted = drive.points.gps_time[small.keep] + ADJUSTED_WEEK_START
    write_las(las, drive, small.keep, point_format=6, version="1.4", crs="none", gps_time=adjusted)
    data = laspy.read(str(las))
    data.header.global_encoding.gps_time_type = laspy.header.GpsTimeType.STANDARD
    data.write(str(las))
    result = run_import(small, tmp_path / "drive", points=las, crs="EPSG:6677")
    assert any("adjusted standard GPS time" in note for note in result.notes)
    imported = load_drive(tmp_path / "drive")
    np.testing.assert_allclose(
        imported.points.gps_time, drive.points.gps_time[small.keep], rtol=0, atol=1e-7
    )
    np.testing.assert_array_equal(imported.points.phase, drive.points.phase[small.keep])


# ------------------------------------------------------------------------------ named errors


def test_a_las_without_gps_time(drive: Drive, small: Delivery, tmp_path: Path) -> None:
    las = tmp_path / "format0.las"
    write_las(las, drive, small.keep, point_format=0)
    out = tmp_path / "drive"
    with pytest.raises(MissingGpsTimeError, match="point format 0 has no gps_time"):
        run_import(small, out, points=las)
    assert_nothing_left(out)


def test_a_trajectory_cut_short(small: Delivery, tmp_path: Path) -> None:
    lines = small.trajectory.read_text().splitlines()
    short = tmp_path / "short.csv"
    short.write_text("\n".join(lines[: len(lines) // 2]) + "\n")
    out = tmp_path / "drive"
    with pytest.raises(TrajectoryCoverageError, match=r"span GPS time .* covers only") as error:
        run_import(small, out, images_csv=None, calibration=None, trajectory=short)
    assert "points" in str(error.value)
    assert_nothing_left(out)
    with pytest.raises(TrajectoryCoverageError, match="images span"):
        run_import(small, out, trajectory=short)
    assert_nothing_left(out)


def test_images_without_calibration(small: Delivery, drive: Drive, tmp_path: Path) -> None:
    out = tmp_path / "drive"
    with pytest.raises(MissingCalibrationError, match="no camera calibration"):
        run_import(small, out, calibration=None)
    front_only = tmp_path / "front.yaml"
    write_calibration_yaml(front_only, drive, ["front"])
    with pytest.raises(MissingCalibrationError, match="camera 'left' has no calibration"):
        run_import(small, out, calibration=front_only)
    assert_nothing_left(out)


def test_missing_files(small: Delivery, tmp_path: Path) -> None:
    out = tmp_path / "drive"
    with pytest.raises(MissingSourceFileError, match="nowhere.laz: point cloud"):
        run_import(small, out, points=tmp_path / "nowhere.laz")
    with pytest.raises(MissingSourceFileError, match="calibration"):
        run_import(small, out, calibration=tmp_path / "nowhere.yaml")
    listing = tmp_path / "images.csv"
    listing.write_text(small.images.read_text().replace("photos/", str(small.folder / "gone/"), 1))
    with pytest.raises(MissingSourceFileError, match="image file is missing"):
        run_import(small, out, images_csv=listing)
    assert_nothing_left(out)


def test_malformed_sources(small: Delivery, tmp_path: Path) -> None:
    out = tmp_path / "drive"
    no_yaw = tmp_path / "no_yaw.csv"
    no_yaw.write_text("time,x,y,z,roll,pitch\n1,2,3,4,5,6\n")
    with pytest.raises(SourceFormatError, match=r"lacks the columns \['yaw'\]"):
        run_import(small, out, trajectory=no_yaw)
    bad_number = tmp_path / "bad_number.csv"
    lines = small.trajectory.read_text().splitlines()
    bad_number.write_text("\n".join([lines[0], lines[1], lines[2].replace(",", ",x", 1)]))
    with pytest.raises(SourceFormatError, match="line 3: not a number"):
        run_import(small, out, trajectory=bad_number)
    broken = tmp_path / "broken.yaml"
    broken.write_text("%YAML:1.0\nfront: {camera_matrix: [1, 2\n")
    with pytest.raises(SourceFormatError, match="not valid JSON/YAML"):
        run_import(small, out, calibration=broken)
    not_las = tmp_path / "not.las"
    not_las.write_text("hello")
    with pytest.raises(SourceFormatError, match="not a readable LAS/LAZ"):
        run_import(small, out, points=not_las)
    assert_nothing_left(out)


def test_degrees_without_the_flag(drive: Drive, small: Delivery, tmp_path: Path) -> None:
    table = np.column_stack(
        [
            drive.trajectory.time,
            drive.trajectory.position + drive.origin,
            np.rad2deg(drive.trajectory.attitude) + [0.0, 95.0, 0.0],
        ]
    )
    path = tmp_path / "degrees.csv"
    np.savetxt(path, table, delimiter=",", header=",".join(TRAJECTORY_COLUMNS), comments="")
    with pytest.raises(SourceFormatError, match="--trajectory-degrees"):
        run_import(small, tmp_path / "drive", trajectory=path)


def test_scanner_rates_are_required(small: Delivery, tmp_path: Path) -> None:
    with pytest.raises(InvalidOptionError, match="rotation_rate_hz"):
        run_import(small, tmp_path / "drive", scanner={"measurements_per_second": 3e5})
    with pytest.raises(InvalidOptionError, match="epoch must lie at or before the first point"):
        run_import(
            small,
            tmp_path / "drive",
            scanner={"rotations_per_second": 100, "measurements_per_second": 3e5, "t0": 4e5},
        )


def test_an_image_of_the_wrong_size(small: Delivery, drive: Drive, tmp_path: Path) -> None:
    calibration = tmp_path / "cameras.json"
    cameras = json.loads((drive.root / "cameras.json").read_text())
    cameras[0]["width"] = 640
    calibration.write_text(json.dumps(cameras))
    with pytest.raises(SourceFormatError, match="is calibrated for 640 x"):
        run_import(small, tmp_path / "drive", calibration=calibration)


def test_an_existing_output_is_kept_without_overwrite(small: Delivery, tmp_path: Path) -> None:
    out = tmp_path / "drive"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(OutputExistsError, match="--overwrite"):
        run_import(small, out)
    assert (out / "keep.txt").read_text() == "mine"
    with pytest.raises(MissingSourceFileError):  # a failed import keeps the old output too
        run_import(small, out, overwrite=True, trajectory=tmp_path / "missing.csv")
    assert (out / "keep.txt").read_text() == "mine"
    run_import(small, out, overwrite=True, images_csv=None, calibration=None)
    assert not (out / "keep.txt").exists() and load_drive(out).images == []


def test_an_output_holding_an_input_is_refused_and_every_input_survives(
    small: Delivery, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    copy = out / "delivery"
    shutil.copytree(small.folder, copy)
    moved = Delivery(
        copy,
        *(copy / p.relative_to(small.folder) for p in astuple(small)[1:6]),
        small.keep,
    )
    before = file_tree(out)
    with pytest.raises(InputInsideOutputError, match="holds the input"):
        run_import(moved, out, overwrite=True)
    with pytest.raises(InputInsideOutputError, match="holds the input"):
        run_import(moved, copy, overwrite=True)
    with pytest.raises(InputInsideOutputError, match="is the input"):
        run_import(moved, moved.calibration, overwrite=True)
    # Only the listed images lie in photos/: refused once the list is read, before any writing.
    with pytest.raises(InputInsideOutputError, match="holds the input .*photos"):
        run_import(moved, copy / "photos", overwrite=True)
    assert file_tree(out) == before
    args = ["import", "las", str(moved.points), "--trajectory", str(moved.trajectory)]
    assert main([*args, "--scanner", str(moved.scanner), "--out", str(out), "--overwrite"]) == 2
    assert file_tree(out) == before


# ------------------------------------------------------------------------------- calibration


def test_calibration_layouts(tmp_path: Path) -> None:
    ros = tmp_path / "left_cam.yaml"
    ros.write_text(
        "image_width: 640\nimage_height: 480\ndistortion_model: plumb_bob\n"
        "camera_matrix: {rows: 3, cols: 3, data: [500, 0, 320, 0, 500, 240, 0, 0, 1]}\n"
        "distortion_coefficients: {rows: 1, cols: 5, data: [0.1, -0.01, 0, 0, 0]}\n"
        "T_vehicle_camera: [[0, 0, 1, 1.5], [-1, 0, 0, 0], [0, -1, 0, 1.2], [0, 0, 0, 1]]\n"
    )
    (camera,) = read_calibration(ros)
    assert camera.name == "left_cam" and (camera.width, camera.height) == (640, 480)
    np.testing.assert_array_equal(camera.dist, [0.1, -0.01, 0, 0, 0])

    four = ros.read_text().replace(
        "cols: 5, data: [0.1, -0.01, 0, 0, 0]", "cols: 4, data: [0.1, -0.01, 0, 0]"
    )
    (tmp_path / "four.yaml").write_text("camera_name: side\n" + four)
    (camera,) = read_calibration(tmp_path / "four.yaml")
    assert camera.name == "side" and camera.dist[4] == 0

    for old, new in (
        ("cols: 5, data: [0.1, -0.01, 0, 0, 0]", "cols: 8, data: [0.1, 0, 0, 0, 0, 0.2, 0, 0]"),
        ("plumb_bob", "equidistant"),
        ("[0, 0, 0, 1]]", "[0, 0, 1, 1]]"),
    ):
        (tmp_path / "bad.yaml").write_text(ros.read_text().replace(old, new))
        with pytest.raises(SourceFormatError):
            read_calibration(tmp_path / "bad.yaml")


# ------------------------------------------------------------------- streaming several files


def test_several_files_out_of_order_stream_into_contiguous_tiles(
    drive: Drive, delivery: Delivery, tmp_path: Path
) -> None:
    """Four files given out of order, one LAZ, two of them interleaved in time (as spatial tiles
    or two scanners overlap), read in chunks that do not divide them: the drive holds exactly the
    delivery's points in time order, in tiles that follow each other."""
    n = len(drive.points)
    a, b = int(0.3 * n), int(0.7 * n)
    middle = np.arange(a, b)
    parts = {
        "late.laz": np.arange(b, n),
        "middle_even.las": middle[::2],
        "early.las": np.arange(a),
        "middle_odd.las": middle[1::2],
    }
    for name, keep in parts.items():
        write_las(tmp_path / name, drive, keep, point_format=6, version="1.4")
    out = tmp_path / "drive"
    result = run_import(
        delivery,
        out,
        points=[tmp_path / name for name in parts],
        tile_m=10.0,
        chunk_points=7_001,
    )
    assert result.n_points == n and result.crs == "EPSG:6677"
    imported = load_drive(out)
    ours, theirs = imported.points, drive.points
    np.testing.assert_array_equal(ours.gps_time, theirs.gps_time)
    assert np.abs((ours.xyz + imported.origin) - (theirs.xyz + drive.origin)).max() <= 1e-4
    np.testing.assert_array_equal(ours.intensity, theirs.intensity)
    np.testing.assert_array_equal(ours.rotation, theirs.rotation)
    np.testing.assert_array_equal(ours.phase, theirs.phase)

    # Tiles: each the next run of the drive's points, 10 m of driving apart, read on their own.
    source = open_drive(out)
    tiles = source.tiles.tiles
    assert len(tiles) == result.n_tiles >= 3
    offsets = source.tiles.offsets()
    assert offsets[-1] == n
    for k, tile in enumerate(tiles):
        points, _ = source.read_tiles([k])
        times = theirs.gps_time[offsets[k] : offsets[k + 1]]
        np.testing.assert_array_equal(points.gps_time, times)
        assert tile.gps_time == (times[0], times[-1])
        # The vehicle drove its k-th 10 m while the tile's points were scanned.
        driven = vehicle_station(source.trajectory, np.array(tile.gps_time))
        assert k * 10.0 - 1e-6 <= driven[0] <= driven[1] <= (k + 1) * 10.0 + 1e-6
        if k:
            assert tile.gps_time[0] > tiles[k - 1].gps_time[1]


def test_a_file_out_of_time_order_is_refused(drive: Drive, small: Delivery, tmp_path: Path) -> None:
    out = tmp_path / "drive"
    backwards = tmp_path / "backwards.las"
    write_las(backwards, drive, small.keep[::-1])
    with pytest.raises(PointsOutOfTimeOrderError, match="backwards.las: its last point"):
        run_import(small, out, points=backwards)
    assert_nothing_left(out)
    # Two points swapped across a chunk boundary: found while streaming, nothing left behind.
    swapped = small.keep.copy()
    swapped[[100, 101]] = swapped[[101, 100]]
    write_las(tmp_path / "swapped.las", drive, swapped)
    with pytest.raises(PointsOutOfTimeOrderError, match=r"swapped.las: point 101 \(GPS time"):
        run_import(small, out, points=tmp_path / "swapped.las", chunk_points=101)
    assert_nothing_left(out)


def test_bad_tile_and_chunk_sizes(small: Delivery, tmp_path: Path) -> None:
    with pytest.raises(InvalidOptionError, match="longer than 0 m"):
        run_import(small, tmp_path / "drive", tile_m=0.0)
    with pytest.raises(InvalidOptionError, match="at least 1 point"):
        run_import(small, tmp_path / "drive", chunk_points=0)
    assert_nothing_left(tmp_path / "drive")


#: A long synthetic delivery: a straight road driven at SPEED_M_S, a profile scanner of
#: ROTATIONS_HZ x MEASUREMENTS_HZ sweeping a 10 m circle around the vehicle.
SPEED_M_S, ROTATIONS_HZ, MEASUREMENTS_HZ = 10.0, 100.0, 80_000.0
LONG_T0_S, LONG_ORIGIN = 346_000.0, np.array([-7_400.0, -34_680.0, 40.0])


def write_long_delivery(folder: Path, n_points: int, n_files: int) -> tuple[list[Path], Path]:
    """``n_points`` points in ``n_files`` LAS files of consecutive time ranges (returned out of
    order), and the trajectory CSV; written file by file so the test holds one file's points."""
    folder.mkdir(parents=True)
    # Half a pulse before the first point, so the vehicle passes every tile's end between two
    # pulses; a quarter pulse after the last, so no empty tile follows.
    pulse = 1 / MEASUREMENTS_HZ
    time = np.linspace(LONG_T0_S - pulse / 2, LONG_T0_S + (n_points - 0.75) * pulse, 100)
    table = np.zeros((len(time), 7))
    table[:, 0] = time
    table[:, 1:4] = LONG_ORIGIN + np.outer(time - time[0], [SPEED_M_S, 0.0, 0.0])
    trajectory = folder / "trajectory.csv"
    np.savetxt(trajectory, table, delimiter=",", header=",".join(TRAJECTORY_COLUMNS), comments="")
    paths = []
    bounds = np.linspace(0, n_points, n_files + 1).astype(int)
    for i, (lo, hi) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
        k = np.arange(lo, hi)
        t = LONG_T0_S + k / MEASUREMENTS_HZ
        angle = (
            2 * np.pi * (k % (MEASUREMENTS_HZ / ROTATIONS_HZ)) / (MEASUREMENTS_HZ / ROTATIONS_HZ)
        )
        header = laspy.LasHeader(point_format=6, version="1.4")
        header.offsets, header.scales = LONG_ORIGIN, np.array([1e-3] * 3)
        las = laspy.LasData(header)
        las.x = LONG_ORIGIN[0] + SPEED_M_S * (t - LONG_T0_S)
        las.y = LONG_ORIGIN[1] + 10 * np.cos(angle)
        las.z = LONG_ORIGIN[2] + 10 * np.sin(angle)
        las.gps_time = t
        las.intensity = (k % 4096).astype(np.uint16)
        paths.append(folder / f"part_{i}.las")
        las.write(str(paths[-1]))
    return paths[1::2] + paths[0::2], trajectory


def test_a_long_delivery_imports_in_bounded_memory(tmp_path: Path) -> None:
    """2.4 M points in 4 files, 120 MB as a drive's point arrays (50 bytes a point), imported in
    chunks of 10 000 points into 5 m tiles of 40 000 points.

    What is in memory at once: the tile being filled, which the writer concatenates, encodes and
    gives track coordinates when the vehicle passes its end (under 300 bytes a tile point), and
    one chunk of each file open at once (here one: the files follow each other), read, merged and
    turned into the lattice (under 300 bytes a chunk point). Neither grows with the delivery, so
    the traced peak stays under 300 B x 40 000 + 300 B x 10 000 + 8 MB (Python's own) = 23 MB,
    a fifth of the delivery (the importer that read it whole grew by 500 MB resident memory).
    """
    n_points, chunk_points, tile_m = 2_400_000, 10_000, 5.0
    paths, trajectory = write_long_delivery(tmp_path / "delivery", n_points, n_files=4)
    scanner = {
        "rotation_rate_hz": ROTATIONS_HZ,
        "measurement_rate_hz": MEASUREMENTS_HZ,
        "t0_s": LONG_T0_S,
    }
    gc.collect()
    tracemalloc.start()
    try:
        result = import_las_delivery(
            paths,
            trajectory,
            tmp_path / "drive",
            scanner=scanner,
            crs="EPSG:6677",
            tile_m=tile_m,
            chunk_points=chunk_points,
            compress=False,
        )
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    tile_points = int(tile_m / SPEED_M_S * MEASUREMENTS_HZ)
    assert peak < 300 * tile_points + 300 * chunk_points + 8e6 < 50 * n_points / 5
    assert result.n_points == n_points and result.n_tiles == 60
    source = open_drive(tmp_path / "drive")
    assert [t.points for t in source.tiles.tiles] == [tile_points] * 60
    points, _ = source.read_tiles([37])
    k = 37 * tile_points + np.arange(tile_points)
    np.testing.assert_allclose(points.gps_time, LONG_T0_S + k / MEASUREMENTS_HZ, rtol=0, atol=1e-7)
    np.testing.assert_array_equal(points.phase, k % (MEASUREMENTS_HZ / ROTATIONS_HZ))


@pytest.mark.parametrize(("offset", "value"), [(131, float("nan")), (155, float("inf"))])
def test_a_header_whose_scale_or_offset_is_not_a_number_is_refused_before_any_writing(
    small: Delivery, tmp_path: Path, offset: int, value: float
) -> None:
    """LAS 1.2 header: the x scale factor at byte 131, the x offset at byte 155 (every coordinate
    is integer * scale + offset, so none would be a number)."""
    raw = bytearray(small.points.read_bytes())
    raw[offset : offset + 8] = np.float64(value).tobytes()
    broken = tmp_path / "broken.las"
    broken.write_bytes(bytes(raw))
    out = tmp_path / "drive"
    with pytest.raises(SourceFormatError, match="scales .* and offsets .* must be finite"):
        run_import(small, out, points=broken)
    assert_nothing_left(out)


def test_a_truncated_laz_is_a_named_error(small: Delivery, tmp_path: Path) -> None:
    compressed = tmp_path / "cloud.laz"
    laspy.read(str(small.points)).write(str(compressed))
    data = compressed.read_bytes()
    compressed.write_bytes(data[: len(data) // 2])
    out = tmp_path / "drive"
    with pytest.raises(SourceFormatError, match="not a readable LAS/LAZ file"):
        run_import(small, out, points=compressed)
    assert_nothing_left(out)


@pytest.mark.parametrize(
    ("case", "error"),
    [
        (
            "rotations 0",
            "SourceFormatError: scanner: ScannerParams.rotation_rate_hz must lie within",
        ),
        ("measurements nan", "ScannerParams.measurement_rate_hz must be a finite number"),
        ("out is a file", "OutputKindError"),
        ("out is a link", "OutputSymlinkError"),
        ("out is a link loop", "OutputSymlinkError"),
    ],
)
def test_a_bad_option_or_output_is_named_before_any_point_is_read(
    small: Delivery,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    case: str,
    error: str,
) -> None:
    """These once failed with a traceback, some after the whole import had run."""
    import guardrail_core.importers.las_delivery as las_delivery

    def no_reading(*args: object, **kwargs: object) -> None:
        raise AssertionError("the points were read before the error")

    monkeypatch.setattr(las_delivery, "_stream_points", no_reading)
    out = tmp_path / "out"
    rates = ["--rotations-per-second", "100", "--measurements-per-second", "3e5"]
    if case == "rotations 0":
        rates[1] = "0"
    elif case == "measurements nan":
        rates[3] = "nan"
    elif case == "out is a file":
        out.write_text("kept")
    elif case == "out is a link":
        (tmp_path / "real").mkdir()
        out.symlink_to(tmp_path / "real")
    else:
        out.symlink_to(tmp_path / "loop")
        (tmp_path / "loop").symlink_to(out)
    before = {p.name: p.is_symlink() for p in tmp_path.iterdir()}
    for overwrite in ([], ["--overwrite"]):
        capsys.readouterr()
        argv = [str(small.points), "--trajectory", str(small.trajectory), "--out", str(out)]
        assert main(["import", "las", *argv, *rates, *overwrite]) == 2
        err = capsys.readouterr().err
        assert error in err and "Traceback" not in err
        assert {p.name: p.is_symlink() for p in tmp_path.iterdir()} == before
    if case == "out is a file":
        assert out.read_text() == "kept"
