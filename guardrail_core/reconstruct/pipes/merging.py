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
#: A parabola is judged on at least this many vertices a side of a junction (3 fix one).
_FIT_VERTICES = 3
#: A piece's first vertices that may stand off the curve it continues: the hook a stray
#: streak starts it with (two slices of 30 mm).
_HOOK_VERTICES = 2


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
    (:func:`_overlap`), or when their ends lie on one parabola (:func:`_on_one_curve`). The
    first such pair in x order is merged, then the search starts again (the merged piece is
    shaped anew).
    """
    while True:
        skels.sort(key=lambda k: float(k.xy[:, 0].min()))
        found = _first_mergeable(skels, p)
        if found is None:
            return skels
        i, j, b = found
        skels[i] = union(skels[i], b, pts, p)
        skels.pop(j)


def _first_mergeable(skels: list[Skeleton], p: PipeParams) -> tuple[int, int, Skeleton] | None:
    """The first pair (i, j) that merges, with ``skels[j]`` as it joins (its hook at the
    junction left out, :func:`_on_one_curve`), or None."""
    cos_turn = math.cos(math.radians(p.merge_angle_deg))
    sin_line = math.sin(math.radians(max(p.horizontal_angle_deg, _MIN_LINE_ANGLE_DEG)))
    for i, a in enumerate(skels):
        for j in range(i + 1, len(skels)):
            b = skels[j]
            if _can_merge(a, b, p, cos_turn, sin_line):
                return i, j, b
            trimmed = _on_one_curve(a, b, p)
            if trimmed is not None:
                return i, j, trimmed
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


def _on_one_curve(a: Skeleton, b: Skeleton, p: PipeParams) -> Skeleton | None:
    """``b`` without its hook when ``a``'s end and ``b``'s start lie on one smooth curve across
    the junction, else None.

    The vertices of each piece within ``direction_window_m`` (in x) of the junction, ``b``'s
    from past ``a``'s end, must lie within half of ``link_distance_m`` of one parabola y(x)
    fitted to them all; up to ``_HOOK_VERTICES`` of ``b``'s first vertices may stand off it
    and are left out of ``b``. A wave's chain broken at a trough turns 50-60° by the chord
    directions of its two pieces, and a piece that a stray streak started beside a crest
    begins with a hook 5 cm off the wave; neither passes the end-to-start test. Neither piece
    horizontal or vertical, at least one curved, ``b`` starting within ``merge_gap_m`` of
    ``a``'s end (in x and in distance).
    """
    if "curved" not in (a.kind, b.kind) or {a.kind, b.kind} & {"horizontal", "vertical"}:
        return None
    if a.chain is None or b.chain is None:
        return None
    if float(np.linalg.norm(b.xy[0] - a.xy[-1])) > p.merge_gap_m:
        return None
    x_end = float(a.xy[-1, 0])
    if abs(float(b.xy[0, 0]) - x_end) > p.merge_gap_m:
        return None
    window = p.direction_window_m
    tail = a.xy[a.xy[:, 0] >= x_end - window]
    past = np.flatnonzero(b.xy[:, 0] > x_end)
    if len(past) == 0:
        return None
    head = b.xy[past[0] :]
    head = head[head[:, 0] <= head[0, 0] + window]
    tolerance = 0.5 * p.link_distance_m
    for skip in range(min(_HOOK_VERTICES, len(head) - _FIT_VERTICES) + 1):
        used = head[skip:]
        if len(tail) < _FIT_VERTICES or len(used) < _FIT_VERTICES:
            return None
        xy = np.vstack([tail, used])
        if np.any(np.diff(xy[:, 0]) <= 0):  # not a curve y(x) across the junction
            return None
        fit = np.polynomial.Polynomial.fit(xy[:, 0], xy[:, 1], 2)
        if np.abs(fit(xy[:, 0]) - xy[:, 1]).max() <= tolerance:
            return _without_start(b, b.chain, float(used[0, 0]))
    return None


def _without_start(b: Skeleton, chain: Chain, x_from: float) -> Skeleton:
    """``b`` (chained as ``chain``) with its centres and vertices before ``x_from`` (metres)
    left out; its points stay."""
    keep = chain.centres[:, 0] >= x_from - _TINY_GAP
    kept = Chain(centres=chain.centres[keep], shared=chain.shared[keep], own=chain.own)
    return Skeleton(xy=b.xy[b.xy[:, 0] >= x_from - _TINY_GAP], kind=b.kind, idx=b.idx, chain=kept)


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
