"""Ray-traced camera images of a synthetic scene, with a per-pixel truth mask.

One primary ray per pixel (through the distorted lens, from :meth:`Camera.pixel_rays`) gives
both the colour and the truth class of the pixel, so mask and image agree exactly. Shading is
deliberately simple but has the cues a crop classifier (Matsumoto et al. 2019, §3.2) learns
from: textured albedo, sun with cast shadows, sky light, glossy highlights and sky reflections,
a sky with a sun glow, distance haze, vignetting, exposure and white balance, sRGB gamma and
sensor noise. Everything is vectorised numpy in float32; the only heavy calls are Open3D's ray
casts (primary rays and shadow rays).

Radiometry is relative: a white Lambertian surface facing a sun of intensity 1 has radiance
~1, which maps to full scale at exposure 1 before white balance.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from guardrail_core.params import StageParams, param
from guardrail_core.sensors.camera import Camera
from guardrail_core.synth.materials import MATERIAL_NAMES, MATERIALS
from guardrail_core.synth.raycast import SceneRaycaster

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Lighting:
    """Illumination and camera settings of one drive (or one frame).

    Attributes
    ----------
    sun_direction : (3,) unit vector toward the sun, local (world) frame, z up
    sun_intensity : float, irradiance of the sun on a surface facing it (relative, ~1 sunny)
    ambient : float, sky (ambient) irradiance on an upward surface (relative)
    sky_zenith, sky_horizon : (3,) linear RGB radiance of the sky straight up and at the horizon
    exposure : float, gain from scene radiance to sensor full scale
    white_balance : (3,) per-channel RGB gains of the camera
    haze_distance_m : float, metres at which haze has replaced 63% of a surface's radiance
    sun_colour : (3,) linear RGB tint of direct sunlight (warmer when the sun is low)
    headlight : float, irradiance of the vehicle's lamps (at the camera) on a surface facing
        them 10 m away, falling off with the square of the distance (0 by day)
    """

    sun_direction: Vec3
    sun_intensity: float
    ambient: float
    sky_zenith: Vec3
    sky_horizon: Vec3
    exposure: float
    white_balance: Vec3
    haze_distance_m: float
    sun_colour: Vec3 = (1.0, 1.0, 1.0)
    headlight: float = 0.0


@dataclass(frozen=True)
class RenderParams(StageParams):
    """Constants of the shading model (tuned by eye on street scenes)."""

    shadow_offset_m: float = param(
        0.004,
        unit="m",
        ge=0,
        le=1,
        doc="shadow-ray origin offset along the normal, shadow_offset_m + shadow_offset_per_m * "
        "distance, so float32 hit points far away do not shadow themselves",
    )
    shadow_offset_per_m: float = param(
        2e-4, unit="m/m", ge=0, le=0.1, doc="growth of the shadow-ray offset with distance"
    )
    ambient_floor: float = param(
        0.45, ge=0, le=1, doc="fraction of sky light still reaching a downward-facing surface"
    )
    shininess_min: float = param(
        8.0, ge=0, le=10_000, doc="Blinn-Phong exponent: min + span * material.specular"
    )
    shininess_span: float = param(150.0, ge=0, le=10_000, doc="see shininess_min")
    reflection_strength: float = param(
        0.6, ge=0, le=10, doc="scale of the Fresnel-weighted sky reflection on glossy materials"
    )
    texture_octave_ratio: float = param(
        6.0, gt=0, le=1000, doc="feature size of the coarse noise octave / the material's scale"
    )
    texture_fine_weight: float = param(
        0.6, ge=0, le=1, doc="share of the texture amplitude given to the fine octave"
    )
    texture_min_cells_px: float = param(
        0.6,
        unit="px",
        ge=0,
        le=1000,
        doc="a noise octave fades out when its cell spans fewer pixels than this",
    )
    sun_glow_width: float = param(
        0.0015, gt=0, le=2, doc="sharp glow around the sun: exp((cos - 1) / width)"
    )
    sun_glow_strength: float = param(6.0, ge=0, le=1000, doc="see sun_glow_width")
    sun_halo_power: float = param(
        12.0, ge=0, le=1000, doc="broad forward-scattering halo: max(cos, 0) ** power"
    )
    sun_halo_strength: float = param(0.35, ge=0, le=100, doc="see sun_halo_power")
    ground_below_horizon: float = param(
        0.35,
        ge=0,
        le=10,
        doc="radiance of the (unmodelled) ground seen below the horizon, times the horizon's",
    )
    vignetting: float = param(
        0.45, ge=0, le=1, doc="fraction of the cos^4 fall-off the lens shows (0 none, 1 full)"
    )
    optics_blur_sigma_px: float = param(
        0.55,
        unit="px",
        ge=0,
        le=100,
        doc="Gaussian blur of the lens and sensor (softens aliased edges)",
    )
    shot_noise_gain: float = param(
        1.0 / 1500.0,
        ge=0,
        le=1,
        doc="photon-noise variance per unit signal (1 / full-well electrons)",
    )
    read_noise: float = param(
        0.0012, ge=0, le=1, doc="read-noise standard deviation, fraction of full scale"
    )
    chunk_rays: int = param(
        65536,
        ge=1,
        le=2**31 - 1,
        doc="hits shaded per block (a speed knob only; results do not depend on it)",
    )


DEFAULT_RENDER_PARAMS = RenderParams()

# Per-material lookup tables (indexed by face_material), built once.
_ALBEDO = np.array([MATERIALS[n].albedo for n in MATERIAL_NAMES], np.float32)
_SPECULAR = np.array([MATERIALS[n].specular for n in MATERIAL_NAMES], np.float32)
_TEXTURE = np.array([MATERIALS[n].texture for n in MATERIAL_NAMES], np.float32)
_TEXTURE_SCALE = np.array([MATERIALS[n].texture_scale_m for n in MATERIAL_NAMES], np.float32)

# Linear [0, 1] to 8-bit sRGB via a lookup table (much cheaper than a pow per sample).
_LUT_SIZE = 4096
_lut_x = np.linspace(0.0, 1.0, _LUT_SIZE)
_SRGB_LUT = np.round(
    255.0 * np.where(_lut_x <= 0.0031308, 12.92 * _lut_x, 1.055 * _lut_x ** (1 / 2.4) - 0.055)
).astype(np.uint8)


# --------------------------------------------------------------------------------------------
# Lighting
# --------------------------------------------------------------------------------------------


def _vec3(values) -> Vec3:
    x, y, z = (float(v) for v in values)
    return (x, y, z)


def random_lighting(rng: np.random.Generator) -> Lighting:
    """Plausible daylight: sun 15-70 degrees high at any azimuth; ~25% of the time overcast."""
    elevation = np.radians(rng.uniform(15.0, 70.0))
    azimuth = rng.uniform(0.0, 2 * np.pi)
    sun = (
        np.cos(elevation) * np.cos(azimuth),
        np.cos(elevation) * np.sin(azimuth),
        np.sin(elevation),
    )
    # Low sun is warmer: less blue and green reaches the ground through more air.
    warmth = float(np.clip((np.degrees(elevation) - 15.0) / 35.0, 0.0, 1.0))
    sun_colour = (1.0, 0.90 + 0.10 * warmth, 0.76 + 0.24 * warmth)
    if rng.random() < 0.25:
        # Overcast: diffuse light from a grey sky, faint sun, short haze.
        grey = rng.uniform(0.55, 0.85)
        sun_intensity = rng.uniform(0.05, 0.2)
        ambient = rng.uniform(0.55, 0.8)
        zenith = (grey * 0.92, grey * 0.95, grey)
        horizon = (grey, grey, grey * 1.02)
        haze = rng.uniform(80.0, 300.0)
    else:
        sun_intensity = rng.uniform(0.85, 1.15)
        ambient = rng.uniform(0.18, 0.32)
        blue = rng.uniform(0.8, 1.0)
        zenith = (0.18 * blue, 0.36 * blue, 0.80 * blue)
        horizon = (0.72, 0.80, 0.90)
        haze = rng.uniform(150.0, 600.0)
    wb = rng.normal(1.0, 0.04, 3)
    wb = np.clip(wb / wb[1], 0.88, 1.12)  # green channel is the reference
    return Lighting(
        sun_direction=_vec3(sun),
        sun_intensity=float(sun_intensity),
        ambient=float(ambient),
        sky_zenith=_vec3(zenith),
        sky_horizon=_vec3(horizon),
        exposure=float(rng.uniform(0.7, 1.3)),
        white_balance=_vec3(wb),
        haze_distance_m=float(haze),
        sun_colour=sun_colour,
    )


def random_night_lighting(rng: np.random.Generator) -> Lighting:
    """Night: no sun, a faint sky glow, the vehicle's own lamps lighting what is near, and the
    camera's gain turned up (the sensor noise grows with it)."""
    glow = rng.uniform(0.004, 0.02)
    wb = rng.normal(1.0, 0.06, 3)
    wb = np.clip(wb / wb[1], 0.85, 1.15)
    return Lighting(
        sun_direction=(0.0, 0.0, -1.0),
        sun_intensity=0.0,
        ambient=float(rng.uniform(0.003, 0.015)),
        sky_zenith=(glow * 0.5, glow * 0.6, glow),
        sky_horizon=(glow * 1.6, glow * 1.3, glow),  # sodium-orange city glow on the horizon
        exposure=float(rng.uniform(3.0, 8.0)),
        white_balance=_vec3(wb),
        haze_distance_m=float(rng.uniform(150.0, 600.0)),
        headlight=float(rng.uniform(0.012, 0.03)),
    )


# --------------------------------------------------------------------------------------------
# Procedural texture
# --------------------------------------------------------------------------------------------

#: Linear RGB tint of halogen and LED headlamps (slightly warm).
_LAMP_COLOUR = (1.0, 0.95, 0.85)

_HASH_X, _HASH_Y, _HASH_Z = np.uint32(0x8DA6B343), np.uint32(0xD8163841), np.uint32(0xCB1AB31F)


def _mix32(h: np.ndarray) -> np.ndarray:
    """An integer avalanche (lowbias32) of uint32 values, in place, returned."""
    h ^= h >> np.uint32(16)
    h *= np.uint32(0x7FEB352D)
    h ^= h >> np.uint32(15)
    h *= np.uint32(0x846CA68B)
    h ^= h >> np.uint32(16)
    return h


def value_noise(p: np.ndarray) -> np.ndarray:
    """Smooth 3D value noise at points ``p`` (N, 3) in lattice units, (N,) float32 in [-1, 1].

    Lattice values come from a hash of the integer cell corner, so the noise is stable in world
    coordinates (the same wall looks the same from every frame) and needs no tables.
    """
    cell = np.floor(p)
    f = (p - cell).astype(np.float32)
    u = f * f * (3.0 - 2.0 * f)  # smoothstep: no creases at cell borders
    i = cell.astype(np.int64).astype(np.uint32)  # wraps negatives, fine for hashing
    # Independent per-axis hashes, combined per corner and mixed once more.
    hx = (_mix32(i[:, 0] * _HASH_X), _mix32((i[:, 0] + np.uint32(1)) * _HASH_X))
    hy = (_mix32(i[:, 1] * _HASH_Y), _mix32((i[:, 1] + np.uint32(1)) * _HASH_Y))
    hz = (_mix32(i[:, 2] * _HASH_Z), _mix32((i[:, 2] + np.uint32(1)) * _HASH_Z))
    scale = np.float32(2.0 / 16777216.0)

    def corner(a: int, b: int, c: int) -> np.ndarray:
        h = hx[a] + (hy[b] ^ hz[c])
        h *= np.uint32(0x9E3779B1)
        h ^= h >> np.uint32(15)
        return (h >> np.uint32(8)).astype(np.float32) * scale - np.float32(1.0)

    ux, uy, uz = u[:, 0], u[:, 1], u[:, 2]

    def lerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
        return a + (b - a) * t

    x00 = lerp(corner(0, 0, 0), corner(1, 0, 0), ux)
    x10 = lerp(corner(0, 1, 0), corner(1, 1, 0), ux)
    x01 = lerp(corner(0, 0, 1), corner(1, 0, 1), ux)
    x11 = lerp(corner(0, 1, 1), corner(1, 1, 1), ux)
    return lerp(lerp(x00, x10, uy), lerp(x01, x11, uy), uz)


def _texture_factor(
    points: np.ndarray,
    material: np.ndarray,
    footprint_m: np.ndarray,
    params: RenderParams,
) -> np.ndarray:
    """Albedo multiplier (N,) float32 around 1 for hits at ``points`` (N, 3), metres.

    Two octaves: the material's feature size and a coarser one for blotches. An octave whose
    cells are smaller than a pixel's ``footprint_m`` (N,) on the surface fades to its mean,
    as the pixel would average it (no sparkle on distant asphalt).
    """
    amplitude = _TEXTURE[material]
    scale = _TEXTURE_SCALE[material]
    total = np.zeros(len(points), np.float32)
    octaves = (
        (1.0, params.texture_fine_weight),
        (params.texture_octave_ratio, 1.0 - params.texture_fine_weight),
    )
    for k, (ratio, weight) in enumerate(octaves):
        cell = scale * np.float32(ratio)
        fade = np.clip((cell / footprint_m - params.texture_min_cells_px) / 1.5, 0.0, 1.0)
        # A per-octave offset so the two octaves do not share lattice corners.
        p = points / cell[:, None] + np.float32(17.31 * (k + 1))
        total += np.float32(weight) * fade * value_noise(p)
    return np.maximum(1.0 + amplitude * total, 0.05)


# --------------------------------------------------------------------------------------------
# Sky and shading
# --------------------------------------------------------------------------------------------


def sky_radiance(
    directions: np.ndarray, lighting: Lighting, params: RenderParams = DEFAULT_RENDER_PARAMS
) -> np.ndarray:
    """Linear RGB radiance (N, 3) float32 of the sky along unit world ``directions`` (N, 3).

    A horizon-to-zenith gradient plus a glow and halo around the sun; below the horizon a dim
    stand-in for the distant ground.
    """
    d = directions.astype(np.float32, copy=False)
    zenith = np.asarray(lighting.sky_zenith, np.float32)
    horizon = np.asarray(lighting.sky_horizon, np.float32)
    up = np.clip(d[:, 2], 0.0, 1.0)
    blend = np.sqrt(up)[:, None]  # the sky stays pale near the horizon, then deepens quickly
    rad = horizon + (zenith - horizon) * blend
    below = d[:, 2] < 0
    if np.any(below):
        rad[below] = horizon * np.float32(params.ground_below_horizon)
    sun = np.asarray(lighting.sun_direction, np.float32)
    cos = d @ sun
    glow = params.sun_glow_strength * np.exp((cos - 1.0) / params.sun_glow_width)
    halo = params.sun_halo_strength * np.maximum(cos, 0.0) ** params.sun_halo_power
    sun_colour = np.asarray(lighting.sun_colour, np.float32)
    rad += (lighting.sun_intensity * (glow + halo))[:, None].astype(np.float32) * sun_colour
    return rad


def render_image(
    raycaster: SceneRaycaster,
    camera: Camera,
    T_world_camera: np.ndarray,
    lighting: Lighting,
    rng: np.random.Generator,
    *,
    pixel_rays: np.ndarray | None = None,
    params: RenderParams = DEFAULT_RENDER_PARAMS,
) -> tuple[np.ndarray, np.ndarray]:
    """Render one image and its truth mask.

    Parameters
    ----------
    raycaster : the scene
    camera : the camera (its intrinsics and distortion define the pixel rays)
    T_world_camera : (4, 4) camera frame to local world frame
    lighting : sun, sky and camera exposure
    rng : source of the sensor noise (same seed and inputs -> identical image)
    pixel_rays : (H, W, 3) ``camera.pixel_rays()``, cached by the caller (it is costly)
    params : shading constants

    Returns
    -------
    image : (H, W, 3) uint8 sRGB
    mask : (H, W) uint8 TruthClass id of the surface each pixel's ray hits, 0 for sky
    """
    if pixel_rays is None:
        pixel_rays = camera.pixel_rays()
    h, w = camera.height, camera.width
    if pixel_rays.shape != (h, w, 3):
        raise ValueError(f"pixel_rays has shape {pixel_rays.shape}, expected {(h, w, 3)}")
    mesh = raycaster.mesh
    rotation = np.asarray(T_world_camera[:3, :3], np.float32)
    origin = np.asarray(T_world_camera[:3, 3], np.float64)
    rays_cam = pixel_rays.reshape(-1, 3).astype(np.float32, copy=False)
    dirs = rays_cam @ rotation.T  # (N, 3) world directions, unit

    hits = raycaster.cast(origin, dirs)
    hit = hits.face >= 0
    mask = np.zeros(h * w, np.uint8)
    mask[hit] = mesh.face_class[hits.face[hit]]

    radiance = np.empty((h * w, 3), np.float32)
    radiance[~hit] = sky_radiance(dirs[~hit], lighting, params)
    idx = np.flatnonzero(hit)
    pixel_angle = 1.0 / float(camera.K[0, 0])  # radians per pixel near the centre
    # Shade in blocks: the temporaries then stay in cache, which is ~2x faster than whole-frame.
    for start in range(0, len(idx), params.chunk_rays):
        sel = idx[start : start + params.chunk_rays]
        radiance[sel] = _shade_hits(
            raycaster,
            origin,
            np.take(dirs, sel, axis=0),
            hits.t[sel].astype(np.float32),
            hits.face[sel],
            np.take(hits.normal, sel, axis=0).astype(np.float32),
            pixel_angle,
            lighting,
            params,
        )

    img = radiance.reshape(h, w, 3)
    # Lens: partial cos^4 fall-off toward the corners, then a slight blur.
    cos_axis = np.abs(rays_cam[:, 2]).reshape(h, w)
    vignette = 1.0 - params.vignetting * (1.0 - cos_axis**4)
    gain = np.float32(lighting.exposure) * np.asarray(lighting.white_balance, np.float32)
    img *= vignette[:, :, None] * gain
    if params.optics_blur_sigma_px > 0:
        img = np.asarray(cv2.GaussianBlur(img, (0, 0), params.optics_blur_sigma_px), np.float32)
    # Sensor: shot noise (variance proportional to signal) plus read noise, before the tone curve.
    signal = np.clip(img, 0.0, 1.0)
    sigma = np.sqrt(signal * np.float32(params.shot_noise_gain) + np.float32(params.read_noise**2))
    img = signal + sigma * rng.standard_normal(img.shape, dtype=np.float32)
    index = np.clip(img * (_LUT_SIZE - 1) + 0.5, 0, _LUT_SIZE - 1).astype(np.uint16)
    return _SRGB_LUT[index], mask.reshape(h, w)


def _shade_hits(
    raycaster: SceneRaycaster,
    origin: np.ndarray,
    dirs: np.ndarray,
    t: np.ndarray,
    face: np.ndarray,
    normal: np.ndarray,
    pixel_angle: float,
    lighting: Lighting,
    params: RenderParams,
) -> np.ndarray:
    """Linear RGB radiance (M, 3) float32 of M surface hits.

    ``dirs`` (M, 3) unit world ray directions, ``t`` (M,) hit distances (m), ``face`` (M,) face
    ids, ``normal`` (M, 3) face normals as wound (float32, modified in place), ``origin`` (3,)
    the camera centre, ``pixel_angle`` the angular size of a pixel (rad).
    """
    mesh = raycaster.mesh
    material = mesh.face_material[face]
    points = origin.astype(np.float32) + dirs * t[:, None]

    # Normals face the camera (meshes are not consistently wound; sheets have two sides).
    cos_view = np.einsum("ij,ij->i", normal, dirs)
    flip = cos_view > 0
    normal[flip] *= -1.0
    cos_view = np.abs(cos_view)

    # Pixel footprint on the surface (m) for texture filtering: ray spread x distance / incidence.
    footprint = t * np.float32(pixel_angle) / np.maximum(cos_view, 0.15)
    albedo = _ALBEDO[material] * _texture_factor(points, material, footprint, params)[:, None]

    sun = np.asarray(lighting.sun_direction, np.float32)
    sun_colour = np.asarray(lighting.sun_colour, np.float32)
    n_dot_l = normal @ sun
    lit = n_dot_l > 0
    if lighting.sun_intensity > 0 and np.any(lit):
        offset = params.shadow_offset_m + params.shadow_offset_per_m * t[lit]
        shadow_origins = points[lit] + normal[lit] * offset[:, None]
        shadow_dirs = np.broadcast_to(sun, shadow_origins.shape)
        blocked = raycaster.occluded(shadow_origins, shadow_dirs)
        idx = np.flatnonzero(lit)[blocked]
        lit[idx] = False
    direct = np.where(lit, n_dot_l, 0.0).astype(np.float32) * np.float32(lighting.sun_intensity)

    # Sky light: the sky's mean colour, less of it for surfaces that face down.
    sky_colour = 0.5 * (
        np.asarray(lighting.sky_zenith, np.float32) + np.asarray(lighting.sky_horizon, np.float32)
    )
    sky_colour = sky_colour / max(float(sky_colour.mean()), 1e-6)
    up_factor = params.ambient_floor + (1.0 - params.ambient_floor) * 0.5 * (1.0 + normal[:, 2])
    ambient = np.float32(lighting.ambient) * up_factor

    rad = albedo * (direct[:, None] * sun_colour + ambient[:, None] * sky_colour)
    if lighting.headlight > 0:  # the lamps sit at the camera: lit as seen, fading with distance
        lamp = np.float32(lighting.headlight) * cos_view * (10.0 / np.maximum(t, 2.0)) ** 2
        rad += albedo * lamp[:, None] * np.array(_LAMP_COLOUR, np.float32)

    specular = _SPECULAR[material]
    glossy = specular > 0
    if np.any(glossy):
        g = np.flatnonzero(glossy)
        n_g, d_g, s_g = normal[g], dirs[g], specular[g]
        # Blinn-Phong sun highlight, only where the sun reaches the surface.
        half = sun - d_g
        half /= np.linalg.norm(half, axis=1, keepdims=True)
        n_dot_h = np.clip(np.einsum("ij,ij->i", n_g, half), 0.0, 1.0)
        shininess = params.shininess_min + params.shininess_span * s_g
        highlight = s_g * n_dot_h**shininess * (shininess + 8.0) / 64.0  # energy-ish normalised
        highlight *= lit[g] * np.float32(lighting.sun_intensity)
        # Fresnel-weighted reflection of the sky (car bodies, glass, glossy paint).
        cos_g = cos_view[g]
        fresnel = 0.04 + 0.96 * (1.0 - cos_g) ** 5
        reflected = d_g + 2.0 * cos_g[:, None] * n_g
        env = sky_radiance(reflected, lighting, params)
        env_w = np.float32(params.reflection_strength) * s_g * fresnel
        rad[g] += highlight[:, None] * sun_colour + env_w[:, None] * env

    # Aerial perspective: blend toward the horizon colour with distance.
    haze = 1.0 - np.exp(-t / np.float32(lighting.haze_distance_m))
    horizon = np.asarray(lighting.sky_horizon, np.float32)
    rad += haze[:, None] * (horizon - rad)
    return rad
