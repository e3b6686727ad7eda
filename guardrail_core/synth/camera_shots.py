"""The simulated vehicle's cameras: every camera fires each ``image_every_m`` metres driven, and
each image and its truth mask is written as soon as it is rendered."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from guardrail_core.formats.drive import ImageRecord
from guardrail_core.sensors.camera import Camera
from guardrail_core.sensors.trajectory import Trajectory
from guardrail_core.synth.camera_render import (
    random_lighting,
    random_night_lighting,
    render_image,
)
from guardrail_core.synth.raycast import SceneRaycaster


def shot_times(trajectory: Trajectory, every_m: float) -> np.ndarray:
    """(N,) GPS seconds at which the vehicle has driven ``every_m`` / 2, 1.5 ``every_m``, ...
    metres."""
    travelled = np.concatenate(
        [[0.0], np.cumsum(np.linalg.norm(np.diff(trajectory.position, axis=0), axis=1))]
    )
    marks = np.arange(every_m / 2, travelled[-1], every_m)
    return np.interp(marks, travelled, trajectory.time)


class ShotWriter:
    """Renders shots of every camera into ``folder`` (``images/CAMERA/NNNNNN.jpg`` and
    ``truth/masks/CAMERA/NNNNNN.png``), numbering them on from call to call.

    ``rng`` draws one sun (``night``: the vehicle's lamps) for the whole drive, then each
    image's exposure and sensor noise in shot order, so the images do not depend on how the
    shots are split between calls.
    """

    def __init__(
        self,
        cameras: list[Camera],
        folder: Path,
        rng: np.random.Generator,
        jpeg_quality: int,
        night: bool = False,
    ) -> None:
        self.cameras = cameras
        self.folder = Path(folder)
        self.rng = rng
        self.jpeg_quality = jpeg_quality
        # exposure varies per shot
        self.lighting = random_night_lighting(rng) if night else random_lighting(rng)
        self.records: list[ImageRecord] = []
        self._shots = 0
        self._rays: dict[str, np.ndarray] = {}  # each camera's pixel rays, made at its first shot

    def shoot(
        self,
        raycaster: SceneRaycaster,
        trajectory: Trajectory,
        times: np.ndarray,
        progress: Callable[[int], None] | None = None,
    ) -> None:
        """Fire every camera at each of ``times`` (GPS s, increasing) against ``raycaster``'s
        scene; ``progress`` is called with 1 per image."""
        for t in np.asarray(times, np.float64):
            T_world_vehicle = trajectory.T_world_vehicle(float(t))
            name = f"{self._shots:06d}"
            for camera in self.cameras:
                T_world_camera = T_world_vehicle @ camera.T_vehicle_camera
                shot_light = dataclasses.replace(
                    self.lighting,
                    exposure=self.lighting.exposure * float(self.rng.uniform(0.85, 1.15)),
                )
                image, mask = render_image(
                    raycaster,
                    camera,
                    T_world_camera,
                    shot_light,
                    self.rng,
                    pixel_rays=self._pixel_rays(camera),
                )
                image_file = Path("images") / camera.name / f"{name}.jpg"
                mask_file = Path("truth") / "masks" / camera.name / f"{name}.png"
                (self.folder / image_file).parent.mkdir(parents=True, exist_ok=True)
                (self.folder / mask_file).parent.mkdir(parents=True, exist_ok=True)
                cv2.imwrite(
                    str(self.folder / image_file),
                    image[:, :, ::-1],
                    [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality],
                )
                cv2.imwrite(str(self.folder / mask_file), mask)
                self.records.append(
                    ImageRecord(str(image_file), camera.name, float(t), T_world_camera)
                )
                if progress is not None:
                    progress(1)
            self._shots += 1

    def _pixel_rays(self, camera: Camera) -> np.ndarray:
        if camera.name not in self._rays:  # costly (seconds at 1024 x 768): once per drive
            self._rays[camera.name] = camera.pixel_rays()
        return self._rays[camera.name]
