"""Straight stretches of a curved pipe, given back to the chaining (§4.3).

The random line search takes any stretch straight within its tolerance: the flank of a wave
between a crest and a trough is one, 0.4 m long and leaning 45°. Its points are then out of
the chaining, which leaves the wave in pieces on either side of it, and no piece is the pipe.
A diagonal line with a curved chain's end near one of its ends, turning from it by no more
than a wave's crest does, may be such a stretch: its points go back to the chaining, and it was
one when the curve chained again runs along it (else the line stays).
"""

from __future__ import annotations

import math

import numpy as np

from guardrail_core.reconstruct.pipes.params import PipeParams
from guardrail_core.reconstruct.pipes.polylines import (
    end_direction,
    resample,
    share_near,
    unit_vector,
)
from guardrail_core.reconstruct.pipes.skeleton import Skeleton


def stretch_turn_deg(line: Skeleton, curve: Skeleton, p: PipeParams) -> float:
    """Degrees: the smallest turn between the line's direction and the curve's at an end of the
    curve within ``link_gap_m`` of an end of the line that it leads into (the curve's end to
    the line's start, the line's end to the curve's start); 180 where there is none."""
    u = unit_vector(line.xy[-1] - line.xy[0])
    best = 180.0
    pairs = (
        (curve.xy[-1], end_direction(curve.xy, p, end=True), line.xy[0]),
        (curve.xy[0], -end_direction(curve.xy, p, end=False), line.xy[-1]),
    )
    for curve_end, direction, line_end in pairs:
        if float(np.linalg.norm(curve_end - line_end)) <= p.link_gap_m:
            cos = float(np.clip(direction @ u, -1.0, 1.0))
            best = min(best, math.degrees(math.acos(cos)))
    return best


def curve_stretches(lines: list[Skeleton], chains: list[Skeleton], p: PipeParams) -> list[int]:
    """Indices into ``lines`` of the diagonal lines that are straight stretches of a curved
    chain of ``chains`` (:func:`stretch_turn_deg` at most ``stretch_turn_deg``)."""
    curves = [c for c in chains if c.kind == "curved"]
    return [
        i
        for i, line in enumerate(lines)
        if line.kind == "diagonal"
        and any(stretch_turn_deg(line, c, p) <= p.stretch_turn_deg for c in curves)
    ]


def runs_along_a_curve(
    line: Skeleton, chains: list[Skeleton], x_range: tuple[float, float], p: PipeParams
) -> bool:
    """Whether a curved chain of ``chains`` runs along ``line`` (``duplicate_share`` of it
    within ``link_distance_m``) and on past both its ends in x, by ``slice_interval_m``, where
    an end is not within ``link_gap_m`` of the unit's ends ``x_range`` (metres, the poles'
    margins): the line is inside the curve, not a pipe of its own that a chain ran into."""
    probe = resample(line.xy, p.slice_interval_m)
    lo, hi = float(line.xy[:, 0].min()), float(line.xy[:, 0].max())
    for c in chains:
        if c.kind != "curved" or share_near(probe, c.xy, p.link_distance_m) < p.duplicate_share:
            continue
        before = c.xy[0, 0] <= lo - p.slice_interval_m or lo <= x_range[0] + p.link_gap_m
        after = c.xy[-1, 0] >= hi + p.slice_interval_m or hi >= x_range[1] - p.link_gap_m
        if before and after:
            return True
    return False
