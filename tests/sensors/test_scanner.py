"""The scanner model: the lattice arithmetic, the mounting's scan lines, noise and intensity."""

from __future__ import annotations

import numpy as np
import pytest

from guardrail_core.errors import DriveFormatError
from guardrail_core.geom.mesh import box
from guardrail_core.params import ParameterError
from guardrail_core.sensors.scanner import ScannerParams, scanner_mounting
from guardrail_core.sensors.trajectory import Trajectory
from guardrail_core.synth.mesh import MeshBuilder
from guardrail_core.synth.raycast import SceneRaycaster
from guardrail_core.synth.scanner import ReturnModel, scan

WALL_Y = 4.0  # a wall 4 m to the vehicle's left, along its path


def _wall_scene(material: str = "concrete") -> SceneRaycaster:
    builder = MeshBuilder()
    builder.add(
        box([50.0, WALL_Y + 0.1, 1.0], [120.0, 0.2, 6.0]), cls=9, object_id=1, material=material
    )
    return SceneRaycaster(builder.build())


def _straight_drive(seconds: float = 0.2, speed: float = 10.0) -> Trajectory:
    t = 1000.0 + np.arange(0.0, seconds + 1e-9, 0.01)
    position = np.stack([5.0 + speed * (t - t[0]), np.zeros_like(t), np.full_like(t, 1.8)], axis=1)
    return Trajectory(time=t, position=position, attitude=np.zeros((len(t), 3)))


def _scan_lines_slope(pitch_deg: float) -> float:
    """Median d(along)/d(height) of each rotation's points on the wall."""
    scanner = ScannerParams(t0_s=1000.0, T_vehicle_scanner=scanner_mounting(pitch_deg=pitch_deg))
    result = scan(_wall_scene(), _straight_drive(), scanner, np.random.default_rng(0))
    on_wall = np.abs(result.xyz[:, 1] - WALL_Y) < 0.05
    slopes = []
    for r in np.unique(result.rotation[on_wall]):
        pts = result.xyz[on_wall & (result.rotation == r)]
        if np.ptp(pts[:, 2]) > 1.0:
            slopes.append(np.polyfit(pts[:, 2], pts[:, 0], 1)[0])
    assert len(slopes) >= 10
    return float(np.median(slopes))


def test_lattice_arithmetic_round_trips() -> None:
    scanner = ScannerParams(t0_s=345_600.0)
    k = np.array([0, 1, 2999, 3000, 123_456_789])
    t = scanner.t0_s + k / scanner.measurement_rate_hz
    rotation, phase = scanner.lattice_from_gps_time(t)
    np.testing.assert_array_equal(rotation, k // 3000)
    np.testing.assert_array_equal(phase, k % 3000)
    np.testing.assert_allclose(scanner.gps_time_of(rotation, phase), t, rtol=0, atol=1e-9)


def test_rates_that_make_no_lattice_are_refused() -> None:
    with pytest.raises(ParameterError, match="whole multiple"):
        ScannerParams(rotation_rate_hz=100.0, measurement_rate_hz=150_050.0)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"rotation_rate_hz": 0.0}, "rotation_rate_hz must lie within"),
        ({"range_noise_m": -0.001}, "range_noise_m must lie within"),
        ({"min_range_m": 200.0}, "min_range_m .* must lie below max_range_m"),
        ({"kind": "flash"}, "kind must be one of"),
        ({"kind": "multibeam"}, "needs rings >= 1"),
        ({"T_vehicle_scanner": np.eye(3)}, "finite 4x4 matrix"),
    ],
)
def test_scanner_params_out_of_range_are_named(changes: dict, message: str) -> None:
    with pytest.raises(ParameterError, match=message):
        ScannerParams(**changes)


def test_drive_json_scanner_round_trips_under_the_formats_names() -> None:
    scanner = ScannerParams(t0_s=345_600.0, range_noise_m=0.01)
    data = scanner.to_json()
    assert {"rotations_per_second", "measurements_per_second", "t0"} <= set(data)
    assert not {"rotation_rate_hz", "measurement_rate_hz", "t0_s"} & set(data)
    assert ScannerParams.from_json(data).to_json() == data
    with pytest.raises(DriveFormatError, match="whole multiple"):
        ScannerParams.from_json(data | {"measurements_per_second": 150_050.0})
    # Every key is required: drive format 2.0 has always written them all.
    for key in sorted(set(data) - {"beam_direction"}):
        with pytest.raises(DriveFormatError, match=f"lacks the key '{key}'"):
            ScannerParams.from_json({k: v for k, v in data.items() if k != key})


@pytest.mark.parametrize(
    ("pitch_deg", "slope"), [(0.0, 0.0), (-45.0, -1.0), (-30.0, -np.tan(np.deg2rad(30)))]
)
def test_mounting_pitch_sets_the_slope_of_the_scan_lines(pitch_deg: float, slope: float) -> None:
    # A scan plane tilted by the mounting pitch meets a vertical wall along lines of that slope
    # (plus the ~1 cm the vehicle moves while the beam sweeps the wall).
    assert _scan_lines_slope(pitch_deg) == pytest.approx(slope, abs=0.05)


def test_range_noise_and_one_return_per_pulse() -> None:
    scanner = ScannerParams(t0_s=1000.0, range_noise_m=0.005)
    result = scan(_wall_scene(), _straight_drive(), scanner, np.random.default_rng(1))
    on_wall = np.abs(result.xyz[:, 1] - WALL_Y) < 0.05
    # Off-plane scatter of wall points: the along-beam noise projected on the wall's normal.
    assert 0.002 < np.std(result.xyz[on_wall, 1] - WALL_Y) < 0.006
    k = scanner.measurement_index(result.gps_time)
    assert np.all(np.diff(k) > 0)


def test_intensity_follows_reflectivity() -> None:
    scanner = ScannerParams(t0_s=1000.0)
    bright = scan(_wall_scene("white"), _straight_drive(), scanner, np.random.default_rng(2))
    dark = scan(_wall_scene("rubber"), _straight_drive(), scanner, np.random.default_rng(2))
    assert np.median(bright.intensity) > 2 * np.median(dark.intensity)
    assert len(dark.xyz) < len(bright.xyz)  # weak returns drop out


def test_intensity_gain_scales_every_intensity_and_dropout_thins_the_returns() -> None:
    scanner = ScannerParams(t0_s=1000.0)
    wall, drive = _wall_scene("concrete"), _straight_drive()
    calibrated = scan(wall, drive, scanner, np.random.default_rng(3))
    # The same seed draws the same dropouts and noise: only the intensities change.
    dim = scan(
        wall, drive, scanner, np.random.default_rng(3), returns=ReturnModel(intensity_gain=0.5)
    )
    np.testing.assert_array_equal(dim.xyz, calibrated.xyz)
    strong = calibrated.intensity > 2000
    assert strong.mean() > 0.9
    ratio = dim.intensity[strong] / calibrated.intensity[strong].astype(float)
    np.testing.assert_allclose(ratio, 0.5, atol=1e-3)

    sparse = scan(
        wall, drive, scanner, np.random.default_rng(3), returns=ReturnModel(base_dropout=0.3)
    )
    # A wall at 4 m loses almost nothing to a weak signal: the extra 29 % goes.
    assert len(sparse) / len(calibrated) == pytest.approx(0.71 / 0.99, abs=0.02)
