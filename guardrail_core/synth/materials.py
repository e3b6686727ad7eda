"""Surface materials: how a surface looks to the cameras and returns to the laser scanner.

Paints are shared by guardrails and confounders alike (white, yellow, green, brown, galvanised
grey, rust), so that colour alone cannot tell a guardrail from a fence or a bollard.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Material:
    """Optical properties of a surface.

    Attributes
    ----------
    albedo : (3,) float, linear RGB in [0, 1]
        Diffuse reflectance seen by the cameras.
    reflectivity : float in [0, 1]
        Diffuse reflectance at the scanner's near-infrared wavelength; drives intensity.
    specular : float in [0, 1]
        Strength of a Blinn-Phong highlight (glossy paint, glass).
    texture : float in [0, 1]
        Amplitude of the procedural albedo variation (asphalt grain, grass, bark).
    texture_scale_m : float, metres
        Feature size of that variation.
    dropout : float in [0, 1]
        Extra probability that a laser return is lost (glass, foliage gaps, dark paint).
    """

    albedo: tuple[float, float, float]
    reflectivity: float
    specular: float = 0.05
    texture: float = 0.05
    texture_scale_m: float = 0.05
    dropout: float = 0.0


#: Paints used on guardrails and on confounders.
PAINTS: dict[str, Material] = {
    "white": Material((0.80, 0.80, 0.78), 0.75, specular=0.25, texture=0.03),
    "yellow": Material((0.80, 0.62, 0.08), 0.60, specular=0.25, texture=0.03),
    "green": Material((0.10, 0.35, 0.18), 0.35, specular=0.20, texture=0.03),
    "brown": Material((0.28, 0.17, 0.10), 0.30, specular=0.15, texture=0.04),
    "galvanised": Material(
        (0.55, 0.57, 0.58), 0.55, specular=0.45, texture=0.08, texture_scale_m=0.02
    ),
    "rust": Material((0.38, 0.18, 0.09), 0.25, specular=0.05, texture=0.25, texture_scale_m=0.03),
}

#: Everything else in a street.
SURFACES: dict[str, Material] = {
    "asphalt": Material(
        (0.09, 0.09, 0.10), 0.18, specular=0.02, texture=0.35, texture_scale_m=0.03
    ),
    "lane_paint": Material((0.85, 0.85, 0.82), 0.80, specular=0.05, texture=0.10),
    "concrete": Material(
        (0.50, 0.49, 0.46), 0.45, specular=0.02, texture=0.15, texture_scale_m=0.05
    ),
    "paving": Material((0.42, 0.36, 0.32), 0.40, specular=0.02, texture=0.25, texture_scale_m=0.15),
    "grass": Material((0.12, 0.25, 0.06), 0.40, specular=0.0, texture=0.45, texture_scale_m=0.04),
    "bark": Material((0.20, 0.14, 0.09), 0.30, specular=0.0, texture=0.35, texture_scale_m=0.02),
    "foliage": Material(
        (0.07, 0.20, 0.05), 0.45, specular=0.0, texture=0.55, texture_scale_m=0.08, dropout=0.35
    ),
    "brick": Material((0.45, 0.20, 0.14), 0.35, specular=0.02, texture=0.25, texture_scale_m=0.07),
    "plaster": Material((0.70, 0.66, 0.58), 0.55, specular=0.02, texture=0.08, texture_scale_m=0.3),
    "glass": Material((0.10, 0.13, 0.16), 0.05, specular=0.9, texture=0.0, dropout=0.7),
    "rubber": Material((0.03, 0.03, 0.03), 0.08, specular=0.05, texture=0.05),
    "car_red": Material((0.55, 0.05, 0.05), 0.40, specular=0.6, texture=0.0),
    "car_blue": Material((0.05, 0.12, 0.45), 0.35, specular=0.6, texture=0.0),
    "car_silver": Material((0.60, 0.61, 0.62), 0.55, specular=0.7, texture=0.0),
    "car_black": Material((0.03, 0.03, 0.035), 0.10, specular=0.7, texture=0.0),
    "sign_blue": Material((0.05, 0.20, 0.55), 0.90, specular=0.3, texture=0.0),  # retroreflective
    "sign_red": Material((0.70, 0.05, 0.05), 0.90, specular=0.3, texture=0.0),
    "cloth_dark": Material((0.08, 0.08, 0.12), 0.20, specular=0.0, texture=0.10),
    "cloth_light": Material((0.60, 0.55, 0.45), 0.45, specular=0.0, texture=0.10),
    "skin": Material((0.60, 0.45, 0.35), 0.40, specular=0.1, texture=0.02),
    # Clipped evergreen hedges (azalea, box) and unmown verge grass: the laser goes in between
    # the leaves and blades, so many pulses come back from deeper in or not at all.
    "hedge": Material(
        (0.05, 0.17, 0.05), 0.40, specular=0.0, texture=0.6, texture_scale_m=0.05, dropout=0.25
    ),
    "tall_grass": Material(
        (0.25, 0.32, 0.10), 0.35, specular=0.0, texture=0.5, texture_scale_m=0.03, dropout=0.2
    ),
    # A parked car's side windows: the laser comes back from the glass and the seats behind it
    # faintly but often (in a real multibeam frame, at half to nine tenths of the doors' point
    # density with intensity near 0), unlike shop windows.
    "car_glass": Material((0.10, 0.13, 0.16), 0.05, specular=0.9, texture=0.0, dropout=0.3),
}

MATERIALS: dict[str, Material] = {**PAINTS, **SURFACES}

#: Stable integer ids (position in this tuple) used in per-face arrays.
MATERIAL_NAMES: tuple[str, ...] = tuple(MATERIALS)
MATERIAL_ID: dict[str, int] = {name: i for i, name in enumerate(MATERIAL_NAMES)}
