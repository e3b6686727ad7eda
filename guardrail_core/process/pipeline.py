"""``guardrail process``: a drive through extraction (§3) and reconstruction (§4) into one run
folder, tile by tile.

The drive is cut into processing tiles along the trajectory (:mod:`.tile_plan`); each tile is
extracted, classified and label-corrected with a margin of its neighbours (:mod:`.tile_task`),
as a Dask task or here; the parts are joined as they end (:mod:`.stitch`); their guardrail
points are grouped into runs, so a run across a tile edge is one run, and each run is
reconstructed, again as a task, as soon as no tile still running can add to it
(:mod:`.run_stream`). The run folder is written whole or not at all.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from guardrail_core.distributed import (
    ClusterSpec,
    LaterTasks,
    TaskFailure,
    dask_client,
    map_tasks,
)
from guardrail_core.errors import (
    EmptyDriveError,
    GuardrailError,
    ReconstructionError,
    TilesFailedError,
)
from guardrail_core.extract.classify.crop_classifier import GuardrailClassifier
from guardrail_core.extract.pipeline import ExtractionParams
from guardrail_core.formats.atomic import staged_folder
from guardrail_core.formats.drive import Drive, PointCloud, drive_parts, open_drive
from guardrail_core.formats.drive_tiles import vehicle_station
from guardrail_core.formats.run_folder import RUN_FORMAT_VERSION, write_run_files
from guardrail_core.formats.run_folder_paths import RunFolder
from guardrail_core.formats.run_info import DriveRef, ModelRef, Processing, RunInfo, TileOutcome
from guardrail_core.process.run_stream import RunStream
from guardrail_core.process.stitch import PartStitcher
from guardrail_core.process.tile_plan import ProcessTile, plan_tiles
from guardrail_core.process.tile_task import TileJob, process_window, run_tile_job
from guardrail_core.reconstruct.pipeline import (
    Reconstruction,
    ReconstructionParams,
    RunInput,
    reconstruct_run_meshes,
)
from guardrail_core.reconstruct.writing import write_reconstruction
from guardrail_core.sensors.track import TrackCoordinates, track_coordinates

#: Metres of its neighbours a tile sees on either side: well beyond a post's or a hole's slices
#: and the label correction's reach, so a tile's own points come out as in the whole drive
#: (seed 202's 150 m street in 50 m tiles: every point's label equal with 10 m, all but 1 of
#: 3.0 M with 5 m).
DEFAULT_MARGIN_M = 10.0
#: Metres of trajectory per processing tile on the command line.
DEFAULT_TILE_M = 100.0
#: Metres a drive tile's recorded bounds are widened by: its points are read back rounded to
#: the LAS scale (at most a centimetre), and may lie that much outside.
_BOUNDS_SLACK_M = 0.01
_PARTS_DIR = ".parts"


def process_drive(
    drive: Drive,
    model: GuardrailClassifier,
    out: Path,
    *,
    params: ExtractionParams = ExtractionParams(),
    reconstruction: ReconstructionParams | None = ReconstructionParams(),
    overwrite: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
    progress: bool = False,
    tile_m: float | None = None,
    margin_m: float = DEFAULT_MARGIN_M,
) -> RunInfo:
    """Extract guardrail segments from a drive held in memory with a trained model, reconstruct
    the guardrails and write the run folder, in this process.

    Parameters
    ----------
    drive : the drive
    model : the trained classifier
    out : the run folder to write; written whole or not at all
    params : extraction parameters
    reconstruction : reconstruction parameters (§4); None leaves the reconstruction out
    overwrite : replace an existing run folder
    inputs : further inputs besides the drive's parts (the model folder), which ``out`` must
        not be, hold, or replace
    progress : show progress bars
    tile_m : metres of trajectory per processing tile; None: the whole drive as one tile
    margin_m : metres of its neighbours each tile sees on either side

    Returns
    -------
    The run's ``run.json`` content (counts, model, parameters, tiles), with
    ``reconstruction``: the summary of the reconstruction (when reconstructed).

    Raises
    ------
    EmptyDriveError
        The drive has no points.
    OutputExistsError
        ``out`` exists, is not empty and ``overwrite`` is False.
    InputInsideOutputError
        ``out`` is, holds or would replace a part of the drive or another input; raised before
        any work.

    References
    ----------
    Matsumoto et al. 2019, §3 (Fig. 3) and §4.
    """
    if len(drive.points) == 0:
        raise EmptyDriveError(f"{drive.root}: the drive has no points")
    clock = time.perf_counter()
    track = track_coordinates(drive.points.xyz, drive.points.gps_time, drive.trajectory)
    track_stage = {"seconds": round(time.perf_counter() - clock, 4), "points": len(drive.points)}
    tiles = _plan(drive, params, tile_m, margin_m)
    offsets = drive.tile_offsets()

    def run_tile(tile: ProcessTile, part: Path) -> TileOutcome:
        window, window_track, index = _window_in_memory(drive, track, tile)
        return process_window(
            window,
            window_track,
            index,
            offsets,
            model,
            tile,
            part,
            params,
            ground_reach_m=(reconstruction or ReconstructionParams()).runs.ground_reach_m,
            progress=progress and len(tiles) == 1,
        )

    return _process(
        drive,
        model,
        out,
        tiles,
        run_here=run_tile,
        tile_points=np.diff(offsets).tolist(),
        params=params,
        reconstruction=reconstruction,
        overwrite=overwrite,
        inputs=inputs,
        progress=progress,
        processing=(tile_m, margin_m, ClusterSpec()),
        client=None,
        stages={"track": track_stage},
        clock=clock,
    )


def process_drive_folder(
    drive_root: str | os.PathLike,
    model_dir: str | os.PathLike,
    out: Path,
    *,
    params: ExtractionParams = ExtractionParams(),
    reconstruction: ReconstructionParams | None = ReconstructionParams(),
    overwrite: bool = False,
    progress: bool = False,
    tile_m: float | None = DEFAULT_TILE_M,
    margin_m: float = DEFAULT_MARGIN_M,
    cluster: ClusterSpec | None = None,
    client: object | None = None,
) -> RunInfo:
    """:func:`process_drive` of a drive folder too long to hold in memory: each tile is a task
    that reads only the drive tiles it touches, on the Dask cluster of ``cluster`` (an
    embedded LocalCluster, or the scheduler it names), or one after another here for
    ``cluster.workers == 0``. ``client``: an existing ``dask.distributed.Client`` to use
    instead (``cluster`` then only names it in ``run.json``).

    A tile that fails with a named error is recorded in ``run.json`` (``processing.tiles``) and
    its points get ``POINT_UNPROCESSED``; the rest of the drive completes.
    """
    from guardrail_core.extract.classify.model_folder import load_model

    cluster = cluster or ClusterSpec()
    source = open_drive(drive_root, with_truth=False)
    if source.tiles.points == 0:
        raise EmptyDriveError(f"{source.root}: the drive has no points")
    model = load_model(Path(model_dir))
    drive = source.drive(PointCloud(*([np.zeros(0)] * 5)))  # metadata only: no points here
    drive = dataclasses.replace(drive, tiles=source.tiles)
    tiles = _plan(drive, params, tile_m, margin_m)
    reach = (reconstruction or ReconstructionParams()).runs.ground_reach_m

    def job(tile: ProcessTile, part: Path) -> TileJob:
        return TileJob(
            drive=str(Path(drive_root).resolve()),
            model=str(Path(model_dir).resolve()),
            part=str(part.resolve()),
            tile=tile,
            params=params.to_json(),
            ground_reach_m=reach,
        )

    return _process(
        drive,
        model,
        out,
        tiles,
        make_job=job,
        tile_points=[t.points for t in source.tiles.tiles],
        reads=[[int(d) for d in source.tiles.touching(*t.window_m)] for t in tiles],
        tile_boxes=_tile_boxes(source.tiles.tiles, drive.origin),
        params=params,
        reconstruction=reconstruction,
        overwrite=overwrite,
        inputs=[model_dir],
        progress=progress,
        processing=(tile_m, margin_m, cluster),
        client=client,
        n_points=source.tiles.points,
    )


def _plan(
    drive: Drive, params: ExtractionParams, tile_m: float | None, margin_m: float
) -> list[ProcessTile]:
    length = float(vehicle_station(drive.trajectory, drive.trajectory.time[-1:])[0])
    return plan_tiles(length, tile_m, margin_m, params.segments.slice_length_m)


def _tile_boxes(records: Iterable[Any], origin: np.ndarray) -> np.ndarray:
    """(D, 4) [x_min, y_min, x_max, y_max] of each drive tile's points, local frame."""
    boxes = np.array([[*r.bounds_min[:2], *r.bounds_max[:2]] for r in records], np.float64).reshape(
        -1, 4
    )
    shift = np.asarray(origin, np.float64)[:2]
    slack = np.array([-1, -1, 1, 1]) * _BOUNDS_SLACK_M
    return boxes - np.concatenate([shift, shift]) + slack


def _window_in_memory(
    drive: Drive, track: TrackCoordinates, tile: ProcessTile
) -> tuple[Drive, TrackCoordinates, np.ndarray]:
    """The points of an in-memory drive that ``tile`` sees, their track coordinates and
    indices."""
    lo, hi = tile.window_m
    inside = (track.station >= lo) & (track.station < hi)
    if inside.all():
        return drive, track, np.arange(len(drive.points), dtype=np.int64)
    window = dataclasses.replace(drive, points=drive.points.take(inside), truth=None)
    return window, track.take(inside), np.flatnonzero(inside)


def _process(
    drive: Drive,
    model: GuardrailClassifier,
    out: Path,
    tiles: list[ProcessTile],
    *,
    run_here: Callable[[ProcessTile, Path], TileOutcome] | None = None,
    make_job: Callable[[ProcessTile, Path], TileJob] | None = None,
    tile_points: list[int],
    reads: list[list[int]] | None = None,
    tile_boxes: np.ndarray | None = None,
    params: ExtractionParams,
    reconstruction: ReconstructionParams | None,
    overwrite: bool,
    inputs: Iterable[str | os.PathLike],
    progress: bool,
    processing: tuple[float | None, float, ClusterSpec],
    client: object | None,
    n_points: int | None = None,
    stages: dict[str, dict[str, float]] | None = None,
    clock: float | None = None,
) -> RunInfo:
    """The tiles (``run_here``: each processed here, one after another; ``make_job``: each a
    Dask task on ``client`` or on the cluster of ``processing``), stitched as they end
    (``reads``: the drive tiles each tile's window reads, see :class:`PartStitcher`), and the
    reconstruction of each run as soon as it is closed (``tile_boxes``: (D, 4) xy boxes of the
    drive tiles, where the points still to come lie; without them every run waits for the last
    tile)."""
    out = Path(out)
    started = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    clock = time.perf_counter() if clock is None else clock
    n_points = len(drive.points) if n_points is None else n_points
    tile_m, margin_m, cluster = processing
    sources = [*drive_parts(drive.root), *inputs]
    phases: dict[str, float] = {}  # wall seconds of each phase, in order
    lap = time.perf_counter()

    def phase(name: str) -> None:
        nonlocal lap
        now = time.perf_counter()
        phases[name] = round(phases.get(name, 0.0) + now - lap, 4)
        lap = now

    with staged_folder(out, overwrite=overwrite, inputs=sources) as staging:
        parts_dir = staging / _PARTS_DIR
        parts_dir.mkdir()
        part_of = {t.number: parts_dir / f"{t.number:06d}" for t in tiles}
        stitcher = PartStitcher(staging, tile_points, len(tiles), reads)
        stream = None
        if reconstruction is not None:
            stream = RunStream(drive.trajectory.position, reconstruction)
        # The last part that reads each drive tile: its points may come until that one is joined.
        last_reader = np.full(len(tile_points), len(tiles), np.int64)
        if reads is not None and tile_boxes is not None:
            last_reader[:] = -1
            for k, ids in enumerate(reads):
                last_reader[ids] = k

        with _client(client, cluster) as dask:
            phase("start")
            later: LaterTasks[RunInput, Any] = LaterTasks(
                dask,
                partial(reconstruct_run_meshes, params=reconstruction or ReconstructionParams()),
            )
            reconstruct_start: float | None = None

            def start_runs(runs: list[RunInput]) -> None:
                nonlocal reconstruct_start
                if runs and reconstruct_start is None:
                    reconstruct_start = time.perf_counter()
                for run in sorted(runs, key=lambda r: -len(r.xyz)):  # longest first
                    later.start(run)

            def stitch(i: int, result: TileOutcome | TaskFailure) -> None:
                good = not isinstance(result, TaskFailure) and result.error is None
                joined = stitcher.add(i, part_of[tiles[i].number] if good else None)
                if stream is None:
                    return
                for part in joined:
                    with np.load(part / "guardrail.npz", allow_pickle=False) as data:
                        stream.add(
                            data["index"], data["xyz"], data["ground_index"], data["ground_xyz"]
                        )
                if tile_boxes is not None and stitcher.joined < len(tiles):
                    start_runs(stream.close(tile_boxes[last_reader >= stitcher.joined]))

            results: list[Any]
            if run_here is not None:
                results = map_tasks(
                    None,
                    lambda t: run_here(t, part_of[t.number]),
                    tiles,
                    desc="tiles",
                    unit="tile",
                    progress=progress and len(tiles) > 1,
                    points=lambda o: o.points,
                    failures=(GuardrailError,),
                    on_result=stitch,
                )
            else:
                assert make_job is not None  # one of the two is given (the callers above)
                results = map_tasks(
                    dask,
                    run_tile_job,
                    [make_job(t, part_of[t.number]) for t in tiles],
                    desc="tiles",
                    unit="tile",
                    progress=progress,
                    points=lambda o: o.points,
                    on_result=stitch,
                )
            phase("tiles")
            outcomes = [_outcome_of(tile, r) for tile, r in zip(tiles, results, strict=True)]
            if not any(o.error is None for o in outcomes):
                raise TilesFailedError(
                    f"{drive.root}: every tile failed: "
                    + "; ".join(f"tile {o.number}: {o.error}" for o in outcomes)
                )
            if stream is not None:
                # The runs still open go to the workers first, so that they are reconstructed
                # while the run's tables are written here.
                start_runs(stream.close())
            stitched = stitcher.finish()
            image_files = [record.file for record in drive.images]
            info = RunInfo(
                format_version=RUN_FORMAT_VERSION,
                created=started,
                drive=DriveRef(
                    path=str(Path(drive.root).resolve()), points=n_points, tiles=len(tile_points)
                ),
                model=ModelRef(version=model.version, mode=model.mode, threshold=model.threshold),
                params=params.to_json(),
                counts=stitched.counts,
                images=tuple(image_files),
            )
            timings: dict[str, Any] = {
                "points_in": n_points,
                "stages": {**(stages or {}), **stitched.stages},
                "total_seconds": 0.0,
            }
            write_run_files(
                staging,
                info=info.to_json(),
                segments=stitched.segments,
                timings=timings,
                image_files=image_files,
            )
            phase("stitch")
            if reconstruction is not None:
                assert stream is not None
                done_runs = later.results(desc="reconstruct", unit="run", progress=progress)
                final_id = stream.final_ids()
                models: list[Any] = [None] * len(done_runs)
                for run, result in zip(later.items, done_runs, strict=True):
                    final = int(final_id[run.run_id])  # the stream's numbers are provisional
                    if isinstance(result, TaskFailure):
                        raise ReconstructionError(
                            f"reconstructing run {final} failed: {result.error}"
                        )
                    model_, superimposed, mesh = result
                    models[final] = (dataclasses.replace(model_, run_id=final), superimposed, mesh)
                seconds = round(time.perf_counter() - (reconstruct_start or time.perf_counter()), 4)
                summary = write_reconstruction(
                    RunFolder(staging).reconstruction.root,
                    Reconstruction(
                        [m for m, _, _ in models],
                        [s for _, s, _ in models],
                        {m.run_id: mesh for m, _, mesh in models if mesh is not None},
                    ),
                    params=reconstruction,
                    origin=drive.origin,
                    crs=drive.crs,
                    seconds=seconds,
                )
                timings["stages"]["reconstruct"] = {
                    "seconds": seconds,
                    "points": stream.points_added,
                }
                info = dataclasses.replace(info, reconstruction=summary)
                phase("reconstruct")
        phase("finish")  # the cluster closed
        wall = round(time.perf_counter() - clock, 4)
        info = dataclasses.replace(
            info,
            processing=Processing(
                tile_m=None if len(tiles) == 1 else tile_m,
                margin_m=margin_m,
                workers=cluster.workers,
                scheduler=cluster.label,
                seconds=wall,
                tiles=tuple(outcomes),
            ),
        )
        run_json = {**info.to_json()}
        run_json.pop("reconstruction", None)  # run.json does not hold the summary
        folder = RunFolder(staging)
        folder.run_file.write_text(json.dumps(run_json, indent=2) + "\n")
        timings["total_seconds"] = wall
        timings["phases"] = phases
        folder.timings_file.write_text(json.dumps(timings, indent=2) + "\n")
        _remove_tree(parts_dir)
    return info


@contextmanager
def _client(client: object | None, cluster: ClusterSpec) -> Iterator[object | None]:
    """The caller's client, or one for ``cluster`` (None: tasks run here)."""
    if client is not None:
        yield client
        return
    with dask_client(cluster) as own:
        yield own


def _outcome_of(tile: ProcessTile, result: TileOutcome | TaskFailure) -> TileOutcome:
    """A tile's outcome; a task that failed beyond Dask's retries becomes a failed outcome."""
    if isinstance(result, TaskFailure):
        return TileOutcome(tile.number, tile.station_m, 0, 0.0, result.error)
    return result


def _remove_tree(path: Path) -> None:
    """Remove the parts folder (inside the staging folder: never an input)."""
    shutil.rmtree(path)
