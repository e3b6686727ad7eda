"""Simulate a whole drive: scene, vehicle motion, scanner, cameras, truth, written as a drive folder.

Memory does not grow with the drive's length: the scene is built a window of driving at a time
(:mod:`.scene_window`), the scan runs in chunks of scan time (:mod:`.scan_plan`) whose points go
straight into the drive's tiles (:class:`~guardrail_core.formats.drive_tiles.TiledPointWriter`),
and images are written as they are rendered.
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from guardrail_core.classes import TruthClass
from guardrail_core.errors import InvalidOptionError, MissingDriveFileError
from guardrail_core.formats.atomic import staged_folder
from guardrail_core.formats.drive import Drive
from guardrail_core.formats.drive_tiles import DEFAULT_DRIVE_TILE_M, TiledPointWriter
from guardrail_core.formats.drive_writer import write_drive_metadata
from guardrail_core.progress import progress_bar
from guardrail_core.synth.camera_rig import default_camera_rig
from guardrail_core.synth.camera_shots import ShotWriter, shot_times
from guardrail_core.synth.designs import DESIGNS_DIR
from guardrail_core.synth.mesh import SceneMesh
from guardrail_core.synth.raycast import SceneRaycaster
from guardrail_core.synth.scan_plan import plan_scan
from guardrail_core.synth.scanner import Scan
from guardrail_core.synth.scene import SCENES_DIR, Scene, build_scene, plan_scene
from guardrail_core.synth.scene_window import SceneWindows, drive_windows, window_positions
from guardrail_core.synth.vehicle import drive_along

#: 2: the scene is built per object stream and the scan drawn per chunk of scan time, so that
#: long drives are simulated in windows and tiles; drives differ from version 1's for a seed.
#: 3: parked cars' side windows lean in and return as real ones do (``car_glass``).
SIMULATOR_VERSION = "3"


@dataclass(frozen=True)
class SimulationOptions:
    """What the simulated vehicle records besides the scene, and how the work is cut up.

    Attributes
    ----------
    image_every_m : float, metres driven between camera shots (all cameras fire together)
    image_size : (width, height) pixels of every camera
    jpeg_quality : int, 0-100
    compress : bool, LAZ (True) or LAS (False)
    night : bool, the images taken at night, lit by the vehicle's lamps
    scene_window_m : float, metres of driving scanned against one build of the scene near them
        (memory against rebuilding: a window holds the scene within the scanner's range, 120 m,
        of it; the points do not depend on it)
    """

    image_every_m: float = 5.0
    image_size: tuple[int, int] = (1024, 768)
    jpeg_quality: int = 92
    compress: bool = True
    scene_window_m: float = 200.0
    night: bool = False

    def __post_init__(self) -> None:
        width, height = self.image_size
        if not self.image_every_m > 0:
            raise InvalidOptionError(f"image spacing must be positive, got {self.image_every_m} m")
        if min(width, height) < 16:
            raise InvalidOptionError(
                f"images must be at least 16 x 16 pixels, got {width} x {height}"
            )
        if not 0 <= self.jpeg_quality <= 100:
            raise InvalidOptionError(f"JPEG quality lies in 0..100, got {self.jpeg_quality}")
        if not self.scene_window_m > 0:
            raise InvalidOptionError(
                f"scene windows must be longer than 0 m, got {self.scene_window_m}"
            )


@dataclass(frozen=True)
class SimulationSummary:
    """What a simulation wrote, and how long each stage took (seconds).

    ``points_by_class`` counts the points of each :class:`~guardrail_core.classes.TruthClass`
    (those with any); ``n_tiles`` the point tiles written.
    """

    out: Path
    n_points: int
    n_images: int
    length_m: float
    duration_s: float
    seconds: dict[str, float]
    n_tiles: int = 1
    points_by_class: dict[int, int] = dataclasses.field(default_factory=dict)


def simulate_drive(
    spec: dict,
    out: str | os.PathLike,
    *,
    seed: int = 0,
    options: SimulationOptions = SimulationOptions(),
    overwrite: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
    progress: bool = True,
    tile_m: float | None = DEFAULT_DRIVE_TILE_M,
) -> SimulationSummary:
    """Simulate a drive through the scene of ``spec`` and write it to the folder ``out``.

    The points are written in tiles of ``tile_m`` metres of driving (None: one tile) as they are
    scanned. The same spec, seed and options give the same drive, byte for byte in points and
    truth once the tiles are put together, whatever ``tile_m``.
    The folder is written beside ``out`` and renamed at the end
    (:func:`guardrail_core.formats.atomic.staged_folder`): an error leaves nothing behind.
    ``inputs`` are the files the spec came from (the scene YAML); ``out`` must not be, hold or
    replace one of them, nor the shipped scenes and designs
    (:class:`~guardrail_core.errors.InputInsideOutputError`, before any work).
    """
    if tile_m is not None and not tile_m > 0:
        raise InvalidOptionError(f"tiles must be longer than 0 m, got {tile_m}")
    out = Path(out)
    seconds = dict.fromkeys(("scene", "scanner", "cameras", "write"), 0.0)
    scene_seq, motion_seq, scan_seq, camera_seq = np.random.SeedSequence(seed).spawn(4)
    # The shipped scenes and designs are inputs of every simulation.
    sources = [*inputs, SCENES_DIR, DESIGNS_DIR]
    with staged_folder(out, overwrite=overwrite, inputs=sources) as staging:
        with _timed(seconds, "scene"):
            layout = plan_scene(spec, seed=_scene_seed(scene_seq))
            t0 = 345_600.0 + 60.0 * (seed % 1000)  # GPS seconds of the week: Thursday, 00:00+
            trajectory = drive_along(
                layout.road,
                layout.vehicle,
                s_start=layout.drive_span[0],
                s_end=layout.drive_span[1],
                t0=t0,
                rng=np.random.default_rng(motion_seq),
            )
            scanner = dataclasses.replace(layout.scanner, t0_s=float(trajectory.time[0]))
            # A part is needed while the scanner (or a camera, about as far from the vehicle's
            # origin) may reach it.
            reach = scanner.max_range_m + float(np.linalg.norm(scanner.T_vehicle_scanner[:3, 3]))
            with progress_bar(
                total=len(layout.parts),
                desc="scene",
                unit="part",
                enabled=progress,
                leave=False,
            ) as bar:
                scene = SceneWindows(layout.parts, reach + 1.0, progress=bar.update)

        plan = plan_scan(trajectory, scanner, layout.multibeam, scan_seq, returns=layout.returns)
        cameras = default_camera_rig(width=options.image_size[0], height=options.image_size[1])
        shots = shot_times(trajectory, options.image_every_m)
        shooter = ShotWriter(
            cameras,
            staging,
            np.random.default_rng(camera_seq),
            options.jpeg_quality,
            night=options.night,
        )
        writer = TiledPointWriter(
            staging,
            origin=layout.origin,
            trajectory=trajectory,
            tile_m=tile_m,
            compress=options.compress,
            with_truth=True,
        )
        counts = np.zeros(len(TruthClass), np.int64)
        next_shot = 0
        with (
            progress_bar(
                total=int(plan.units.sum()),
                desc="scanning",
                unit=plan.unit,
                enabled=progress,
                leave=False,
                position=0,
            ) as scan_bar,
            progress_bar(
                total=len(shots) * len(cameras),
                desc="cameras",
                unit="img",
                enabled=progress,
                leave=False,
                position=1,
            ) as camera_bar,
        ):
            for window in drive_windows(trajectory, plan.spans, options.scene_window_m):
                with _timed(seconds, "scene"):
                    positions, gap = window_positions(trajectory, window.span)
                    mesh = scene.mesh_near(positions, slack_m=gap / 2)
                    raycaster = SceneRaycaster(mesh)
                for c in window.chunks:
                    with _timed(seconds, "scanner"):
                        result = plan.scan_chunk(raycaster, c)
                    with _timed(seconds, "write"):
                        counts += _append(writer, result, mesh)
                    scan_bar.update(int(plan.units[c]))
                with _timed(seconds, "cameras"):
                    end = int(np.searchsorted(shots, window.shots_before, side="left"))
                    shooter.shoot(raycaster, trajectory, shots[next_shot:end], camera_bar.update)
                    next_shot = end
                del raycaster, mesh  # before the next window's scene is built

        with _timed(seconds, "write"):
            index = writer.close()
            write_drive_metadata(
                staging,
                crs=layout.crs,
                origin=layout.origin,
                scanner=scanner,
                trajectory=trajectory,
                cameras=cameras,
                images=shooter.records,
                objects=scene.objects,
                source={
                    "simulator": SIMULATOR_VERSION,
                    "seed": seed,
                    "scene": layout.spec.get("name", "scene"),
                    "image_every_m": options.image_every_m,
                    **({"night": True} if options.night else {}),
                },
            )
            (staging / "truth" / "scene.yaml").write_text(
                yaml.safe_dump(layout.spec, sort_keys=False)
            )
    length = float(np.sum(np.linalg.norm(np.diff(trajectory.position, axis=0), axis=1)))
    return SimulationSummary(
        out=out,
        n_points=int(counts.sum()),
        n_images=len(shooter.records),
        length_m=length,
        duration_s=float(trajectory.time[-1] - trajectory.time[0]),
        seconds=seconds,
        n_tiles=len(index),
        points_by_class={i: int(n) for i, n in enumerate(counts) if n},
    )


@contextmanager
def _timed(seconds: dict[str, float], stage: str) -> Iterator[None]:
    """Add the seconds the enclosed block takes to ``seconds[stage]``."""
    start = time.perf_counter()
    try:
        yield
    finally:
        seconds[stage] += time.perf_counter() - start


def _append(writer: TiledPointWriter, result: Scan, mesh: SceneMesh) -> np.ndarray:
    """Write a chunk's returns with their truth (from the faces they hit in ``mesh``); return its
    count of points (T,) per :class:`~guardrail_core.classes.TruthClass`."""
    point_class = mesh.face_class[result.face]
    # The LAS file's own types: the points a tile holds until it is written take less memory.
    writer.append(
        result.xyz,
        result.gps_time,
        result.intensity,
        result.rotation.astype(np.uint32),
        result.phase.astype(np.uint16),
        point_class,
        mesh.face_object[result.face],
    )
    return np.bincount(point_class, minlength=len(TruthClass))[: len(TruthClass)]


def _scene_seed(sequence: np.random.SeedSequence) -> int:
    return int(sequence.generate_state(1)[0])


def rebuild_scene(drive: Drive) -> Scene:
    """The scene a synthetic drive was simulated from: the same meshes and truth."""
    path = drive.root / "truth" / "scene.yaml"
    if not path.is_file() or "seed" not in drive.source:
        raise MissingDriveFileError(
            f"{drive.root}: not a simulated drive (no truth/scene.yaml or seed)"
        )
    scene_seq = np.random.SeedSequence(int(drive.source["seed"])).spawn(4)[0]
    return build_scene(yaml.safe_load(path.read_text()), seed=_scene_seed(scene_seq))
