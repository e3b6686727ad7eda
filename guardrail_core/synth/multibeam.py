"""A spinning multi-beam scanner (a Velodyne HDL-64E as on the KITTI car, or another preset of
:mod:`guardrail_core.sensors.lidar_models`) taking single frames.

Real multi-beam data comes as frames: one turn of 64 beams, 10 times a second. The simulator takes
one frame every ``frame_every_m`` metres, so that a drive holds frames that barely overlap, each as
sparse as a single KITTI scan (the case an imported KITTI frame presents). Every firing leaves from
the sensor's pose at its own instant; the lattice is the importer's: ring (highest beam first) x
azimuth bin, one block of rows per frame.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from guardrail_core.params import StageParams, param
from guardrail_core.sensors.lidar_models import LIDAR_MODELS
from guardrail_core.sensors.scanner import ScannerParams, azimuth_phase
from guardrail_core.sensors.trajectory import Trajectory
from guardrail_core.synth.random_streams import child_rng, seed_sequence
from guardrail_core.synth.raycast import SceneRaycaster
from guardrail_core.synth.scanner import ReturnModel, Scan, measure_returns


@dataclass(frozen=True)
class MultibeamParams(StageParams):
    """The multi-beam scanner and how often it takes a frame."""

    elevations_deg: tuple[float, ...] = param(
        LIDAR_MODELS["hdl64e"].elevations_deg,
        unit="deg",
        ge=-90,
        le=90,
        doc="(R,) beam elevations, highest first",
    )
    firings_per_rotation: int = param(
        2083,
        ge=1,
        le=100_000,
        doc="azimuth steps per turn (the HDL-64E: about 2083 at 10 Hz)",
    )
    elevation_jitter_deg: float = param(
        0.03, unit="deg", ge=0, le=5, doc="1 sigma of each beam's calibration error"
    )
    frame_every_m: float = param(
        60.0, unit="m", gt=0, le=10_000, doc="metres driven between frames"
    )

    def check_relations(self) -> None:
        elevations = np.asarray(self.elevations_deg, np.float64)
        if elevations.ndim != 1 or len(elevations) == 0:
            self.fail(f"elevations_deg must hold one elevation per beam, got {self.elevations_deg}")
        if not np.all(np.abs(elevations) <= 90):
            self.fail(f"elevations_deg must lie within [-90, 90] deg, got {self.elevations_deg}")
        if np.any(np.diff(elevations) > 0):
            self.fail("elevations_deg must run from the highest beam to the lowest")


@dataclass(frozen=True)
class FrameBeams:
    """The beams of one turn, in firing order (ring by ring, as KITTI stores them).

    Attributes
    ----------
    direction : (B, 3) float64 unit beam directions in the vehicle frame, B = rings x steps
    ring : (B,) int64, 0 = highest beam; step : (B,) int64, firing step within the turn
    phase : (B,) int64, the lattice's azimuth bin
    rings, steps : int
    """

    direction: np.ndarray
    ring: np.ndarray
    step: np.ndarray
    phase: np.ndarray
    rings: int
    steps: int


def frame_beams(
    scanner: ScannerParams, params: MultibeamParams, rng: np.random.Generator
) -> FrameBeams:
    """The beams of every frame; ``rng`` draws each beam's calibration error (once per drive)."""
    rings = len(params.elevations_deg)
    elevation = np.deg2rad(
        np.asarray(params.elevations_deg) + rng.normal(0.0, params.elevation_jitter_deg, rings)
    )
    steps = params.firings_per_rotation
    azimuth = -np.pi + 2 * np.pi * (np.arange(steps) + 0.5) / steps
    beam = np.stack(
        [
            np.cos(elevation)[:, None] * np.cos(azimuth)[None, :],
            np.cos(elevation)[:, None] * np.sin(azimuth)[None, :],
            np.broadcast_to(np.sin(elevation)[:, None], (rings, steps)),
        ],
        axis=2,
    ).reshape(-1, 3)
    return FrameBeams(
        direction=beam @ scanner.T_vehicle_scanner[:3, :3].T,
        ring=np.repeat(np.arange(rings), steps),
        step=np.tile(np.arange(steps), rings),
        phase=azimuth_phase(beam, scanner.points_per_rotation),
        rings=rings,
        steps=steps,
    )


def frame_starts(
    trajectory: Trajectory, scanner: ScannerParams, params: MultibeamParams
) -> np.ndarray:
    """(F,) GPS seconds: the start of a frame every ``params.frame_every_m`` metres driven, the
    first half a spacing in, each ending before the trajectory does."""
    travelled = np.concatenate(
        [[0.0], np.cumsum(np.linalg.norm(np.diff(trajectory.position, axis=0), axis=1))]
    )
    turn_s = 1.0 / scanner.rotation_rate_hz
    marks = np.arange(params.frame_every_m / 2, travelled[-1], params.frame_every_m)
    starts = np.interp(marks, travelled, trajectory.time)
    return starts[starts + turn_s <= trajectory.time[-1]]


def scan_frame(
    raycaster: SceneRaycaster,
    trajectory: Trajectory,
    scanner: ScannerParams,
    beams: FrameBeams,
    frame: int,
    start: float,
    rng: np.random.Generator,
    *,
    returns: ReturnModel = ReturnModel(),
) -> Scan:
    """Frame number ``frame``, a turn from ``start`` (GPS s), sorted by time (the drive
    format's order: the beams of a step fire together); ``rotation`` = frame x (rings + 1) +
    ring, ``phase`` = azimuth bin."""
    turn_s = 1.0 / scanner.rotation_rate_hz
    t = start + beams.step * (turn_s / beams.steps)
    rot_wv, pos_wv = trajectory.poses(t)
    origin = pos_wv + rot_wv @ scanner.T_vehicle_scanner[:3, 3]
    direction = np.einsum("nij,nj->ni", rot_wv, beams.direction)
    idx, xyz, intensity, face = measure_returns(raycaster, origin, direction, scanner, returns, rng)
    rotation = frame * (beams.rings + 1) + beams.ring[idx]
    result = Scan(xyz, t[idx], intensity, rotation, beams.phase[idx], face)
    return result.take(np.argsort(result.gps_time, kind="stable"))


def scan_frames(
    raycaster: SceneRaycaster,
    trajectory: Trajectory,
    scanner: ScannerParams,
    params: MultibeamParams,
    rng: np.random.Generator | np.random.SeedSequence | int | None,
    *,
    returns: ReturnModel = ReturnModel(),
    progress: Callable[[int], None] | None = None,
) -> Scan:
    """Take one frame every ``params.frame_every_m`` metres along the trajectory.

    ``scanner`` gives the turn rate, range limits, noise and ``T_vehicle_scanner``; its
    ``points_per_rotation`` is the lattice's azimuth bins. The beams' calibration errors come
    from child (0,) of ``rng``'s seed sequence, frame f's noise from child (1, f)
    (:func:`~guardrail_core.synth.random_streams.child_rng`). ``progress`` is called with 1 per
    frame.

    Returns the scan, sorted by time, with ``rotation`` = frame x (rings + 1) + ring and
    ``phase`` = azimuth bin.
    """
    sequence = seed_sequence(rng)
    beams = frame_beams(scanner, params, child_rng(sequence, 0))
    parts = []
    for frame, start in enumerate(frame_starts(trajectory, scanner, params)):
        frame_rng = child_rng(sequence, 1, frame)
        parts.append(
            scan_frame(
                raycaster, trajectory, scanner, beams, frame, start, frame_rng, returns=returns
            )
        )
        if progress is not None:
            progress(1)
    result = Scan.concatenate(parts)
    # Frames closer than a turn's drive overlap in time.
    return result.take(np.argsort(result.gps_time, kind="stable"))
