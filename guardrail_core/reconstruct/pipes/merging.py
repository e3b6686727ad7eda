"""Pieces of one pipe that the chaining left apart, merged (§4.3): duplicates (two chains that
followed one pipe) and fragments (a pipe broken at a gap, a crossing or a junction)."""

from __future__ import annotations

import math

import numpy as np

from guardrail_core.errors import ReconstructionError
from guardrail_core.reconstruct.pipes.params import PipeParams
from guardrail_core.reconstruct.pipes.polylines import (
    distance_to_polyline,
    end_direction,
    resample,
    share_near,
    unit_vector,
)
from guardrail_core.reconstruct.pipes.shaping import shape_chain
from guardrail_core.reconstruct.pipes.skeleton import Chain, Skeleton

#: Gaps (metres) below this are zero: the step across has no direction.
_TINY_GAP = 1e-9
#: Two straight pieces are on one line within at least this angle (degrees): a sine above zero.
_MIN_LINE_ANGLE_DEG = 1e-3


def merge_duplicates(skels: list[Skeleton], pts: np.ndarray, p: PipeParams) -> list[Skeleton]:
    """Merge each chained skeleton that runs along a bigger one (``duplicate_share`` of it
    within ``link_distance_m``) into it, biggest first."""
    kept: list[Skeleton] = []
    for s in sorted(skels, key=lambda k: -len(k.idx)):
        probe = resample(s.xy, p.slice_interval_m)
        for i, k in enumerate(kept):
            if share_near(probe, k.xy, p.link_distance_m) >= p.duplicate_share:
                kept[i] = union(k, s, pts, p)
                break
        else:
            kept.append(s)
    return kept


def union(a: Skeleton, b: Skeleton, pts: np.ndarray, p: PipeParams) -> Skeleton:
    """One skeleton shaped from the centres and points of two chained pieces of a pipe.

    Raises
    ------
    ReconstructionError
        A piece was not chained from slices (it has no centres to shape).
    """
    if a.chain is None or b.chain is None:
        raise ReconstructionError("only skeletons chained from slices can be merged")
    centres = np.vstack([a.chain.centres, b.chain.centres])
    shared = np.concatenate([a.chain.shared, b.chain.shared])
    order = np.argsort(centres[:, 0], kind="stable")
    own = np.union1d(a.chain.own, b.chain.own)
    chain = Chain(centres=centres[order], shared=shared[order], own=own)
    return shape_chain(chain, np.union1d(a.idx, b.idx), pts, p)


def merge_fragments(skels: list[Skeleton], pts: np.ndarray, p: PipeParams) -> list[Skeleton]:
    """Join pieces of one pipe that the linking left apart (gaps, crossings, junctions).

    Two straight pieces merge when they lie on one line (directions within
    ``horizontal_angle_deg``, ends within ``link_distance_m`` of the other's line) with at most
    ``merge_gap_m`` between them; two pieces merge end to start when the gap is at most
    ``merge_gap_m`` and the step from one to the other continues both directions (within
    ``merge_angle_deg``), or when their ends ran past each other along one curve
    (:func:`_overlap`). The first such pair in x order is merged, then the search starts
    again (the merged piece is shaped anew).
    """
    while True:
        skels.sort(key=lambda k: float(k.xy[:, 0].min()))
        pair = _first_mergeable(skels, p)
        if pair is None:
            return skels
        i, j = pair
        skels[i] = union(skels[i], skels[j], pts, p)
        skels.pop(j)


def _first_mergeable(skels: list[Skeleton], p: PipeParams) -> tuple[int, int] | None:
    cos_turn = math.cos(math.radians(p.merge_angle_deg))
    sin_line = math.sin(math.radians(max(p.horizontal_angle_deg, _MIN_LINE_ANGLE_DEG)))
    for i, a in enumerate(skels):
        for j in range(i + 1, len(skels)):
            if _can_merge(a, skels[j], p, cos_turn, sin_line):
                return i, j
    return None


def _can_merge(a: Skeleton, b: Skeleton, p: PipeParams, cos_turn: float, sin_line: float) -> bool:
    """Whether ``b`` (starting farther in x) continues ``a`` (see :func:`merge_fragments`)."""
    a_end, b_start = a.xy[-1], b.xy[0]
    gap = b_start[0] - a_end[0]
    if gap > p.merge_gap_m:
        return False
    if a.kind != "curved" and b.kind != "curved":  # straight pieces may overlap
        da = unit_vector(a.xy[-1] - a.xy[0])
        db = unit_vector(b.xy[-1] - b.xy[0])
        if abs(da[0] * db[1] - da[1] * db[0]) > sin_line:
            return False
        na = np.array([-da[1], da[0]])
        return bool(np.all(np.abs((b.xy - a.xy[0]) @ na) <= p.link_distance_m))
    if gap < 0 and _overlap(a, b, p, cos_turn):
        return True
    if gap < -p.link_distance_m:
        return False
    step = b_start - a_end
    n = float(np.linalg.norm(step))
    if n > p.merge_gap_m:
        return False
    ea = end_direction(a.xy, p, end=True)
    sb = -end_direction(b.xy, p, end=False)
    if n < _TINY_GAP:
        return bool(ea @ sb >= cos_turn)
    step = step / n
    return bool(ea @ step >= cos_turn and sb @ step >= cos_turn)


def _overlap(a: Skeleton, b: Skeleton, p: PipeParams, cos_turn: float) -> bool:
    """Whether ``b`` takes over from ``a`` where both follow one curve: ``b`` starts behind
    ``a``'s end (by at most ``merge_gap_m`` in x), each of those two ends lies within
    ``link_distance_m`` of the other piece, and the pieces head the same way there (within
    ``merge_angle_deg``). A wave's chain broken on its flank, with the two pieces' ends run
    past each other, leaves this; the step from end to start then points back."""
    if {a.kind, b.kind} & {"horizontal", "vertical"}:
        return False
    if a.xy[-1, 0] - b.xy[0, 0] > p.merge_gap_m:
        return False
    b_on_a, _ = distance_to_polyline(b.xy[:1], a.xy)
    a_on_b, _ = distance_to_polyline(a.xy[-1:], b.xy)
    if b_on_a[0] > p.link_distance_m or a_on_b[0] > p.link_distance_m:
        return False
    ea = end_direction(a.xy, p, end=True)
    sb = -end_direction(b.xy, p, end=False)
    return bool(ea @ sb >= cos_turn)


def merge_meetings(skels: list[Skeleton], p: PipeParams) -> list[Skeleton]:
    """Join pieces of one curve that meet end to start once their ends were joined
    (:func:`guardrail_core.reconstruct.pipes.joining.extend_and_join`): at least one of them
    curved, neither horizontal nor vertical, the end and the start within ``slice_interval_m``
    and the turn between them at most ``merge_angle_deg``. An arch whose chain ran up into a
    king post too sparse to be found breaks at its crown; the two halves' ends are joined at
    the crown, where they run on smoothly. Lattice pipes meeting at a corner turn by 90°."""
    cos_turn = math.cos(math.radians(p.merge_angle_deg))
    while True:
        pair = _first_meeting(skels, p, cos_turn)
        if pair is None:
            return skels
        i, j = pair
        a, b = skels[i], skels[j]
        skels[i] = Skeleton(
            xy=np.vstack([a.xy, b.xy[1:]]), kind="curved", idx=np.union1d(a.idx, b.idx)
        )
        skels.pop(j)


def _first_meeting(skels: list[Skeleton], p: PipeParams, cos_turn: float) -> tuple[int, int] | None:
    """The first pair (i, j) whose end of ``skels[i]`` meets the start of ``skels[j]`` as
    :func:`merge_meetings` joins them, or None."""
    for i, a in enumerate(skels):
        for j, b in enumerate(skels):
            if i == j or "curved" not in (a.kind, b.kind):
                continue
            if {a.kind, b.kind} & {"horizontal", "vertical"}:
                continue
            if float(np.linalg.norm(b.xy[0] - a.xy[-1])) > p.slice_interval_m:
                continue
            ea = end_direction(a.xy, p, end=True)
            sb = -end_direction(b.xy, p, end=False)
            if float(ea @ sb) >= cos_turn:
                return i, j
    return None
