"""The profile laser scanner's parameters and its scan lattice.

A 360-degree profile scanner fires ``measurements_per_second`` pulses while its mirror turns
``rotations_per_second`` times a second. Measurement ``k`` (counted from the epoch ``t0``) is fired
at ``t0 + k / measurements_per_second``; it lies on rotation ``k // points_per_rotation`` at phase
``k % points_per_rotation``. The (rotation, phase) pair places every point on a 2D lattice whose
neighbours are neighbours on the object, which §3.1 turns into a wireframe.

A spinning multi-beam scanner (a Velodyne, as in KITTI) has a lattice too: ring x azimuth. Its
points carry no per-pulse index that a GPS time could give, so its importer stores the lattice with
the points: ``rotation`` = the frame's block of rows plus the ring (rings ordered by elevation),
``phase`` = the azimuth bin, ``points_per_rotation`` azimuth bins per turn.

References
----------
Matsumoto et al. 2019, §3.1; Kohira & Masuda 2017 (lattice from GPS time and scanner parameters).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from guardrail_core.errors import DriveFormatError
from guardrail_core.geometry import make_transform, rotation_from_euler

#: Scanner kinds: a profile scanner (one beam, a mirror turning across the road) and a spinning
#: multi-beam scanner (rings of beams turning about the vertical).
PROFILE = "profile"
MULTIBEAM = "multibeam"
SCANNER_KINDS = (PROFILE, MULTIBEAM)
#: Azimuth bins per turn of a multi-beam scanner's lattice: twice the ~2000 firings per turn of a
#: Velodyne HDL-64E at 10 Hz, so two points of a ring rarely share a bin; the wireframe's reach
#: bridges the empty bins between them.
AZIMUTH_BINS = 4096


def azimuth_phase(direction: np.ndarray, bins: int = AZIMUTH_BINS) -> np.ndarray:
    """(N,) int64 azimuth bin in ``[0, bins)`` of sensor-frame directions or points (N, 3):
    the phase of a multi-beam scanner's lattice; bin 0 starts at azimuth -pi (straight back)."""
    azimuth = np.arctan2(direction[:, 1], direction[:, 0])
    return np.clip(np.floor((azimuth + np.pi) / (2 * np.pi) * bins), 0, bins - 1).astype(np.int64)


#: Default mounting: on the roof at the rear, the rotation axis tilted 45 degrees up from the
#: driving direction so that scan lines cross vertical roadside planes obliquely, as on the
#: paper's MMS-X.
DEFAULT_MOUNT_POSITION_M = (-0.6, 0.0, 0.55)
DEFAULT_MOUNT_RPY_DEG = (0.0, -45.0, 0.0)


def scanner_mounting(
    position_m: tuple[float, float, float] = DEFAULT_MOUNT_POSITION_M,
    roll_deg: float = DEFAULT_MOUNT_RPY_DEG[0],
    pitch_deg: float = DEFAULT_MOUNT_RPY_DEG[1],
    yaw_deg: float = DEFAULT_MOUNT_RPY_DEG[2],
) -> np.ndarray:
    """``T_vehicle_scanner`` (4, 4) from a position (m, vehicle frame) and Z-Y-X angles (degrees)."""
    rotation = rotation_from_euler(np.deg2rad(roll_deg), np.deg2rad(pitch_deg), np.deg2rad(yaw_deg))
    return make_transform(rotation, position_m)


@dataclass(frozen=True)
class ScannerParams:
    """Parameters of a profile scanner (defaults: RIEGL VQ-250 as on the paper's MMS-X).

    Attributes
    ----------
    rotations_per_second : float, Hz
    measurements_per_second : float, Hz
    t0 : float, seconds (GPS time of measurement 0: the epoch of the lattice)
    range_noise_m : float, metres (1 sigma along the beam)
    min_range_m, max_range_m : float, metres
    T_vehicle_scanner : (4, 4) float64
        Scanner frame to vehicle frame. In the scanner frame the mirror turns about +x and the beam
        of phase p points along ``(0, cos a, sin a)`` with ``a = 2 pi p / points_per_rotation``.
    kind : str, :data:`PROFILE` or :data:`MULTIBEAM`
    rings : int, beams of a multi-beam scanner (0 for a profile scanner). Its lattice rows are
        rings and its phases azimuth bins; the lattice is stored with the points.
    """

    rotations_per_second: float = 100.0
    measurements_per_second: float = 300_000.0
    t0: float = 0.0
    range_noise_m: float = 0.005
    min_range_m: float = 1.5
    max_range_m: float = 120.0
    T_vehicle_scanner: np.ndarray = field(default_factory=scanner_mounting)
    kind: str = PROFILE
    rings: int = 0

    def __post_init__(self) -> None:
        if self.kind not in SCANNER_KINDS:
            raise DriveFormatError(
                f"scanner: kind must be one of {', '.join(SCANNER_KINDS)}, got {self.kind!r}"
            )
        if self.kind == MULTIBEAM and self.rings < 1:
            raise DriveFormatError(
                f"scanner: a multi-beam scanner needs rings >= 1, got {self.rings}"
            )
        ratio = self.measurements_per_second / self.rotations_per_second
        if self.rotations_per_second <= 0 or abs(ratio - round(ratio)) > 1e-9 or ratio < 1:
            raise DriveFormatError(
                "scanner: measurements_per_second must be a positive whole multiple of "
                f"rotations_per_second, got {self.measurements_per_second} and "
                f"{self.rotations_per_second}"
            )

    @property
    def points_per_rotation(self) -> int:
        return int(round(self.measurements_per_second / self.rotations_per_second))

    def measurement_index(self, gps_time: np.ndarray) -> np.ndarray:
        """Measurement number k (N,) int64 of each GPS time (N,) seconds."""
        return np.rint(
            (np.asarray(gps_time, np.float64) - self.t0) * self.measurements_per_second
        ).astype(np.int64)

    def lattice_from_gps_time(self, gps_time: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The scan lattice of points from their GPS times (§3.1).

        Returns
        -------
        rotation : (N,) int64, the mirror rotation the point was measured on
        phase : (N,) int64, the pulse number within that rotation, in [0, points_per_rotation)

        Raises
        ------
        DriveFormatError
            A multi-beam scanner: its lattice cannot follow from time and must be stored.
        """
        if self.kind != PROFILE:
            raise DriveFormatError(
                f"scanner: the lattice of a {self.kind} scanner does not follow from GPS time; "
                "its point cloud must store the rotation and phase dimensions"
            )
        k = self.measurement_index(gps_time)
        return np.divmod(k, self.points_per_rotation)

    def gps_time_of(self, rotation: np.ndarray, phase: np.ndarray) -> np.ndarray:
        """GPS time (N,) seconds of lattice cells (rotation, phase)."""
        k = np.asarray(rotation, np.int64) * self.points_per_rotation + np.asarray(phase, np.int64)
        return self.t0 + k / self.measurements_per_second

    def to_json(self) -> dict:
        if self.kind == MULTIBEAM:
            beams = (
                "multi-beam: rotation = frame block + ring (by elevation), phase = azimuth bin of "
                "points_per_rotation per turn; stored with the points"
            )
        else:
            beams = "scanner frame (0, cos a, sin a), a = 2 pi phase / points_per_rotation"
        return {
            "kind": self.kind,
            "rings": self.rings,
            "rotations_per_second": self.rotations_per_second,
            "measurements_per_second": self.measurements_per_second,
            "t0": self.t0,
            "range_noise_m": self.range_noise_m,
            "min_range_m": self.min_range_m,
            "max_range_m": self.max_range_m,
            "T_vehicle_scanner": np.asarray(self.T_vehicle_scanner).tolist(),
            "beam_direction": beams,
        }

    @classmethod
    def from_json(cls, data: dict) -> ScannerParams:
        try:
            transform = np.asarray(data["T_vehicle_scanner"], np.float64)
            if transform.shape != (4, 4) or not np.all(np.isfinite(transform)):
                raise DriveFormatError("scanner.T_vehicle_scanner must be a finite 4x4 matrix")
            return cls(
                rotations_per_second=float(data["rotations_per_second"]),
                measurements_per_second=float(data["measurements_per_second"]),
                t0=float(data["t0"]),
                range_noise_m=float(data.get("range_noise_m", 0.005)),
                min_range_m=float(data.get("min_range_m", 0.0)),
                max_range_m=float(data.get("max_range_m", np.inf)),
                T_vehicle_scanner=transform,
                kind=str(data.get("kind", PROFILE)),
                rings=int(data.get("rings", 0)),
            )
        except KeyError as exc:
            raise DriveFormatError(f"drive.json: scanner lacks the key {exc.args[0]!r}") from exc
        except (TypeError, ValueError) as exc:
            raise DriveFormatError(
                f"drive.json: scanner has a value of the wrong type: {exc}"
            ) from exc
