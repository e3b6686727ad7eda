"""Roadside vegetation: clipped hedges, shrubs, patches of tall grass and young trees, laid on
the ground.

Real roadsides are green: hedges planted right behind guardrails (the planting strips between a
road and its sidewalk, the hedge in a motorway's median), shrubs on the verge, grass no one has
mown. To a laser scanner they are rough, porous surfaces beside and touching the rails, and a
classifier that never saw them calls them guardrail (KITTI sequence 01's median hedge). Each
builder lays its mesh on the road's ground (:meth:`~guardrail_core.synth.road.Road.point`), so
a hedge follows curves, embankments and ditches.

Positions are those of every scene item: ``at`` metres along the centreline, ``offset`` metres
outward from the carriageway's edge, on ``side``. Sizes the spec leaves open are drawn from the
object's own random stream.
"""

from __future__ import annotations

import numpy as np

from guardrail_core.classes import TruthClass
from guardrail_core.geom.mesh import cylinder, grid_surface, sphere
from guardrail_core.synth.mesh import MeshBuilder
from guardrail_core.synth.road import SIDES, Road

VEGETATION_KINDS = ("hedge", "shrub", "tall_grass", "young_tree")
#: Kinds that run ``length`` metres along the road from ``at``.
EXTENDED_VEGETATION = frozenset({"hedge", "tall_grass"})
#: Spec keys of each kind's size (metres) and the range a size left open is drawn from.
SIZES: dict[str, dict[str, tuple[float, float]]] = {
    "hedge": {"height": (0.6, 1.4), "depth": (0.5, 1.0)},
    "shrub": {"height": (0.5, 1.8), "width": (0.6, 2.0)},
    "tall_grass": {"height": (0.15, 0.8), "width": (1.0, 4.0)},
    "young_tree": {"height": (2.2, 4.0), "width": (0.6, 1.6)},
}
#: Metres between a hedge's mesh rows along the road (leaf-scale roughness).
ROW_STEP_M = 0.06
#: Metres between a grass patch's mesh rows and columns (tufts).
GRASS_STEP_M = 0.1


def vegetation_sizes(kind: str, item: dict, rng: np.random.Generator) -> dict[str, float]:
    """The sizes of ``kind`` (metres): the spec ``item``'s, or drawn where it leaves one open."""
    return {
        key: float(item[key]) if key in item else float(rng.uniform(lo, hi))
        for key, (lo, hi) in SIZES[kind].items()
    }


def build_vegetation(
    kind: str,
    *,
    road: Road,
    side: str,
    offset: float,
    at: float,
    length: float,
    sizes: dict[str, float],
    object_id: int,
    builder: MeshBuilder,
    rng: np.random.Generator,
) -> dict:
    """Add one piece of vegetation to ``builder`` and return its truth record.

    ``offset`` is the line of a hedge's or shrub's centre, or the road-side edge of a grass
    patch (which reaches ``width`` metres outward); ``length`` (m) is used by the extended kinds
    (:data:`EXTENDED_VEGETATION`). Returns ``{"id", "kind", "class", "paint": None,
    "geometry"}`` with ``base`` (3,), the ground point at ``at`` on the offset line, the sizes
    and, for extended kinds, ``length``.
    """
    if kind not in VEGETATION_KINDS:
        raise ValueError(f"unknown vegetation kind {kind!r}; expected one of {VEGETATION_KINDS}")
    end = min(at + length, road.length) if kind in EXTENDED_VEGETATION else at
    if kind in EXTENDED_VEGETATION and not end - at > 0.1:
        raise ValueError(f"{kind} needs more than 0.1 m of road, got {end - at:.2f} m")
    sign = SIDES[side]
    edge = road.half_width + offset

    def ground(s: np.ndarray, outward: np.ndarray, up: np.ndarray) -> np.ndarray:
        """World points (..., 3) ``up`` metres over the ground at (s, ``outward`` of the edge)."""
        shape = np.broadcast(s, outward, up).shape
        s, outward, up = (np.broadcast_to(v, shape).ravel() for v in (s, outward, up))
        p = road.point(s, sign * (edge + outward))
        p[:, 2] += up
        return p.reshape(*shape, 3)

    cls = TruthClass.TREE if kind == "young_tree" else TruthClass.VEGETATION
    if kind == "hedge":
        pieces = [(_hedge(ground, end - at, sizes["height"], sizes["depth"], at, rng), "hedge")]
    elif kind == "shrub":
        pieces = [(_shrub(ground, at, sizes["height"], sizes["width"], rng), "hedge")]
    elif kind == "young_tree":
        pieces = _young_tree(ground, at, sizes["height"], sizes["width"], rng)
    else:
        grass = _tall_grass(ground, end - at, sizes["height"], sizes["width"], at, rng)
        pieces = [(grass, "tall_grass")]
    for mesh, material in pieces:
        builder.add(mesh, cls=cls, object_id=int(object_id), material=material)
    geometry: dict = {"base": ground(np.array(at), np.array(0.0), np.array(0.0)).tolist()}
    if kind in EXTENDED_VEGETATION:
        geometry["length"] = float(end - at)
    geometry.update(sizes)
    return {
        "id": int(object_id),
        "kind": kind,
        "class": int(cls),
        "paint": None,
        "geometry": geometry,
    }


def _waves(rng: np.random.Generator, n: int, wavelength: tuple[float, float], amplitude: float):
    """A smooth random field of ``n`` plane waves in (along m, angle rad): f(a, b) -> relative."""
    k = 2 * np.pi / rng.uniform(*wavelength, n)
    m = rng.integers(0, 4, n)
    phase = rng.uniform(0, 2 * np.pi, n)
    amp = rng.uniform(0.3, 1.0, n) * amplitude / np.sqrt(n)

    def field(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return (amp * np.sin(a[..., None] * k + b[..., None] * m + phase)).sum(-1)

    return field


def _hedge(ground, length: float, height: float, depth: float, at: float, rng) -> tuple:
    """A clipped hedge: a boxy rounded section (across, up) swept along the road, bulging
    smoothly and rough at leaf scale, its ends rounded shut below the ground."""
    a = np.linspace(0.0, length, max(2, int(np.ceil(length / ROW_STEP_M)) + 1))
    theta = np.linspace(0.0, np.pi, 25)  # from the back foot over the top to the front foot
    cos, sin = np.cos(theta), np.sin(theta)
    sink = 0.05
    c = 0.5 * depth * np.sign(cos) * np.sqrt(np.abs(cos))  # a superellipse of exponent 4
    u = -sink + (height + sink) * np.sqrt(sin)
    bulge = 1.0 + _waves(rng, 6, (0.6, 3.0), 0.12)(a[:, None], theta[None, :])
    taper = np.sqrt(np.clip(np.minimum(a, length - a) / 0.3, 0.0, 1.0))[:, None]
    centre_u = 0.45 * height
    leaf = rng.normal(0.0, 0.025, (len(a), len(theta)))  # metres along the section's normal
    dc, du = c[None, :], (u - centre_u)[None, :]
    norm = np.maximum(np.hypot(dc, du), 1e-6)
    across = (dc * bulge + leaf * dc / norm) * taper
    up = (centre_u + du * bulge + leaf * du / norm + sink) * taper - sink
    return grid_surface(ground(at + a[:, None], across, up))


def _shrub(ground, at: float, height: float, width: float, rng) -> tuple:
    """A shrub: a lumpy, leaf-rough ellipsoid whose lowest tenth is below the ground."""
    verts, faces = sphere(np.zeros(3), 1.0, subdivisions=3)
    lumps = _waves(rng, 6, (0.8, 2.5), 0.25)
    angle = np.arctan2(verts[:, 1], verts[:, 0])
    scale = 1.0 + lumps(verts[:, 2] * 2.0, angle) + rng.normal(0.0, 0.03, len(verts))
    radii = np.array([width / 2, width / 2, height / 2])
    local = verts * radii * scale[:, None]
    centre = ground(np.array(at), np.array(0.0), np.array(0.4 * height))
    return local + centre, faces


def _tall_grass(ground, length: float, height: float, width: float, at: float, rng) -> tuple:
    """Unmown grass: a ragged surface of varying height (``height`` its tallest tuft) over the
    ground, tapering to it at the patch's borders, with a third of its faces left out where
    pulses reach the ground."""
    a = np.linspace(0.0, length, max(2, int(np.ceil(length / GRASS_STEP_M)) + 1))
    c = np.linspace(0.0, width, max(2, int(np.ceil(width / GRASS_STEP_M)) + 1))
    smooth = _waves(rng, 5, (0.5, 4.0), 0.5)(a[:, None], c[None, :] * 2.0)
    blades = rng.uniform(0.6, 1.3, (len(a), len(c)))
    border = np.minimum(np.minimum(a, length - a)[:, None], np.minimum(c, width - c)[None, :])
    tufts = np.maximum(1.0 + smooth, 0.2) * blades * np.clip(border / 0.3, 0.0, 1.0)
    # The tallest tuft is ``height``; the border sinks 2 cm, so no face lies on the ground's.
    up = height * tufts / tufts.max() - 0.02
    verts, faces = grid_surface(ground(at + a[:, None], c[None, :], up))
    kept = rng.random(len(faces)) >= 0.35
    return verts, faces[kept]


def _young_tree(ground, at: float, height: float, width: float, rng) -> list[tuple]:
    """A young street tree: a trunk 5-10 cm thick (a railing post's girth) tied to a stake
    beside it, and a small lumpy crown from 1.3-2.0 m up to ``height``; (mesh, material) pieces.
    """
    foot = ground(np.array(at), np.array(0.0), np.array(-0.05))
    up = np.array([0.0, 0.0, 1.0])
    crown_base = float(rng.uniform(1.3, 2.0))
    crown_h = max(height - crown_base, 0.5)
    trunk = cylinder(
        foot, foot + (crown_base + 0.5 * crown_h) * up, float(rng.uniform(0.025, 0.05))
    )
    side = rng.normal(size=2)
    side = np.r_[side / np.linalg.norm(side), 0.0] * 0.15
    stake = cylinder(foot + side, foot + side + float(rng.uniform(1.4, 1.9)) * up, 0.03, sections=8)
    verts, faces = sphere(np.zeros(3), 1.0, subdivisions=2)
    lumps = _waves(rng, 5, (0.8, 2.5), 0.3)
    angle = np.arctan2(verts[:, 1], verts[:, 0])
    scale = 1.0 + lumps(verts[:, 2] * 2.0, angle) + rng.normal(0.0, 0.04, len(verts))
    radii = np.array([width / 2, width / 2, crown_h / 2])
    crown = foot + (crown_base + crown_h / 2) * up + verts * radii * scale[:, None]
    return [(trunk, "bark"), (stake, "bark"), ((crown, faces), "foliage")]
