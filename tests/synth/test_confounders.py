"""Confounders: every kind builds finite, plausibly sized geometry of the right class."""

from __future__ import annotations

import json

import numpy as np
import pytest

from guardrail_core.classes import TruthClass
from guardrail_core.synth.confounders import CONFOUNDER_KINDS, EXTENDED_KINDS, build_confounder
from guardrail_core.synth.materials import MATERIAL_ID, PAINTS
from guardrail_core.synth.mesh import MeshBuilder

BASE = np.array([10.0, -4.0, 2.5])
ALONG = np.array([np.cos(0.4), np.sin(0.4), 0.0])
TOWARD = np.array([-np.sin(0.4), np.cos(0.4), 0.0])

CLASS = {
    "mesh_fence": TruthClass.FENCE,
    "bar_fence": TruthClass.FENCE,
    "low_wall": TruthClass.WALL,
    "bicycle_rack": TruthClass.BICYCLE_RACK,
    "bollard": TruthClass.BOLLARD,
    "utility_pole": TruthClass.POLE,
    "sign_pole": TruthClass.SIGN,
    "tree": TruthClass.TREE,
    "parked_car": TruthClass.CAR,
    "facade": TruthClass.BUILDING,
    "pedestrian": TruthClass.PEDESTRIAN,
}
#: Plausible total height above the base (m).
HEIGHT = {
    "mesh_fence": (0.85, 1.85),
    "bar_fence": (0.75, 1.25),
    "low_wall": (0.4, 1.0),
    "bicycle_rack": (0.65, 0.9),
    "bollard": (0.8, 1.0),
    "utility_pole": (8.0, 12.0),
    "sign_pole": (2.7, 3.4),
    "tree": (3.0, 10.0),
    "parked_car": (1.4, 1.75),
    "facade": (6.0, 15.0),
    "pedestrian": (1.6, 1.85),
}
PAINTED = {"mesh_fence", "bar_fence", "bicycle_rack", "bollard", "utility_pole", "sign_pole"}
MAX_FACES = 20_000


def _build(kind, seed=0, length=8.0, paint="green", object_id=42):
    builder = MeshBuilder()
    rec = build_confounder(
        kind,
        base=BASE,
        along=ALONG,
        toward_road=TOWARD,
        length=length,
        paint=paint,
        object_id=object_id,
        builder=builder,
        rng=np.random.default_rng(seed),
    )
    return rec, builder.build()


def _local(vertices):
    rel = vertices - BASE
    return np.stack([rel @ ALONG, rel @ TOWARD, rel[:, 2]], axis=1)


def test_kinds_are_the_documented_set():
    assert set(CONFOUNDER_KINDS) == set(CLASS)
    assert EXTENDED_KINDS == {"mesh_fence", "bar_fence", "low_wall", "bicycle_rack", "facade"}


@pytest.mark.parametrize("kind", CONFOUNDER_KINDS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_each_kind_builds_finite_plausible_geometry(kind, seed):
    rec, mesh = _build(kind, seed=seed)
    json.dumps(rec)
    assert rec["id"] == 42 and rec["kind"] == kind and rec["class"] == int(CLASS[kind])
    assert 0 < mesh.n_faces <= MAX_FACES
    assert np.isfinite(mesh.vertices).all()
    assert mesh.faces.min() >= 0 and mesh.faces.max() < len(mesh.vertices)
    assert np.all(mesh.face_class == CLASS[kind])
    assert np.all(mesh.face_object == 42)

    local = _local(mesh.vertices)
    top = local[:, 2].max()
    lo, hi = HEIGHT[kind]
    assert lo <= top <= hi, (kind, top)
    assert rec["geometry"]["height"] == pytest.approx(top, abs=0.05)
    # Stands on the ground: nothing below it, something touching it.
    assert local[:, 2].min() >= -1e-9
    assert local[:, 2].min() <= 0.16  # cars rest on their wheels, fences have posts
    geom = rec["geometry"]
    assert np.allclose(geom["base"], BASE) and np.allclose(geom["along"], ALONG)

    if kind in EXTENDED_KINDS:
        assert geom["length"] == 8.0
        assert -0.1 <= local[:, 0].min() and local[:, 0].max() <= 8.1
        assert np.ptp(local[:, 0]) >= 7.0
    if kind in PAINTED:
        assert rec["paint"] == "green"
        assert (mesh.face_material == MATERIAL_ID["green"]).mean() > 0.5
    else:
        assert rec["paint"] is None
        assert not np.any(np.isin(mesh.face_material, [MATERIAL_ID[p] for p in PAINTS]))


def test_same_seed_same_geometry_other_seed_differs():
    for kind in CONFOUNDER_KINDS:
        _, a = _build(kind, seed=5)
        _, b = _build(kind, seed=5)
        _, c = _build(kind, seed=6)
        assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
        assert a.vertices.shape != c.vertices.shape or not np.allclose(a.vertices, c.vertices)


def test_fences_are_thin_and_fine():
    rec, mesh = _build("mesh_fence")
    g = rec["geometry"]
    assert 0.003 <= g["wire_width"] <= 0.004 and 0.04 <= g["wire_pitch"] <= 0.07
    local = _local(mesh.vertices)
    assert np.ptp(local[:, 1]) < 0.1  # a fence is a thin sheet
    rec, mesh = _build("bar_fence")
    assert 0.10 <= rec["geometry"]["bar_pitch"] <= 0.12
    assert rec["geometry"]["n_bars"] >= 60


def test_point_like_kinds_stay_near_base_and_ignore_length():
    for kind in ("bollard", "sign_pole", "utility_pole", "pedestrian"):
        rec_a, a = _build(kind, length=0.0)
        _, b = _build(kind, length=50.0)
        assert np.array_equal(a.vertices, b.vertices)
        assert "length" not in rec_a["geometry"]
        assert np.linalg.norm(_local(a.vertices)[:, :2], axis=1).max() < 1.0


def test_specific_shapes():
    rec, mesh = _build("parked_car")
    g = rec["geometry"]
    local = _local(mesh.vertices)
    assert 3.3 <= g["length"] <= 4.9 and 1.4 <= g["width"] <= 1.85
    assert np.ptp(local[:, 0]) == pytest.approx(g["length"], abs=1e-6)
    assert np.isin(MATERIAL_ID["rubber"], mesh.face_material)
    # The side windows begin just inside the doors and lean in towards the roof (tumblehome),
    # so that a car side seen from the road is one surface from sill to roof, as in real scans.
    glass = mesh.face_material == MATERIAL_ID["car_glass"]
    glass_local = _local(mesh.vertices[np.unique(mesh.faces[glass])])
    half_width = g["width"] / 2
    low = glass_local[:, 2] < glass_local[:, 2].min() + 1e-9
    high = glass_local[:, 2] > glass_local[:, 2].max() - 1e-9
    assert np.abs(glass_local[low, 1]).max() == pytest.approx(half_width - 0.03, abs=1e-9)
    lean = (np.abs(glass_local[low, 1]).max() - np.abs(glass_local[high, 1]).max()) / np.ptp(
        glass_local[:, 2]
    )
    assert lean == pytest.approx(0.35, abs=1e-9)

    rec, mesh = _build("facade")
    local = _local(mesh.vertices)
    assert local[:, 1].max() <= 1e-9  # the road-facing face is on the base line
    assert rec["geometry"]["windows"]
    glass = mesh.face_material == MATERIAL_ID["glass"]
    glass_local = _local(mesh.vertices[np.unique(mesh.faces[glass])])
    assert glass_local[:, 1].max() < -0.1  # windows are recessed

    rec, mesh = _build("utility_pole")
    assert 0.15 <= rec["geometry"]["radius_base"] <= 0.2

    rec, mesh = _build("sign_pole")
    assert 0.03 <= rec["geometry"]["radius"] <= 0.04
    plate = rec["geometry"]["plate"]["material"]
    assert plate in ("sign_blue", "sign_red") and np.isin(MATERIAL_ID[plate], mesh.face_material)

    rec, mesh = _build("tree")
    assert np.isin(MATERIAL_ID["foliage"], mesh.face_material)
    assert np.isin(MATERIAL_ID["bark"], mesh.face_material)

    rec, mesh = _build("bicycle_rack")
    assert len(rec["geometry"]["axes"]) >= 7


def test_bad_arguments():
    with pytest.raises(ValueError, match="unknown confounder kind"):
        _build("dragon")
    with pytest.raises(ValueError, match="paint"):
        _build("bollard", paint="pink")
    with pytest.raises(ValueError, match="length"):
        _build("mesh_fence", length=0.0)
    builder = MeshBuilder()
    with pytest.raises(ValueError, match="parallel"):
        build_confounder(
            "bollard",
            base=BASE,
            along=ALONG,
            toward_road=ALONG,
            length=1.0,
            paint="white",
            object_id=1,
            builder=builder,
            rng=np.random.default_rng(0),
        )
