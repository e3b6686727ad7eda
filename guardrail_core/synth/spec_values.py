"""Typed values read from a scene spec mapping, with errors that say where in the spec."""

from __future__ import annotations

from typing import Any

import numpy as np

from guardrail_core.errors import SceneSpecError
from guardrail_core.synth.materials import PAINTS
from guardrail_core.synth.road import SIDES


def spec_value(mapping: dict, key: str, kind: type, where: str, default: Any = ...) -> Any:
    """``mapping[key]`` checked to be of ``kind`` (float accepts ints), or ``default``."""
    if key not in mapping:
        if default is ...:
            raise SceneSpecError(f"{where}: missing key {key!r}")
        return default
    value = mapping[key]
    if kind is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise SceneSpecError(f"{where}.{key}: expected a number, got {value!r}")
        return float(value)
    if not isinstance(value, kind):
        raise SceneSpecError(
            f"{where}.{key}: expected {getattr(kind, '__name__', kind)}, got {value!r}"
        )
    return value


def spec_side(item: dict, where: str) -> str:
    """The ``side`` of an item: left or right."""
    side = spec_value(item, "side", str, where)
    if side not in SIDES:
        raise SceneSpecError(f"{where}.side: expected left or right, got {side!r}")
    return side


def spec_paint(item: dict, where: str, rng: np.random.Generator) -> str:
    """The ``paint`` of an item, or one drawn from ``rng`` when the spec leaves it open."""
    paint = spec_value(item, "paint", str, where, str(rng.choice(list(PAINTS))))
    if paint not in PAINTS:
        raise SceneSpecError(f"{where}.paint: unknown paint {paint!r} (known: {', '.join(PAINTS)})")
    return paint
