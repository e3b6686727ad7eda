"""The simulated van's camera rig: a forward camera and two side cameras on the roof.

The vehicle frame's origin is the trajectory reference point, about 1.8 m above the road, so
roof cameras at z ~ +0.6 m sit ~2.4 m above it. The side cameras are yawed ~75-80 degrees toward
the front and pitched ~10 degrees down so roadside guardrails 2-8 m away on either side fill a
good part of the frame (Matsumoto et al. 2019, §3.2 crops images around projected points).

Intrinsics are those of a wide lens: horizontal FOV ~85-90 degrees with visible barrel
distortion that stays monotonic (hence invertible) over the whole sensor. Each camera has its
own, slightly different calibration, as real units do.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from guardrail_core.geom.frames import make_transform, rotation_from_euler
from guardrail_core.sensors.camera import Camera

#: Camera axes (OpenCV: x right, y down, z forward) in the vehicle frame (x fwd, y left, z up)
#: for a camera looking straight ahead: columns are the camera's x, y, z axes.
_R_VEHICLE_FORWARD_CAMERA = np.array(
    [
        [0.0, 0.0, 1.0],
        [-1.0, 0.0, 0.0],
        [0.0, -1.0, 0.0],
    ]
)


@dataclass(frozen=True)
class CameraMount:
    """Nominal calibration of one rig camera, resolution-independent.

    Attributes
    ----------
    name : str
    position_m : (3,) vehicle-frame position of the optical centre, metres
    yaw_deg : float, left of forward is positive (about vehicle z)
    pitch_down_deg : float, optical axis below the horizontal
    roll_deg : float, small mounting roll about the optical axis
    focal_rel : float, fx / width (fy = fx * aspect_px)
    aspect_px : float, fy / fx (pixel aspect, ~1)
    principal_offset_rel : (2,) principal point offset from the sensor centre, / width and / height
    dist : (5,) Brown-Conrady k1, k2, p1, p2, k3 (OpenCV order)
    """

    name: str
    position_m: tuple[float, float, float]
    yaw_deg: float
    pitch_down_deg: float
    roll_deg: float
    focal_rel: float
    aspect_px: float
    principal_offset_rel: tuple[float, float]
    dist: tuple[float, float, float, float, float]


#: The rig. fx ~ 0.62 * width gives a ~88 degree horizontal FOV once barrel distortion is counted.
RIG_MOUNTS: tuple[CameraMount, ...] = (
    CameraMount(
        name="front",
        position_m=(0.95, 0.02, 0.62),
        yaw_deg=0.4,
        pitch_down_deg=8.0,
        roll_deg=0.2,
        focal_rel=0.625,
        aspect_px=1.0005,
        principal_offset_rel=(0.0086, -0.0071),
        dist=(-0.252, 0.081, 0.0006, -0.0004, -0.0102),
    ),
    CameraMount(
        name="left",
        position_m=(0.55, 0.58, 0.60),
        yaw_deg=78.0,
        pitch_down_deg=10.0,
        roll_deg=-0.3,
        focal_rel=0.618,
        aspect_px=0.9996,
        principal_offset_rel=(-0.0061, 0.0094),
        dist=(-0.247, 0.077, -0.0005, 0.0007, -0.0095),
    ),
    CameraMount(
        name="right",
        position_m=(0.55, -0.57, 0.59),
        yaw_deg=-76.5,
        pitch_down_deg=10.5,
        roll_deg=0.25,
        focal_rel=0.622,
        aspect_px=1.0003,
        principal_offset_rel=(0.0052, 0.0063),
        dist=(-0.256, 0.084, 0.0004, 0.0005, -0.0108),
    ),
)


def mount_rotation(yaw_deg: float, pitch_down_deg: float, roll_deg: float) -> np.ndarray:
    """``R_vehicle_camera`` (3, 3) for a camera yawed left, pitched down and rolled (degrees).

    Pitch and yaw act on the vehicle axes (pitch first, about y; ``Ry(+a)`` tilts x down since
    z is up), roll about the camera's own optical axis.
    """
    r_mount = rotation_from_euler(0.0, np.radians(pitch_down_deg), np.radians(yaw_deg))
    c, s = np.cos(np.radians(roll_deg)), np.sin(np.radians(roll_deg))
    r_roll = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # about camera z
    return r_mount @ _R_VEHICLE_FORWARD_CAMERA @ r_roll


def camera_from_mount(mount: CameraMount, *, width: int, height: int) -> Camera:
    """A :class:`Camera` of ``width`` x ``height`` pixels built from a :class:`CameraMount`."""
    fx = mount.focal_rel * width
    fy = fx * mount.aspect_px
    # Pixel centres at integer coordinates: the sensor centre is at ((W-1)/2, (H-1)/2).
    cx = (width - 1) / 2 + mount.principal_offset_rel[0] * width
    cy = (height - 1) / 2 + mount.principal_offset_rel[1] * height
    k = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    rotation = mount_rotation(mount.yaw_deg, mount.pitch_down_deg, mount.roll_deg)
    return Camera(
        name=mount.name,
        width=int(width),
        height=int(height),
        K=k,
        dist=np.array(mount.dist, dtype=np.float64),
        T_vehicle_camera=make_transform(rotation, np.array(mount.position_m, dtype=np.float64)),
    )


def default_camera_rig(*, width: int = 1024, height: int = 768) -> list[Camera]:
    """The van's three roof cameras, ``front``, ``left`` and ``right``, at ``width`` x ``height``.

    Intrinsics scale with the resolution, so a smaller rig (for tests) sees the same field.
    """
    return [camera_from_mount(m, width=width, height=height) for m in RIG_MOUNTS]
