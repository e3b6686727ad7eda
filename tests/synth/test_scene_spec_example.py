"""The documentation's own scene spec builds, so a new user's first try works."""

from __future__ import annotations

import re
from pathlib import Path

import yaml

from guardrail_core.synth.scene import build_scene

SIMULATE_PAGE = Path(__file__).resolve().parents[2] / "docs" / "how-to" / "simulate.md"


def test_the_documented_scene_spec_builds() -> None:
    blocks = re.findall(
        r"```yaml\n(# my_street.yaml\n.*?)```", SIMULATE_PAGE.read_text(), flags=re.S
    )
    assert len(blocks) == 1
    scene = build_scene(yaml.safe_load(blocks[0]))
    kinds = sorted(o["kind"] for o in scene.objects)
    assert kinds.count("guardrail") == 2 and "bar_fence" in kinds and "parked_car" in kinds
