"""Tile-wise processing: tiles with margins give the whole drive's results; Dask runs equal
in-process runs, survive a killed worker, and report a corrupt tile while the rest completes."""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from guardrail_core.distributed import ClusterSpec
from guardrail_core.formats.drive import Drive, load_drive, open_drive
from guardrail_core.formats.drive_writer import write_drive_files
from guardrail_core.formats.run_folder import POINT_UNPROCESSED
from guardrail_core.formats.run_folder_paths import RunFolder
from guardrail_core.process import process_drive, process_drive_folder
from guardrail_core.process.tile_plan import plan_tiles
from guardrail_core.sensors.track import track_coordinates

TILE_M = 10.0


def final_labels(run: Path) -> np.ndarray:
    """(N,) int8 per drive point: 1 guardrail, 0 other segment, or the point's negative code."""
    folder = RunFolder.open(run)
    segment, label = folder.point_segment(), folder.segments()["label"]
    out = np.where(segment < 0, segment, 0).astype(np.int8)
    out[segment >= 0] = label[segment[segment >= 0]]
    return out


def run_models(run: Path) -> list[dict]:
    return json.loads((run / "reconstruction" / "models.json").read_text())["runs"]


@pytest.fixture(scope="module")
def tiled_drive(drive: Drive, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The test drive re-written in tiles of 10 m of driving."""
    out = tmp_path_factory.mktemp("tiled") / "drive"
    out.mkdir()
    for name in ("images",):
        os.symlink(drive.root / name, out / name)
    write_drive_files(
        out,
        crs=drive.crs,
        origin=drive.origin,
        scanner=drive.scanner,
        trajectory=drive.trajectory,
        points=drive.points,
        cameras=list(drive.cameras.values()),
        images=drive.images,
        truth=drive.truth,
        source=drive.source,
        tile_m=TILE_M,
    )
    return out


@pytest.fixture(scope="module")
def whole_run(drive: Drive, model_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    from guardrail_core.extract.classify.model_folder import load_model

    out = tmp_path_factory.mktemp("whole") / "run"
    info = process_drive(drive, load_model(model_path), out)
    assert info.processing is not None and len(info.processing.tiles) == 1
    return out


@pytest.fixture(scope="module")
def tiled_run(drive: Drive, model_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    from guardrail_core.extract.classify.model_folder import load_model

    out = tmp_path_factory.mktemp("tiled") / "run"
    info = process_drive(drive, load_model(model_path), out, tile_m=TILE_M)
    assert info.processing is not None and len(info.processing.tiles) >= 3
    return out


def test_tiles_give_the_whole_drives_labels_runs_and_poles(whole_run: Path, tiled_run: Path):
    assert np.array_equal(final_labels(tiled_run), final_labels(whole_run))
    whole, tiled = run_models(whole_run), run_models(tiled_run)
    assert len(tiled) == len(whole)
    assert [len(r["poles"]) for r in tiled] == [len(r["poles"]) for r in whole]
    assert RunFolder.open(tiled_run).info().counts == RunFolder.open(whole_run).info().counts


def test_a_run_across_tile_edges_is_reconstructed_as_one(tiled_run: Path):
    """A guardrail longer than two tiles is one run of the tiled run, its poles on both sides
    of the tile edges."""
    spans = []
    for run in run_models(tiled_run):
        poles = np.array([p["position"][:2] for p in run["poles"]]).reshape(-1, 2)
        if len(poles) > 1:
            spans.append(float(np.linalg.norm(poles.max(axis=0) - poles.min(axis=0))))
    assert max(spans) > 2 * TILE_M


def test_folder_processing_in_process_equals_the_in_memory_run(
    tiled_drive: Path, model_path: Path, whole_run: Path, tmp_path: Path
):
    out = tmp_path / "run"
    info = process_drive_folder(
        tiled_drive, model_path, out, tile_m=TILE_M, cluster=ClusterSpec(workers=0)
    )
    assert info.drive.tiles == len(open_drive(tiled_drive).tiles) > 1
    assert len(list((out / "points").glob("*.npz"))) == info.drive.tiles
    assert np.array_equal(final_labels(out), final_labels(whole_run))
    assert len(run_models(out)) == len(run_models(whole_run))
    timings = json.loads((out / "timings.json").read_text())
    phases = timings["phases"]
    assert list(phases) == ["start", "tiles", "stitch", "reconstruct", "finish"]
    assert all(v >= 0 for v in phases.values())
    assert phases["tiles"] > 0 and sum(phases.values()) <= timings["total_seconds"]


def test_parts_stitched_as_they_end_in_any_order_give_the_same_run(
    tiled_drive: Path, model_path: Path, tiled_run: Path, tmp_path: Path, monkeypatch
):
    """Tiles end in any order on a cluster: each part is joined once those before it are, and
    each drive tile's points are written as soon as the parts reading it are joined."""
    import guardrail_core.process.pipeline as pipeline
    import guardrail_core.process.stitch as stitch

    real_map = pipeline.map_tasks
    events: list[str] = []

    def ends_in_reverse(client, function, items, *, on_result=None, **options):
        results = real_map(client, function, items, **options)
        if on_result is not None:
            for i in reversed(range(len(results))):
                events.append(f"end {i}")
                on_result(i, results[i])
        return results

    real_write = stitch.write_point_tile

    def write(folder, tile, segment):
        events.append(f"points {tile}")
        real_write(folder, tile, segment)

    monkeypatch.setattr(pipeline, "map_tasks", ends_in_reverse)
    monkeypatch.setattr(stitch, "write_point_tile", write)
    out = tmp_path / "run"
    info = process_drive_folder(
        tiled_drive, model_path, out, tile_m=TILE_M, cluster=ClusterSpec(workers=0)
    )
    # The same run as the tiles stitched in order (in memory): segments numbered alike.
    assert np.array_equal(final_labels(out), final_labels(tiled_run))
    in_order = RunFolder.open(tiled_run)
    assert RunFolder.open(out).info().counts == in_order.info().counts
    for name, column in RunFolder.open(out).segments().items():
        np.testing.assert_array_equal(column, in_order.segments()[name], err_msg=name)
    assert np.array_equal(RunFolder.open(out).point_segment(), in_order.point_segment())
    # The embeddings are appended part by part to the run's file, and nothing else is left.
    embeddings = RunFolder.open(out).embeddings()
    assert embeddings is not None and embeddings.shape == (info.counts.segments, 1280)
    assert np.array_equal(embeddings, in_order.embeddings(), equal_nan=True)
    assert np.isfinite(embeddings).all(axis=1).sum() >= info.counts.crops.asked
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in tiled_run.iterdir())
    # Nothing could be joined before tile 0 ended, last; then every drive tile was written.
    tiles = len(info.processing.tiles) if info.processing else 0
    assert events[:tiles] == [f"end {i}" for i in reversed(range(tiles))]
    assert sorted(events[tiles:]) == sorted(f"points {d}" for d in range(info.drive.tiles))


def test_drive_tiles_are_written_while_later_tiles_still_run(
    tiled_drive: Path, model_path: Path, tmp_path: Path, monkeypatch
):
    import guardrail_core.process.stitch as stitch

    events: list[str] = []
    real_write = stitch.write_point_tile
    real_add = stitch.PartStitcher.add

    def write(folder, tile, segment):
        events.append("points")
        real_write(folder, tile, segment)

    def add(self, k, part):
        events.append("part")
        return real_add(self, k, part)

    monkeypatch.setattr(stitch, "write_point_tile", write)
    monkeypatch.setattr(stitch.PartStitcher, "add", add)
    # Narrow margins, so that the first tiles' windows do not read the last drive tiles.
    process_drive_folder(
        tiled_drive,
        model_path,
        tmp_path / "run",
        tile_m=TILE_M,
        margin_m=2.0,
        cluster=ClusterSpec(workers=0),
    )
    assert events.count("part") >= 3
    # Point tiles come out between the parts, not all after the last one.
    assert events.index("points") < len(events) - 1 - events[::-1].index("part")


def test_runs_closed_as_the_tiles_end_give_the_models_of_runs_closed_at_the_end(
    tiled_drive: Path, model_path: Path, tiled_run: Path, tmp_path: Path, monkeypatch
):
    """A drive folder's runs are reconstructed as they are closed (the drive tiles' bounds say
    where points may still come: tests/process/test_run_stream.py); the models and meshes are those of
    the same tiles with every run closed after the last (the in-memory run, which has no
    bounds)."""
    import guardrail_core.process.pipeline as pipeline

    started: list[int] = []
    real_reconstruct = pipeline.reconstruct_run_meshes

    def reconstruct(run, params):
        started.append(run.run_id)
        return real_reconstruct(run, params=params)

    monkeypatch.setattr(pipeline, "reconstruct_run_meshes", reconstruct)
    out = tmp_path / "run"
    process_drive_folder(
        tiled_drive, model_path, out, tile_m=TILE_M, cluster=ClusterSpec(workers=0)
    )
    assert sorted(started) == list(range(len(run_models(tiled_run))))
    assert len(started) > 1
    streamed = json.loads((out / "reconstruction" / "models.json").read_text())
    at_end = json.loads((tiled_run / "reconstruction" / "models.json").read_text())
    streamed.pop("seconds"), at_end.pop("seconds")
    assert streamed == at_end
    for mesh in sorted((tiled_run / "reconstruction" / "meshes").iterdir()):
        assert (out / "reconstruction" / "meshes" / mesh.name).read_bytes() == mesh.read_bytes()


def test_a_window_reads_only_the_drive_tiles_it_touches(tiled_drive: Path, tmp_path: Path):
    """Every drive tile a processing tile's window does not touch is unreadable: the window
    still reads, and holds exactly the points of the tiles it touches that lie in it."""
    from guardrail_core.process.tile_task import read_window

    source = open_drive(tiled_drive, with_truth=False)
    tile = plan_tiles(32.0, TILE_M, 2.0, 0.5)[1]
    touched = source.tiles.touching(*tile.window_m)
    assert 0 < len(touched) < len(source.tiles)
    copy = tmp_path / "drive"
    copy.mkdir()
    for item in tiled_drive.iterdir():
        if item.name == "points":
            (copy / "points").mkdir()
            for f in item.iterdir():
                (copy / "points" / f.name).write_bytes(f.read_bytes())
        else:
            os.symlink(item, copy / item.name)
    for i, record in enumerate(source.tiles.tiles):
        if i not in touched:
            (copy / record.file).write_bytes(b"not a point cloud")
    window, track, index = read_window(open_drive(copy, with_truth=False), tile)
    whole = load_drive(tiled_drive, with_truth=False)
    station = track_coordinates(whole.points.xyz, whole.points.gps_time, whole.trajectory).station
    expected = np.flatnonzero((station >= tile.window_m[0]) & (station < tile.window_m[1]))
    assert np.array_equal(index, expected)
    assert np.array_equal(window.points.xyz, whole.points.xyz[expected])


def test_a_corrupt_tile_is_reported_by_name_and_the_rest_completes(
    tiled_drive: Path, model_path: Path, whole_run: Path, tmp_path: Path
):
    copy = tmp_path / "drive"
    copy.mkdir()
    for item in tiled_drive.iterdir():
        if item.name == "points":
            (copy / "points").mkdir()
            for f in item.iterdir():
                (copy / "points" / f.name).write_bytes(f.read_bytes())
        else:
            os.symlink(item, copy / item.name)
    source = open_drive(copy)
    last = len(source.tiles) - 1
    bad = source.tiles.tiles[last]
    (copy / bad.file).write_bytes(b"this is no point cloud")
    out = tmp_path / "run"
    info = process_drive_folder(
        copy, model_path, out, tile_m=TILE_M, margin_m=1.0, cluster=ClusterSpec(workers=0)
    )
    assert info.processing is not None
    failed = info.processing.failed
    assert failed and all(bad.file in (t.error or "") for t in failed)
    assert all("DriveFormatError" in (t.error or "") for t in failed)
    assert len(failed) < len(info.processing.tiles)  # the others finished
    labels, whole = final_labels(out), final_labels(whole_run)
    done = labels != POINT_UNPROCESSED
    assert done.any() and (~done).any()
    # Points of the tiles that completed and lie away from the failed ones are as in the whole.
    assert (labels[done] == whole[done]).mean() > 0.99


def test_a_local_cluster_run_equals_the_in_process_run_and_survives_a_killed_worker(
    tiled_drive: Path, model_path: Path, whole_run: Path, tmp_path: Path
):
    from dask.distributed import Client, LocalCluster

    with (
        LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=":0") as cluster,
        Client(cluster) as client,
    ):
        killed: list[int] = []

        def kill_a_busy_worker() -> None:
            # Wait for a tile's part to be half written (its folder there, its part.json not
            # yet), then kill the busy workers: the retried tile finds the half-written part.
            while not killed:
                half = [
                    p
                    for p in tmp_path.glob(".run.partial-*/.parts/*")
                    if not (p / "part.json").exists()
                ]
                busy = [w for w, tasks in client.processing().items() if tasks]
                if half and busy:
                    pids = client.run(os.getpid, workers=busy)
                    for pid in pids.values():
                        os.kill(pid, signal.SIGKILL)
                    killed.extend(pids.values())
                time.sleep(0.01)

        killer = threading.Thread(target=kill_a_busy_worker, daemon=True)
        killer.start()
        out = tmp_path / "run"
        info = process_drive_folder(
            tiled_drive,
            model_path,
            out,
            tile_m=TILE_M,
            cluster=ClusterSpec(workers=2),
            client=client,
        )
        killer.join(timeout=60)
    assert killed, "a worker was killed while it held a tile"
    assert info.processing is not None and not info.processing.failed
    assert np.array_equal(final_labels(out), final_labels(whole_run))
    # The runs, reconstructed on the workers as they were closed, numbered as in the whole drive.
    on_cluster = json.loads((out / "reconstruction" / "models.json").read_text())
    whole = json.loads((whole_run / "reconstruction" / "models.json").read_text())
    on_cluster.pop("seconds"), whole.pop("seconds")
    assert on_cluster == whole and len(whole["runs"]) > 1


def test_the_road_near_guardrails_is_what_a_full_distance_query_finds() -> None:
    """The grid pre-filter of the road points a tile hands to the reconstruction drops none."""
    from scipy.spatial import cKDTree

    from guardrail_core.process.tile_task import _near

    rng = np.random.default_rng(1)
    for _ in range(20):
        n = 50_000
        xy = rng.uniform(-50, 50, (n, 2)) * rng.uniform(0.05, 3)
        targets = rng.random(n) < rng.choice([0.0005, 0.01, 0.2])
        candidates = ~targets & (rng.random(n) < 0.7)
        reach = float(rng.choice([0.3, 1.0, 5.0]))
        distance, _ = cKDTree(xy[targets]).query(xy[candidates], distance_upper_bound=reach)
        expected = np.flatnonzero(candidates)[np.isfinite(distance)]
        np.testing.assert_array_equal(_near(xy, targets, candidates, reach), expected)
    assert len(_near(xy, np.zeros(n, bool), candidates, 1.0)) == 0
