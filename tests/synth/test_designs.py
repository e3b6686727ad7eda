"""Guardrail designs: shipped YAML, loader validation, and the built mesh against its truth."""

from __future__ import annotations

import json
import textwrap

import numpy as np
import pytest

from guardrail_core.classes import TruthClass
from guardrail_core.errors import SceneSpecError
from guardrail_core.synth.designs import (
    ARC_STEP_DEG,
    DESIGNS_DIR,
    Design,
    list_designs,
    load_design,
    scaled_height,
    thrie_beam_section,
    w_beam_section,
)
from guardrail_core.synth.guardrail import PIPE_SECTIONS, build_guardrail_run
from guardrail_core.synth.mesh import MeshBuilder

REQUIRED = [
    "pipe_simple_2",
    "pipe_simple_3",
    "pipe_verticals",
    "pipe_diagonal_x",
    "pipe_arch",
    "pipe_wave",
    "beam_w",
    "beam_thrie",
]


# ------------------------------------------------------------------------------ shipped designs


def test_shipped_designs_load_and_are_realistic():
    names = list_designs()
    assert set(REQUIRED) <= set(names)
    designs = [load_design(n) for n in names]
    assert sum(d.type == "pipe" for d in designs) >= 4
    assert sum(d.type == "beam" for d in designs) >= 2
    for d in designs:
        assert isinstance(d, Design)
        assert d.name == (DESIGNS_DIR / f"{d.name}.yaml").stem
        assert d.description, d.name
        if d.type == "pipe":
            assert d.unit_length == pytest.approx(2.0)
            assert 0.8 <= d.pole.height <= 1.15
            assert 0.025 <= d.pole.radius <= 0.04
            assert d.pipes and not d.beams
            for p in d.pipes:
                assert 0.010 <= p.radius <= 0.025
                assert p.points.dtype == np.float64 and p.points.shape[1] == 2
                assert p.points[:, 0].min() >= 0 and p.points[:, 0].max() <= d.unit_length
                assert not p.points.flags.writeable
        else:
            assert d.unit_length == pytest.approx(4.0)
            assert d.pole.radius == pytest.approx(0.0699)
            assert d.beams
            for b in d.beams:
                centre = 0.5 * (b.section[:, 1].min() + b.section[:, 1].max())
                assert 0.5 <= centre <= 0.65
                assert b.section[:, 0].min() > d.pole.radius  # clear of the post
                assert len(b.section) >= 40


def test_every_shipped_file_has_a_description_comment():
    for path in DESIGNS_DIR.glob("*.yaml"):
        assert "# description:" in path.read_text(), path


def test_pipe_kinds_of_shipped_designs():
    kinds = {n: [p.kind for p in load_design(n).pipes] for n in REQUIRED[:6]}
    assert kinds["pipe_simple_2"] == ["horizontal"] * 2
    assert kinds["pipe_simple_3"] == ["horizontal"] * 3
    assert kinds["pipe_verticals"].count("vertical") >= 8
    assert kinds["pipe_diagonal_x"].count("diagonal") == 2
    assert "curved" in kinds["pipe_arch"]
    assert "curved" in kinds["pipe_wave"]


def test_arc_is_sampled_finely_and_exactly():
    arch = load_design("pipe_arch")
    arc = next(p for p in arch.pipes if p.kind == "curved")
    rel = arc.points - np.array([1.0, 0.2])
    assert np.allclose(np.linalg.norm(rel, axis=1), 0.55)
    step = np.degrees(np.diff(np.unwrap(np.arctan2(rel[:, 1], rel[:, 0]))))
    assert np.all(np.abs(step) <= ARC_STEP_DEG + 1e-9)
    assert np.allclose(arc.points[[0, -1]], [[1.55, 0.2], [0.45, 0.2]])


def test_w_beam_and_thrie_beam_sections():
    w = load_design("beam_w").beams[0].section
    tall = np.ptp(w[:, 1])
    assert 0.31 <= tall <= 0.35
    assert 0.07 <= np.ptp(w[:, 0]) <= 0.10
    assert len(w) >= 40
    # Two ridges: local maxima of across along the section.
    for section, ridges in ((w_beam_section(), 2), (thrie_beam_section(), 3)):
        a = section[:, 0]
        peaks = np.flatnonzero((a[1:-1] > a[:-2]) & (a[1:-1] >= a[2:]))
        assert len(peaks) == ridges
        # Smooth: no kink sharper than ~25 degrees between consecutive segments.
        seg = np.diff(section, axis=0)
        ang = np.arctan2(seg[:, 0], seg[:, 1])
        assert np.abs(np.diff(ang)).max() < np.radians(25)
    assert 0.45 <= np.ptp(load_design("beam_thrie").beams[0].section[:, 1]) <= 0.55


# ------------------------------------------------------------------------------ bad specs

GOOD = """
type: pipe
unit_length: 2.0
pole: {radius: 0.03, height: 0.8}
pipes:
  - {points: [[0, 0.7], [2, 0.7]], radius: 0.02}
"""


def _write(tmp_path, text, name="custom.yaml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def test_load_by_path_and_default_name(tmp_path):
    d = load_design(_write(tmp_path, GOOD))
    assert d.name == "custom" and d.type == "pipe" and d.pole.cap is True
    assert d.pipes[0].kind == "horizontal"


@pytest.mark.parametrize(
    ("text", "key"),
    [
        (GOOD.replace("type: pipe", "type: rope"), "type"),
        (GOOD.replace("radius: 0.02}", "}"), "pipes[0].radius"),
        (GOOD.replace("radius: 0.02", "radius: -0.02"), "pipes[0].radius"),
        (GOOD.replace("radius: 0.02", "radius: 0"), "pipes[0].radius"),
        (GOOD.replace("[2, 0.7]", "[2.5, 0.7]"), "pipes[0].points"),
        (GOOD.replace("[0, 0.7]", "[-0.1, 0.7]"), "pipes[0].points"),
        (GOOD.replace("[0, 0.7]", "[0, -0.7]"), "pipes[0].points"),
        (GOOD.replace("radius: 0.02", "radius: 0.02, kind: vertical"), "pipes[0].kind"),
        (GOOD.replace("radius: 0.02", "radius: 0.02, kind: spiral"), "pipes[0].kind"),
        (GOOD.replace("radius: 0.02", "radius: 0.02, colour: red"), "pipes[0].colour"),
        (GOOD.replace("unit_length: 2.0", "unit_length: two"), "unit_length"),
        (GOOD.replace("unit_length: 2.0\n", ""), "unit_length"),
        (GOOD.replace("pole: {radius: 0.03, height: 0.8}", "pole: {height: 0.8}"), "pole.radius"),
        (GOOD.replace("height: 0.8}", "height: 0.8, cap: maybe}"), "pole.cap"),
        (GOOD + "colour: red\n", "colour"),
        (
            GOOD.replace("pipes:\n  - {points: [[0, 0.7], [2, 0.7]], radius: 0.02}", "pipes: []"),
            "pipes",
        ),
        (GOOD.replace("[[0, 0.7], [2, 0.7]]", "[[0, 0.7]]"), "pipes[0].points"),
        (GOOD.replace("[[0, 0.7], [2, 0.7]]", "[[0, 0.7], [0, 0.7]]"), "pipes[0].points"),
        (
            GOOD.replace(
                "points: [[0, 0.7], [2, 0.7]]",
                "arc: {centre: [1, 0.2], radius: 1.5, from_deg: 0, to_deg: 180}",
            ),
            "pipes[0].arc",
        ),
        (
            GOOD.replace(
                "points: [[0, 0.7], [2, 0.7]]",
                "arc: {centre: [1, 0.2], radius: 0.5, from_deg: 0}",
            ),
            "pipes[0].arc.to_deg",
        ),
        (
            GOOD.replace("points: [[0, 0.7], [2, 0.7]]", "wave: {x: [0, 2], y: 0.5, periods: 1}"),
            "pipes[0].wave.amplitude",
        ),
        (
            """
            type: beam
            unit_length: 4.0
            pole: {radius: 0.07, height: 0.8}
            beams:
              - {section: z_beam, height: 0.6, offset: 0.1, thickness: 0.003}
            """,
            "beams[0].section",
        ),
        (
            """
            type: beam
            unit_length: 4.0
            pole: {radius: 0.07, height: 0.8}
            beams:
              - {section: w_beam, offset: 0.1, thickness: 0.003}
            """,
            "beams[0].height",
        ),
        (
            """
            type: beam
            unit_length: 4.0
            pole: {radius: 0.07, height: 0.8}
            beams:
              - {section: w_beam, height: 0.6, offset: 0.02, thickness: 0.003}
            """,
            "beams[0].offset",
        ),
        (
            """
            type: beam
            unit_length: 4.0
            pole: {radius: 0.07, height: 0.8}
            beams:
              - {section: w_beam, height: 0.6, offset: 0.1}
            """,
            "beams[0].thickness",
        ),
        (
            """
            type: beam
            unit_length: 4.0
            pole: {radius: 0.07, height: 0.8}
            """,
            "beams",
        ),
    ],
)
def test_bad_specs_name_the_file_and_the_key(tmp_path, text, key):
    path = _write(tmp_path, text, "bad_design.yaml")
    with pytest.raises(SceneSpecError) as info:
        load_design(path)
    message = str(info.value)
    assert "bad_design.yaml" in message
    assert key in message, message


def test_unknown_name_missing_file_and_bad_yaml(tmp_path):
    with pytest.raises(SceneSpecError, match="no_such_design"):
        load_design("no_such_design")
    with pytest.raises(SceneSpecError, match="does not exist"):
        load_design(tmp_path / "absent.yaml")
    with pytest.raises(SceneSpecError, match="not valid YAML"):
        load_design(_write(tmp_path, "type: [pipe\n", "broken.yaml"))
    with pytest.raises(SceneSpecError, match="mapping"):
        load_design(_write(tmp_path, "- 1\n- 2\n", "list.yaml"))


# ------------------------------------------------------------------------------ built geometry


def _curved_run(n_poles=3, spacing=2.0, radius=12.0, slope=0.03):
    """Poles on a circle of ``radius`` (chord ~ spacing), rising ``slope``; toward the centre."""
    step = spacing / radius
    t = np.arange(n_poles) * step + 0.2
    poles = np.stack(
        [radius * np.cos(t), radius * np.sin(t), 5.0 + slope * spacing * np.arange(n_poles)], 1
    )
    toward = np.stack([-np.cos(t), -np.sin(t), np.zeros_like(t)], 1)
    return poles, toward


def _segment_distance(points, axis):
    """Distance (N,) from points (N, 3) to the polyline axis (K, 3)."""
    a, b = axis[:-1], axis[1:]
    ab = b - a
    rel = points[:, None, :] - a[None]
    f = np.clip(np.einsum("nkj,kj->nk", rel, ab) / np.einsum("kj,kj->k", ab, ab), 0, 1)
    foot = a[None] + f[..., None] * ab[None]
    return np.linalg.norm(points[:, None, :] - foot, axis=2).min(axis=1)


def _faces_vertices(mesh, cls, object_id):
    sel = (mesh.face_class == cls) & (mesh.face_object == object_id)
    return mesh.vertices[np.unique(mesh.faces[sel])]


@pytest.mark.parametrize("name", ["pipe_simple_3", "pipe_diagonal_x", "pipe_arch", "pipe_wave"])
def test_pipe_tubes_lie_at_their_radius_from_the_truth_axes(name):
    design = load_design(name)
    poles, toward = _curved_run()
    builder = MeshBuilder()
    builder.add((np.zeros((3, 3)), np.array([[0, 1, 2]])), cls=0, object_id=0, material="asphalt")
    rec = build_guardrail_run(design, poles, toward, paint="white", object_id=7, builder=builder)
    mesh = builder.build()
    json.dumps(rec)  # plain JSON types only
    assert rec["id"] == 7 and rec["kind"] == "guardrail" and rec["type"] == "pipe"
    assert rec["design"] == name and rec["paint"] == "white"
    assert len(rec["units"]) == 2 and len(rec["pipes"]) == 2 * len(design.pipes)
    assert not rec["beams"]

    # Every face of the object carries the id; classes are only pole and pipe.
    obj = mesh.face_object == 7
    assert set(np.unique(mesh.face_class[obj])) == {
        TruthClass.GUARDRAIL,
        TruthClass.GUARDRAIL_POLE,
    }

    verts = _faces_vertices(mesh, TruthClass.GUARDRAIL, 7)
    axes = [np.array(p["axis"]) for p in rec["pipes"]]
    radii = np.array([p["radius"] for p in rec["pipes"]])
    ends = np.vstack([a[[0, -1]] for a in axes])
    # Cap centres sit on the axis ends; every other vertex is a ring vertex.
    is_cap = np.linalg.norm(verts[:, None] - ends[None], axis=2).min(axis=1) < 1e-12
    rings = verts[~is_cap]
    dist = np.stack([_segment_distance(rings, a) for a in axes], axis=1)  # (N, pipes)
    err = np.abs(dist - radii[None]).min(axis=1)
    # Straight pipes are exact; at bends the mitre may widen the ring by 1/cos(half bend).
    max_bend = 0.0
    for a in axes:
        if len(a) > 2:
            seg = np.diff(a, axis=0)
            seg /= np.linalg.norm(seg, axis=1, keepdims=True)
            cos = np.clip(np.einsum("ij,ij->i", seg[:-1], seg[1:]), -1, 1)
            max_bend = max(max_bend, float(np.arccos(cos).max()))
    tol = 1e-9 + radii.max() * (1 / np.cos(max_bend / 2) - 1)
    assert err.max() < max(tol, 1e-6)
    # Each pipe owns a full set of ring vertices.
    for k, a in enumerate(axes):
        on_k = np.abs(dist[:, k] - radii[k]) < max(tol, 1e-6)
        assert on_k.sum() >= PIPE_SECTIONS * len(a)

    # Straight pipes are exact: vertices best explained by a straight pipe sit at its radius.
    owner = np.abs(dist - radii[None]).argmin(axis=1)
    straight = np.array([p["kind"] != "curved" for p in rec["pipes"]])
    assert straight[owner].any()
    assert err[straight[owner]].max() < 1e-6

    # Pipe axes are the design scaled between the poles: x=0 / x=L on the pole axes.
    for p in rec["pipes"]:
        unit = rec["units"][p["unit"]]
        p0, p1 = np.array(unit["start"]), np.array(unit["end"])
        axis = np.array(p["axis"])
        spec = design.pipes[rec["pipes"].index(p) % len(design.pipes)]
        f = spec.points[:, 0] / design.unit_length
        expected = p0 + f[:, None] * (p1 - p0) + spec.points[:, 1:2] * np.array([0, 0, 1.0])
        assert np.allclose(axis, expected, atol=1e-12)
        # Axis points lie in the vertical plane through the two pole axes.
        chord = (p1 - p0)[:2]
        normal = np.array([-chord[1], chord[0]]) / np.linalg.norm(chord)
        assert np.abs((axis[:, :2] - p0[:2]) @ normal).max() < 1e-9
        for end, x in ((axis[0], spec.points[0, 0]), (axis[-1], spec.points[-1, 0])):
            if x in (0.0, design.unit_length):
                pole = p0 if x == 0.0 else p1
                assert np.linalg.norm(end[:2] - pole[:2]) < 1e-12

    # Poles in the truth are the input poles.
    assert np.allclose([p["position"] for p in rec["poles"]], poles, atol=0)
    assert all(p["radius"] == design.pole.radius for p in rec["poles"])
    assert all(p["height"] == design.pole.height for p in rec["poles"])
    # Pole faces hug the vertical pole axes.
    pv = _faces_vertices(mesh, TruthClass.GUARDRAIL_POLE, 7)
    horiz = np.linalg.norm(pv[:, None, :2] - poles[None, :, :2], axis=2).min(axis=1)
    assert horiz.max() <= design.pole.radius + 1e-9
    assert rec["length"] == pytest.approx(np.linalg.norm(np.diff(poles, axis=0), axis=1).sum())


def test_beam_run_is_continuous_and_offset_toward_the_road():
    design = load_design("beam_w")
    poles, toward = _curved_run(n_poles=4, spacing=4.0, radius=40.0)
    builder = MeshBuilder()
    rec = build_guardrail_run(
        design, poles, toward, paint="galvanised", object_id=3, builder=builder
    )
    mesh = builder.build()
    json.dumps(rec)
    assert rec["type"] == "beam" and len(rec["beams"]) == 1 and not rec["pipes"]
    beam = rec["beams"][0]
    assert np.allclose(beam["path"], poles)
    assert beam["thickness"] == pytest.approx(0.0023)
    section = np.array(beam["section"])
    verts = _faces_vertices(mesh, TruthClass.GUARDRAIL, 3)
    # Beam vertices at the poles: across (toward road) and up relative to the ground point.
    for p, t in zip(poles, toward, strict=True):
        at_pole = verts[np.abs((verts - p)[:, :2] @ np.array([-t[1], t[0]])) < 1e-9]
        across = (at_pole - p) @ t
        up = at_pole[:, 2] - p[2]
        assert len(at_pole) == 2 * len(section) + 1
        # Each vertex is within thickness/2 of the section mid curve.
        d = np.linalg.norm(np.stack([across, up], 1)[:, None] - section[None], axis=2).min(1)
        assert d.max() <= beam["thickness"] / 2 + 1e-9
        assert across.min() > design.pole.radius  # in front of the post, toward the road
    assert 0.31 <= np.ptp(section[:, 1]) <= 0.35
    assert np.all(mesh.face_object == 3)


def test_build_guardrail_run_validates_inputs():
    design = load_design("pipe_simple_2")
    poles, toward = _curved_run()
    kwargs = {"paint": "white", "object_id": 1, "builder": MeshBuilder()}
    with pytest.raises(ValueError, match="P >= 2"):
        build_guardrail_run(design, poles[:1], toward[:1], **kwargs)
    with pytest.raises(ValueError, match="toward_road"):
        build_guardrail_run(design, poles, toward[:2], **kwargs)
    bad = poles.copy()
    bad[1, 0] = np.nan
    with pytest.raises(ValueError, match="finite"):
        build_guardrail_run(design, bad, toward, **kwargs)
    with pytest.raises(ValueError, match="paint"):
        build_guardrail_run(design, poles, toward, **{**kwargs, "paint": "pink"})
    with pytest.raises(ValueError, match="apart"):
        build_guardrail_run(design, poles[[0, 0]], toward[:2], **kwargs)


@pytest.mark.parametrize("name", ["pipe_arch", "pipe_ladder", "beam_w", "beam_thrie"])
def test_a_design_scaled_in_height_keeps_its_shape_along_and_its_kinds(name):
    """Pipes: every height and the pole's times the factor, nothing along the unit moves;
    beams: the pole times the factor, the plate lifted whole to a mean height times the factor."""
    design = load_design(name)
    assert scaled_height(design, 1.0) is design
    tall = scaled_height(design, 1.15)
    assert tall.pole.height == pytest.approx(1.15 * design.pole.height, abs=1e-12)
    assert (tall.name, tall.unit_length, tall.pole.radius) == (
        design.name,
        design.unit_length,
        design.pole.radius,
    )
    for a, b in zip(design.pipes, tall.pipes, strict=True):
        np.testing.assert_allclose(b.points, a.points * [1.0, 1.15], atol=1e-12)
        assert (b.kind, b.radius) == (a.kind, a.radius)
        assert not b.points.flags.writeable
    for a, b in zip(design.beams, tall.beams, strict=True):
        np.testing.assert_allclose(b.section - b.section[0], a.section - a.section[0], atol=1e-12)
        assert b.section[:, 1].mean() == pytest.approx(1.15 * a.section[:, 1].mean(), abs=1e-12)
        assert b.section.max(axis=0)[1] < tall.pole.height + 0.05
    with pytest.raises(SceneSpecError, match="height_scale"):
        scaled_height(design, 0.2)
