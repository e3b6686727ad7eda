"""Chains that ran on along a rail (a straight pipe): cut back, or dropped as its duplicate.

Past a junction the chain of a diagonal or an arch's foot can take over the rail's points and run
on along it. Its ends along the rail are cut (the rail runs on through them) and what is left is
shaped again; what still runs along a rail once cut is the rail's duplicate.
"""

from __future__ import annotations

import numpy as np

from guardrail_core.reconstruct.pipes.params import PipeParams
from guardrail_core.reconstruct.pipes.polylines import (
    distance_to_polyline,
    resample,
    share_near,
    unit_vector,
)
from guardrail_core.reconstruct.pipes.shaping import straight_or_curved
from guardrail_core.reconstruct.pipes.skeleton import Skeleton


def runs_along(s: Skeleton, lines: list[Skeleton], p: PipeParams) -> bool:
    """Whether ``s`` mostly follows one of the straight pipes ``lines`` (``duplicate_share`` of
    it within ``link_distance_m``): a duplicate."""
    probe = resample(s.xy, p.slice_interval_m)
    return any(share_near(probe, line.xy, p.link_distance_m) >= p.duplicate_share for line in lines)


def cut_back(
    s: Skeleton, rails: list[Skeleton], length: float, pts: np.ndarray, p: PipeParams
) -> None:
    """Cut the ends of ``s`` that run along a rail and, when it is curved, shape it again from
    its own part (a diagonal that ran on along a rail is straight once that part is cut).

    ``length``: the unit's length, metres; ``pts`` (N, 3): the points between the poles.
    """
    if _trim_along(s, rails, length, p) and s.kind == "curved":
        _reshape(s, pts, p)


def _trim_along(s: Skeleton, lines: list[Skeleton], length: float, p: PipeParams) -> bool:
    """Cut the ends of ``s`` within ``line_band_m`` of a rail (a straight pipe, taken from pole
    to pole) for ``join_slack`` of ``join_distance_m`` or more. The rail runs on through them:
    its end is moved out to the last of them. The cut end is joined to the rail again by
    :func:`guardrail_core.reconstruct.pipes.joining.extend_and_join`. Returns whether it was cut.
    """
    if not lines or len(s.xy) < 3:
        return False
    near = np.full(len(s.xy), -1)
    best = np.full(len(s.xy), np.inf)
    for j, line in enumerate(lines):
        a, b = line.xy[0], line.xy[-1]
        u = unit_vector(b - a)
        if abs(u[0]) < p.toward_pole_min_cos:
            continue
        reach = np.vstack([a + (0.0 - a[0]) / u[0] * u, a + (length - a[0]) / u[0] * u])
        dist = distance_to_polyline(s.xy, reach)[0]
        closer = (dist <= p.line_band_m) & (dist < best)
        near[closer], best[closer] = j, dist[closer]
    along = near >= 0
    if along.all() or not along.any():
        return False
    step = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(s.xy, axis=0), axis=1))])
    first, last = int(np.argmin(along)), len(along) - 1 - int(np.argmin(along[::-1]))
    least = p.join_distance_m * p.join_slack
    cut_head = step[first] >= least
    cut_tail = step[-1] - step[last] >= least
    start = first if cut_head else 0
    stop = last + 1 if cut_tail else len(along)
    if not (cut_head or cut_tail) or stop - 1 <= start:
        return False
    for tip, cut in ((0, cut_head), (-1, cut_tail)):
        if cut:
            _run_on(lines[int(near[tip])], s.xy[tip])
    s.xy = s.xy[start:stop]
    return True


def _reshape(s: Skeleton, pts: np.ndarray, p: PipeParams) -> None:
    """Shape a cut chain again from its part and its points within ``link_distance_m`` of it."""
    own = s.idx[distance_to_polyline(pts[s.idx, :2], s.xy)[0] <= p.link_distance_m]
    if len(own) >= 2:
        shared = np.zeros(len(s.xy), bool)
        s.xy, s.kind = straight_or_curved(s.xy, shared, own, s.idx, pts, p)


def _run_on(line: Skeleton, point: np.ndarray) -> None:
    """Move the nearer end of a straight skeleton out to ``point`` (2,) projected on it, if
    beyond."""
    a, b = line.xy[0], line.xy[-1]
    u = unit_vector(b - a)
    t = float((point - a) @ u)
    if t > float((b - a) @ u):
        line.xy = np.vstack([line.xy[:-1], a + t * u])
    elif t < 0:
        line.xy = np.vstack([a + t * u, line.xy[1:]])
