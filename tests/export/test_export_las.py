"""``guardrail export RUN_DIR --las OUT``: the drive's points with the run's result as LAS 1.4."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import laspy
import numpy as np
import pytest

from guardrail_core.cli import main
from guardrail_core.errors import (
    DriveDimensionError,
    DriveFormatError,
    ExportError,
    InputInsideOutputError,
    MissingDriveFileError,
    OutputExistsError,
    OutputKindError,
    RunFolderError,
)
from guardrail_core.export.las import (
    CLASS_GUARDRAIL,
    CLASS_GUARDRAIL_POLE,
    CLASS_ROAD_SURFACE,
    NO_PROBABILITY,
    POLE_TOLERANCE_M,
    ExportSummary,
    export_run_las,
    pole_points,
)
from guardrail_core.formats.drive import Drive
from guardrail_core.formats.drive_tiles import TileIndex, TileRecord, read_tile_index
from guardrail_core.formats.reconstruction_folder import RECONSTRUCTION_DIR
from guardrail_core.formats.run_folder import load_run
from guardrail_core.reconstruct.model import Pole
from guardrail_core.reconstruct.run_models import load_run_models
from tests.drive_files import drive_las, tile_file, write_drive_copy
from tests.file_tree import file_tree


@pytest.fixture(scope="module")
def exported(
    run_path: Path, drive_path: Path, tmp_path_factory: pytest.TempPathFactory
) -> tuple[ExportSummary, laspy.LasData]:
    out = tmp_path_factory.mktemp("export") / "result.laz"
    summary = export_run_las(run_path, out, drive_dir=drive_path)
    return summary, laspy.read(str(out))


def _drive_copy(
    drive_path: Path, folder: Path, *, crs: str | None = None, las: laspy.LasData | None = None
) -> Path:
    """drive.json and the point tiles of the test drive (all the export reads), with changes;
    with ``las``, a drive whose one tile is that point file."""
    folder.mkdir()
    meta = json.loads((drive_path / "drive.json").read_text())
    if crs is not None:
        meta["crs"] = crs
    if las is None:
        shutil.copytree(drive_path / "points", folder / "points")
    else:
        (folder / "points").mkdir()
        las.write(str(folder / "points" / "000000.las"))  # uncompressed: quicker to write
        xyz = np.column_stack([las.x, las.y, las.z])
        lo, hi = xyz.min(axis=0), xyz.max(axis=0)
        tile = TileRecord(
            file="points/000000.las",
            truth=None,
            gps_time=(float(np.min(las.gps_time)), float(np.max(las.gps_time))),
            station_m=(0.0, 0.0),  # the export does not read it
            bounds_min=(float(lo[0]), float(lo[1]), float(lo[2])),
            bounds_max=(float(hi[0]), float(hi[1]), float(hi[2])),
            points=len(las.points),
        )
        (folder / meta["files"]["points"]).write_text(json.dumps(TileIndex((tile,)).to_json()))
    (folder / "drive.json").write_text(json.dumps(meta))
    return folder


def _guardrail(run_path: Path) -> np.ndarray:
    run = load_run(run_path)
    segment = run.point_segment
    out = np.zeros(len(segment), bool)
    out[segment >= 0] = run.segments["label"][segment[segment >= 0]]
    return out


# ------------------------------------------------------------------------- the exported file


def test_every_point_of_the_drive_in_map_coordinates(
    exported: tuple[ExportSummary, laspy.LasData], drive: Drive, drive_path: Path
) -> None:
    summary, las = exported
    assert summary.points == len(las.points) == len(drive.points)
    assert las.header.version == laspy.header.Version(1, 4)
    assert las.header.point_format.id == summary.point_format == 6
    np.testing.assert_array_equal(las.header.offsets, drive.origin)
    np.testing.assert_allclose(las.header.scales, 1e-4)
    local = np.column_stack([las.x, las.y, las.z]) - drive.origin
    assert np.abs(local - drive.points.xyz).max() <= 1e-4
    source = drive_las(drive_path)
    np.testing.assert_array_equal(las.X, source.X)  # the very integers of the drive's file
    np.testing.assert_array_equal(las.gps_time, drive.points.gps_time)
    np.testing.assert_array_equal(las.intensity, drive.points.intensity)
    np.testing.assert_array_equal(las.return_number, source.return_number)
    np.testing.assert_array_equal(las.number_of_returns, source.number_of_returns)
    np.testing.assert_array_equal(las.rotation, drive.points.rotation)
    np.testing.assert_array_equal(las.phase, drive.points.phase)


def test_guardrail_pole_and_road_classes(
    exported: tuple[ExportSummary, laspy.LasData], run_path: Path, drive_path: Path
) -> None:
    summary, las = exported
    run = load_run(run_path)
    classification = np.asarray(las.classification)
    guardrail = _guardrail(run_path)
    label = run.segments["label"]
    n_guardrail = int(run.segments["n_points"][label].sum())
    assert n_guardrail > 0
    is_guardrail = np.isin(classification, [CLASS_GUARDRAIL, CLASS_GUARDRAIL_POLE])
    assert int(is_guardrail.sum()) == n_guardrail == summary.guardrail_points
    np.testing.assert_array_equal(is_guardrail, guardrail)
    poles = classification == CLASS_GUARDRAIL_POLE
    assert int(poles.sum()) == summary.pole_points > 0
    assert summary.pole_points < summary.guardrail_points

    original = np.asarray(drive_las(drive_path).classification)
    road = (run.point_segment == -1) & np.isin(original, [0, 1])
    assert road.any()
    assert np.all(classification[road] == CLASS_ROAD_SURFACE)
    assert int(road.sum()) == summary.road_points
    rest = ~guardrail & ~road
    np.testing.assert_array_equal(classification[rest], original[rest])


def test_every_pole_point_lies_on_a_reconstructed_pole(
    exported: tuple[ExportSummary, laspy.LasData], run_path: Path, drive: Drive
) -> None:
    _, las = exported
    runs = load_run_models(run_path).runs
    poles = [p for r in runs for p in r.poles]
    assert poles
    local = np.column_stack([las.x, las.y, las.z]) - drive.origin
    position = np.array([p.position for p in poles])  # (P, 3)
    radius = np.array([p.radius for p in poles])
    height = np.array([p.height for p in poles])
    # Brute force, every point against every pole: (M, P).
    guardrail = _guardrail(run_path)
    xyz = local[guardrail]
    horizontal = np.linalg.norm(xyz[:, None, :2] - position[None, :, :2], axis=2)
    dz = xyz[:, None, 2] - position[None, :, 2]
    on = (
        (horizontal <= radius + POLE_TOLERANCE_M)
        & (dz >= -POLE_TOLERANCE_M)
        & (dz <= height + POLE_TOLERANCE_M)
    )
    np.testing.assert_array_equal(
        np.asarray(las.classification)[guardrail] == CLASS_GUARDRAIL_POLE, on.any(axis=1)
    )


def test_segment_probability_and_run_dimensions(
    exported: tuple[ExportSummary, laspy.LasData], run_path: Path
) -> None:
    summary, las = exported
    run = load_run(run_path)
    segment = run.point_segment
    names = list(las.point_format.extra_dimension_names)
    assert {"segment_id", "guardrail_probability", "run_id"} <= set(names)
    assert las.segment_id.dtype == np.int32 and las.run_id.dtype == np.int32
    assert las.guardrail_probability.dtype == np.float32
    np.testing.assert_array_equal(las.segment_id, segment)

    probability = np.asarray(las.guardrail_probability)
    assert not np.isnan(probability).any()
    inside = segment >= 0
    expected = run.segments["probability"][segment[inside]]
    expected = np.where(np.isnan(expected), NO_PROBABILITY, expected)
    np.testing.assert_array_equal(probability[inside], expected.astype(np.float32))
    assert np.all(probability[~inside] == NO_PROBABILITY)

    runs = load_run_models(run_path).runs
    run_id = np.asarray(las.run_id)
    guardrail = _guardrail(run_path)
    assert np.all(run_id[~guardrail] == -1)
    for model in runs:
        assert int((run_id == model.run_id).sum()) == model.n_points
    assert summary.run_points == sum(m.n_points for m in runs)
    assert not summary.warnings


def test_the_crs_round_trips(exported: tuple[ExportSummary, laspy.LasData], drive: Drive) -> None:
    summary, las = exported
    assert drive.crs == summary.crs == "EPSG:6677"
    assert las.header.global_encoding.wkt
    crs = las.header.parse_crs()
    assert crs is not None and crs.to_epsg() == 6677
    with laspy.open(str(summary.out)) as reader:
        assert reader.header.are_points_compressed  # .laz


def test_pole_points_lie_within_the_tolerance() -> None:
    pole = Pole(np.array([1.0, 2.0, 0.5]), 0.05, 1.0, 10)
    r = 0.05 + POLE_TOLERANCE_M
    xyz = np.array(
        [
            [1.0 + r - 0.001, 2.0, 1.0],  # at the edge, inside
            [1.0 + r + 0.001, 2.0, 1.0],  # just outside
            [1.0, 2.0, 0.5 - POLE_TOLERANCE_M + 0.001],  # at the foot
            [1.0, 2.0, 0.5 - POLE_TOLERANCE_M - 0.001],  # below it
            [1.0, 2.0, 1.5 + POLE_TOLERANCE_M - 0.001],  # at the top
            [1.0, 2.0, 1.5 + POLE_TOLERANCE_M + 0.001],  # above it
        ]
    )
    np.testing.assert_array_equal(pole_points(xyz, [pole]), [True, False, True, False, True, False])
    assert not pole_points(xyz, []).any()


# ---------------------------------------------------------------------------------- variants


def test_a_crs_pyproj_cannot_read_writes_no_crs_and_warns(
    run_path: Path, drive_path: Path, tmp_path: Path
) -> None:
    drive = _drive_copy(drive_path, tmp_path / "drive", crs="local")
    out = tmp_path / "out" / "result.las"  # the folder is made
    summary = export_run_las(run_path, out, drive_dir=drive)
    assert summary.crs is None
    assert any("'local'" in w and "no CRS" in w for w in summary.warnings)
    with laspy.open(str(out)) as reader:
        assert not reader.header.are_points_compressed  # .las
        assert reader.header.parse_crs() is None
        assert not reader.header.global_encoding.wkt
        assert reader.header.point_count == summary.points


@pytest.fixture(scope="module")
def tiled_drive(drive: Drive, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The test drive written anew in 5 m tiles."""
    return write_drive_copy(drive, tmp_path_factory.mktemp("tiled") / "drive", tile_m=5.0)


def test_a_drive_of_many_tiles_exports_the_very_same_points(
    exported: tuple[ExportSummary, laspy.LasData],
    run_path: Path,
    tiled_drive: Path,
    tmp_path: Path,
) -> None:
    summary, las = exported
    assert len(read_tile_index(tiled_drive)) >= 5
    again = export_run_las(run_path, tmp_path / "result.laz", drive_dir=tiled_drive)
    assert dataclasses.replace(again, out=summary.out) == summary
    tiled = laspy.read(str(again.out))
    assert tiled.point_format == las.point_format
    for name in las.point_format.dimension_names:
        np.testing.assert_array_equal(tiled[name], las[name], err_msg=name)
    assert tiled.header.point_count == las.header.point_count
    np.testing.assert_array_equal(tiled.header.mins, las.header.mins)
    np.testing.assert_array_equal(tiled.header.maxs, las.header.maxs)
    assert tiled.header.parse_crs().to_epsg() == 6677


def test_a_bad_tile_is_named_and_nothing_is_written(
    run_path: Path, tiled_drive: Path, tmp_path: Path
) -> None:
    drive = tmp_path / "drive"
    shutil.copytree(tiled_drive, drive, ignore=shutil.ignore_patterns("images", "truth"))
    out = tmp_path / "out" / "result.laz"
    coloured = laspy.convert(laspy.read(str(tile_file(drive, 1))), point_format_id=7)
    coloured.write(str(tile_file(drive, 1)))
    with pytest.raises(DriveFormatError, match=r"000001\.laz: point format 7 .* differs"):
        export_run_las(run_path, out, drive_dir=drive)
    shutil.copy(tile_file(tiled_drive, 1), tile_file(drive, 1))
    index_file = drive / "points" / "index.json"
    index = json.loads(index_file.read_text())
    index["tiles"][1]["points"] += 1  # the drive's total stays the run's
    index["tiles"][2]["points"] -= 1
    index_file.write_text(json.dumps(index))
    with pytest.raises(DriveDimensionError, match=r"000001\.laz: holds .* the tile index says"):
        export_run_las(run_path, out, drive_dir=drive)
    tile_file(drive, 3).unlink()
    with pytest.raises(MissingDriveFileError, match=r"000003\.laz"):
        export_run_las(run_path, out, drive_dir=drive)
    assert not out.parent.exists() or not list(out.parent.iterdir())


def test_a_drive_tile_of_an_older_point_format_keeps_colours_and_scan_angles(
    run_path: Path, drive_path: Path, tmp_path: Path
) -> None:
    import pyproj

    source = laspy.convert(drive_las(drive_path), point_format_id=3, file_version="1.2")
    n = len(source.points)
    rng = np.random.default_rng(0)
    colour = rng.integers(0, 65535, (3, n), dtype=np.uint16)
    source.red, source.green, source.blue = colour
    source.scan_angle_rank = rng.integers(-90, 90, n).astype(np.int8)
    source.classification = np.full(n, 2, np.uint8)  # ASPRS ground: the road keeps it
    source.header.add_crs(pyproj.CRS.from_epsg(6669))  # GeoTIFF keys of another CRS
    drive = _drive_copy(drive_path, tmp_path / "drive", las=source)
    out = tmp_path / "result.laz"
    summary = export_run_las(run_path, out, drive_dir=drive)
    las = laspy.read(str(out))
    assert summary.point_format == las.header.point_format.id == 7
    np.testing.assert_array_equal(np.stack([las.red, las.green, las.blue]), colour)
    np.testing.assert_array_equal(
        las.scan_angle, np.round(np.asarray(source.scan_angle_rank) / 0.006).astype(np.int16)
    )
    np.testing.assert_array_equal(las.gps_time, source.gps_time)
    assert summary.road_points == 0
    classification = np.asarray(las.classification)
    guardrail = _guardrail(run_path)
    assert np.all(classification[~guardrail] == 2)
    assert np.isin(classification[guardrail], [CLASS_GUARDRAIL, CLASS_GUARDRAIL_POLE]).all()
    # The drive's CRS (EPSG:6677) as WKT; the stale GeoTIFF keys are gone.
    assert las.header.parse_crs().to_epsg() == 6677
    assert not [v for v in las.header.vlrs if type(v).__name__.startswith("Geo")]


def test_a_run_without_reconstruction_has_no_pole_points_and_warns(
    run_path: Path, drive_path: Path, tmp_path: Path
) -> None:
    run = tmp_path / "run"
    shutil.copytree(run_path, run, ignore=shutil.ignore_patterns(RECONSTRUCTION_DIR))
    summary = export_run_las(run, tmp_path / "result.laz", drive_dir=drive_path)
    assert summary.pole_points == summary.run_points == 0
    assert summary.guardrail_points > 0
    assert any("no reconstruction" in w for w in summary.warnings)
    las = laspy.read(str(summary.out))
    assert not (np.asarray(las.classification) == CLASS_GUARDRAIL_POLE).any()
    assert np.all(np.asarray(las.run_id) == -1)


# ---------------------------------------------------------------------------------- refusals


def test_a_drive_with_other_points_is_refused_and_nothing_is_written(
    run_path: Path, drive_path: Path, tmp_path: Path
) -> None:
    source = drive_las(drive_path)
    fewer = laspy.LasData(source.header, source.points[:-10])
    drive = _drive_copy(drive_path, tmp_path / "fewer", las=fewer)
    out = tmp_path / "out"
    out.mkdir()
    with pytest.raises(RunFolderError, match="made from a drive of"):
        export_run_las(run_path, out / "result.laz", drive_dir=drive)
    # As many points, but other ones: found by the segments' point counts and GPS times.
    source.gps_time = np.asarray(source.gps_time) + 1.0
    drive = _drive_copy(drive_path, tmp_path / "shifted", las=source)
    with pytest.raises(RunFolderError, match="another drive"):
        export_run_las(run_path, out / "result.laz", drive_dir=drive)
    assert not list(out.iterdir())


def test_output_names_that_cannot_be_written_are_refused(
    run_path: Path, drive_path: Path, tmp_path: Path
) -> None:
    with pytest.raises(ExportError, match=r"\.laz"):
        export_run_las(run_path, tmp_path / "result.ply", drive_dir=drive_path)
    (tmp_path / "old.laz").write_bytes(b"an earlier export")
    with pytest.raises(OutputExistsError, match="--overwrite"):
        export_run_las(run_path, tmp_path / "old.laz", drive_dir=drive_path)
    assert (tmp_path / "old.laz").read_bytes() == b"an earlier export"
    (tmp_path / "folder.laz").mkdir()
    with pytest.raises(OutputKindError, match="is a folder"):
        export_run_las(run_path, tmp_path / "folder.laz", drive_dir=drive_path, overwrite=True)


def test_an_output_that_is_an_input_is_refused_and_the_inputs_survive(
    run_path: Path, drive_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    drive = _drive_copy(drive_path, tmp_path / "drive")
    points = tile_file(drive)
    run = tmp_path / "run"
    shutil.copytree(run_path, run)
    (run / "points" / "old.laz").write_bytes(b"not the run's, but in its points folder")
    (tmp_path / "alias").symlink_to(drive)
    before = file_tree(tmp_path)
    for out in (points, tmp_path / "alias" / points.relative_to(drive)):
        with pytest.raises(InputInsideOutputError, match="is the input"):
            export_run_las(run, out, drive_dir=drive, overwrite=True)
    with pytest.raises(InputInsideOutputError, match="inside the input folder"):
        export_run_las(run, run / "points" / "old.laz", drive_dir=drive, overwrite=True)
    command = ["export", str(run), "--las", str(points), "--drive", str(drive), "--overwrite"]
    assert main(command) == 2
    assert "InputInsideOutputError" in capsys.readouterr().err
    assert file_tree(tmp_path) == before


def test_a_failed_write_leaves_nothing_and_keeps_the_old_file(
    run_path: Path, drive_path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "result.laz"
    out.write_bytes(b"the previous export")

    def fail(self: laspy.LasWriter, points: object) -> None:
        self.dest.write(b"half a tile")
        raise OSError("disk full")

    monkeypatch.setattr(laspy.LasWriter, "write_points", fail)
    with pytest.raises(OSError, match="disk full"):
        export_run_las(run_path, out, drive_dir=drive_path, overwrite=True)
    assert out.read_bytes() == b"the previous export"
    assert [p.name for p in tmp_path.iterdir()] == ["result.laz"]


# ---------------------------------------------------------------------------------- the CLI


def test_export_command_refuses_an_existing_file_without_overwrite(
    run_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "result.laz"
    # The drive comes from run.json.
    assert main(["export", str(run_path), "--las", str(out)]) == 0
    captured = capsys.readouterr()
    assert "points" in captured.out and "EPSG:6677" in captured.out and str(out) in captured.out
    assert "warning" not in captured.err
    first = out.stat().st_mtime_ns

    assert main(["export", str(run_path), "--las", str(out)]) == 2
    assert "OutputExistsError" in capsys.readouterr().err
    assert out.stat().st_mtime_ns == first

    assert main(["export", str(run_path), "--las", str(out), "--overwrite"]) == 0
    assert len(laspy.read(str(out)).points) == len(load_run(run_path).point_segment)
    assert [p.name for p in tmp_path.iterdir()] == ["result.laz"]


def test_export_command_prints_the_crs_warning(
    run_path: Path, drive_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    drive = _drive_copy(drive_path, tmp_path / "drive", crs="unknown")
    out = tmp_path / "result.las"
    assert main(["export", str(run_path), "--las", str(out), "--drive", str(drive)]) == 0
    captured = capsys.readouterr()
    assert "warning:" in captured.err and "'unknown'" in captured.err
    assert "CRS none" in captured.out


def test_export_command_with_another_drive_fails_with_a_message(
    run_path: Path, drive_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    source = drive_las(drive_path)
    drive = _drive_copy(
        drive_path, tmp_path / "drive", las=laspy.LasData(source.header, source.points[:100])
    )
    out = tmp_path / "result.laz"
    assert main(["export", str(run_path), "--las", str(out), "--drive", str(drive)]) == 2
    err = capsys.readouterr().err
    assert "RunFolderError" in err and "--drive" in err
    assert not out.exists()


def test_a_run_whose_drive_moved_names_the_drive_option(run_path: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    shutil.copytree(run_path, run, ignore=shutil.ignore_patterns(RECONSTRUCTION_DIR))
    info = json.loads((run / "run.json").read_text())
    info["drive"]["path"] = str(tmp_path / "moved")
    (run / "run.json").write_text(json.dumps(info))
    with pytest.raises(MissingDriveFileError, match="--drive"):
        export_run_las(run, tmp_path / "result.laz")
    assert not (tmp_path / "result.laz").exists()
