"""Damaged guardrails in the simulator: each kind changes the meshes the scanner sees as the
spec says, its truth records what is there, bad items are named, random damage leaves the
street of a seed as it was."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml

from guardrail_core.classes import TruthClass
from guardrail_core.errors import SceneSpecError
from guardrail_core.synth.designs import load_design
from guardrail_core.synth.mesh import SceneMesh
from guardrail_core.synth.random_damage import DENT_DEPTH_M, DROP_M, LEAN_DEG
from guardrail_core.synth.random_scene import random_scene_spec
from guardrail_core.synth.scene import build_scene, load_scene_spec, plan_scene

SPACING = {"beam_w": 4.0, "pipe_simple_2": 2.0}


def _spec(design: str, damage: list | None = None, length: float = 16.0) -> dict:
    run: dict = {
        "design": design,
        "side": "right",
        "offset": 0.4,
        "start": 10.0,
        "length": length,
        "pole_spacing": SPACING[design],
        "paint": "white",
    }
    if damage is not None:
        run["damage"] = damage
    return {
        "road": {"centreline": [{"straight": 40.0}], "undulation_m": 0.0, "grade_percent": 0.0},
        "vehicle": {},
        "guardrails": [run],
        "objects": [],
    }


def _run(design: str, damage: list | None = None, length: float = 16.0) -> tuple[SceneMesh, dict]:
    """The guardrail run alone: its mesh and truth record."""
    part = next(
        p for p in plan_scene(_spec(design, damage, length)).parts if p.name.startswith("g")
    )
    mesh, record = part.mesh()
    assert record is not None
    return mesh, record


def _vertices(mesh: SceneMesh, cls: int) -> np.ndarray:
    return mesh.vertices[np.unique(mesh.faces[mesh.face_class == cls])]


def test_the_spacings_are_the_designs() -> None:
    for name, spacing in SPACING.items():
        assert load_design(name).unit_length == spacing


def test_a_dent_pushes_the_beam_back_by_its_depth_at_its_centre_and_nowhere_beyond() -> None:
    """Built with a dent of 60 mm and with the same dent a nanometre deep (the same sampling),
    the beam's vertices differ by at most 60 mm, horizontally, away from the road (the run is
    on the right of a road along +x: away is -y), and not at all beyond half its length."""
    dent = {"kind": "dent", "at_m": 6.0, "depth_m": 0.06, "length_m": 0.3, "height_m": 0.6}
    deep, record = _run("beam_w", [dent])
    flat, _ = _run("beam_w", [{**dent, "depth_m": 1e-9}])
    a, b = _vertices(deep, TruthClass.GUARDRAIL), _vertices(flat, TruthClass.GUARDRAIL)
    assert a.shape == b.shape
    push = b - a
    assert np.abs(push[:, [0, 2]]).max() < 1e-9
    assert push[:, 1].max() == pytest.approx(0.06, abs=1e-3)
    assert push[:, 1].min() >= -1e-12  # every vertex moved away from the road, or not at all
    along = a[:, 0] - 10.0
    assert np.abs(push[np.abs(along - 6.0) > 0.15, 1]).max() < 1e-12
    ground = record["poles"][0]["position"][2]
    assert np.abs(push[np.abs(a[:, 2] - ground - 0.6) > 0.15, 1]).max() < 1e-12
    (item,) = record["damage"]
    assert item["kind"] == "dent" and item["unit"] == 1
    assert item["magnitude"] == 0.06 and item["magnitude_unit"] == "m"
    assert item["at_m"] == 6.0 and item["length_m"] == 0.3
    np.testing.assert_allclose(item["position"][:2], [16.0, record["poles"][0]["position"][1]])


def test_a_dent_on_a_pipe_railing_bends_its_top_rail() -> None:
    """On a pipe design the dent (at the top rail by default) pushes the pipes' axes."""
    _, record = _run(
        "pipe_simple_2", [{"kind": "dent", "unit": 2, "depth_m": 0.04, "length_m": 1.0}]
    )
    _, plain = _run("pipe_simple_2")
    top = max(
        range(len(plain["pipes"])), key=lambda k: np.array(plain["pipes"][k]["axis"])[:, 2].max()
    )
    j = top % len(load_design("pipe_simple_2").pipes)
    axis = np.array(next(p["axis"] for p in record["pipes"] if p["unit"] == 2 and p["pipe"] == j))
    straight_y = np.array(plain["pipes"][top]["axis"])[0, 1]
    assert (straight_y - axis[:, 1]).max() == pytest.approx(0.04, abs=1e-3)


def test_a_bent_pipe_bows_by_its_offset_at_mid_unit_in_truth_and_mesh() -> None:
    mesh, record = _run(
        "pipe_simple_2", [{"kind": "bent_pipe", "unit": 3, "pipe": 0, "offset_m": 0.07}]
    )
    _, plain = _run("pipe_simple_2")
    pipes = len(load_design("pipe_simple_2").pipes)
    bent = np.array(next(p["axis"] for p in record["pipes"] if (p["unit"], p["pipe"]) == (3, 0)))
    straight = np.array(plain["pipes"][3 * pipes]["axis"])
    bow = straight[0, 1] - bent[:, 1]  # away from the road: -y
    assert bow.max() == pytest.approx(0.07, abs=1e-6)
    mid = bent[np.argmax(bow)]
    assert mid[0] == pytest.approx(10.0 + 7.0, abs=1e-6)
    assert bow[0] == pytest.approx(0.0, abs=1e-9) and bow[-1] == pytest.approx(0.0, abs=1e-9)
    # The tube is built around the bent axis: its ring at mid-unit lies the radius from it.
    radius = record["pipes"][0]["radius"]
    rail = _vertices(mesh, TruthClass.GUARDRAIL)
    near = np.linalg.norm(rail - mid, axis=1)
    assert near.min() == pytest.approx(radius, abs=2e-3)
    straight_mid = mid + [0, 0.07, 0]  # where the axis was: now outside the tube
    assert np.linalg.norm(rail - straight_mid, axis=1).min() > radius + 0.01


def test_a_missing_pipe_and_a_missing_post_are_not_built_nor_in_the_truth() -> None:
    plain_mesh, plain = _run("pipe_simple_2")
    mesh, record = _run(
        "pipe_simple_2",
        [{"kind": "missing_pipe", "unit": 1, "pipe": 1}, {"kind": "missing_post", "pole": 4}],
    )
    assert len(record["pipes"]) == len(plain["pipes"]) - 1
    assert (1, 1) not in {(p["unit"], p["pipe"]) for p in record["pipes"]}
    assert [p["index"] for p in record["poles"]] == [0, 1, 2, 3, 5, 6, 7, 8]
    foot = np.array(plain["poles"][4]["position"])
    poles = _vertices(mesh, TruthClass.GUARDRAIL_POLE)
    assert np.linalg.norm(poles[:, :2] - foot[:2], axis=1).min() > 0.5
    per_pole = np.sum(plain_mesh.face_class == TruthClass.GUARDRAIL_POLE) // len(plain["poles"])
    assert np.sum(mesh.face_class == TruthClass.GUARDRAIL_POLE) == per_pole * 8
    kinds = [d["kind"] for d in record["damage"]]
    assert kinds == ["missing_pipe", "missing_post"] and record["damage"][1]["pole"] == 4


@pytest.mark.parametrize(("direction", "toward"), [("away", [0, -1, 0]), ("forward", [1, 0, 0])])
def test_a_leaning_post_is_rotated_about_its_foot_by_its_lean(direction: str, toward: list) -> None:
    mesh, record = _run(
        "beam_w", [{"kind": "leaning_post", "pole": 2, "lean_deg": 7.5, "direction": direction}]
    )
    pole = record["poles"][2]
    axis, foot = np.array(pole["axis"]), np.array(pole["position"])
    assert np.rad2deg(np.arccos(axis[2])) == pytest.approx(7.5, abs=1e-9)
    assert np.dot(axis[:2], toward[:2]) > 0.1
    # In the mesh: the post's highest point (its cap's top) lies on the leaned axis.
    verts = _vertices(mesh, TruthClass.GUARDRAIL_POLE)
    mine = verts[np.linalg.norm(verts[:, :2] - foot[:2], axis=1) < 0.5]
    top = mine[np.argmax(mine[:, 2])] - foot
    angle = np.rad2deg(np.arccos(top[2] / np.linalg.norm(top)))
    assert angle == pytest.approx(7.5, abs=0.1)
    assert np.dot(top[:2], toward[:2]) > 0
    assert "axis" not in record["poles"][1]
    assert record["damage"][0]["magnitude_unit"] == "deg"


def test_a_lowered_run_stands_lower_by_its_drop() -> None:
    plain_mesh, plain = _run("beam_w")
    mesh, record = _run("beam_w", [{"kind": "lowered", "drop_m": 0.045}])
    z0 = np.array([p["position"][2] for p in plain["poles"]])
    z1 = np.array([p["position"][2] for p in record["poles"]])
    np.testing.assert_allclose(z0 - z1, 0.045, atol=1e-12)
    for cls in (TruthClass.GUARDRAIL, TruthClass.GUARDRAIL_POLE):
        drop = _vertices(plain_mesh, cls) - _vertices(mesh, cls)
        np.testing.assert_allclose(drop, np.broadcast_to([0, 0, 0.045], drop.shape), atol=1e-12)
    assert record["damage"][0]["drop_m"] == 0.045


def test_a_missing_end_loses_its_last_unit_and_post() -> None:
    plain_mesh, plain = _run("beam_w")
    mesh, record = _run("beam_w", [{"kind": "end_missing"}])
    assert len(record["units"]) == len(plain["units"]) - 1
    assert [p["index"] for p in record["poles"]] == [0, 1, 2, 3]
    assert record["beams"][0]["path"] == plain["beams"][0]["path"][:-1]
    rail = _vertices(mesh, TruthClass.GUARDRAIL)
    assert rail[:, 0].max() == pytest.approx(
        _vertices(plain_mesh, TruthClass.GUARDRAIL)[:, 0].max() - 4.0, abs=0.01
    )
    first, _ = _run("beam_w", [{"kind": "end_missing", "end": "first"}])
    assert _vertices(first, TruthClass.GUARDRAIL)[:, 0].min() > 10.0 + 4.0 - 0.01


def test_a_bent_end_pushes_its_rails_back_to_its_offset_and_tilts_its_post() -> None:
    _, plain = _run("beam_w")
    mesh, record = _run("beam_w", [{"kind": "end_damaged", "offset_m": 0.2}])
    rail, rail0 = (
        _vertices(mesh, TruthClass.GUARDRAIL),
        _vertices(_run("beam_w")[0], TruthClass.GUARDRAIL),
    )
    end_x = 26.0
    at_end = np.abs(rail[:, 0] - end_x) < 1e-6
    assert rail[at_end, 1].max() == pytest.approx(
        rail0[np.abs(rail0[:, 0] - end_x) < 1e-6, 1].max() - 0.2, abs=1e-6
    )
    before = rail[:, 0] < 22.0 - 1e-6
    assert rail[before, 1].max() == pytest.approx(rail0[:, 1].max(), abs=1e-9)
    axis = np.array(record["poles"][-1]["axis"])
    height = plain["poles"][-1]["height"]
    assert axis[1] * height / axis[2] == pytest.approx(-0.2, abs=1e-9)


def _bad(edit: dict) -> dict:
    return {"kind": "dent", "at_m": 5.0, "depth_m": 0.05, "length_m": 0.5, **edit}


@pytest.mark.parametrize(
    ("design", "damage", "message"),
    [
        ("beam_w", {"kind": "dent"}, r"guardrails\[0\]: damage is not a list|expected a list"),
        ("beam_w", [7], r"guardrails\[0\]\.damage\[0\]: expected a mapping"),
        ("beam_w", [{"kind": "crumpled"}], r"damage\[0\]\.kind: unknown kind 'crumpled'"),
        ("beam_w", [_bad({"depth_m": 0.0})], r"damage\[0\]\.depth_m: 0.0 must lie in"),
        ("beam_w", [_bad({"depth_m": "deep"})], r"damage\[0\]\.depth_m: expected a number"),
        ("beam_w", [_bad({"length_m": 9})], r"damage\[0\]\.length_m"),
        ("beam_w", [_bad({"at_m": 17.0})], r"damage\[0\]\.at_m: 17.0 m is not on the run"),
        ("beam_w", [_bad({"unit": 1})], r"damage\[0\]: a dent needs either unit or at_m"),
        ("beam_w", [_bad({"height_m": -1})], r"damage\[0\]\.height_m"),
        (
            "beam_w",
            [{"kind": "bent_pipe", "unit": 0, "pipe": 0, "offset_m": 0.05}],
            "needs a pipe design",
        ),
        (
            "pipe_simple_2",
            [{"kind": "bent_pipe", "unit": 8, "pipe": 0, "offset_m": 0.05}],
            r"damage\[0\]\.unit: 8 is not a unit",
        ),
        (
            "pipe_simple_2",
            [{"kind": "missing_pipe", "unit": 0, "pipe": 9}],
            r"damage\[0\]\.pipe: 9",
        ),
        (
            "pipe_simple_2",
            [{"kind": "bent_pipe", "unit": 0, "pipe": 0}],
            r"damage\[0\]: missing key 'offset_m'",
        ),
        ("beam_w", [{"kind": "missing_post", "pole": 5}], r"damage\[0\]\.pole: 5 is not a pole"),
        ("beam_w", [{"kind": "missing_post"}], r"damage\[0\]: missing key 'pole'"),
        ("beam_w", [{"kind": "leaning_post", "pole": 1, "lean_deg": 60}], r"damage\[0\]\.lean_deg"),
        (
            "beam_w",
            [{"kind": "leaning_post", "pole": 1, "lean_deg": 5, "direction": "up"}],
            r"damage\[0\]\.direction: 'up'",
        ),
        ("beam_w", [{"kind": "lowered", "drop_m": -0.02}], r"damage\[0\]\.drop_m"),
        (
            "beam_w",
            [{"kind": "end_damaged", "end": "middle", "offset_m": 0.1}],
            r"damage\[0\]\.end: 'middle'",
        ),
        (
            "beam_w",
            [
                {"kind": "missing_post", "pole": 2},
                {"kind": "leaning_post", "pole": 2, "lean_deg": 4},
            ],
            r"damage: leaning_post repeats a damage to the same pole",
        ),
        (
            "beam_w",
            [{"kind": "end_missing"}, {"kind": "leaning_post", "pole": 4, "lean_deg": 4}],
            "a unit or pole that end_missing removes",
        ),
    ],
)
def test_bad_damage_is_refused_naming_the_field(design: str, damage, message: str) -> None:
    with pytest.raises(SceneSpecError, match=message):
        plan_scene(_spec(design, damage))


def test_a_run_without_damage_is_built_as_before() -> None:
    """An empty damage list is no damage: the very same mesh and truth as without the key."""
    a_mesh, a = _run("pipe_simple_2")
    b_mesh, b = _run("pipe_simple_2", [])
    np.testing.assert_array_equal(a_mesh.vertices, b_mesh.vertices)
    assert a == b and "damage" not in a


def test_random_damage_leaves_the_street_of_a_seed_as_it_was() -> None:
    """--damage 0 (the default) gives the street of the seed, byte for byte; with a share, only
    the runs' damage lists are new, and each damaged street builds."""
    for seed in range(3):
        plain = random_scene_spec(seed, 120.0)
        assert random_scene_spec(seed, 120.0, damage=0.0) == plain
        damaged = random_scene_spec(seed, 120.0, damage=1.0)
        stripped = copy.deepcopy(damaged)
        for g in stripped["guardrails"]:
            g.pop("damage", None)
        assert stripped == plain
    a = build_scene(random_scene_spec(1, 60.0), seed=1)
    b = build_scene(random_scene_spec(1, 60.0, damage=0.0), seed=1)
    np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)
    assert a.objects == b.objects
    with pytest.raises(SceneSpecError, match="--damage"):
        random_scene_spec(1, 100.0, damage=1.5)


def test_random_damage_draws_its_kinds_and_magnitudes_in_the_benchmark_ranges() -> None:
    items = []
    shares = []
    for seed in range(12):
        spec = random_scene_spec(seed, 150.0, damage=0.5, medians=0.5)
        runs = spec["guardrails"]
        shares.append(np.mean(["damage" in g for g in runs]))
        for g in runs:
            assert 1 <= len(g.get("damage", [None])) <= 3
            items += g.get("damage", [])
        if seed >= 3:
            continue
        # Every damaged run builds, its damage in its truth (the runs alone: quicker).
        rails = [p for p in plan_scene(spec, seed=seed).parts if p.name.startswith("guardrails")]
        truth = [part.mesh()[1] or {} for part in rails]
        assert [len(o.get("damage", [])) for o in truth] == [len(g.get("damage", [])) for g in runs]
    assert 0.3 < np.mean(shares) < 0.7
    kinds = {d["kind"] for d in items}
    assert kinds == {
        "dent",
        "bent_pipe",
        "missing_pipe",
        "missing_post",
        "leaning_post",
        "lowered",
        "end_missing",
        "end_damaged",
    }
    depth = [d["depth_m"] for d in items if d["kind"] == "dent"]
    assert DENT_DEPTH_M[0] <= min(depth) and max(depth) <= DENT_DEPTH_M[1]
    lean = [d["lean_deg"] for d in items if d["kind"] == "leaning_post"]
    assert LEAN_DEG[0] <= min(lean) and max(lean) <= LEAN_DEG[1]
    drop = [d["drop_m"] for d in items if d["kind"] == "lowered"]
    assert DROP_M[0] <= min(drop) and max(drop) <= DROP_M[1]


def test_the_documented_damage_builds_into_the_truth() -> None:
    """The scene-spec page's damaged runs, on the shipped straight street: every item is in
    the truth of its run."""
    page = (Path(__file__).resolve().parents[2] / "docs" / "scene-spec.md").read_text()
    block = page[page.index("## Damaged guardrails") :]
    runs = yaml.safe_load(
        block[block.index("```yaml\n") + 8 : block.index("```\n", block.index("```yaml"))]
    )
    spec = load_scene_spec("test_straight")
    spec["guardrails"] = runs["guardrails"]
    spec["objects"] = []
    truth = [o for o in build_scene(spec).objects if o["kind"] == "guardrail"]
    assert [[d["kind"] for d in o["damage"]] for o in truth] == [
        [d["kind"] for d in r["damage"]] for r in runs["guardrails"]
    ]
