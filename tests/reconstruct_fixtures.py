"""Seeded synthetic guardrail runs for the reconstruction tests (numpy only, fast).

A run of pipe units: poles (vertical cylinders standing on the ground) joined by horizontal
rails, optionally with balusters that stop at the lowest rail. The scanner sees the road side
of every cylinder (a +-75 degree arc around the direction to the road) with Gaussian range
noise. Straight or on an arc; the ground has a grade.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

UP = np.array([0.0, 0.0, 1.0])


@dataclass
class SynthRun:
    xyz: np.ndarray  # (N, 3) guardrail points
    is_pole: np.ndarray  # (N,) bool
    ground: np.ndarray  # (G, 3) ground points
    poles: np.ndarray  # (P, 3) true ground points of the pole axes, in order
    toward_road: np.ndarray  # (3,)
    pole_radius: float
    pole_height: float


def _front_arc(rng, n, normal, side):
    """(n, 3) unit directions within +-75 degrees of ``normal`` in the plane (normal, side)."""
    t = rng.uniform(-np.radians(75), np.radians(75), n)
    return np.cos(t)[:, None] * normal + np.sin(t)[:, None] * side


def make_run(
    n_units: int = 4,
    *,
    spacing: float = 2.0,
    arc_radius: float | None = None,
    grade: float = 0.02,
    pole_radius: float = 0.0305,
    pole_height: float = 0.8,
    rails: tuple[float, ...] = (0.4, 0.76),
    rail_radius: float = 0.0243,
    balusters: bool = False,
    missing: tuple[int, ...] = (),
    noise: float = 0.005,
    pole_points: int = 80,
    rail_points_per_m: int = 120,
    seed: int = 0,
) -> SynthRun:
    rng = np.random.default_rng(seed)
    n_poles = n_units + 1
    s = np.arange(n_poles) * spacing
    if arc_radius is None:
        xy = np.stack([s, np.zeros_like(s)], 1)
    else:  # on an arc bending toward the road (-y side at the start)
        ang = s / arc_radius
        xy = np.stack([arc_radius * np.sin(ang), -arc_radius * (1 - np.cos(ang))], 1)
    poles = np.column_stack([xy + [10.0, 20.0], 1.0 + grade * s])
    pts, pole_mask = [], []
    normal_list = []
    for i in range(n_units):
        a, b = poles[i], poles[i + 1]
        along = (b - a) * [1, 1, 0]
        along /= np.linalg.norm(along)
        normal_list.append(np.cross(along, UP))  # road side: x × up
    normals = np.array(normal_list)
    pole_normal = np.vstack([normals[:1], (normals[:-1] + normals[1:]) / 2, normals[-1:]])
    pole_normal /= np.linalg.norm(pole_normal, axis=1, keepdims=True)
    for i, g in enumerate(poles):
        if i in missing:
            continue
        n = pole_normal[i]
        side = np.cross(UP, n)
        d = _front_arc(rng, pole_points, n, side)
        h = rng.uniform(0.0, pole_height, pole_points)
        r = pole_radius + rng.normal(0, noise, pole_points)
        pts.append(g + r[:, None] * d + h[:, None] * UP)
        pole_mask.append(np.ones(pole_points, bool))
    for i in range(n_units):
        a, b = poles[i], poles[i + 1]
        n = normals[i]
        length = np.linalg.norm((b - a)[:2])
        k = int(rail_points_per_m * length)
        for y in rails:
            t = rng.uniform(0, 1, k)
            axis = a + t[:, None] * (b - a) + y * UP
            d = _front_arc(rng, k, n, UP)
            r = rail_radius + rng.normal(0, noise, k)
            pts.append(axis + r[:, None] * d)
            pole_mask.append(np.zeros(k, bool))
        if balusters:
            lo = min(rails)
            for x in np.arange(0.25, length - 0.1, 0.25):
                base = a + (b - a) * (x / length) + lo * UP
                m = 40
                h = rng.uniform(0.0, max(rails) - lo, m)
                side = np.cross(UP, n)
                d = _front_arc(rng, m, n, side)
                r = 0.011 + rng.normal(0, noise, m)
                pts.append(base + r[:, None] * d + h[:, None] * UP)
                pole_mask.append(np.zeros(m, bool))
    xyz = np.concatenate(pts)
    # Ground: a band on both sides of every unit, following the grade.
    ground_parts = []
    for i in range(n_units):
        a, b = poles[i], poles[i + 1]
        u = rng.uniform([-0.3, -1.5], [1.3, 1.5], (1500, 2))
        base = a + u[:, :1] * (b - a)
        ground_parts.append(base + u[:, 1:] * normals[i] + rng.normal(0, 0.003, (len(u), 1)) * UP)
    ground = np.concatenate(ground_parts)
    keep = np.array([i not in missing for i in range(n_poles)])
    return SynthRun(
        xyz=xyz,
        is_pole=np.concatenate(pole_mask),
        ground=ground,
        poles=poles[keep] if missing else poles,
        toward_road=normals[n_units // 2],
        pole_radius=pole_radius,
        pole_height=pole_height,
    )
