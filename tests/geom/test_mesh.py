"""The shared mesh primitives: tubes (uniform and exact mitres), plates, volumes, orientation."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from guardrail_core.geom.mesh import (
    dome,
    outward,
    plate,
    signed_volume,
    thick_outline,
    tube,
)


def _line_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance (N,) of points (N, 3) from the infinite line through a and b."""
    d = (b - a) / np.linalg.norm(b - a)
    rel = points - a
    return np.linalg.norm(rel - np.outer(rel @ d, d), axis=1)


def _closed(v: np.ndarray, f: np.ndarray) -> trimesh.Trimesh:
    m = trimesh.Trimesh(v, f, process=False)
    assert m.is_watertight and m.is_winding_consistent
    return m


def test_straight_tube_radius_and_volume():
    r, length, sections = 0.0243, 2.0, 64
    axis = np.array([[0.0, 0.8, 0.0], [length, 0.8, 0.0]])
    v, f = tube(axis, r, sections=sections, caps=True)
    ring = v[:-2]  # the two cap centres come last
    np.testing.assert_allclose(_line_distance(ring, axis[0], axis[1]), r, atol=1e-9)
    m = _closed(v, f)
    polygon_area = sections / 2 * np.sin(2 * np.pi / sections) * r**2
    assert m.volume == pytest.approx(polygon_area * length, rel=1e-9)
    assert m.volume == pytest.approx(np.pi * r**2 * length, rel=0.02)
    assert signed_volume(v, f) == pytest.approx(m.volume, rel=1e-9)


def test_exact_mitre_keeps_the_radius_from_both_segments():
    t = np.linspace(0.0, 4.0, 7)  # a coarse helix: bends of about 60°, none near the clip
    axis = np.c_[np.cos(t), np.sin(t), 0.3 * t]
    r, m = 0.05, 12
    v, f = tube(axis, r, sections=m, caps=True, exact_mitre=True)
    rings = v[:-2].reshape(len(axis), m, 3)
    for i in range(len(axis)):
        for k in (i - 1, i):  # the segments on either side of vertex i
            if 0 <= k < len(axis) - 1:
                np.testing.assert_allclose(
                    _line_distance(rings[i], axis[k], axis[k + 1]), r, atol=1e-9
                )
    _closed(v, f)


def test_default_tube_mitre_is_unchanged():
    """The simulator's tube: interior rings scaled uniformly by 1 / cos(half the bend)."""
    axis = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]])
    v, _ = tube(axis, 0.1, sections=8, caps=False)
    middle = v.reshape(3, 8, 3)[1]
    np.testing.assert_allclose(np.linalg.norm(middle - axis[1], axis=1), 0.1 * np.sqrt(2))


def test_plate_is_closed_outward_and_has_the_section_area():
    z = np.linspace(0.0, 0.06, 30)
    section = np.c_[0.3 * (z - 0.03) ** 2, np.linspace(0.35, 0.7, 30)]  # (z, y)
    t, length = 0.003, 2.0
    path = np.array([[0.0, 0.0, 0.0], [length, 0.0, 0.0]])
    across = np.tile([0.0, 0.0, 1.0], (2, 1))
    up = np.tile([0.0, 1.0, 0.0], (2, 1))
    v, f = plate(section, t, path, across, up, caps=True)
    m = _closed(v, f)
    arc = np.linalg.norm(np.diff(section, axis=0), axis=1).sum()
    assert m.volume == pytest.approx(t * arc * length, rel=0.01)
    # Reversing the path or the section still gives outward faces.
    v2, f2 = plate(section[::-1], t, path[::-1], across, up)
    assert _closed(v2, f2).volume == pytest.approx(m.volume, rel=1e-9)


def test_thick_outline_offsets_by_half_the_thickness():
    section = np.c_[np.zeros(5), np.linspace(0.0, 1.0, 5)]
    outline = thick_outline(section, 0.004)
    assert outline.shape == (11, 2)
    np.testing.assert_allclose(np.abs(outline[:, 0]), 0.002)


def test_dome_apex_and_outward_flip():
    v, f = dome(np.array([1.0, 2.0, 3.0]), 0.05, sections=16, rings=4)
    assert v[:, 2].max() == pytest.approx(3.05)
    assert len(f) == 16 * (2 * 4 - 1)
    closed = tube(np.array([[0.0, 0, 0], [0, 0, 1.0]]), 0.1, sections=16)
    inverted = (closed[0], closed[1][:, ::-1])
    assert signed_volume(*inverted) < 0
    assert signed_volume(*outward(inverted)) == pytest.approx(-signed_volume(*inverted))


@pytest.mark.parametrize(
    ("section", "thickness"),
    [(np.zeros((1, 2)), 0.003), (np.array([[0.0, 0.0], [0.0, 0.0]]), 0.003), (np.eye(2), 0.0)],
)
def test_plate_rejects_degenerate_input(section, thickness):
    path = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    with pytest.raises(ValueError):
        plate(section, thickness, path, np.tile([0, 0, 1.0], (2, 1)), np.tile([0, 1.0, 0], (2, 1)))
