"""Planting close behind pedestrian railings along kerbs: young trees tied to stakes and low
hedges, as junctions and town streets hold them.

A young tree's trunk and stake have a railing post's girth and stand a step behind the rail, so
a classifier must learn them from the geometry around them. Added to a random street's spec
(:func:`~guardrail_core.synth.random_scene.random_scene_spec`) from a random stream of its own, so a
street without them is the street of the same seed.
"""

from __future__ import annotations

import numpy as np

from guardrail_core.synth.designs import load_design

#: Metres between young trees along a railing.
TREE_SPACING_M = (4.0, 9.0)
#: Metres behind the rail's post line where the trees stand.
TREE_SETBACK_M = (0.4, 1.0)


def add_kerb_planting(
    guardrails: list[dict], objects: list[dict], share: float, rng: np.random.Generator
) -> None:
    """Behind ``share`` (0-1) of the pipe runs (pedestrian railings): young trees every 4-9 m,
    0.4-1.0 m behind the rail, and, one time in two, a low clipped hedge right behind it.
    ``objects`` is extended in place."""
    for run in guardrails:
        if load_design(run["design"]).type != "pipe" or rng.random() >= share:
            continue
        at = run["start"] + float(rng.uniform(0.5, 3.0))
        while at < run["start"] + run["length"] - 0.5:
            setback = float(rng.uniform(*TREE_SETBACK_M))
            objects.append(
                {
                    "kind": "young_tree",
                    "side": run["side"],
                    "offset": round(run["offset"] + setback, 3),
                    "at": round(at, 3),
                }
            )
            at += float(rng.uniform(*TREE_SPACING_M))
        if rng.random() < 0.5:
            depth = float(rng.uniform(0.4, 0.8))
            objects.append(
                {
                    "kind": "hedge",
                    "side": run["side"],
                    "offset": round(run["offset"] + 0.12 + depth / 2, 3),
                    "at": run["start"],
                    "length": run["length"],
                    "depth": round(depth, 2),
                    "height": round(float(rng.uniform(0.5, 1.0)), 2),
                }
            )
