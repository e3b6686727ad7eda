"""Scene specs: the shipped ones build, random scenes mix everything, bad specs are named."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from guardrail_core.classes import TruthClass
from guardrail_core.errors import SceneSpecError
from guardrail_core.synth.confounders import CONFOUNDER_KINDS
from guardrail_core.synth.designs import list_designs, load_design
from guardrail_core.synth.scene import build_scene, list_scenes, load_scene_spec, random_scene_spec
from guardrail_core.synth.vegetation import VEGETATION_KINDS


@pytest.mark.parametrize("name", list_scenes())
def test_shipped_scenes_build(name: str) -> None:
    scene = build_scene(load_scene_spec(name))
    assert scene.mesh.n_faces > 1000
    assert np.isfinite(scene.mesh.vertices).all()
    runs = [o for o in scene.objects if o["kind"] == "guardrail"]
    assert runs and all(len(r["poles"]) >= 2 for r in runs)


def test_random_scene_mixes_every_design_and_every_kind() -> None:
    spec = random_scene_spec(3, 400.0)
    scene = build_scene(spec, seed=3)
    designs = {o["design"] for o in scene.objects if o["kind"] == "guardrail"}
    kinds = {o["kind"] for o in scene.objects} - {"guardrail"}
    assert designs == set(list_designs())
    assert kinds == (set(CONFOUNDER_KINDS) | set(VEGETATION_KINDS)) - (
        {"parked_car"} if spec["road"]["lanes"] == 1 else set()
    )
    assert {load_design(d).type for d in designs} == {"pipe", "beam"}
    paints = {o["paint"] for o in scene.objects if o["kind"] == "guardrail"}
    assert len(paints) >= 3  # colour alone cannot tell a guardrail


def test_random_scene_is_reproducible_and_round_trips_through_yaml(tmp_path: Path) -> None:
    spec = random_scene_spec(5, 120.0)
    assert spec == random_scene_spec(5, 120.0)
    assert spec != random_scene_spec(6, 120.0)
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(spec))
    a, b = build_scene(spec, seed=1), build_scene(load_scene_spec(path), seed=1)
    np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)


def test_guardrail_poles_follow_a_curve_at_the_spacing() -> None:
    spec = load_scene_spec("sample")
    scene = build_scene(spec)
    for run in (o for o in scene.objects if o["kind"] == "guardrail"):
        poles = np.array([p["position"] for p in run["poles"]])
        gaps = np.linalg.norm(np.diff(poles[:, :2], axis=0), axis=1)
        np.testing.assert_allclose(gaps, run["pole_spacing"], atol=0.01)
        # Poles stand on the sidewalk: ground height there, not the road's.
        s_guess = np.array([run["start"]])
        assert poles[0, 2] > scene.road.point(s_guess, np.zeros(1))[0, 2] - 0.1


def test_faces_carry_their_class() -> None:
    scene = build_scene(load_scene_spec("test_straight"))
    classes = set(np.unique(scene.mesh.face_class))
    assert {
        TruthClass.ROAD,
        TruthClass.CURB,
        TruthClass.SIDEWALK,
        TruthClass.GUARDRAIL,
        TruthClass.GUARDRAIL_POLE,
    } <= classes


def _spec() -> dict:
    return load_scene_spec("test_straight")


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda s: s.pop("road"), "road: expected a mapping"),
        (lambda s: s["road"].update(centreline=[{"spiral": 3}]), r"road.centreline\[0\]"),
        (
            lambda s: s["road"].update(centreline=[{"arc": {"radius": 5, "angle_deg": 90}}]),
            "tighter than any road",
        ),
        (lambda s: s["road"].update(lanes=0), "road.lanes"),
        (lambda s: s["vehicle"].update(lane=7), "vehicle.lane"),
        (lambda s: s["vehicle"].update(speed_mps=[12, 5]), "vehicle.speed_mps"),
        (lambda s: s["vehicle"].update(end=999), "must lie on the road"),
        (lambda s: s["guardrails"][0].update(side="middle"), r"guardrails\[0\].side"),
        (lambda s: s["guardrails"][0].update(start=55), r"guardrails\[0\]: .* runs off the road"),
        (lambda s: s["guardrails"][0].update(paint="purple"), "unknown paint 'purple'"),
        (
            lambda s: s["guardrails"][0].update(length="long"),
            r"guardrails\[0\].length: expected a number",
        ),
        (lambda s: s["objects"][0].update(kind="ufo"), "unknown kind 'ufo'"),
        (lambda s: s["objects"][0].update(at=1000), r"objects\[0\].at"),
        (lambda s: s.update(origin=[1, 2]), "origin"),
        (lambda s: s.update(scanner={"measurements_per_second": 123_457}), "whole multiple"),
        (lambda s: s.update(scanner={"measurement_rate_hz": 123_457}), "whole multiple"),
        (lambda s: s.update(scanner={"range_noise_m": -0.01}), "scanner: .*range_noise_m"),
        (lambda s: s.update(scanner={"mounting": {"position_m": [0, 0]}}), "position_m"),
        (
            lambda s: s.update(scanner={"mounting": {"pitch_deg": "steep"}}),
            "pitch_deg: expected a number",
        ),
    ],
)
def test_bad_specs_name_what_is_wrong(edit, message: str) -> None:
    spec = _spec()
    edit(spec)
    with pytest.raises(SceneSpecError, match=message):
        build_scene(spec)


def test_unknown_scene_file_lists_the_shipped_ones(tmp_path: Path) -> None:
    with pytest.raises(SceneSpecError, match="sample"):
        load_scene_spec(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("road: [unclosed")
    with pytest.raises(SceneSpecError, match="not valid YAML"):
        load_scene_spec(bad)


def test_random_scene_needs_some_length() -> None:
    with pytest.raises(SceneSpecError, match="at least 20 m"):
        random_scene_spec(0, 5.0)
