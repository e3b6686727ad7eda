"""Truth classes of points and pixels, shared by the simulator, the truth files and evaluation.

The ids are stable: they are written into drive truth files (``truth/points.npz`` and the
per-image masks), so a change here is a change of the drive format.
"""

from __future__ import annotations

from enum import IntEnum


class TruthClass(IntEnum):
    """Semantic class of a surface in a synthetic scene (uint8 in truth files)."""

    NONE = 0  # sky / no surface (masks only)
    ROAD = 1
    ROAD_MARKING = 2
    CURB = 3
    SIDEWALK = 4
    TERRAIN = 5
    GUARDRAIL = 6  # pipes and beams of a guardrail
    GUARDRAIL_POLE = 7  # the poles (posts) of a guardrail
    FENCE = 8  # mesh and bar fences
    WALL = 9
    BICYCLE_RACK = 10
    BOLLARD = 11
    POLE = 12  # utility and street-light poles
    SIGN = 13  # sign poles and plates
    TREE = 14
    CAR = 15
    BUILDING = 16
    PEDESTRIAN = 17
    VEGETATION = 18  # hedges, shrubs and grass taller than a mown verge (trees are TREE)


#: Classes that together make a guardrail: the detection target of §3.
GUARDRAIL_CLASSES: frozenset[int] = frozenset({TruthClass.GUARDRAIL, TruthClass.GUARDRAIL_POLE})
