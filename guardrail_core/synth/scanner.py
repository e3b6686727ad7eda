"""The 360-degree profile laser scanner: rays from the moving vehicle into the scene.

Every measurement k is fired at ``t0_s + k / measurement_rate_hz`` from the scanner's pose at that
instant, so motion skews each profile exactly as on a real mobile mapping system; ranges get Gaussian noise
along the beam, returns get an intensity from the material and the incidence angle, and weak
returns drop out.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from guardrail_core.params import StageParams, param
from guardrail_core.sensors.scanner import ScannerParams
from guardrail_core.sensors.trajectory import Trajectory
from guardrail_core.synth.materials import MATERIAL_NAMES, MATERIALS
from guardrail_core.synth.random_streams import child_rng, seed_sequence
from guardrail_core.synth.raycast import SceneRaycaster

_REFLECTIVITY = np.array([MATERIALS[name].reflectivity for name in MATERIAL_NAMES])
_DROPOUT = np.array([MATERIALS[name].dropout for name in MATERIAL_NAMES])


@dataclass(frozen=True)
class ReturnModel(StageParams):
    """How a surface answers a pulse."""

    base_dropout: float = param(0.01, ge=0, le=1, doc="probability of losing any return")
    weak_signal: float = param(
        0.06,
        gt=0,
        le=1,
        doc="signal level (reflectivity x cos(incidence) x range factor) below which returns "
        "start to drop out",
    )
    range_knee_m: float = param(
        15.0, unit="m", gt=0, le=1000, doc="beyond this the received signal falls as 1 / r^2"
    )
    intensity_noise: float = param(0.04, ge=0, le=10, doc="relative 1 sigma of the intensity")
    intensity_gain: float = param(
        1.0,
        gt=0,
        le=100,
        doc="factor on every recorded intensity: a scanner whose intensity is calibrated "
        "differently (clipped at the format's maximum)",
    )


@dataclass(frozen=True)
class Scan:
    """Returns of a scan, ordered by time.

    Attributes
    ----------
    xyz : (N, 3) float64, metres, local frame
    gps_time : (N,) float64, seconds
    intensity : (N,) uint16
    rotation, phase : (N,) int64, the scan lattice
    face : (N,) int64, the scene face each return came from (the truth)
    """

    xyz: np.ndarray
    gps_time: np.ndarray
    intensity: np.ndarray
    rotation: np.ndarray
    phase: np.ndarray
    face: np.ndarray

    def __len__(self) -> int:
        return len(self.gps_time)

    @classmethod
    def concatenate(cls, parts: Sequence[Scan]) -> Scan:
        """The returns of ``parts`` one after the other (an empty scan for none)."""
        if not parts:
            empty = np.zeros(0, np.int64)
            return cls(np.zeros((0, 3)), np.zeros(0), empty.astype(np.uint16), empty, empty, empty)
        return cls(
            *(np.concatenate([getattr(p, f.name) for p in parts]) for f in dataclasses.fields(cls))
        )

    def take(self, index: np.ndarray) -> Scan:
        """The returns at ``index`` (an array of indices or a mask)."""
        return Scan(*(getattr(self, f.name)[index] for f in dataclasses.fields(self)))


def measure_returns(
    raycaster: SceneRaycaster,
    origin: np.ndarray,
    direction: np.ndarray,
    scanner: ScannerParams,
    returns: ReturnModel,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Fire pulses and keep the returns a scanner would record.

    Parameters
    ----------
    origin, direction : (M, 3) float64, the pulses' origins (metres, local frame) and unit
        directions
    scanner : its range limits and range noise
    returns : how surfaces answer (dropout, intensity)

    Returns
    -------
    index : (K,) int64, the pulses that returned
    xyz : (K, 3) float64, metres, the measured points (range noise along the beam)
    intensity : (K,) uint16
    face : (K,) int64, the scene face hit (the truth)
    """
    hits = raycaster.cast(origin, direction)
    ok = hits.hit & (hits.t >= scanner.min_range_m) & (hits.t <= scanner.max_range_m)
    idx = np.flatnonzero(ok)
    face = hits.face[idx]
    rng_m = hits.t[idx]
    cos_inc = np.abs(np.einsum("ij,ij->i", hits.normal[idx], direction[idx]))
    material = raycaster.mesh.face_material[face]
    range_factor = np.minimum(1.0, (returns.range_knee_m / rng_m) ** 2)
    signal = _REFLECTIVITY[material] * cos_inc * range_factor
    p_drop = (
        returns.base_dropout
        + _DROPOUT[material]
        + np.clip(1 - signal / returns.weak_signal, 0, 1) * 0.9
    )
    kept = rng.random(len(idx)) >= np.clip(p_drop, 0.0, 1.0)
    idx, face, rng_m, signal = idx[kept], face[kept], rng_m[kept], signal[kept]
    measured = rng_m + rng.normal(0.0, scanner.range_noise_m, len(idx))
    xyz = origin[idx] + direction[idx] * measured[:, None]
    # Intensity: square root compresses the dynamic range the way scanners report it.
    level = (
        returns.intensity_gain
        * np.sqrt(np.clip(signal, 0, 1))
        * (1 + returns.intensity_noise * rng.standard_normal(len(idx)))
    )
    intensity = np.clip(level * 65535, 0, 65535).astype(np.uint16)
    return idx, xyz, intensity, face


def rotation_chunks(
    trajectory: Trajectory, scanner: ScannerParams, rotations_per_chunk: int = 100
) -> np.ndarray:
    """(C, 2) int64: the whole rotations ``[first, end)`` scanned from ``trajectory.time[0]`` to
    ``trajectory.time[-1]``, cut every ``rotations_per_chunk`` rotations from the first."""
    ppr = scanner.points_per_rotation
    k_first = int(np.ceil((trajectory.time[0] - scanner.t0_s) * scanner.measurement_rate_hz - 1e-6))
    k_last = int(
        np.floor((trajectory.time[-1] - scanner.t0_s) * scanner.measurement_rate_hz + 1e-6)
    )
    r_first, r_last = -(-k_first // ppr), k_last // ppr  # whole rotations only
    starts = np.arange(r_first, r_last, rotations_per_chunk, dtype=np.int64)
    return np.stack([starts, np.minimum(starts + rotations_per_chunk, r_last)], axis=1)


def scan_rotations(
    raycaster: SceneRaycaster,
    trajectory: Trajectory,
    scanner: ScannerParams,
    rotations: tuple[int, int],
    rng: np.random.Generator,
    *,
    returns: ReturnModel = ReturnModel(),
) -> Scan:
    """Scan the rotations ``[first, end)`` (``scanner.t0_s`` is rotation 0's first pulse)."""
    ppr = scanner.points_per_rotation
    mount_r = scanner.T_vehicle_scanner[:3, :3]
    mount_t = scanner.T_vehicle_scanner[:3, 3]
    angles = 2 * np.pi * np.arange(ppr) / ppr
    beam_scanner = np.stack([np.zeros(ppr), np.cos(angles), np.sin(angles)], axis=1)
    beam_vehicle = beam_scanner @ mount_r.T
    k = np.arange(int(rotations[0]) * ppr, int(rotations[1]) * ppr, dtype=np.int64)
    t = scanner.t0_s + k / scanner.measurement_rate_hz
    rot_wv, pos_wv = trajectory.poses(t)
    phase = k % ppr
    origin = pos_wv + rot_wv @ mount_t
    direction = np.einsum("nij,nj->ni", rot_wv, beam_vehicle[phase])
    idx, xyz, intensity, face = measure_returns(raycaster, origin, direction, scanner, returns, rng)
    return Scan(xyz, t[idx], intensity, k[idx] // ppr, phase[idx], face)


def scan(
    raycaster: SceneRaycaster,
    trajectory: Trajectory,
    scanner: ScannerParams,
    rng: np.random.Generator | np.random.SeedSequence | int | None,
    *,
    returns: ReturnModel = ReturnModel(),
    rotations_per_chunk: int = 100,
    progress: Callable[[int], None] | None = None,
) -> Scan:
    """Scan the scene from ``trajectory.time[0]`` to ``trajectory.time[-1]``.

    Chunk c of :func:`rotation_chunks` draws its noise and dropouts from child c of ``rng``'s
    seed sequence (:func:`~guardrail_core.synth.random_streams.child_rng`), so a drive scanned
    chunk by chunk (the simulator) draws exactly what one scanned whole does.
    ``progress`` is called with the number of rotations done after each chunk.
    """
    sequence = seed_sequence(rng)
    parts = []
    for c, (r0, r1) in enumerate(rotation_chunks(trajectory, scanner, rotations_per_chunk)):
        chunk_rng = child_rng(sequence, c)
        parts.append(
            scan_rotations(raycaster, trajectory, scanner, (r0, r1), chunk_rng, returns=returns)
        )
        if progress is not None:
            progress(int(r1 - r0))
    return Scan.concatenate(parts)
