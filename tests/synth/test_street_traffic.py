"""Random streets with motorway medians and with cars in the lanes beside the vehicle."""

from __future__ import annotations

import numpy as np
import pytest

from guardrail_core.classes import TruthClass
from guardrail_core.errors import SceneSpecError
from guardrail_core.synth.designs import load_design
from guardrail_core.synth.random_scene import random_scene_spec
from guardrail_core.synth.scene import build_scene
from guardrail_core.synth.street_traffic import MEDIAN_GAP_M


def _without(spec: dict, added: list[dict], key: str) -> dict:
    return {**spec, key: [item for item in spec[key] if item not in added]}


def test_medians_add_a_rail_back_to_back_and_leave_the_street_as_it_was() -> None:
    for seed in range(8):
        plain = random_scene_spec(seed, 300.0)
        assert random_scene_spec(seed, 300.0, medians=0.0) == plain
        median = random_scene_spec(seed, 300.0, medians=1.0)
        n = len(plain["guardrails"])
        assert median["guardrails"][:n] == plain["guardrails"]
        far = median["guardrails"][n:]
        near = [
            g
            for g in plain["guardrails"]
            if g["side"] == "left" and load_design(g["design"]).type == "beam"
        ]
        # Every left-side beam run has its far rail: same design and stretch, facing away.
        assert len(far) == len(near)
        for a, b in zip(near, far, strict=True):
            assert b["facing"] == "away" and b["design"] == a["design"]
            assert (b["start"], b["length"], b["side"]) == (a["start"], a["length"], "left")
            assert MEDIAN_GAP_M[0] <= b["offset"] - a["offset"] <= MEDIAN_GAP_M[1] + 1e-3
        # Hedges between them; every other object is the plain street's.
        hedges = [o for o in median["objects"] if o not in plain["objects"]]
        assert all(h["kind"] == "hedge" and h["side"] == "left" for h in hedges)
        assert _without(median, hedges, "objects")["objects"] == plain["objects"]
    with pytest.raises(SceneSpecError, match="--medians"):
        random_scene_spec(1, 100.0, medians=1.5)


def test_a_far_rail_faces_the_other_carriageway() -> None:
    spec = random_scene_spec(1, 60.0)
    spec["guardrails"] = [
        {"design": "beam_w", "side": "left", "offset": 0.4, "start": 10.0, "length": 16.0},
        {
            "design": "beam_w",
            "side": "left",
            "offset": 2.0,
            "start": 10.0,
            "length": 16.0,
            "facing": "away",
        },
    ]
    spec["objects"] = []
    near, far = (o for o in build_scene(spec, seed=1).objects if o["kind"] == "guardrail")
    assert "facing" not in near and far["facing"] == "away"
    np.testing.assert_allclose(
        np.array(far["beams"][0]["across"]), -np.array(near["beams"][0]["across"]), atol=1e-9
    )
    # Back to back: the near rail's beam faces away from the far rail (toward the road), the
    # far rail's away from the near one (toward the other carriageway); both hang on their posts.
    near_posts = np.array([p["position"][:2] for p in near["poles"]])
    far_posts = np.array([p["position"][:2] for p in far["poles"]])
    apart = far_posts - near_posts
    for run, posts, sign in ((near, near_posts, -1.0), (far, far_posts, 1.0)):
        across = np.array(run["beams"][0]["across"])[:, :2]
        assert np.allclose(np.array(run["beams"][0]["path"])[:, :2], posts, atol=1e-9)
        assert np.all(sign * np.einsum("ij,ij->i", across, apart) > 1.0)
    spec["guardrails"][1]["facing"] = "sideways"
    with pytest.raises(SceneSpecError, match=r"guardrails\[1\]\.facing: 'sideways'"):
        build_scene(spec, seed=1)


def test_traffic_stands_in_the_lanes_beside_the_vehicle() -> None:
    checked = 0
    for seed in range(12):
        plain = random_scene_spec(seed, 300.0)
        assert random_scene_spec(seed, 300.0, traffic=0.0) == plain
        busy = random_scene_spec(seed, 300.0, traffic=1.0)
        cars = [o for o in busy["objects"] if o not in plain["objects"]]
        assert _without(busy, cars, "objects") == plain
        road, lane = plain["road"], plain["vehicle"]["lane"]
        beside = {lane - 1, lane + 1} & set(range(road["lanes"]))
        if not beside:
            assert cars == []
            continue
        half = road["lanes"] * road["lane_width"] / 2
        centres = {round(-half + (k + 0.5) * road["lane_width"], 3) for k in beside}
        ego = -half + (lane + 0.5) * road["lane_width"]
        for car in cars:
            assert car["kind"] == "parked_car"
            lateral = (1 if car["side"] == "left" else -1) * (half + car["offset"])
            assert round(lateral, 3) in centres
            assert 2.5 <= abs(lateral - ego) <= 3.6  # a lane width beside the scanner
            assert plain["vehicle"]["start"] <= car["at"] <= plain["vehicle"]["end"]
        assert len(cars) >= len(beside) * 300 / 45  # a car at least every 45 m of each lane
        checked += 1
    assert checked >= 6
    with pytest.raises(SceneSpecError, match="--traffic"):
        random_scene_spec(1, 100.0, traffic=-0.1)


def test_cars_beside_the_vehicle_are_scanned_as_cars(tmp_path) -> None:
    from guardrail_core.formats.drive import load_drive
    from guardrail_core.synth.simulate import SimulationOptions, simulate_drive

    seed = next(s for s in range(20) if random_scene_spec(s, 60.0)["road"]["lanes"] >= 2)
    spec = random_scene_spec(seed, 60.0, traffic=1.0)
    simulate_drive(
        spec,
        tmp_path / "d",
        seed=seed,
        options=SimulationOptions(image_every_m=1000.0),
        progress=False,
    )
    truth = load_drive(tmp_path / "d").truth
    assert truth is not None
    cars = {o["id"] for o in truth.objects if o["kind"] == "parked_car"}
    hit = np.isin(truth.point_object, list(cars))
    assert hit.any() and (truth.point_class[hit] == TruthClass.CAR).all()
