"""Drive format 2.0: the points as tiles along the trajectory with an index, read whole or a
window at a time; a bad index refused by name."""

from __future__ import annotations

import gc
import json
import re
import shutil
import tracemalloc
from pathlib import Path

import cv2
import laspy
import numpy as np
import pytest

from guardrail_core.cli import main
from guardrail_core.errors import (
    DriveDimensionError,
    DriveFormatError,
    MissingDriveFileError,
    TimestampMismatchError,
)
from guardrail_core.formats.drive import Drive, PointCloud, Truth, load_drive, open_drive
from guardrail_core.formats.drive_summary import count_points
from guardrail_core.formats.drive_tiles import (
    TiledPointWriter,
    read_tile_index,
    tile_boundaries,
    vehicle_station,
)
from guardrail_core.sensors.track import track_coordinates
from tests.drive_files import write_drive_copy

TILE_M = 5.0


@pytest.fixture(scope="module")
def tiled(drive: Drive, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The session's ~32 m test drive written anew in 5 m tiles."""
    return write_drive_copy(drive, tmp_path_factory.mktemp("tiled") / "drive", tile_m=TILE_M)


@pytest.fixture
def copy(tiled: Path, tmp_path: Path) -> Path:
    """A private copy of the tiled drive, to break."""
    out = tmp_path / "drive"
    shutil.copytree(tiled, out)
    return out


def _edit_index(root: Path, edit) -> Path:
    path = root / "points" / "index.json"
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))
    return path


def _assert_same_points(a: PointCloud, b: PointCloud) -> None:
    for name in ("xyz", "gps_time", "intensity", "rotation", "phase"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def _assert_same_truth(a: Truth | None, b: Truth | None) -> None:
    assert a is not None and b is not None
    np.testing.assert_array_equal(a.point_class, b.point_class)
    np.testing.assert_array_equal(a.point_object, b.point_object)
    assert a.objects == b.objects


# ------------------------------------------------------------------------- writing and reading


def test_tiles_follow_each_other_in_time_and_along_the_road(drive: Drive, tiled: Path) -> None:
    index = read_tile_index(tiled)
    length = vehicle_station(drive.trajectory, drive.trajectory.time[-1:])[0]
    assert len(index) == int(np.ceil(length / TILE_M)) >= 6
    assert index.points == len(drive.points)
    offsets = index.offsets()
    assert offsets[0] == 0 and offsets[-1] == len(drive.points)
    # Tile k holds exactly the points scanned between the vehicle's k-th and (k+1)-th 5 m mark.
    cuts = np.concatenate([[-np.inf], tile_boundaries(drive.trajectory, TILE_M), [np.inf]])
    time = drive.points.gps_time
    for k, tile in enumerate(index.tiles):
        assert tile.file == f"points/{k:06d}.laz" and tile.truth == f"truth/points/{k:06d}.npz"
        mine = slice(offsets[k], offsets[k + 1])
        np.testing.assert_array_equal((time >= cuts[k]) & (time < cuts[k + 1]), _mask(mine, time))
        assert tile.points > 0
        assert tile.gps_time == (time[mine][0], time[mine][-1])
        # The vehicle drove its 5 m while the tile was scanned; station_m is where its points are.
        driven = vehicle_station(drive.trajectory, np.array(tile.gps_time))
        assert k * TILE_M - 1e-9 <= driven[0] <= driven[1] <= (k + 1) * TILE_M + 1e-9
        station = track_coordinates(drive.points.xyz[mine], time[mine], drive.trajectory).station
        assert tile.station_m == (station.min(), station.max())
        world = drive.points.xyz[mine] + drive.origin
        np.testing.assert_allclose(tile.bounds_min, world.min(axis=0), atol=1e-4)
        np.testing.assert_allclose(tile.bounds_max, world.max(axis=0), atol=1e-4)
        with laspy.open(str(tiled / tile.file)) as reader:
            assert reader.header.point_count == tile.points
        if k:  # no overlap, and no gap either: tile k starts with the point after tile k-1's last
            assert index.tiles[k - 1].gps_time[1] < tile.gps_time[0]


def _mask(part: slice, time: np.ndarray) -> np.ndarray:
    out = np.zeros(len(time), bool)
    out[part] = True
    return out


def test_a_tiled_drive_loads_the_very_points_and_truth(drive: Drive, tiled: Path) -> None:
    again = load_drive(tiled)
    _assert_same_points(again.points, drive.points)
    _assert_same_truth(again.truth, drive.truth)
    assert again.crs == drive.crs and np.array_equal(again.origin, drive.origin)
    assert [(r.file, r.camera, r.gps_time) for r in again.images] == [
        (r.file, r.camera, r.gps_time) for r in drive.images
    ]


def test_points_written_in_chunks_make_the_same_tiles(
    drive: Drive, tiled: Path, tmp_path: Path
) -> None:
    """The streaming writer (a producer's chunks, cut anywhere) writes what one append writes."""
    assert drive.truth is not None
    writer = TiledPointWriter(
        tmp_path, origin=drive.origin, trajectory=drive.trajectory, tile_m=TILE_M, with_truth=True
    )
    p, t = drive.points, drive.truth
    for part in np.array_split(np.arange(len(p)), 37):
        writer.append(
            p.xyz[part],
            p.gps_time[part],
            p.intensity[part],
            p.rotation[part],
            p.phase[part],
            t.point_class[part],
            t.point_object[part],
        )
    index = writer.close()
    assert index == read_tile_index(tiled) == read_tile_index(tmp_path)
    for tile in index.tiles:
        assert (tmp_path / tile.file).read_bytes() == (tiled / tile.file).read_bytes(), tile.file
        assert tile.truth is not None
        with np.load(tmp_path / tile.truth) as chunked, np.load(tiled / tile.truth) as whole:
            for name in ("class", "object_id"):
                np.testing.assert_array_equal(chunked[name], whole[name])


def test_the_writer_refuses_points_out_of_time_order_and_tiles_of_no_length(
    drive: Drive, tmp_path: Path
) -> None:
    with pytest.raises(DriveFormatError, match="longer than 0 m"):
        TiledPointWriter(tmp_path, origin=drive.origin, trajectory=drive.trajectory, tile_m=0.0)
    writer = TiledPointWriter(
        tmp_path, origin=drive.origin, trajectory=drive.trajectory, tile_m=TILE_M
    )
    p = drive.points
    later, earlier = slice(1000, 2000), slice(0, 1000)
    writer.append(
        p.xyz[later], p.gps_time[later], p.intensity[later], p.rotation[later], p.phase[later]
    )
    with pytest.raises(TimestampMismatchError, match="GPS time order"):
        writer.append(
            p.xyz[earlier],
            p.gps_time[earlier],
            p.intensity[earlier],
            p.rotation[earlier],
            p.phase[earlier],
        )


def test_a_stretch_without_points_leaves_an_empty_tile_in_its_place(
    drive: Drive, tmp_path: Path
) -> None:
    """Tile k stays the k-th 5 m of driving when the scanner saw nothing for a while."""
    assert drive.truth is not None
    station = vehicle_station(drive.trajectory, drive.points.gps_time)
    keep = (station < 10.0) | (station >= 15.0)  # nothing while the vehicle drove 10..15 m
    p, t = drive.points, drive.truth
    points = PointCloud(
        p.xyz[keep], p.gps_time[keep], p.intensity[keep], p.rotation[keep], p.phase[keep]
    )
    truth = Truth(t.point_class[keep], t.point_object[keep], t.objects, t.mask_files)
    folder = write_drive_copy(drive, tmp_path / "gap", tile_m=TILE_M, points=points, truth=truth)
    source = open_drive(folder)
    assert [tile.points == 0 for tile in source.tiles.tiles] == [
        k == 2 for k in range(len(source.tiles))
    ]
    empty, empty_truth = source.read_tiles([2])
    assert len(empty) == 0 and empty_truth is not None and len(empty_truth.point_class) == 0
    again = load_drive(folder)
    _assert_same_points(again.points, points)
    _assert_same_truth(again.truth, truth)


# ------------------------------------------------------------------------------------ windows


def test_a_window_reads_only_the_tiles_it_touches(drive: Drive, copy: Path) -> None:
    source = open_drive(copy)
    index = source.tiles
    lo, hi = 14.0, 16.0
    touched = index.touching(lo, hi)
    assert 0 < len(touched) < len(index) - 2
    for k, tile in enumerate(index.tiles):
        if k not in touched:  # garbage where the tiles the window does not touch were
            (copy / tile.file).write_bytes(b"not a point cloud")
            assert tile.truth is not None
            (copy / tile.truth).write_bytes(b"not a truth file")
    points, truth = open_drive(copy).read_tiles(touched)

    offsets = index.offsets()
    mine = np.concatenate([np.arange(offsets[k], offsets[k + 1]) for k in touched])
    assert drive.truth is not None and truth is not None
    for name in ("xyz", "gps_time", "intensity", "rotation", "phase"):
        np.testing.assert_array_equal(getattr(points, name), getattr(drive.points, name)[mine])
    np.testing.assert_array_equal(truth.point_class, drive.truth.point_class[mine])
    np.testing.assert_array_equal(truth.point_object, drive.truth.point_object[mine])
    # Every point at a station in the window is among them.
    station = track_coordinates(drive.points.xyz, drive.points.gps_time, drive.trajectory).station
    inside = (station >= lo) & (station < hi)
    assert inside.sum() > 1000 and np.isin(drive.points.gps_time[inside], points.gps_time).all()
    # The garbage is there: a tile outside the window does not read.
    outside = next(k for k in range(len(index)) if k not in touched)
    with pytest.raises(DriveFormatError, match=re.escape(index.tiles[outside].file)):
        source.read_tiles([outside])


def test_info_tells_the_tiles_and_the_length(
    drive: Drive, tiled: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["info", str(tiled)]) == 0
    out = capsys.readouterr().out
    n = len(read_tile_index(tiled))
    length = float(np.linalg.norm(np.diff(drive.trajectory.position, axis=0), axis=1).sum())
    assert f"trajectory {length:.1f} m" in out
    assert re.search(rf"tiles +{n}, {length / n:.1f} m of driving each on average", out), out


# ----------------------------------------------------------------------------------- bad index


def test_a_missing_tile_is_named(copy: Path) -> None:
    (copy / "points" / "000003.laz").unlink()
    with pytest.raises(MissingDriveFileError, match=r"points: point cloud '000003\.laz'"):
        load_drive(copy)


def test_a_truncated_tile_is_a_named_error_for_every_command(
    copy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    tile = copy / "points" / "000002.laz"
    tile.write_bytes(tile.read_bytes()[: tile.stat().st_size // 2])
    with pytest.raises(DriveFormatError, match=r"000002\.laz: not a readable LAS/LAZ file"):
        load_drive(copy)
    capsys.readouterr()
    assert main(["info", str(copy)]) == 2
    err = capsys.readouterr().err
    assert "DriveFormatError" in err and "000002.laz" in err and "Traceback" not in err


def test_an_image_time_that_is_not_a_number_is_named(copy: Path) -> None:
    path = copy / "images.json"
    images = json.loads(path.read_text())
    images[1]["gps_time"] = "soon"
    path.write_text(json.dumps(images))
    with pytest.raises(DriveFormatError, match=r"images\.json\[1\]: gps_time is not a number"):
        open_drive(copy)


def test_a_missing_truth_tile_is_named(copy: Path) -> None:
    (copy / "truth" / "points" / "000001.npz").unlink()
    with pytest.raises(MissingDriveFileError, match=r"000001\.npz"):
        load_drive(copy)
    assert load_drive(copy, with_truth=False).truth is None


def test_a_missing_index_is_named(copy: Path) -> None:
    (copy / "points" / "index.json").unlink()
    with pytest.raises(MissingDriveFileError, match=r"index\.json"):
        load_drive(copy)


def test_a_tile_count_other_than_the_index_says_is_named(copy: Path) -> None:
    _edit_index(copy, lambda d: d["tiles"][2].update(points=d["tiles"][2]["points"] + 1))
    with pytest.raises(DriveDimensionError, match=r"000002\.laz: holds \d+ points, the tile index"):
        load_drive(copy)


def test_tiles_overlapping_in_time_are_refused(copy: Path) -> None:
    def overlap(data: dict) -> None:
        data["tiles"][2]["gps_time"][0] = data["tiles"][1]["gps_time"][1] - 0.01

    path = _edit_index(copy, overlap)
    with pytest.raises(TimestampMismatchError, match=re.escape(str(path)) + ": tile 2 starts"):
        load_drive(copy)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d.update(format_version=2), "tile index version 2 is not readable"),
        (lambda d: d.update(format="something-else"), "not a guardrail-tiles index"),
        (lambda d: d["tiles"][1].pop("points"), r"tiles\[1\]: lacks the key 'points'"),
        (lambda d: d["tiles"][1].update(gps_time=[2.0, 1.0]), r"tiles\[1\]\.gps_time: expected"),
        (lambda d: d.update(tiles={}), "expected a list of tiles"),
    ],
)
def test_a_malformed_index_is_a_format_error_naming_it(copy: Path, edit, message: str) -> None:
    path = _edit_index(copy, edit)
    with pytest.raises(DriveFormatError, match=re.escape(str(path)) + ".*" + message):
        load_drive(copy)


@pytest.mark.parametrize("file", ["/etc/hostname", "images/../../outside.jpg"])
def test_an_image_path_outside_the_drive_is_refused(copy: Path, file: str) -> None:
    path = copy / "images.json"
    images = json.loads(path.read_text())
    images[0]["file"] = file
    path.write_text(json.dumps(images))
    with pytest.raises(DriveFormatError, match=r"images\.json\[0\]: file .* inside the drive"):
        open_drive(copy)


def test_info_decodes_every_image(copy: Path, capsys: pytest.CaptureFixture[str]) -> None:
    images = json.loads((copy / "images.json").read_text())
    (copy / images[1]["file"]).write_bytes(b"not an image at all")
    small = cv2.imread(str(copy / images[2]["file"]))
    cv2.imwrite(str(copy / images[2]["file"]), small[::2, ::2])
    open_drive(copy)  # opening only checks that the files exist; info decodes them
    assert main(["info", str(copy)]) == 2
    err = capsys.readouterr().err
    assert "DriveFormatError" in err and "Traceback" not in err
    assert f"2 of {len(images)} images are bad" in err
    assert f"{images[1]['file']}: not a readable image" in err
    assert f"{images[2]['file']}: about" in err and "is calibrated for" in err


def test_info_holds_one_tile_at_a_time(tiled: Path) -> None:
    """``guardrail info`` once read the whole drive at once: 6.4 GB for 3 km."""
    source = open_drive(tiled)
    n = len(source.tiles)
    assert n >= 5

    def peak(work) -> int:
        gc.collect()
        tracemalloc.start()
        try:
            work()
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()

    whole = peak(lambda: source.read_tiles(range(n)))
    one = max(peak(lambda i=i: source.read_tiles([i])) for i in range(n))
    counted = peak(lambda: count_points(source))
    assert counted < 1.5 * one and counted < whole / 2, (counted, one, whole)
    counts = count_points(source)
    points, truth = source.read_tiles(range(n))
    assert counts.points == len(points)
    assert truth is not None and counts.by_class is not None
    np.testing.assert_array_equal(
        counts.by_class, np.bincount(truth.point_class, minlength=len(counts.by_class))
    )
