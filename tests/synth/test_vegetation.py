"""Roadsides as real ones are: embankments, ditches, hedges, shrubs and tall grass on the ground,
scanned with the noise, dropouts and intensity calibration a spec asks for."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from guardrail_core.classes import TruthClass
from guardrail_core.errors import SceneSpecError
from guardrail_core.formats.drive import load_drive
from guardrail_core.synth.mesh import MeshBuilder
from guardrail_core.synth.random_scene import random_scene_spec
from guardrail_core.synth.raycast import SceneRaycaster
from guardrail_core.synth.road import Road, Roadside, RoadSpec
from guardrail_core.synth.scene import build_scene, plan_scene
from guardrail_core.synth.simulate import SimulationOptions, simulate_drive
from guardrail_core.synth.vegetation import SIZES, VEGETATION_KINDS, build_vegetation

SIDEWALK_M = 2.5
CURB_M = 0.18
LEVEL = Roadside()


def _road(left: Roadside = LEVEL, right: Roadside = LEVEL) -> Road:
    return Road(
        RoadSpec(
            segments=(("straight", 40.0, 0.0), ("arc", 40.0, 1 / 120.0)),
            roadside_left=left,
            roadside_right=right,
        )
    )


def _ground_below(road: Road, xy: np.ndarray) -> np.ndarray:
    """Heights (N,) of the road's own mesh straight below the points ``xy`` (N, 2)."""
    builder = MeshBuilder()
    road.build_mesh(builder)
    origin = np.column_stack([xy, np.full(len(xy), 50.0)])
    hits = SceneRaycaster(builder.build()).cast(origin, np.tile([0.0, 0.0, -1.0], (len(xy), 1)))
    assert hits.hit.all()
    return 50.0 - hits.t


def test_roadside_heights_follow_the_slope_beyond_the_ditch() -> None:
    side = Roadside(slope=0.3, ditch_depth_m=0.5, ditch_width_m=1.2)
    beyond = np.array([-1.0, 0.0, 0.6, 1.2, 2.2, 5.2])
    np.testing.assert_allclose(side.height(beyond), [0.0, 0.0, -0.5, 0.0, 0.3, 1.2], atol=1e-12)
    falling = Roadside(slope=-0.4)
    np.testing.assert_allclose(falling.height(np.array([0.0, 2.5])), [0.0, -1.0])
    assert Roadside().level and not side.level


def test_the_verge_mesh_lies_on_the_ground_heights_of_an_embankment_and_a_ditch() -> None:
    road = _road(
        left=Roadside(slope=0.45),
        right=Roadside(slope=-0.3, ditch_depth_m=0.6, ditch_width_m=1.5),
    )
    walk = road.half_width + CURB_M + SIDEWALK_M
    rng = np.random.default_rng(0)
    s = rng.uniform(1.0, 79.0, 400)
    lateral = np.where(rng.random(400) < 0.5, 1.0, -1.0) * (walk + rng.uniform(0.0, 5.9, 400))
    points = road.point(s, lateral)
    # The mesh (columns every 0.25 m, rows every 0.5 m on a curve) follows the ditch and slope
    # to within a few centimetres.
    np.testing.assert_allclose(_ground_below(road, points[:, :2]), points[:, 2], atol=0.05)
    # The left verge climbs 0.45 m per metre, the right falls into its ditch and then away.
    centre = road.point(np.array([20.0]), np.array([0.0]))[0, 2]
    far_left = road.point(np.array([20.0]), np.array([walk + 5.0]))[0, 2]
    assert far_left - centre > 0.15 + 2.0
    ditch = road.point(np.array([20.0]), np.array([-(walk + 0.75)]))[0, 2]
    assert ditch < road.point(np.array([20.0]), np.array([-walk]))[0, 2] - 0.55


@pytest.mark.parametrize("kind", VEGETATION_KINDS)
def test_vegetation_stands_on_the_ground_within_its_size(kind: str) -> None:
    road = _road(left=Roadside(slope=0.3))
    builder = MeshBuilder()
    offset = CURB_M + SIDEWALK_M + 1.0
    sizes = {key: (lo + hi) / 2 for key, (lo, hi) in SIZES[kind].items()}
    record = build_vegetation(
        kind,
        road=road,
        side="left",
        offset=offset,
        at=30.0,
        length=20.0,  # over the start of the curve
        sizes=sizes,
        object_id=7,
        builder=builder,
        rng=np.random.default_rng(1),
    )
    mesh = builder.build()
    # A young tree is a tree (its trunk and stake stand like a railing's posts).
    cls = TruthClass.TREE if kind == "young_tree" else TruthClass.VEGETATION
    assert record["class"] == cls and record["kind"] == kind
    assert set(mesh.face_class.tolist()) == {cls}
    assert set(mesh.face_object.tolist()) == {7}
    # Height over the ground below each vertex: on the slope, within the size (+ leaf noise).
    v = mesh.vertices
    s_near = road.s[np.argmin(np.linalg.norm(road.xy[None] - v[::7, None, :2], axis=2), axis=1)]
    _, _, left = road.frame(s_near)
    centre, _, _ = road.frame(s_near)
    lateral = np.einsum("ij,ij->i", v[::7, :2] - centre[:, :2], left[:, :2])
    over = v[::7, 2] - road.ground_height(s_near, lateral)
    assert over.min() > -0.35 * sizes["height"]
    assert over.max() < 1.45 * sizes["height"]
    assert np.percentile(over, 90) > 0.4 * sizes["height"]
    # It stands where it was put: outward of the road edge by the offset (and its width).
    width = sizes.get("depth", sizes.get("width", 0.0))
    outward = lateral - road.half_width
    lo = offset - (0 if kind == "tall_grass" else 0.6 * width) - 0.1
    hi = offset + (1.05 if kind == "tall_grass" else 0.6) * width + 0.1
    assert lo < outward.min() and outward.max() < hi
    if kind in ("hedge", "tall_grass"):
        assert record["geometry"]["length"] == pytest.approx(20.0)


def test_random_streets_keep_their_road_guardrails_and_objects_with_a_green_roadside() -> None:
    green, bare = random_scene_spec(12, 300.0), random_scene_spec(12, 300.0, roadside=False)
    assert green["guardrails"] == bare["guardrails"]
    plants = [o for o in green["objects"] if o["kind"] in VEGETATION_KINDS]
    assert [o for o in green["objects"] if o["kind"] not in VEGETATION_KINDS] == bare["objects"]
    assert green["objects"][: len(bare["objects"])] == bare["objects"]  # object ids kept
    # Young trees stand behind railings only where asked (--young-trees).
    assert {o["kind"] for o in plants} == set(VEGETATION_KINDS) - {"young_tree"}
    assert "roadside" not in bare["road"] and set(green["road"]["roadside"]) == {"left", "right"}
    # Hedges stand behind the rails of a run of their side, never in front of them.
    runs = green["guardrails"]
    for hedge in (o for o in plants if o["kind"] == "hedge"):
        run = next(
            r
            for r in runs
            if r["side"] == hedge["side"] and r["start"] <= hedge["at"] <= r["start"] + r["length"]
        )
        assert hedge["offset"] - hedge["depth"] / 2 >= run["offset"] + 0.1 - 1e-9
    # Over many streets, every lie of the land turns up.
    slopes = [
        random_scene_spec(seed, 60.0)["road"]["roadside"][side]
        for seed in range(30)
        for side in ("left", "right")
    ]
    assert (
        min(s["slope_percent"] for s in slopes) < -15 < 15 < max(s["slope_percent"] for s in slopes)
    )
    assert any(s["slope_percent"] == 0 for s in slopes) and any("ditch" in s for s in slopes)


BAD_SPECS = [
    (
        {"objects": [{"kind": "hedge", "side": "left", "at": 10}]},
        r"objects\[0\]: missing key 'length'",
    ),
    (
        {"objects": [{"kind": "shrub", "side": "left", "at": 10, "height": -1}]},
        r"objects\[0\]\.height: -1 m is not a size",
    ),
    ({"objects": [{"kind": "hedgehog", "side": "left", "at": 10}]}, r"known: .*tall_grass"),
    (
        {"objects": [{"kind": "tall_grass", "side": "left", "at": 89.99, "length": 5}]},
        r"objects\[0\]\.at: a tall_grass at 89.99 m has no road left",
    ),
    ({"road": {"roadside": {"left": {"slope_percent": 150}}}}, r"roadside\.left\.slope_percent"),
    ({"road": {"roadside": {"right": {"ditch": {"depth": 5}}}}}, r"roadside\.right\.ditch"),
    ({"scanner": {"dropout": 1.5}}, r"scanner\.dropout"),
    ({"scanner": {"intensity_gain": 0}}, r"scanner\.intensity_gain"),
]


@pytest.mark.parametrize(("change", "message"), BAD_SPECS)
def test_bad_roadside_vegetation_and_scanner_keys_are_named(change: dict, message: str) -> None:
    spec = random_scene_spec(4, 40.0, roadside=False)
    for key, value in change.items():
        spec[key] = {**spec[key], **value} if key == "road" else value
    with pytest.raises(SceneSpecError, match=message):
        plan_scene(spec)


def test_a_drive_past_a_hedge_behind_a_guardrail_scans_both(tmp_path: Path) -> None:
    spec = random_scene_spec(4, 40.0, roadside=False)
    spec["guardrails"] = [
        {"design": "pipe_simple_2", "side": "left", "offset": 0.4, "start": 30.0, "length": 20.0}
    ]
    spec["objects"] = [
        {"kind": "hedge", "side": "left", "offset": 1.0, "at": 30.0, "length": 20.0},
        {"kind": "tall_grass", "side": "left", "offset": 3.0, "at": 30.0, "length": 20.0},
    ]
    spec["road"]["roadside"] = {"left": {"slope_percent": 40, "ditch": {"depth": 0.4}}}
    spec["scanner"] = {"dropout": 0.05, "intensity_gain": 0.8, "range_noise_m": 0.01}
    simulate_drive(
        spec,
        tmp_path / "drive",
        seed=4,
        options=SimulationOptions(image_every_m=1000.0),
        progress=False,
    )
    drive = load_drive(tmp_path / "drive")
    assert drive.truth is not None
    truth = drive.truth.point_class
    assert np.count_nonzero(truth == TruthClass.VEGETATION) > 5_000
    assert np.count_nonzero(truth == TruthClass.GUARDRAIL) > 1_000
    scene = build_scene(spec, seed=0)
    assert {o["kind"] for o in scene.objects} == {"guardrail", "hedge", "tall_grass"}
