"""The mapping vehicle's motion: speed, lane keeping and attitude along the road."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from guardrail_core.params import StageParams, param
from guardrail_core.sensors.trajectory import Trajectory
from guardrail_core.synth.road import Road


@dataclass(frozen=True)
class VehicleParams(StageParams):
    """How the vehicle drives."""

    speed_mps: tuple[float, float] = param(
        (8.0, 12.0),
        unit="m/s",
        gt=0,
        le=60,
        doc="(min, max); the speed wanders smoothly between them",
    )
    lane: int = param(
        0, ge=0, le=20, doc="lane index counted from the left edge of the carriageway (0: leftmost)"
    )
    wander_m: float = param(
        0.15, unit="m", ge=0, le=5, doc="amplitude of the lateral wander inside the lane"
    )
    reference_height_m: float = param(
        1.8, unit="m", gt=0, le=10, doc="height of the vehicle origin (IMU) above the road"
    )
    rate_hz: float = param(100.0, unit="Hz", gt=0, le=10_000, doc="trajectory sampling rate")
    vibration_deg: float = param(
        0.08, unit="deg", ge=0, le=10, doc="1 sigma of the body's roll and pitch vibration"
    )
    body_roll_per_mps2: float = param(
        0.006,
        unit="rad/(m/s^2)",
        ge=-1,
        le=1,
        doc="body roll per m/s^2 of lateral acceleration",
    )

    def check_relations(self) -> None:
        low, high = self.speed_mps
        if not 0 < low <= high <= 60:
            self.fail(
                f"speed_mps must be (min, max) with 0 < min <= max <= 60, got {self.speed_mps}"
            )


def _smooth_noise(n: int, dt: float, period_s: float, rng: np.random.Generator) -> np.ndarray:
    """Zero-mean noise (n,) of unit standard deviation, smooth over ``period_s`` seconds."""
    width = max(1, int(period_s / dt))
    kernel = np.hanning(2 * width + 1)
    noise = np.convolve(rng.standard_normal(n + 2 * width), kernel / kernel.sum(), mode="same")[
        width:-width
    ]
    return noise / max(noise.std(), 1e-12)


def drive_along(
    road: Road,
    params: VehicleParams,
    *,
    s_start: float,
    s_end: float,
    t0: float,
    rng: np.random.Generator,
) -> Trajectory:
    """Drive the road from ``s_start`` to ``s_end`` metres; returns the sampled trajectory."""
    v_lo, v_hi = params.speed_mps
    dt = 1.0 / params.rate_hz
    n = int(np.ceil((s_end - s_start) / v_lo / dt)) + 2
    t = np.arange(n) * dt
    # Speed: a slow wave between the limits, as in traffic.
    phase = rng.uniform(0, 2 * np.pi, 2)
    wave = (
        0.5
        + 0.35 * np.sin(2 * np.pi * t / 23.0 + phase[0])
        + 0.15 * np.sin(2 * np.pi * t / 7.0 + phase[1])
    )
    speed = v_lo + (v_hi - v_lo) * np.clip(wave, 0.0, 1.0)
    s = s_start + np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * dt)])
    keep = np.searchsorted(s, s_end) + 1
    t, s, speed = t[:keep], s[:keep], speed[:keep]
    n = len(t)

    lane_centre = -road.half_width + (params.lane + 0.5) * road.spec.lane_width
    lateral = lane_centre + params.wander_m * _smooth_noise(n, dt, 3.0, rng) / 2
    ground = road.point(s, lateral)
    _, tangent, _ = road.frame(s)
    position = ground.copy()
    position[:, 2] += params.reference_height_m + 0.004 * _smooth_noise(n, dt, 0.15, rng)

    # Yaw follows the path (the road heading plus the slope of the lateral wander).
    dlat_ds = np.gradient(lateral, s)
    yaw = np.arctan2(tangent[:, 1], tangent[:, 0]) + np.arctan(dlat_ds)
    # Pitch from the road's longitudinal slope (nose up on a climb is negative pitch here).
    slope = np.gradient(road.centre_height(s), s)
    vib = np.deg2rad(params.vibration_deg)
    pitch = -np.arctan(slope) + vib * _smooth_noise(n, dt, 0.3, rng)
    # Roll from the crown under the wheels and the body leaning out of curves.
    cross = -road.spec.crown_slope * np.sign(lateral)
    curvature = np.gradient(np.unwrap(yaw), s)
    roll = (
        np.arctan(cross)
        + params.body_roll_per_mps2 * speed**2 * curvature
        + vib * _smooth_noise(n, dt, 0.3, rng)
    )
    attitude = np.stack([roll, pitch, np.angle(np.exp(1j * yaw))], axis=1)
    return Trajectory(
        time=t0 + t,
        position=position,
        attitude=attitude,
        reference_height_m=params.reference_height_m,
    )
