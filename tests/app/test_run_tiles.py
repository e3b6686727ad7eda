"""The review app reads a drive and its run a tile at a time: windows, segments, their points,
their truth and the operators' labels equal what the whole drive in memory gives, and only the
tiles a request needs are read."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from app.run_tiles import RunTiles
from app.session import ReviewSession
from guardrail_core.errors import RunFolderError
from guardrail_core.extract.segment_truth import segment_truth
from guardrail_core.formats.drive import Drive, DriveSource, open_drive
from guardrail_core.formats.drive_tiles import vehicle_station
from guardrail_core.formats.run_folder import POINTS_DIR, write_point_tile
from guardrail_core.formats.run_folder_paths import RunFolder
from guardrail_core.review.training_labels import segment_labels
from tests.drive_files import write_drive_copy

#: Metres of driving per tile: the ~32 m test drive in four tiles.
TILE_M = 8.0


@pytest.fixture(scope="module")
def tiled(
    drive: Drive, run_path: Path, tmp_path_factory: pytest.TempPathFactory
) -> tuple[Path, Path]:
    """The test drive re-written in tiles of 8 m, and the test run with its point tiles split
    to match (the same points in the same order: the run is the test run's)."""
    root = tmp_path_factory.mktemp("run_tiles")
    drive_out = write_drive_copy(drive, root / "drive", tile_m=TILE_M)
    run_out = root / "run"
    shutil.copytree(run_path, run_out)
    whole = RunFolder.open(run_out).point_segment()
    shutil.rmtree(run_out / POINTS_DIR)
    offsets = open_drive(drive_out).tiles.offsets()
    for tile in range(len(offsets) - 1):
        write_point_tile(run_out, tile, whole[offsets[tile] : offsets[tile + 1]])
    info = json.loads((run_out / "run.json").read_text())
    info["drive"]["tiles"] = len(offsets) - 1
    (run_out / "run.json").write_text(json.dumps(info))
    return drive_out, run_out


@pytest.fixture(scope="module")
def whole(tiled: tuple[Path, Path]) -> np.ndarray:
    """(N,) the run's segment of every point, all tiles read."""
    return RunFolder.open(tiled[1]).point_segment()


def _tiles(tiled: tuple[Path, Path], **options: int) -> RunTiles:
    folder = RunFolder.open(tiled[1])
    return RunTiles(open_drive(tiled[0]), folder, folder.segments()["time"], **options)


def _across_cuts(tiled: tuple[Path, Path]) -> np.ndarray:
    """(K,) the segments scanned across a tile's cut (their points lie in two tiles)."""
    cuts = np.array([t.gps_time[0] for t in open_drive(tiled[0]).tiles.tiles[1:]])
    time = RunFolder.open(tiled[1]).segments()["time"]
    return np.flatnonzero(((cuts[None, :] > time[:, :1]) & (cuts[None, :] <= time[:, 1:])).any(1))


def test_the_drive_has_several_tiles_and_segments_across_their_cuts(
    tiled: tuple[Path, Path],
) -> None:
    assert len(open_drive(tiled[0]).tiles) >= 4
    assert len(_across_cuts(tiled)) >= 2  # what the tests below check across tiles


def test_segments_points_and_truth_equal_the_whole_drive_s(
    tiled: tuple[Path, Path], whole: np.ndarray, drive: Drive
) -> None:
    tiles = _tiles(tiled)
    n_segments = int(whole.max()) + 1
    points, owner = tiles.segment_points(np.arange(n_segments))
    in_segment = np.flatnonzero(whole >= 0)
    np.testing.assert_array_equal(points, in_segment)
    np.testing.assert_array_equal(owner, whole[in_segment])
    across = _across_cuts(tiled)
    for s in [0, n_segments // 2, n_segments - 1, *across]:
        np.testing.assert_array_equal(tiles.points_of([s]), np.flatnonzero(whole == s))
    rng = np.random.default_rng(3)
    some = rng.choice(len(whole), 5000, replace=False)
    np.testing.assert_array_equal(tiles.segment_of(some), whole[some])
    expected = np.unique(whole[some][whole[some] >= 0])
    np.testing.assert_array_equal(tiles.segments_of(some), expected)
    assert drive.truth is not None
    truth = segment_truth(drive.truth.point_class, whole, n_segments)
    ids = rng.permutation(n_segments)
    np.testing.assert_array_equal(tiles.truth(ids[:40]), truth[ids[:40]])  # some, then all
    np.testing.assert_array_equal(tiles.truth(ids), truth[ids])


def test_windows_equal_the_whole_drive_s_points(
    tiled: tuple[Path, Path], whole: np.ndarray, drive: Drive
) -> None:
    tiles = _tiles(tiled)
    station = vehicle_station(drive.trajectory, drive.points.gps_time)
    for lo, hi in [(0.0, 5.0), (6.5, 21.0), (20.0, 1e6), (-5.0, 0.0)]:
        window = tiles.window(lo, hi)
        expected = np.flatnonzero((station >= lo) & (station < hi))
        np.testing.assert_array_equal(window.index, expected)
        np.testing.assert_array_equal(window.xyz, drive.points.xyz[expected])
        np.testing.assert_array_equal(window.segment, whole[expected])
        np.testing.assert_allclose(window.station, station[expected], rtol=0, atol=1e-9)
        assert drive.truth is not None and window.point_class is not None
        np.testing.assert_array_equal(window.point_class, drive.truth.point_class[expected])
    t = drive.points.gps_time
    t0, t1 = float(np.quantile(t, 0.3)), float(np.quantile(t, 0.55))
    scanned = tiles.scanned_between(t0, t1)
    np.testing.assert_array_equal(scanned.index, np.flatnonzero((t >= t0) & (t <= t1)))


def test_only_the_tiles_asked_for_are_read_and_the_cache_stays_in_budget(
    tiled: tuple[Path, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    read: list[int] = []
    original = DriveSource.read_tiles

    def recording(self: DriveSource, ids):  # type: ignore[no-untyped-def]
        read.extend(int(i) for i in ids)
        return original(self, ids)

    monkeypatch.setattr(DriveSource, "read_tiles", recording)
    source = open_drive(tiled[0])
    biggest = max(t.points for t in source.tiles.tiles)
    tiles = _tiles(tiled, points_kept=biggest)  # room for one tile
    assert read == []  # opening reads no point
    window = tiles.window(0.0, 5.0)
    holding = set(np.searchsorted(source.tiles.offsets(), window.index, side="right") - 1)
    # The tiles holding the window's points, and at most the one after (the window ends
    # between two trajectory samples), were read once each.
    assert holding <= set(read) and len(read) == len(set(read)) <= len(holding) + 1
    assert len(read) < len(source.tiles)
    for start in np.arange(0.0, 40.0, 4.0):
        tiles.window(float(start), float(start) + 4.0)
        assert len(tiles._points) == 1  # the budget holds one tile
    read.clear()
    tiles.points_of([0])  # a segment's points: the run's point tile and the truth, no LAS
    assert read == []


def test_a_run_of_another_tiling_is_refused(tiled: tuple[Path, Path], drive_path: Path) -> None:
    folder = RunFolder.open(tiled[1])
    with pytest.raises(RunFolderError, match="tiles"):
        RunTiles(open_drive(drive_path), folder, folder.segments()["time"])


def test_session_labels_on_a_tiled_drive_equal_the_whole_drive_s(
    tiled: tuple[Path, Path], whole: np.ndarray, tmp_path: Path
) -> None:
    review = tmp_path / "review"
    session = ReviewSession(tiled[0], tiled[1], review_dir=review, operator="tester")
    n_segments = session.n_segments
    try:
        component = session.run.segments["component"]
        session.relabel([0, n_segments // 2], "guardrail")
        session.relabel(
            [int(np.flatnonzero(component == component[n_segments - 1])[0])],
            "other",
            expand="component",
        )
        session.relabel([n_segments // 2], "other")
        session.undo()
        expected = segment_labels(whole, n_segments, session.store.point_labels())
        np.testing.assert_array_equal(session.operator_label, expected)
        assert (session.operator_label >= 0).sum() >= 3
    finally:
        session.close()
    again = ReviewSession(tiled[0], tiled[1], review_dir=review, operator="tester")
    try:  # a new session works the segments' labels out from the labelled points alone
        np.testing.assert_array_equal(again.operator_label, expected)
    finally:
        again.close()
