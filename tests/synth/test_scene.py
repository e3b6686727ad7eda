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
from guardrail_core.synth.random_scene import LONG_RUN_M, random_scene_spec
from guardrail_core.synth.scene import build_scene, list_scenes, load_scene_spec
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
    # Young trees stand behind railings only where asked (--young-trees).
    assert kinds == (set(CONFOUNDER_KINDS) | set(VEGETATION_KINDS)) - {"young_tree"} - (
        {"parked_car"} if spec["road"]["lanes"] == 1 else set()
    )
    assert {load_design(d).type for d in designs} == {"pipe", "beam"}
    paints = {o["paint"] for o in scene.objects if o["kind"] == "guardrail"}
    assert len(paints) >= 3  # colour alone cannot tell a guardrail


def test_random_streets_can_hold_long_guardrail_runs() -> None:
    """long_runs: that share of the runs is 40-120 m long (a run that would pass the street's
    end stops before it, at any length); 0, the default, leaves every seed's street as it was,
    with runs of 6-24 m."""
    plain = [random_scene_spec(seed, 300.0) for seed in range(20)]
    assert [random_scene_spec(seed, 300.0, long_runs=0.0) for seed in range(20)] == plain
    assert max(g["length"] for spec in plain for g in spec["guardrails"]) <= 24
    runs = [
        g
        for seed in range(20)
        for g in random_scene_spec(seed, 300.0, long_runs=0.35)["guardrails"]
    ]
    lengths = np.array([g["length"] for g in runs])
    long = lengths >= LONG_RUN_M[0]
    assert abs(long.mean() - 0.35) < 0.06
    assert lengths.max() <= LONG_RUN_M[1] and lengths.min() >= 2 * 2.0
    assert np.mean((lengths <= 24) | long) > 0.98  # the rest stopped at the street's end
    assert {g["design"] for g, is_long in zip(runs, long, strict=True) if is_long} == set(
        list_designs()
    )
    with pytest.raises(SceneSpecError, match="--long-runs"):
        random_scene_spec(1, 100.0, long_runs=1.5)


def test_a_street_without_curbs_has_its_guardrails_at_road_level() -> None:
    """curb_height 0: the same street with every guardrail post 0.15 m (the default curb)
    lower, on a shoulder at road level."""
    curbs = build_scene(random_scene_spec(1, 60.0), seed=1)
    shoulders = build_scene(random_scene_spec(1, 60.0, curb_height=0.0), seed=1)

    def post_heights(scene) -> np.ndarray:
        return np.array(
            [
                p["position"][2]
                for o in scene.objects
                if o["kind"] == "guardrail"
                for p in o["poles"]
            ]
        )

    assert len(post_heights(curbs)) >= 20
    np.testing.assert_allclose(post_heights(curbs) - post_heights(shoulders), 0.15, atol=1e-9)
    with pytest.raises(SceneSpecError, match="--curb-height"):
        random_scene_spec(1, 100.0, curb_height=-0.1)


def test_random_streets_can_vary_the_height_of_their_guardrails() -> None:
    """height_jitter: every run gets a height_scale 1 +- the jitter, drawn from a stream of its
    own (the rest of the street is the seed's), and its truth posts are that much taller; 0, the
    default, leaves every seed's street as it was."""
    plain = [random_scene_spec(seed, 150.0) for seed in range(6)]
    assert [random_scene_spec(seed, 150.0, height_jitter=0.0) for seed in range(6)] == plain
    assert all("height_scale" not in g for spec in plain for g in spec["guardrails"])
    jittered = [random_scene_spec(seed, 150.0, height_jitter=0.15) for seed in range(6)]
    scales = np.array([g["height_scale"] for spec in jittered for g in spec["guardrails"]])
    assert scales.min() >= 0.85 and scales.max() <= 1.15 and scales.std() > 0.05
    for a, b in zip(plain, jittered, strict=True):
        for g in b["guardrails"]:
            g.pop("height_scale")
        assert a == b
    spec = random_scene_spec(2, 60.0, height_jitter=0.15)
    runs = [o for o in build_scene(spec, seed=2).objects if o["kind"] == "guardrail"]
    assert len(runs) == len(spec["guardrails"]) >= 2
    for run, item in zip(runs, spec["guardrails"], strict=True):
        assert run["height_scale"] == item["height_scale"]
        designed = load_design(item["design"]).pole.height
        for pole in run["poles"]:
            assert pole["height"] == pytest.approx(designed * item["height_scale"], abs=1e-9)
    with pytest.raises(SceneSpecError, match="--height-jitter"):
        random_scene_spec(1, 100.0, height_jitter=0.6)
    spec["guardrails"][1]["height_scale"] = 3.0
    with pytest.raises(SceneSpecError, match=r"guardrails\[1\]\.height_scale: 0.5 to 2.0"):
        build_scene(spec, seed=2)


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
        (
            lambda s: s.update(scanner={"measurements_per_second": 300_000}),
            r"scanner\.measurements_per_second: a scene spec names it measurement_rate_hz",
        ),
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
