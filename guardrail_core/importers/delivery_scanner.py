"""The scanner of a LAS/LAZ delivery, and the scan lattice (§3.1) its points' GPS times give.

A profile scanner measures at a fixed rate while its mirror turns at a fixed rate, both locked to
an epoch ``t0``: a point's time then names its rotation (the scan line) and its phase (the
position along the line), the lattice on which extraction finds neighbours.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from guardrail_core.errors import InvalidOptionError, SourceFormatError
from guardrail_core.importers.calibration import mount_transform, read_structured_file
from guardrail_core.importers.delivery_sources import PathLike
from guardrail_core.params import ParameterError
from guardrail_core.sensors.scanner import DRIVE_JSON_KEYS, ScannerParams, scanner_mounting

#: A point is off the scanner's measurement grid when its time lies further than this (in
#: measurement intervals) from the nearest pulse; more than OFF_GRID_NOTE_FRACTION such points
#: suggest wrong scanner rates or epoch.
OFF_GRID_TOLERANCE = 0.25
OFF_GRID_NOTE_FRACTION = 0.05
_SCANNER_FLOAT_KEYS = ("range_noise_m", "min_range_m", "max_range_m")


def read_scanner_file(path: PathLike) -> dict:
    """Scanner parameters from JSON or YAML: the keys of ``ScannerParams.to_json`` (a drive's
    ``drive.json`` works too: its ``scanner`` block is used)."""
    path = Path(path)
    data = read_structured_file(path, "scanner parameters")
    if isinstance(data, Mapping) and isinstance(data.get("scanner"), Mapping):
        data = data["scanner"]
    if not isinstance(data, Mapping):
        raise SourceFormatError(f"{path}: expected a mapping of scanner parameters")
    return dict(data)


def scanner_params(fields: Mapping, first_gps_time: float, where: str = "scanner") -> ScannerParams:
    """:class:`ScannerParams` of a profile scanner from a mapping of its fields.

    ``rotation_rate_hz`` and ``measurement_rate_hz`` are required. ``t0_s`` (GPS seconds)
    defaults to ``first_gps_time`` rounded down to a whole second: the epoch of a scanner whose
    mirror is synchronised to the GPS pulse per second (and whose rotations per second are whole).
    ``T_vehicle_scanner`` is 16 or 6 numbers (:func:`mount_transform`), default the simulator's
    mount. ``range_noise_m``, ``min_range_m``, ``max_range_m`` default to ScannerParams'.
    ``drive.json``'s names of the rates and epoch (:data:`DRIVE_JSON_KEYS`:
    ``rotations_per_second``, ``measurements_per_second``, ``t0``) are read too, so that a
    drive's ``scanner`` block serves as a scanner file (:func:`read_scanner_file`).
    """
    fields = {DRIVE_JSON_KEYS.get(key, key): value for key, value in fields.items()}
    kind = str(fields.get("kind", "profile"))
    if kind != "profile":
        raise SourceFormatError(
            f"{where}: a {kind} scanner's lattice does not follow from GPS time; a LAS delivery "
            "needs a profile scanner (kind: profile)"
        )
    missing = [
        key for key in ("rotation_rate_hz", "measurement_rate_hz") if fields.get(key) is None
    ]
    if missing:
        raise InvalidOptionError(
            f"{where}: the scan lattice needs the scanner's {' and '.join(missing)}; give them "
            "in a scanner file (--scanner) or as --rotations-per-second and "
            "--measurements-per-second"
        )
    try:
        rotations = float(fields["rotation_rate_hz"])
        measurements = float(fields["measurement_rate_hz"])
        t0 = fields.get("t0_s")
        epoch = float(t0) if t0 is not None else float(math.floor(first_gps_time))
        # Absent ranges keep ScannerParams' defaults (class attributes of the dataclass).
        ranges = {k: float(fields.get(k, getattr(ScannerParams, k))) for k in _SCANNER_FLOAT_KEYS}
    except (TypeError, ValueError) as exc:
        raise SourceFormatError(f"{where}: a scanner parameter is not a number ({exc})") from exc
    mount = fields.get("T_vehicle_scanner")
    transform = (
        scanner_mounting()
        if mount is None
        else mount_transform(mount, f"{where}: T_vehicle_scanner")
    )
    try:
        return ScannerParams(
            rotation_rate_hz=rotations,
            measurement_rate_hz=measurements,
            t0_s=epoch,
            range_noise_m=ranges["range_noise_m"],
            min_range_m=ranges["min_range_m"],
            max_range_m=ranges["max_range_m"],
            T_vehicle_scanner=transform,
        )
    except ParameterError as exc:
        raise SourceFormatError(f"{where}: {exc}") from exc


def scan_lattice(
    scanner: ScannerParams, gps_time: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int]:
    """Rotation (N,) int64, phase (N,) int64 and the number of points off the pulse grid, of
    points at GPS times (N,) s; called chunk by chunk, so the counts add up over a delivery.

    Raises
    ------
    InvalidOptionError
        The epoch ``t0`` lies after a point, or more than 2^32 rotations before one.
    """
    rotation, phase = scanner.lattice_from_gps_time(gps_time)
    if len(gps_time) == 0:
        return rotation, phase, 0
    if rotation.min() < 0 or rotation.max() >= 2**32:
        raise InvalidOptionError(
            f"scanner t0 {scanner.t0_s:.6f} s gives rotations {int(rotation.min())}.."
            f"{int(rotation.max())}: the epoch must lie at or before the first point "
            f"({float(gps_time.min()):.6f} s) and within 2^32 rotations of the last"
        )
    pulses = (gps_time - scanner.t0_s) * scanner.measurement_rate_hz
    off_grid = int(np.count_nonzero(np.abs(pulses - np.rint(pulses)) > OFF_GRID_TOLERANCE))
    return rotation, phase, off_grid
