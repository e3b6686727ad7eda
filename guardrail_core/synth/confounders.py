"""Street objects a guardrail classifier must learn to reject.

Matsumoto et al. 2019, §3.2 and §5.1: sliced segments are classified as "guardrail" or "other
object", and misclassifications come from objects whose shape resembles a guardrail (fences,
walls, bicycle racks, poles). These builders make such objects at realistic Japanese street
sizes, sharing the guardrail paints so that colour alone does not give the answer.

Frame of every builder: ``base`` (3,) is a ground point, ``along`` (3,) the horizontal road
direction, ``toward_road`` (3,) the horizontal direction to the road. Extended kinds (fences,
walls, bicycle racks, facades) run ``length`` metres from ``base`` along ``along``; fences,
walls and racks are centred on that line, a facade's road-facing face lies on it.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cache

import numpy as np
import trimesh

from guardrail_core.classes import TruthClass
from guardrail_core.geom.mesh import Mesh, cylinder, dome, segment_box, sphere, tube
from guardrail_core.synth.materials import PAINTS
from guardrail_core.synth.mesh import MeshBuilder

CONFOUNDER_KINDS = (
    "mesh_fence",
    "bar_fence",
    "low_wall",
    "bicycle_rack",
    "bollard",
    "utility_pole",
    "sign_pole",
    "tree",
    "parked_car",
    "facade",
    "pedestrian",
)
#: Kinds that use ``length``; the others are point-like at ``base``.
EXTENDED_KINDS = frozenset({"mesh_fence", "bar_fence", "low_wall", "bicycle_rack", "facade"})

_Z = np.array([0.0, 0.0, 1.0])


class _Frame:
    """base + a * along + c * across + u * up, with across = toward_road (orthogonalised)."""

    def __init__(self, base: np.ndarray, along: np.ndarray, toward: np.ndarray) -> None:
        self.base = base
        self.along = along
        self.across = toward
        self.rotation = np.stack([along, toward, _Z], axis=1)  # columns: along, across, up

    def at(self, a, c=0.0, u=0.0) -> np.ndarray:
        """World points for local (a, c, u); broadcasts, returns (..., 3)."""
        a, c, u = np.broadcast_arrays(*(np.asarray(v, np.float64) for v in (a, c, u)))
        return (
            self.base + a[..., None] * self.along + c[..., None] * self.across + u[..., None] * _Z
        )

    def box(self, a: float, c: float, u: float, size_acu) -> Mesh:
        """A box centred at local (a, c, u) with size (along, across, up)."""
        return _boxes(self.at(a, c, u), np.asarray(size_acu, np.float64), self.rotation)


def _horizontal_unit(v, name: str) -> np.ndarray:
    v = np.asarray(v, np.float64).reshape(-1)
    if v.shape != (3,) or not np.isfinite(v).all():
        raise ValueError(f"{name} must be a finite (3,) vector, got {v!r}")
    h = np.array([v[0], v[1], 0.0])
    n = np.linalg.norm(h)
    if n < 1e-9:
        raise ValueError(f"{name} must have a horizontal component")
    return h / n


@cache
def _unit_box() -> Mesh:
    """The corners (8, 3) of a unit cube centred on 0 and its faces (12, 3), as ``box`` makes them."""
    mesh = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def _boxes(centre: np.ndarray, size: np.ndarray | tuple, rotation: np.ndarray) -> Mesh:
    """K boxes as one mesh: :func:`~guardrail_core.geom.mesh.box` for many boxes at once.

    ``centre`` (K, 3) metres; ``size`` (K, 3) or (3,) metres along the columns of ``rotation``
    (K, 3, 3) or (3, 3).
    """
    centre = np.asarray(centre, np.float64).reshape(-1, 3)
    k = len(centre)
    size = np.broadcast_to(np.asarray(size, np.float64), (k, 3))
    rotation = np.broadcast_to(np.asarray(rotation, np.float64), (k, 3, 3))
    unit, faces = _unit_box()
    local = unit[None] * size[:, None, :]  # (K, 8, 3)
    vertices = np.einsum("kvj,kij->kvi", local, rotation) + centre[:, None, :]
    offsets = len(unit) * np.arange(k)[:, None, None]
    return vertices.reshape(-1, 3), (faces[None] + offsets).reshape(-1, 3)


def _segment_boxes(p0: np.ndarray, p1: np.ndarray, width: float, depth: float) -> Mesh:
    """K bars of rectangular section ``width`` x ``depth`` (m) from ``p0`` to ``p1`` (K, 3), as
    one mesh: :func:`~guardrail_core.geom.mesh.segment_box` (``up`` = z) for many bars at once
    (a fence's hundreds of wires)."""
    p0, p1 = np.asarray(p0, np.float64).reshape(-1, 3), np.asarray(p1, np.float64).reshape(-1, 3)
    axis = p1 - p0
    length = np.linalg.norm(axis, axis=1)
    x = axis / length[:, None]
    y = np.cross(_Z, x)
    # Vertical bars: segment_box's fallback frame (perpendicular to x and to a helper axis).
    vertical = np.linalg.norm(y, axis=1) < 1e-6
    helper = np.where((np.abs(x[:, 2]) < 0.9)[:, None], _Z, np.array([1.0, 0.0, 0.0]))
    y[vertical] = np.cross(x[vertical], helper[vertical])
    y /= np.linalg.norm(y, axis=1, keepdims=True)
    rotation = np.stack([x, y, np.cross(x, y)], axis=2)  # (K, 3, 3), columns x, y, z
    size = np.stack([length, np.full_like(length, width), np.full_like(length, depth)], axis=1)
    return _boxes((p0 + p1) / 2, size, rotation)


def _prism(frame: _Frame, profile: np.ndarray, c0: float, c1: float, lean: float = 0.0) -> Mesh:
    """A closed prism: a convex (along, up) ``profile`` (K, 2) extruded from across c0 to c1.

    ``lean``: both sides lean inward by this many metres per metre of height above the
    profile's lowest point (a car's tumblehome); 0 gives upright sides.
    """
    k = len(profile)
    inset = lean * (profile[:, 1] - profile[:, 1].min())
    side0 = frame.at(profile[:, 0], c0 + inset, profile[:, 1])
    side1 = frame.at(profile[:, 0], c1 - inset, profile[:, 1])
    vertices = np.vstack([side0, side1])
    j = np.arange(k)
    jn = (j + 1) % k
    walls = np.concatenate([np.stack([j, jn, k + jn], -1), np.stack([j, k + jn, k + j], -1)])
    fan = np.arange(1, k - 1)
    cap0 = np.stack([np.zeros(k - 2, int), fan + 1, fan], -1)
    cap1 = np.stack([np.full(k - 2, k), k + fan, k + fan + 1], -1)
    return vertices, np.vstack([walls, cap0, cap1])


def _frustum(p0: np.ndarray, p1: np.ndarray, r0: float, r1: float, sections: int = 16) -> Mesh:
    """A capped truncated cone on the vertical axis p0 -> p1 with radii r0 (bottom), r1 (top)."""
    ang = np.linspace(0.0, 2 * np.pi, sections, endpoint=False)
    ring = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], axis=1)
    vertices = np.vstack([p0 + r0 * ring, p1 + r1 * ring, [p0, p1]])
    j = np.arange(sections)
    jn = (j + 1) % sections
    s = sections
    faces = np.vstack(
        [
            np.stack([j, jn, s + jn], -1),
            np.stack([j, s + jn, s + j], -1),
            np.stack([np.full(s, 2 * s), jn, j], -1),
            np.stack([np.full(s, 2 * s + 1), s + j, s + jn], -1),
        ]
    )
    return vertices, faces


# --------------------------------------------------------------------------------------------
# Builders: each adds meshes and returns (class, paint or None, geometry dict)
# --------------------------------------------------------------------------------------------


def _mesh_fence(f: _Frame, length, paint, add, rng) -> tuple[int, str | None, dict]:
    """Welded-wire mesh fence: posts every ~2 m, top/bottom frame pipes, 4 mm wire grid."""
    cls = TruthClass.FENCE
    height = float(rng.uniform(0.9, 1.8))
    post_r = float(rng.choice([0.0243, 0.0305]))
    frame_r = 0.0136
    pitch = float(rng.choice([0.05, 0.05, 0.06]))
    wire = float(rng.uniform(0.003, 0.004))
    bottom = 0.05
    n_units = max(1, int(round(length / 2.0)))
    post_a = np.linspace(0.0, length, n_units + 1)
    for a in post_a:  # domed posts whose top is the fence height
        add(cylinder(f.at(a), f.at(a, 0, height - post_r), post_r, sections=12), cls, paint)
        add(dome(f.at(a, 0, height - post_r), post_r, sections=12, rings=3), cls, paint)
    for u in (bottom, height - 0.03):
        add(tube(f.at(np.array([0.0, length]), 0, u), frame_r, sections=10), cls, paint)
    # Wires span the whole length / height as single thin boxes: 12 faces each.
    uprights = np.arange(pitch / 2, length, pitch)
    top = height - 0.03
    add(_segment_boxes(f.at(uprights, 0, bottom), f.at(uprights, 0, top), wire, wire), cls, paint)
    rows = np.arange(bottom + pitch, top, pitch)
    add(_segment_boxes(f.at(0.0, 0, rows), f.at(length, 0, rows), wire, wire), cls, paint)
    geom = {
        "height": height,
        "post_radius": post_r,
        "post_positions": f.at(post_a).tolist(),
        "frame_radius": frame_r,
        "wire_pitch": pitch,
        "wire_width": wire,
    }
    return cls, paint, geom


def _bar_fence(f: _Frame, length, paint, add, rng) -> tuple[int, str | None, dict]:
    """Vertical-bar fence (tategoshi): square bars every 10-12 cm between flat-bar rails."""
    cls = TruthClass.FENCE
    height = float(rng.uniform(0.8, 1.2))
    pitch = float(rng.uniform(0.10, 0.12))
    bar = float(rng.choice([0.013, 0.016, 0.019]))
    post = 0.05
    rail_h, rail_d = 0.04, 0.012
    bottom = 0.08
    n_units = max(1, int(round(length / 2.0)))
    post_a = np.linspace(0.0, length, n_units + 1)
    for a in post_a:
        add(f.box(a, 0.0, height / 2, (post, post, height)), cls, paint)
    for u in (bottom, height - rail_h / 2):
        add(f.box(length / 2, 0.0, u, (length, rail_d, rail_h)), cls, paint)
    bars_a = np.arange(pitch / 2, length, pitch)
    centres = f.at(bars_a, 0.0, (bottom + height) / 2)
    add(_boxes(centres, (bar, bar, height - bottom), f.rotation), cls, paint)
    geom = {
        "height": height,
        "bar_pitch": pitch,
        "bar_width": bar,
        "post_width": post,
        "post_positions": f.at(post_a).tolist(),
        "n_bars": int(len(bars_a)),
    }
    return cls, paint, geom


def _low_wall(f: _Frame, length, paint, add, rng) -> tuple[int, str | None, dict]:
    """A concrete retaining / parapet wall 0.4-1.0 m high, centred on the base line."""
    cls = TruthClass.WALL
    height = float(rng.uniform(0.4, 1.0))
    thickness = float(rng.uniform(0.12, 0.25))
    add(f.box(length / 2, 0.0, height / 2, (length, thickness, height)), cls, "concrete")
    return cls, None, {"height": height, "thickness": thickness, "material": "concrete"}


def _bicycle_rack(f: _Frame, length, paint, add, rng) -> tuple[int, str | None, dict]:
    """Inverted-U stands (phi 48.6 mm) standing across the line every ~0.8-1.0 m."""
    cls = TruthClass.BICYCLE_RACK
    height = float(rng.uniform(0.70, 0.85))
    width = float(rng.uniform(0.45, 0.70))
    spacing = float(rng.uniform(0.8, 1.0))
    r = 0.0243
    bend = width / 2
    n = max(1, int(length // spacing) + 1)
    stands_a = np.arange(n) * spacing
    ang = np.radians(np.arange(180.0, -0.1, -10.0))  # arc from one leg to the other
    c = np.concatenate([[-bend], bend * np.cos(ang), [bend]])
    u = np.concatenate([[0.0], height - r - bend + bend * np.sin(ang), [0.0]])
    axes = []
    for a in stands_a:
        axis = f.at(np.full_like(c, a), c, u)
        add(tube(axis, r, sections=10), cls, paint)
        axes.append(axis.tolist())
    geom = {"height": height, "width": width, "spacing": spacing, "radius": r, "axes": axes}
    return cls, paint, geom


def _bollard(f: _Frame, length, paint, add, rng) -> tuple[int, str | None, dict]:
    """A steel bollard 0.8-1.0 m high, phi 101.6-165.2 mm, dome top."""
    cls = TruthClass.BOLLARD
    height = float(rng.uniform(0.8, 1.0))
    radius = float(rng.choice([0.0508, 0.0572, 0.0699, 0.0826]))
    body = height - radius
    add(cylinder(f.base, f.at(0, 0, body), radius, sections=16), cls, paint)
    add(dome(f.at(0, 0, body), radius, sections=16), cls, paint)
    return cls, paint, {"height": height, "radius": radius}


def _utility_pole(f: _Frame, length, paint, add, rng) -> tuple[int, str | None, dict]:
    """A tapered utility pole 8-12 m tall (base radius 0.15-0.2 m) with a crossarm."""
    cls = TruthClass.POLE
    height = float(rng.uniform(8.0, 12.0))
    r0 = float(rng.uniform(0.15, 0.20))
    r1 = max(r0 - height / 150.0, 0.07)  # concrete poles taper 1/75 on the diameter
    add(_frustum(f.base, f.at(0, 0, height), r0, r1, sections=20), cls, paint)
    arm_len = float(rng.uniform(1.2, 1.8))
    arm_u = height - 0.6
    # The crossarm runs across the road (the wires run along it), bolted on the pole's side.
    arm_a = r1 + 0.045
    arm = segment_box(f.at(arm_a, -arm_len / 2, arm_u), f.at(arm_a, arm_len / 2, arm_u), 0.09, 0.09)
    add(arm, cls, "galvanised")
    geom = {
        "height": height,
        "radius_base": r0,
        "radius_top": r1,
        "crossarm": {"height": arm_u, "length": arm_len, "width": 0.09},
    }
    return cls, paint, geom


def _sign_pole(f: _Frame, length, paint, add, rng) -> tuple[int, str | None, dict]:
    """A sign post (r 0.03-0.038 m, ~3 m) with a round or square plate facing traffic."""
    cls = TruthClass.SIGN
    height = float(rng.uniform(2.8, 3.3))
    radius = float(rng.choice([0.0305, 0.0381]))
    body = height - radius  # the dome tops out at ``height``
    add(cylinder(f.base, f.at(0, 0, body), radius, sections=12), cls, paint)
    add(dome(f.at(0, 0, body), radius, sections=12, rings=3), cls, paint)
    shape = str(rng.choice(["round", "square"]))
    plate_mat = str(rng.choice(["sign_blue", "sign_red"]))
    size = float(rng.choice([0.6, 0.8]))
    centre_u = height - size / 2 - 0.05
    a0, a1 = radius + 0.01, radius + 0.02  # plate just in front of the post, facing along
    if shape == "round":
        plate = cylinder(f.at(a0, 0, centre_u), f.at(a1, 0, centre_u), size / 2, sections=24)
    else:
        plate = f.box((a0 + a1) / 2, 0.0, centre_u, (a1 - a0, size, size))
    add(plate, cls, plate_mat)
    geom = {
        "height": height,
        "radius": radius,
        "plate": {"shape": shape, "size": size, "centre_height": centre_u, "material": plate_mat},
    }
    return cls, paint, geom


def _tree(f: _Frame, length, paint, add, rng) -> tuple[int, str | None, dict]:
    """A street tree: bark trunk and a noisy ellipsoidal foliage canopy (displaced icosphere)."""
    cls = TruthClass.TREE
    trunk_r = float(rng.uniform(0.08, 0.2))
    crown_base = float(rng.uniform(1.8, 3.0))
    crown_rh = float(rng.uniform(1.2, 2.5))  # horizontal radius
    crown_rv = float(rng.uniform(1.0, 1.3)) * crown_rh
    centre_u = crown_base + crown_rv * 0.8
    add(_frustum(f.base, f.at(0, 0, centre_u), trunk_r, trunk_r * 0.6, sections=12), cls, "bark")
    verts, faces = sphere(np.zeros(3), 1.0, subdivisions=3)
    # Smooth radial noise: a few random plane waves over the unit sphere.
    k = 6
    dirs = rng.normal(size=(k, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    freq = rng.uniform(1.5, 4.0, k)
    phase = rng.uniform(0, 2 * np.pi, k)
    amp = rng.uniform(0.04, 0.10, k)
    noise = (amp * np.sin(verts @ dirs.T * freq + phase)).sum(axis=1)
    scale = np.array([crown_rh, crown_rh, crown_rv]) * (1.0 + noise)[:, None]
    add((f.at(0, 0, centre_u) + verts * scale, faces), cls, "foliage")
    top = centre_u + float((verts[:, 2] * scale[:, 2]).max())
    geom = {
        "height": top,
        "trunk_radius": trunk_r,
        "crown_base": crown_base,
        "crown_centre_height": centre_u,
        "crown_radius_horizontal": crown_rh,
        "crown_radius_vertical": crown_rv,
    }
    return cls, None, geom


def _parked_car(f: _Frame, length, paint, add, rng) -> tuple[int, str | None, dict]:
    """A parked car centred on ``base`` (road surface), facing ``along``."""
    cls = TruthClass.CAR
    car_len = float(rng.uniform(3.4, 4.8))  # kei car to mid-size
    width = float(rng.uniform(1.48, 1.80))
    height = float(rng.uniform(1.45, 1.70))
    wheel_r = float(rng.uniform(0.28, 0.33))
    wheel_w = 0.19
    colour = str(rng.choice(["car_red", "car_blue", "car_silver", "car_black"]))
    clearance = 0.15
    belt = height * 0.55  # top of the body (window line)
    half = car_len / 2
    body = np.array(
        [
            [-half, clearance],
            [half, clearance],
            [half, belt - 0.15],
            [half - 0.25, belt],
            [-half + 0.1, belt],
            [-half, belt - 0.1],
        ]
    )
    add(_prism(f, body, -width / 2, width / 2), cls, colour)
    roof_t = 0.05
    cabin = np.array(
        [
            [-half + 0.25, belt],
            [half - 0.9, belt],
            [half - 1.5, height - roof_t],
            [-half + 0.45, height - roof_t],
        ]
    )
    # The side windows start just inside the doors and lean in towards the roof, as on real
    # cars, so a side seen from the road is one surface from the sills to the roof.
    lean = 0.35
    glass_inset = 0.03
    add(_prism(f, cabin, -width / 2 + glass_inset, width / 2 - glass_inset, lean), cls, "car_glass")
    roof_inset = glass_inset + lean * (height - roof_t - belt)
    roof = np.array(
        [
            [-half + 0.45, height - roof_t],
            [half - 1.5, height - roof_t],
            [half - 1.5, height],
            [-half + 0.45, height],
        ]
    )
    add(_prism(f, roof, -width / 2 + roof_inset, width / 2 - roof_inset), cls, colour)
    wheelbase = car_len * 0.62
    for a in (-wheelbase / 2, wheelbase / 2):
        for side in (-1.0, 1.0):
            c_out = side * width / 2
            c_in = c_out - side * wheel_w
            add(
                cylinder(f.at(a, c_in, wheel_r), f.at(a, c_out, wheel_r), wheel_r, sections=16),
                cls,
                "rubber",
            )
    geom = {
        "length": car_len,
        "width": width,
        "height": height,
        "wheel_radius": wheel_r,
        "wheelbase": wheelbase,
        "material": colour,
    }
    return cls, None, geom


def _facade(f: _Frame, length, paint, add, rng) -> tuple[int, str | None, dict]:
    """A building front 6-15 m tall whose road-facing face lies on the base line, with
    windows recessed 0.15 m (glass) in a grid of piers and floor bands."""
    cls = TruthClass.BUILDING
    height = float(rng.uniform(6.0, 15.0))
    depth = float(rng.uniform(5.0, 10.0))
    mat = str(rng.choice(["plaster", "brick"]))
    recess = 0.15
    floor_h = float(rng.uniform(2.8, 3.4))
    n_floors = max(1, int(height // floor_h))
    win_w = float(rng.uniform(0.9, 1.8))
    win_h = float(rng.uniform(1.1, 1.6))
    bay = win_w + float(rng.uniform(0.6, 1.5))
    n_bays = max(1, int(length // bay))
    margin = (length - n_bays * bay) / 2
    # Body behind the recess: its front face is the window (glass) plane.
    add(f.box(length / 2, -recess - depth / 2, height / 2, (length, depth, height)), cls, mat)
    sill = (floor_h - win_h) / 2 + 0.2
    win_a0 = margin + (bay - win_w) / 2 + np.arange(n_bays) * bay
    win_u0 = np.arange(n_floors) * floor_h + sill
    win_u0 = win_u0[win_u0 + win_h < height - 0.3]
    c_front = -recess / 2
    # Horizontal bands between window rows, then piers between windows of each row.
    edges = np.concatenate([[0.0], np.stack([win_u0, win_u0 + win_h], 1).ravel(), [height]])
    for u0, u1 in edges.reshape(-1, 2):
        if u1 - u0 > 1e-6:
            add(f.box(length / 2, c_front, (u0 + u1) / 2, (length, recess, u1 - u0)), cls, mat)
    piers = np.concatenate([[0.0], np.stack([win_a0, win_a0 + win_w], 1).ravel(), [length]])
    for u0 in win_u0:
        for a0, a1 in piers.reshape(-1, 2):
            if a1 - a0 > 1e-6:
                add(
                    f.box((a0 + a1) / 2, c_front, u0 + win_h / 2, (a1 - a0, recess, win_h)),
                    cls,
                    mat,
                )
        for a0 in win_a0:
            add(
                f.box(a0 + win_w / 2, -recess + 0.005, u0 + win_h / 2, (win_w, 0.01, win_h)),
                cls,
                "glass",
            )
    windows = [
        {"along": [float(a), float(a + win_w)], "up": [float(u), float(u + win_h)]}
        for u in win_u0
        for a in win_a0
    ]
    geom = {
        "height": height,
        "depth": depth,
        "material": mat,
        "window_recess": recess,
        "windows": windows,
    }
    return cls, None, geom


def _pedestrian(f: _Frame, length, paint, add, rng) -> tuple[int, str | None, dict]:
    """A standing person 1.6-1.85 m tall facing ``along``: legs, torso, arms, head."""
    cls = TruthClass.PEDESTRIAN
    height = float(rng.uniform(1.6, 1.85))
    top_mat = str(rng.choice(["cloth_dark", "cloth_light"]))
    leg_mat = str(rng.choice(["cloth_dark", "cloth_light"]))
    hip = 0.47 * height
    shoulder = 0.81 * height
    head_r = 0.065 * height
    leg_r = 0.038 * height
    shoulder_w = 0.23 * height
    stride = float(rng.uniform(-0.15, 0.15))
    # Feet lifted by the tilt of the leg so the slanted end ring stays above the ground.
    foot = leg_r * abs(stride) / hip + 1e-3
    for side, s in ((-1, stride), (1, -stride)):
        leg = f.at([s, 0.0], side * 0.09 * height / 1.7, [foot, hip])
        add(tube(leg, leg_r, sections=10), cls, leg_mat)
    add(
        f.box(0.0, 0.0, (hip + shoulder) / 2, (0.13 * height, shoulder_w, shoulder - hip)),
        cls,
        top_mat,
    )
    for side in (-1, 1):
        c = side * (shoulder_w / 2 + 0.045)
        add(
            tube(f.at([0.0, -stride / 2], c, [shoulder - 0.03, 0.5 * height]), 0.04, sections=8),
            cls,
            top_mat,
        )
    neck_top = height - 2 * head_r
    add(cylinder(f.at(0, 0, shoulder), f.at(0, 0, neck_top + 0.02), 0.05, sections=8), cls, "skin")
    add(sphere(f.at(0, 0, height - head_r), head_r, subdivisions=2), cls, "skin")
    return cls, None, {"height": height, "shoulder_width": shoulder_w, "facing": f.along.tolist()}


_BUILDERS: dict[str, Callable] = {
    "mesh_fence": _mesh_fence,
    "bar_fence": _bar_fence,
    "low_wall": _low_wall,
    "bicycle_rack": _bicycle_rack,
    "bollard": _bollard,
    "utility_pole": _utility_pole,
    "sign_pole": _sign_pole,
    "tree": _tree,
    "parked_car": _parked_car,
    "facade": _facade,
    "pedestrian": _pedestrian,
}


def build_confounder(
    kind: str,
    *,
    base: np.ndarray,
    along: np.ndarray,
    toward_road: np.ndarray,
    length: float,
    paint: str,
    object_id: int,
    builder: MeshBuilder,
    rng: np.random.Generator,
) -> dict:
    """Add one confounding object to ``builder`` and return its truth record.

    Parameters
    ----------
    kind : str, one of :data:`CONFOUNDER_KINDS`
    base : (3,) float64, a ground point (m). Start of extended kinds, centre of point-like ones
        (a parked car's centre on the road surface).
    along : (3,) float64, horizontal road direction (normalised here).
    toward_road : (3,) float64, horizontal direction to the road (made orthogonal to ``along``).
    length : float, metres along ``along`` for extended kinds (:data:`EXTENDED_KINDS`); ignored
        for point-like ones.
    paint : str, a key of ``PAINTS``; used by fences, racks, bollards and poles. Walls, trees,
        cars, facades and pedestrians choose their own materials (record ``paint`` is None).
    object_id : int, written on every face.
    builder : MeshBuilder
    rng : numpy Generator for size and shape variations (same seed -> same geometry).

    Returns
    -------
    dict
        ``{"id", "kind", "class", "paint", "geometry"}`` in plain JSON types; ``geometry`` holds
        ``base``, ``along``, ``toward_road``, ``length`` (extended kinds) and kind-specific
        exact parameters, always including ``height`` (m above ``base``).
    """
    if kind not in _BUILDERS:
        raise ValueError(f"unknown confounder kind {kind!r}; expected one of {CONFOUNDER_KINDS}")
    if paint not in PAINTS:
        raise ValueError(f"unknown paint {paint!r}; expected one of {sorted(PAINTS)}")
    base = np.asarray(base, np.float64).reshape(-1)
    if base.shape != (3,) or not np.isfinite(base).all():
        raise ValueError(f"base must be a finite (3,) point, got {base!r}")
    a = _horizontal_unit(along, "along")
    t = _horizontal_unit(toward_road, "toward_road")
    t = t - np.dot(t, a) * a
    if np.linalg.norm(t) < 1e-6:
        raise ValueError("toward_road must not be parallel to along")
    t /= np.linalg.norm(t)
    extended = kind in EXTENDED_KINDS
    if extended and not (np.isfinite(length) and length > 0.1):
        raise ValueError(f"{kind} needs a finite length > 0.1 m, got {length!r}")
    oid = int(object_id)

    def add(mesh: Mesh, cls: int, material: str) -> None:
        builder.add(mesh, cls=cls, object_id=oid, material=material)

    frame = _Frame(base, a, t)
    cls, used_paint, geom = _BUILDERS[kind](frame, float(length), paint, add, rng)
    geometry = {"base": base.tolist(), "along": a.tolist(), "toward_road": t.tolist()}
    if extended:
        geometry["length"] = float(length)
    geometry.update(geom)
    return {
        "id": oid,
        "kind": kind,
        "class": int(cls),
        "paint": used_paint,
        "geometry": geometry,
    }
