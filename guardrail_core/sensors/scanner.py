"""The profile laser scanner's parameters and its scan lattice.

A 360-degree profile scanner fires ``measurement_rate_hz`` pulses a second while its mirror turns
``rotation_rate_hz`` times a second. Measurement ``k`` (counted from the epoch ``t0_s``) is fired
at ``t0_s + k / measurement_rate_hz``; it lies on rotation ``k // points_per_rotation`` at phase
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

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from guardrail_core.errors import DriveFormatError
from guardrail_core.geom.frames import make_transform, rotation_from_euler
from guardrail_core.params import ParameterError, StageParams, param

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

#: ``drive.json``'s keys for the scanner's rates and epoch -> the fields of
#: :class:`ScannerParams`. The file has named them so since drive format 1.0 and keeps them
#: (renaming a key is an incompatible change, a new major version); only the fields carry a unit.
DRIVE_JSON_KEYS: Mapping[str, str] = {
    "rotations_per_second": "rotation_rate_hz",
    "measurements_per_second": "measurement_rate_hz",
    "t0": "t0_s",
}


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
class ScannerParams(StageParams):
    """Parameters of a laser scanner (defaults: a RIEGL VQ-250 profile scanner as on the paper's
    MMS-X).

    ``T_vehicle_scanner`` (4, 4) float64 takes the scanner frame to the vehicle frame. In the
    scanner frame the mirror turns about +x and the beam of phase p points along
    ``(0, cos a, sin a)`` with ``a = 2 pi p / points_per_rotation``.
    """

    rotation_rate_hz: float = param(
        100.0, unit="Hz", gt=0, le=1000, doc="turns of the mirror (or of the head) per second"
    )
    measurement_rate_hz: float = param(
        300_000.0,
        unit="Hz",
        gt=0,
        le=1e8,
        doc="pulses per second; a whole multiple of rotation_rate_hz",
    )
    t0_s: float = param(
        0.0, unit="s", doc="GPS time of measurement 0: the epoch of the scan lattice"
    )
    range_noise_m: float = param(
        0.005, unit="m", ge=0, le=1, doc="1 sigma of the range noise along the beam"
    )
    min_range_m: float = param(1.5, unit="m", ge=0, le=1000, doc="nearest return recorded")
    max_range_m: float = param(
        120.0, unit="m", gt=0, finite=False, doc="farthest return recorded (inf: no limit)"
    )
    T_vehicle_scanner: np.ndarray = field(default_factory=scanner_mounting)
    kind: str = param(PROFILE, choices=SCANNER_KINDS, doc="profile or multibeam")
    rings: int = param(
        0,
        ge=0,
        le=1024,
        doc="beams of a multi-beam scanner (0 for a profile scanner); its lattice rows are rings "
        "and its phases azimuth bins, stored with the points",
    )

    def check_relations(self) -> None:
        if self.kind == MULTIBEAM and self.rings < 1:
            self.fail(f"a multi-beam scanner needs rings >= 1, got {self.rings}")
        ratio = self.measurement_rate_hz / self.rotation_rate_hz
        if abs(ratio - round(ratio)) > 1e-9 or ratio < 1:
            self.fail(
                "measurement_rate_hz must be a positive whole multiple of rotation_rate_hz, got "
                f"{self.measurement_rate_hz} and {self.rotation_rate_hz}"
            )
        if self.min_range_m >= self.max_range_m:
            self.fail(
                f"min_range_m ({self.min_range_m} m) must lie below max_range_m "
                f"({self.max_range_m} m)"
            )
        transform = np.asarray(self.T_vehicle_scanner)
        if transform.shape != (4, 4) or not np.all(np.isfinite(transform)):
            self.fail(f"T_vehicle_scanner must be a finite 4x4 matrix, got shape {transform.shape}")

    @property
    def points_per_rotation(self) -> int:
        return int(round(self.measurement_rate_hz / self.rotation_rate_hz))

    def measurement_index(self, gps_time: np.ndarray) -> np.ndarray:
        """Measurement number k (N,) int64 of each GPS time (N,) seconds."""
        return np.rint(
            (np.asarray(gps_time, np.float64) - self.t0_s) * self.measurement_rate_hz
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
        return self.t0_s + k / self.measurement_rate_hz

    def to_json(self) -> dict[str, Any]:
        """The ``scanner`` block of ``drive.json`` (the matrix as nested lists, and a note of
        the beam directions)."""
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
            # the format's names for these three (DRIVE_JSON_KEYS), not the fields'
            "rotations_per_second": self.rotation_rate_hz,
            "measurements_per_second": self.measurement_rate_hz,
            "t0": self.t0_s,
            "range_noise_m": self.range_noise_m,
            "min_range_m": self.min_range_m,
            "max_range_m": self.max_range_m,
            "T_vehicle_scanner": np.asarray(self.T_vehicle_scanner).tolist(),
            "beam_direction": beams,
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> ScannerParams:
        """The scanner of a ``drive.json`` block (:meth:`to_json`), under the format's key
        names (:data:`DRIVE_JSON_KEYS`). Every key :meth:`to_json` writes is required but
        ``beam_direction``, a note for people: drive format 2.0 has always written them all.

        Raises
        ------
        DriveFormatError
            A key missing, a value of the wrong type, or a value :class:`ScannerParams` refuses.
        """
        if not isinstance(data, Mapping):
            raise DriveFormatError(f"drive.json: expected the scanner as an object, got {data!r}")
        try:
            return cls(
                rotation_rate_hz=float(data["rotations_per_second"]),
                measurement_rate_hz=float(data["measurements_per_second"]),
                t0_s=float(data["t0"]),
                range_noise_m=float(data["range_noise_m"]),
                min_range_m=float(data["min_range_m"]),
                max_range_m=float(data["max_range_m"]),
                T_vehicle_scanner=np.asarray(data["T_vehicle_scanner"], np.float64),
                kind=str(data["kind"]),
                rings=int(data["rings"]),
            )
        except KeyError as exc:
            raise DriveFormatError(f"drive.json: scanner lacks the key {exc.args[0]!r}") from exc
        except (TypeError, ValueError) as exc:
            raise DriveFormatError(
                f"drive.json: scanner has a value of the wrong type: {exc}"
            ) from exc
        except ParameterError as exc:
            raise DriveFormatError(f"drive.json: scanner: {exc}") from exc


def imported_multibeam(
    rotation_hz: float, t0_s: float, rings: int, max_range_m: float
) -> ScannerParams:
    """The scanner of frames imported from a spinning LiDAR: ``rings`` beams turning
    ``rotation_hz`` times a second from ``t0_s`` (GPS s), the vehicle frame its own, the
    lattice's azimuth in :data:`AZIMUTH_BINS` bins, 2 cm range noise, returns to
    ``max_range_m``."""
    return ScannerParams(
        rotation_rate_hz=rotation_hz,
        measurement_rate_hz=rotation_hz * AZIMUTH_BINS,
        t0_s=t0_s,
        range_noise_m=0.02,
        min_range_m=0.0,
        max_range_m=max_range_m,
        T_vehicle_scanner=np.eye(4),
        kind=MULTIBEAM,
        rings=rings,
    )
