"""A drive's scan cut into chunks of scan time, each scanned on its own with its own random stream.

The simulator scans a long drive a chunk at a time against the scene near it, and writes each
chunk's returns as it goes. Chunks are fixed by the scanner and the trajectory alone (100
rotations of the profile scanner; a frame, or frames overlapping in time, of the multi-beam
one), and chunk c draws only from its own child of the scan's seed sequence; so the returns do
not depend on how the drive is tiled, and equal :func:`~guardrail_core.synth.scanner.scan` and
:func:`~guardrail_core.synth.multibeam.scan_frames` of the same seed on the same scene.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from guardrail_core.sensors.scanner import ScannerParams
from guardrail_core.sensors.trajectory import Trajectory
from guardrail_core.synth.multibeam import MultibeamParams, frame_beams, frame_starts, scan_frame
from guardrail_core.synth.random_streams import child_rng
from guardrail_core.synth.raycast import SceneRaycaster
from guardrail_core.synth.scanner import ReturnModel, Scan, rotation_chunks, scan_rotations

#: Profile scanner rotations per chunk: one second at 100 rotations/s, 300,000 pulses.
ROTATIONS_PER_CHUNK = 100


@dataclass(frozen=True)
class ScanPlan:
    """The chunks of a drive's scan.

    Attributes
    ----------
    spans : (C, 2) float64 GPS seconds of each chunk's first and last pulse, in time order
    units : (C,) int64 rotations (profile) or frames (multi-beam) in each chunk, for progress
    unit : str, "rot" or "frame"
    scan_chunk : ``scan_chunk(raycaster, c)`` scans chunk c (its returns sorted by time); the
        raycaster must hold the scene within the scanner's range of the chunk's poses
    """

    spans: np.ndarray
    units: np.ndarray
    unit: str
    scan_chunk: Callable[[SceneRaycaster, int], Scan]

    def __len__(self) -> int:
        return len(self.spans)


def plan_scan(
    trajectory: Trajectory,
    scanner: ScannerParams,
    multibeam: MultibeamParams | None,
    sequence: np.random.SeedSequence,
    *,
    returns: ReturnModel = ReturnModel(),
) -> ScanPlan:
    """Cut the scan of ``trajectory`` into chunks: the profile ``scanner``'s, or with
    ``multibeam`` the frames of the multi-beam scanner."""
    if multibeam is not None:
        return _frames_plan(trajectory, scanner, multibeam, sequence, returns)
    chunks = rotation_chunks(trajectory, scanner, ROTATIONS_PER_CHUNK)
    ppr = scanner.points_per_rotation
    first_pulse = chunks * ppr - np.array([0, 1])  # pulse numbers of the first and last pulse
    spans = scanner.t0_s + first_pulse / scanner.measurement_rate_hz

    def scan_chunk(raycaster: SceneRaycaster, c: int) -> Scan:
        rotations = (int(chunks[c, 0]), int(chunks[c, 1]))
        rng = child_rng(sequence, c)
        return scan_rotations(raycaster, trajectory, scanner, rotations, rng, returns=returns)

    return ScanPlan(spans.reshape(-1, 2), chunks[:, 1] - chunks[:, 0], "rot", scan_chunk)


def _frames_plan(
    trajectory: Trajectory,
    scanner: ScannerParams,
    params: MultibeamParams,
    sequence: np.random.SeedSequence,
    returns: ReturnModel,
) -> ScanPlan:
    beams = frame_beams(scanner, params, child_rng(sequence, 0))
    starts = frame_starts(trajectory, scanner, params)
    turn_s = 1.0 / scanner.rotation_rate_hz
    last = starts + (beams.steps - 1) * (turn_s / beams.steps)
    # A chunk is a frame, or consecutive frames that overlap in time (frames closer than a turn's
    # drive), so that chunks follow each other in time.
    new_chunk = np.concatenate([[True], starts[1:] > np.maximum.accumulate(last)[:-1]])
    first_frame = np.flatnonzero(new_chunk[: len(starts)])
    end_frame = np.append(first_frame[1:], len(starts)).astype(np.int64)
    ends = np.maximum.reduceat(last, first_frame) if len(starts) else np.zeros(0)
    spans = np.stack([starts[first_frame], ends], axis=1)

    def scan_chunk(raycaster: SceneRaycaster, c: int) -> Scan:
        frames = range(int(first_frame[c]), int(end_frame[c]))
        parts = [
            scan_frame(
                raycaster,
                trajectory,
                scanner,
                beams,
                f,
                float(starts[f]),
                child_rng(sequence, 1, f),
                returns=returns,
            )
            for f in frames
        ]
        result = Scan.concatenate(parts)
        return result.take(np.argsort(result.gps_time, kind="stable"))

    return ScanPlan(spans.reshape(-1, 2), end_frame - first_frame, "frame", scan_chunk)
