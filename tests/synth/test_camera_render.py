"""Tests of the camera rig and the ray-traced renderer (image + truth mask)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from guardrail_core.classes import TruthClass
from guardrail_core.geom.frames import make_transform, rotation_from_euler, transform_points
from guardrail_core.geom.mesh import box, grid_surface, sphere
from guardrail_core.sensors.camera import Camera
from guardrail_core.synth.camera_render import (
    Lighting,
    random_lighting,
    random_night_lighting,
    render_image,
)
from guardrail_core.synth.camera_rig import default_camera_rig
from guardrail_core.synth.mesh import MeshBuilder
from guardrail_core.synth.raycast import SceneRaycaster

SMALL = {"width": 320, "height": 240}
#: Vehicle pose: reference point 1.8 m above the road, heading slightly off the x axis.
T_WORLD_VEHICLE = make_transform(rotation_from_euler(0.0, 0.0, 0.2), np.array([3.0, -2.0, 1.8]))


def sunny(sun_azimuth_deg: float = -90.0, sun_elevation_deg: float = 40.0) -> Lighting:
    az, el = np.radians(sun_azimuth_deg), np.radians(sun_elevation_deg)
    return Lighting(
        sun_direction=(np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)),
        sun_intensity=1.0,
        ambient=0.25,
        sky_zenith=(0.17, 0.34, 0.78),
        sky_horizon=(0.72, 0.80, 0.90),
        exposure=1.0,
        white_balance=(1.0, 1.0, 1.0),
        haze_distance_m=400.0,
    )


def ground(builder: MeshBuilder, *, half_size: float = 150.0, material: str = "asphalt") -> None:
    """A flat road at z = 0, subdivided a little (large triangles are fine for Open3D too)."""
    xs = np.linspace(-half_size, half_size, 9)
    x, y = np.meshgrid(xs, xs, indexing="ij")
    pts = np.stack([x, y, np.zeros_like(x)], axis=-1)
    builder.add(grid_surface(pts), cls=TruthClass.ROAD, object_id=0, material=material)


def world_camera(camera: Camera) -> np.ndarray:
    return T_WORLD_VEHICLE @ camera.T_vehicle_camera


def luminance(image: np.ndarray, uv: np.ndarray, half: int = 2) -> float:
    u, v = np.round(uv).astype(int)
    patch = image[v - half : v + half + 1, u - half : u + half + 1].astype(np.float64)
    return float((patch @ [0.2126, 0.7152, 0.0722]).mean())


@pytest.fixture(scope="module")
def small_rig() -> list[tuple[Camera, np.ndarray]]:
    return [(cam, cam.pixel_rays()) for cam in default_camera_rig(**SMALL)]


@pytest.fixture(scope="module")
def full_rig() -> list[tuple[Camera, np.ndarray]]:
    return [(cam, cam.pixel_rays()) for cam in default_camera_rig()]


# ---------------------------------------------------------------------------------------------
# Rig
# ---------------------------------------------------------------------------------------------


def test_rig_layout(full_rig):
    cams = {cam.name: cam for cam, _ in full_rig}
    assert set(cams) == {"front", "left", "right"}
    for cam in cams.values():
        assert (cam.width, cam.height) == (1024, 768)
        r = cam.T_vehicle_camera[:3, :3]
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(r) == pytest.approx(1.0)
        assert 0.5 <= cam.T_vehicle_camera[2, 3] <= 0.7  # on the roof
        # Principal point off-centre, but only slightly.
        off = cam.K[:2, 2] - [(cam.width - 1) / 2, (cam.height - 1) / 2]
        assert 0.5 < np.abs(off).max() < 0.02 * cam.width
        axis = r[:, 2]
        pitch_down = np.degrees(np.arcsin(-axis[2]))
        assert 6.0 <= pitch_down <= 12.0
        # Image rows stay level: the camera's x axis is (nearly) horizontal.
        assert abs(r[2, 0]) < 0.02
    assert cams["front"].T_vehicle_camera[0, 2] > 0.98
    assert cams["left"].T_vehicle_camera[1, 2] > 0.9  # looks left (+y)
    assert cams["right"].T_vehicle_camera[1, 2] < -0.9
    # Each unit has its own calibration.
    ks = [cam.K for cam in cams.values()]
    dists = [cam.dist for cam in cams.values()]
    for i in range(3):
        for j in range(i + 1, 3):
            assert not np.allclose(ks[i], ks[j])
            assert not np.allclose(dists[i], dists[j])


def test_rig_field_of_view_and_distortion(full_rig):
    for cam, rays in full_rig:
        mid = cam.height // 2
        hfov = np.degrees(np.arccos(rays[mid, 0] @ rays[mid, -1]))
        assert 80.0 <= hfov <= 95.0, cam.name
        # Barrel distortion is visible: a straight pinhole would map the corner ray further out.
        k1, k2, _p1, _p2, k3 = cam.dist
        corner = rays[0, 0]
        x = corner[0] / corner[2]
        pinhole_u = cam.K[0, 0] * x + cam.K[0, 2]
        assert pinhole_u < -0.1 * cam.width  # > 100 px of distortion at the corner
        # Radial distortion monotonic (invertible) well beyond the sensor corners.
        r_max = 1.2 * np.hypot(rays[..., 0] / rays[..., 2], rays[..., 1] / rays[..., 2]).max()
        r2 = np.linspace(0.0, r_max, 500) ** 2
        d_radial = 1 + 3 * k1 * r2 + 5 * k2 * r2**2 + 7 * k3 * r2**3
        assert d_radial.min() > 0.3, cam.name


def test_pixel_rays_round_trip(full_rig):
    """Points along every pixel's ray project back onto that pixel (distortion invertible)."""
    for cam, rays in full_rig:
        v, u = np.mgrid[0 : cam.height, 0 : cam.width]
        T = world_camera(cam)
        for depth in (2.0, 30.0):
            pts = transform_points(T, rays.reshape(-1, 3) * depth)
            uv, in_front = cam.project(pts, T)
            assert in_front.all()
            err = np.hypot(uv[:, 0] - u.ravel(), uv[:, 1] - v.ravel())
            assert err.max() < 0.01, (cam.name, float(err.max()))


# ---------------------------------------------------------------------------------------------
# Renderer
# ---------------------------------------------------------------------------------------------


def test_mask_matches_projection_centre_and_corners(small_rig):
    """Spheres on the rays of the centre and corner pixels show up in the mask where projected."""
    for cam, rays in small_rig:
        T = world_camera(cam)
        origin, rotation = T[:3, 3], T[:3, :3]
        margin = 10
        pixels = [
            (cam.width // 2, cam.height // 2),
            (margin, margin),
            (cam.width - 1 - margin, margin),
            (margin, cam.height - 1 - margin),
            (cam.width - 1 - margin, cam.height - 1 - margin),
        ]
        builder = MeshBuilder()
        ground(builder)
        centres = []
        for k, (u, v) in enumerate(pixels):
            d = rotation @ rays[v, u]
            t_ground = -origin[2] / d[2] if d[2] < 0 else np.inf
            centre = origin + d * min(6.0, 0.5 * t_ground)
            centres.append(centre)
            builder.add(
                sphere(centre, 0.2), cls=TruthClass.GUARDRAIL, object_id=k + 1, material="yellow"
            )
        scene = SceneRaycaster(builder.build())
        image, mask = render_image(
            scene, cam, T, sunny(), np.random.default_rng(0), pixel_rays=rays
        )
        uv, in_front = cam.project(np.array(centres), T)
        assert in_front.all()
        np.testing.assert_allclose(uv, np.array(pixels, float), atol=0.01)
        for (u, v), (pu, pv) in zip(pixels, np.round(uv).astype(int), strict=True):
            assert mask[pv, pu] == TruthClass.GUARDRAIL, (cam.name, u, v)
        # The spheres are small: most of the frame is road or sky, not guardrail.
        assert (mask == TruthClass.GUARDRAIL).mean() < 0.2
        assert (mask == TruthClass.ROAD).mean() > 0.2


def test_forward_view_sky_on_top_and_shapes(small_rig):
    cam, rays = next((c, r) for c, r in small_rig if c.name == "front")
    builder = MeshBuilder()
    ground(builder)
    builder.add(
        box((15.0, 0.0, 1.0), (1.0, 1.0, 2.0)),
        cls=TruthClass.WALL,
        object_id=1,
        material="concrete",
    )
    scene = SceneRaycaster(builder.build())
    image, mask = render_image(
        scene, cam, world_camera(cam), sunny(), np.random.default_rng(1), pixel_rays=rays
    )
    assert image.shape == (cam.height, cam.width, 3) and image.dtype == np.uint8
    assert mask.shape == (cam.height, cam.width) and mask.dtype == np.uint8
    assert (mask[:10] == TruthClass.NONE).all()
    assert (mask[-10:] == TruthClass.ROAD).all()
    # Blue sky at the top, darker zenith than horizon band, road greyish and darker than sky.
    top = image[:10].reshape(-1, 3).astype(float).mean(axis=0)
    assert top[2] > top[0] + 20
    road = image[-10:].reshape(-1, 3).astype(float).mean(axis=0)
    assert road.mean() < top.mean()
    assert np.ptp(road) < 25


def test_cast_shadow_is_darker(small_rig):
    """Ground in the box's shadow is darker than sunlit ground of the same material."""
    cam, rays = next((c, r) for c, r in small_rig if c.name == "front")
    T = world_camera(cam)
    heading = T_WORLD_VEHICLE[:3, 0]
    left = T_WORLD_VEHICLE[:3, 1]
    base = T_WORLD_VEHICLE[:3, 3] * [1, 1, 0] + 10.0 * heading  # box footprint centre, on the road
    builder = MeshBuilder()
    ground(builder, material="concrete")
    builder.add(
        box(base + [0, 0, 1.0], (1.0, 1.0, 2.0), T_WORLD_VEHICLE[:3, :3]),
        cls=TruthClass.WALL,
        object_id=1,
        material="concrete",
    )
    scene = SceneRaycaster(builder.build())
    # Sun from the vehicle's right, 40 degrees high: the shadow falls to the left of the box.
    sun_dir = np.cos(np.radians(40)) * -left + [0, 0, np.sin(np.radians(40))]
    lighting = dataclasses.replace(sunny(), sun_direction=tuple(sun_dir))
    mid_box = base + [0, 0, 1.0]
    shadowed = mid_box - sun_dir * (1.0 / sun_dir[2])  # the ray from here to the sun hits the box
    sunlit = base - 1.8 * left  # on the sun side
    assert scene.occluded(shadowed[None] + [0, 0, 0.01], sun_dir[None])[0]
    assert not scene.occluded(sunlit[None] + [0, 0, 0.01], sun_dir[None])[0]
    image, mask = render_image(scene, cam, T, lighting, np.random.default_rng(2), pixel_rays=rays)
    uv, _ = cam.project(np.array([shadowed, sunlit]), T)
    assert cam.inside(uv).all()
    for p in np.round(uv).astype(int):
        assert (mask[p[1] - 2 : p[1] + 3, p[0] - 2 : p[0] + 3] == TruthClass.ROAD).all()
    dark, bright = luminance(image, uv[0]), luminance(image, uv[1])
    assert dark < 0.7 * bright, (dark, bright)


def test_seeded_noise(small_rig):
    cam, rays = small_rig[1]
    builder = MeshBuilder()
    ground(builder)
    builder.add(
        sphere(transform_points(world_camera(cam), np.array([[0.0, 0.0, 5.0]]))[0], 0.5),
        cls=TruthClass.GUARDRAIL,
        object_id=1,
        material="white",
    )
    scene = SceneRaycaster(builder.build())
    T = world_camera(cam)
    lighting = random_lighting(np.random.default_rng(3))
    a, mask_a = render_image(scene, cam, T, lighting, np.random.default_rng(5), pixel_rays=rays)
    b, mask_b = render_image(scene, cam, T, lighting, np.random.default_rng(5), pixel_rays=rays)
    c, mask_c = render_image(scene, cam, T, lighting, np.random.default_rng(6), pixel_rays=rays)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(mask_a, mask_b)
    np.testing.assert_array_equal(mask_a, mask_c)
    diff = np.abs(a.astype(int) - c.astype(int))
    assert (diff > 0).mean() > 0.3  # noise differs almost everywhere...
    assert diff.mean() < 4.0  # ...but it is only sensor noise
    # Rendering without cached rays gives the same image.
    d, _ = render_image(scene, cam, T, lighting, np.random.default_rng(5))
    np.testing.assert_array_equal(a, d)
    with pytest.raises(ValueError):
        render_image(scene, cam, T, lighting, np.random.default_rng(5), pixel_rays=rays[:-1])


def test_random_lighting_ranges():
    rng = np.random.default_rng(0)
    overcast = 0
    for _ in range(200):
        light = random_lighting(rng)
        sun = np.array(light.sun_direction)
        assert np.linalg.norm(sun) == pytest.approx(1.0)
        assert 15.0 - 1e-9 <= np.degrees(np.arcsin(sun[2])) <= 70.0 + 1e-9
        assert 0.7 <= light.exposure <= 1.3
        assert np.all(np.abs(np.array(light.white_balance) - 1.0) <= 0.12 + 1e-9)
        assert light.haze_distance_m > 50.0
        overcast += light.sun_intensity < 0.3 and light.ambient > 0.5
    assert 20 <= overcast <= 90


def test_at_night_the_lamps_light_what_is_near(small_rig):
    """Night: the road 5 m ahead is lit by the vehicle's lamps, 40 m ahead it is dark, and the
    frame is far darker than by day; the sky is no brighter than the near road."""
    cam, rays = next((c, r) for c, r in small_rig if c.name == "front")
    T = world_camera(cam)
    builder = MeshBuilder()
    ground(builder, material="concrete")
    scene = SceneRaycaster(builder.build())
    night = dataclasses.replace(
        random_night_lighting(np.random.default_rng(1)), white_balance=(1.0, 1.0, 1.0)
    )
    assert night.sun_intensity == 0 and night.headlight > 0 and night.exposure >= 3
    image, _ = render_image(scene, cam, T, night, np.random.default_rng(2), pixel_rays=rays)
    day, _ = render_image(scene, cam, T, sunny(), np.random.default_rng(2), pixel_rays=rays)
    heading = T_WORLD_VEHICLE[:3, 0]
    road = T_WORLD_VEHICLE[:3, 3] * [1, 1, 0]
    uv, _ = cam.project(np.array([road + 5.0 * heading, road + 40.0 * heading]), T)
    assert cam.inside(uv).all()
    near, far = luminance(image, uv[0]), luminance(image, uv[1])
    assert near > 2 * far, (near, far)  # sRGB: about five times the light
    assert image.mean() < 0.6 * day.mean()
    assert luminance(image, np.array([cam.width / 2, 3])) < near
    # By day the lamps do nothing: a day's lighting has none.
    assert random_lighting(np.random.default_rng(0)).headlight == 0.0
