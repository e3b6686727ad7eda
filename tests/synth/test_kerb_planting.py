"""Young trees and low hedges close behind pedestrian railings (``--young-trees``)."""

from __future__ import annotations

import numpy as np
import pytest

from guardrail_core.classes import TruthClass
from guardrail_core.errors import SceneSpecError
from guardrail_core.synth.designs import load_design
from guardrail_core.synth.kerb_planting import TREE_SETBACK_M, TREE_SPACING_M
from guardrail_core.synth.random_scene import random_scene_spec
from guardrail_core.synth.scene import build_scene


def test_young_trees_stand_behind_pipe_railings_and_leave_the_street_as_it_was() -> None:
    for seed in range(6):
        plain = random_scene_spec(seed, 200.0)
        assert random_scene_spec(seed, 200.0, young_trees=0.0) == plain
        planted = random_scene_spec(seed, 200.0, young_trees=1.0)
        added = [o for o in planted["objects"] if o not in plain["objects"]]
        assert {**planted, "objects": [o for o in planted["objects"] if o not in added]} == plain
        pipes = [g for g in plain["guardrails"] if load_design(g["design"]).type == "pipe"]
        for run in pipes:
            trees = [
                o
                for o in added
                if o["kind"] == "young_tree"
                and o["side"] == run["side"]
                and run["start"] <= o["at"] <= run["start"] + run["length"]
            ]
            assert len(trees) >= int(run["length"] // (TREE_SPACING_M[1] + 3.0))
            for tree in trees:
                setback = tree["offset"] - run["offset"]
                assert TREE_SETBACK_M[0] <= setback <= TREE_SETBACK_M[1] + 1e-3
        assert {o["kind"] for o in added} <= {"young_tree", "hedge"}
    with pytest.raises(SceneSpecError, match="--young-trees"):
        random_scene_spec(1, 100.0, young_trees=2.0)


def test_a_young_tree_is_a_thin_trunk_a_stake_and_a_crown() -> None:
    spec = random_scene_spec(1, 40.0)
    spec["guardrails"], spec["objects"] = (
        [],
        [{"kind": "young_tree", "side": "left", "offset": 1.0, "at": 20.0, "height": 3.0}],
    )
    scene = build_scene(spec, seed=1)
    (tree,) = (o for o in scene.objects if o["kind"] == "young_tree")
    assert tree["class"] == TruthClass.TREE and tree["geometry"]["height"] == 3.0
    mine = scene.mesh.face_object == tree["id"]
    assert (scene.mesh.face_class[mine] == TruthClass.TREE).all()
    vertices = scene.mesh.vertices[np.unique(scene.mesh.faces[mine])]
    base = np.array(tree["geometry"]["base"])
    height = vertices[:, 2] - base[2]
    assert 2.5 < height.max() < 4.0
    # Below the crown only the trunk and its stake: within 0.25 m of the foot.
    low = vertices[height < 1.2]
    assert len(low) and np.hypot(*(low[:, :2] - base[:2]).T).max() < 0.25
