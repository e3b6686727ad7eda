"""A spinning multi-beam scanner (a Velodyne HDL-64E, as on the KITTI car) taking single frames.

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
from guardrail_core.sensors.scanner import ScannerParams, azimuth_phase
from guardrail_core.sensors.trajectory import Trajectory
from guardrail_core.synth.raycast import SceneRaycaster
from guardrail_core.synth.scanner import ReturnModel, Scan, measure_returns


def hdl64_elevations_deg() -> np.ndarray:
    """(64,) beam elevations, degrees, highest first: the HDL-64E's upper block of 32 beams from
    +2 degrees in 1/3 degree steps, its lower block from -8.83 degrees in 1/2 degree steps."""
    upper = 2.0 - np.arange(32) / 3.0
    lower = -8.83 - 0.5 * np.arange(32)
    return np.concatenate([upper, lower])


@dataclass(frozen=True)
class MultibeamParams(StageParams):
    """The multi-beam scanner and how often it takes a frame."""

    elevations_deg: tuple[float, ...] = param(
        tuple(hdl64_elevations_deg().tolist()),
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


def scan_frames(
    raycaster: SceneRaycaster,
    trajectory: Trajectory,
    scanner: ScannerParams,
    params: MultibeamParams,
    rng: np.random.Generator,
    *,
    returns: ReturnModel = ReturnModel(),
    progress: Callable[[int], None] | None = None,
) -> Scan:
    """Take one frame every ``params.frame_every_m`` metres along the trajectory.

    ``scanner`` gives the turn rate, range limits, noise and ``T_vehicle_scanner``; its
    ``points_per_rotation`` is the lattice's azimuth bins. ``progress`` is called with 1 per frame.

    Returns the scan with ``rotation`` = frame x (rings + 1) + ring and ``phase`` = azimuth bin.
    """
    travelled = np.concatenate(
        [[0.0], np.cumsum(np.linalg.norm(np.diff(trajectory.position, axis=0), axis=1))]
    )
    turn_s = 1.0 / scanner.rotation_rate_hz
    marks = np.arange(params.frame_every_m / 2, travelled[-1], params.frame_every_m)
    starts = np.interp(marks, travelled, trajectory.time)
    starts = starts[starts + turn_s <= trajectory.time[-1]]

    rings = len(params.elevations_deg)
    elevation = np.deg2rad(
        np.asarray(params.elevations_deg) + rng.normal(0.0, params.elevation_jitter_deg, rings)
    )
    steps = params.firings_per_rotation
    azimuth = -np.pi + 2 * np.pi * (np.arange(steps) + 0.5) / steps
    # Beam directions (rings, steps, 3) in the sensor frame, fired ring by ring as KITTI stores them.
    beam = np.stack(
        [
            np.cos(elevation)[:, None] * np.cos(azimuth)[None, :],
            np.cos(elevation)[:, None] * np.sin(azimuth)[None, :],
            np.broadcast_to(np.sin(elevation)[:, None], (rings, steps)),
        ],
        axis=2,
    ).reshape(-1, 3)
    ring = np.repeat(np.arange(rings), steps)
    step = np.tile(np.arange(steps), rings)
    phase = azimuth_phase(beam, scanner.points_per_rotation)
    mount_r = scanner.T_vehicle_scanner[:3, :3]
    mount_t = scanner.T_vehicle_scanner[:3, 3]
    beam_vehicle = beam @ mount_r.T

    parts: list[tuple[np.ndarray, ...]] = []
    for frame, start in enumerate(starts):
        t = start + step * (turn_s / steps)
        rot_wv, pos_wv = trajectory.poses(t)
        origin = pos_wv + rot_wv @ mount_t
        direction = np.einsum("nij,nj->ni", rot_wv, beam_vehicle)
        idx, xyz, intensity, face = measure_returns(
            raycaster, origin, direction, scanner, returns, rng
        )
        parts.append((xyz, t[idx], intensity, frame * (rings + 1) + ring[idx], phase[idx], face))
        if progress is not None:
            progress(1)
    if not parts:
        empty = np.zeros(0, np.int64)
        return Scan(np.zeros((0, 3)), np.zeros(0), empty.astype(np.uint16), empty, empty, empty)
    cols = [np.concatenate(c) for c in zip(*parts, strict=True)]
    # The drive format orders points by time: the beams of a frame fire together.
    order = np.argsort(cols[1], kind="stable")
    return Scan(*(c[order] for c in cols))
