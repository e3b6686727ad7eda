"""Simulate a whole drive: scene, vehicle motion, scanner, cameras, truth, written as a drive folder."""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml
from tqdm import tqdm

from guardrail_core.errors import InvalidOptionError, MissingDriveFileError
from guardrail_core.formats.atomic import staged_folder
from guardrail_core.formats.drive import (
    Drive,
    ImageRecord,
    PointCloud,
    Truth,
    write_drive_files,
)
from guardrail_core.sensors.camera import Camera
from guardrail_core.sensors.trajectory import Trajectory
from guardrail_core.synth.camera_render import random_lighting, render_image
from guardrail_core.synth.camera_rig import default_camera_rig
from guardrail_core.synth.designs import DESIGNS_DIR
from guardrail_core.synth.multibeam import scan_frames
from guardrail_core.synth.raycast import SceneRaycaster
from guardrail_core.synth.scanner import scan
from guardrail_core.synth.scene import SCENES_DIR, Scene, build_scene
from guardrail_core.synth.vehicle import drive_along

SIMULATOR_VERSION = "1"


@dataclass(frozen=True)
class SimulationOptions:
    """What the simulated vehicle records besides the scene.

    Attributes
    ----------
    image_every_m : float, metres driven between camera shots (all cameras fire together)
    image_size : (width, height) pixels of every camera
    jpeg_quality : int, 0-100
    compress : bool, LAZ (True) or LAS (False)
    """

    image_every_m: float = 5.0
    image_size: tuple[int, int] = (1024, 768)
    jpeg_quality: int = 92
    compress: bool = True

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


@dataclass(frozen=True)
class SimulationSummary:
    """What a simulation wrote, and how long each stage took (seconds)."""

    out: Path
    n_points: int
    n_images: int
    length_m: float
    duration_s: float
    seconds: dict[str, float]


def simulate_drive(
    spec: dict,
    out: str | os.PathLike,
    *,
    seed: int = 0,
    options: SimulationOptions = SimulationOptions(),
    overwrite: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
    progress: bool = True,
) -> SimulationSummary:
    """Simulate a drive through the scene of ``spec`` and write it to the folder ``out``.

    The same spec, seed and options give the same drive, byte for byte in points and truth.
    The folder is written beside ``out`` and renamed at the end
    (:func:`guardrail_core.formats.atomic.staged_folder`): an error leaves nothing behind.
    ``inputs`` are the files the spec came from (the scene YAML); ``out`` must not be, hold or
    replace one of them, nor the shipped scenes and designs
    (:class:`~guardrail_core.errors.InputInsideOutputError`, before any work).
    """
    out = Path(out)
    seconds: dict[str, float] = {}
    clock = time.perf_counter()
    scene_seq, motion_seq, scan_seq, camera_seq = np.random.SeedSequence(seed).spawn(4)
    # The shipped scenes and designs are inputs of every simulation.
    sources = [*inputs, SCENES_DIR, DESIGNS_DIR]
    with staged_folder(out, overwrite=overwrite, inputs=sources) as staging:
        scene = build_scene(spec, seed=_scene_seed(scene_seq))
        seconds["scene"] = time.perf_counter() - clock

        clock = time.perf_counter()
        t0 = 345_600.0 + 60.0 * (seed % 1000)  # GPS seconds of the week: Thursday, after 00:00
        trajectory = drive_along(
            scene.road,
            scene.vehicle,
            s_start=scene.drive_span[0],
            s_end=scene.drive_span[1],
            t0=t0,
            rng=np.random.default_rng(motion_seq),
        )
        scanner = dataclasses.replace(scene.scanner, t0_s=float(trajectory.time[0]))
        raycaster = SceneRaycaster(scene.mesh)
        if scene.multibeam is not None:
            with tqdm(desc="scanning", unit="frame", disable=not progress, leave=False) as bar:
                result = scan_frames(
                    raycaster,
                    trajectory,
                    scanner,
                    scene.multibeam,
                    np.random.default_rng(scan_seq),
                    progress=bar.update,
                )
        else:
            n_rot = int((trajectory.time[-1] - trajectory.time[0]) * scanner.rotation_rate_hz)
            with tqdm(
                total=n_rot, desc="scanning", unit="rot", disable=not progress, leave=False
            ) as bar:
                result = scan(
                    raycaster,
                    trajectory,
                    scanner,
                    np.random.default_rng(scan_seq),
                    progress=bar.update,
                )
        points = PointCloud(
            result.xyz, result.gps_time, result.intensity, result.rotation, result.phase
        )
        seconds["scanner"] = time.perf_counter() - clock

        clock = time.perf_counter()
        cameras = default_camera_rig(width=options.image_size[0], height=options.image_size[1])
        images = _shoot(
            raycaster,
            trajectory,
            cameras,
            options,
            staging,
            np.random.default_rng(camera_seq),
            progress,
        )
        seconds["cameras"] = time.perf_counter() - clock

        clock = time.perf_counter()
        truth = Truth(
            point_class=scene.mesh.face_class[result.face],
            point_object=scene.mesh.face_object[result.face],
            objects=scene.objects,
            mask_files={},
        )
        source = {
            "simulator": SIMULATOR_VERSION,
            "seed": seed,
            "scene": scene.spec.get("name", "scene"),
            "image_every_m": options.image_every_m,
        }
        write_drive_files(
            staging,
            crs=scene.crs,
            origin=scene.origin,
            scanner=scanner,
            trajectory=trajectory,
            points=points,
            cameras=cameras,
            images=images,
            truth=truth,
            source=source,
            compress=options.compress,
        )
        (staging / "truth" / "scene.yaml").write_text(yaml.safe_dump(scene.spec, sort_keys=False))
        seconds["write"] = time.perf_counter() - clock
    length = float(np.sum(np.linalg.norm(np.diff(trajectory.position, axis=0), axis=1)))
    return SimulationSummary(
        out=out,
        n_points=len(points),
        n_images=len(images),
        length_m=length,
        duration_s=float(trajectory.time[-1] - trajectory.time[0]),
        seconds=seconds,
    )


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


def _shoot(
    raycaster: SceneRaycaster,
    trajectory: Trajectory,
    cameras: list[Camera],
    options: SimulationOptions,
    folder: Path,
    rng: np.random.Generator,
    progress: bool,
) -> list[ImageRecord]:
    """Fire every camera each ``image_every_m`` metres; write images and truth masks."""
    travelled = np.concatenate(
        [[0.0], np.cumsum(np.linalg.norm(np.diff(trajectory.position, axis=0), axis=1))]
    )
    marks = np.arange(options.image_every_m / 2, travelled[-1], options.image_every_m)
    shot_times = np.interp(marks, travelled, trajectory.time)
    lighting = random_lighting(rng)  # one sun for the whole drive; exposure varies per shot
    rays = {camera.name: camera.pixel_rays() for camera in cameras}
    records = []
    with tqdm(
        total=len(shot_times) * len(cameras),
        desc="cameras",
        unit="img",
        disable=not progress,
        leave=False,
    ) as bar:
        for n, t in enumerate(shot_times):
            T_world_vehicle = trajectory.T_world_vehicle(float(t))
            for camera in cameras:
                T_world_camera = T_world_vehicle @ camera.T_vehicle_camera
                shot_light = dataclasses.replace(
                    lighting, exposure=lighting.exposure * float(rng.uniform(0.85, 1.15))
                )
                image, mask = render_image(
                    raycaster, camera, T_world_camera, shot_light, rng, pixel_rays=rays[camera.name]
                )
                name = f"{n:06d}"
                image_file = Path("images") / camera.name / f"{name}.jpg"
                mask_file = Path("truth") / "masks" / camera.name / f"{name}.png"
                (folder / image_file).parent.mkdir(parents=True, exist_ok=True)
                (folder / mask_file).parent.mkdir(parents=True, exist_ok=True)
                cv2.imwrite(
                    str(folder / image_file),
                    image[:, :, ::-1],
                    [cv2.IMWRITE_JPEG_QUALITY, options.jpeg_quality],
                )
                cv2.imwrite(str(folder / mask_file), mask)
                records.append(ImageRecord(str(image_file), camera.name, float(t), T_world_camera))
                bar.update()
    return records
