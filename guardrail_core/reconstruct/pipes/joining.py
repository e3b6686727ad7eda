"""Ends extended to the pole axes and to the intersection of close ends (§4.3)."""

from __future__ import annotations

import math

import numpy as np

from guardrail_core.reconstruct.pipes.params import PipeParams
from guardrail_core.reconstruct.pipes.polylines import TINY, end_direction
from guardrail_core.reconstruct.pipes.skeleton import Skeleton

#: A ray and a segment closer to parallel than this (the cross product of their directions, m)
#: do not intersect.
_PARALLEL = 1e-9


def extend_and_join(skels: list[Skeleton], length: float, p: PipeParams) -> None:
    """§4.3: extend ends close to a pole to its axis, and close ends to their intersection.

    An end within ``pole_extension_m`` (in x) of a pole axis (x = 0 or ``length``, metres),
    heading toward it, goes to the axis, unless it meets another skeleton on the way. Any other
    end is moved along its direction to the nearest crossing with another skeleton (or with the
    extension of that skeleton's end, which is then extended too) within ``join_distance_m``
    ahead, or within ``join_behind_share`` of it behind (a trim: the points of a vertical pipe
    reach beyond the axis of the rail it stands on). Skeletons are changed in place, one end
    after another.
    """
    for i in range(len(skels)):
        for end in (0, -1):
            _join_end(skels, i, end, length, p)


def _join_end(skels: list[Skeleton], i: int, end: int, length: float, p: PipeParams) -> None:
    """Extend or trim the first (``end`` 0) or last (-1) end of ``skels[i]``."""
    s = skels[i]
    tip = s.xy[end]
    d = end_direction(s.xy, p, end=end == -1)
    pole_x = 0.0 if d[0] < 0 else length
    best_s, best_j, best_t, best_k = math.inf, -1, 0.0, 0
    for j, o in enumerate(skels):
        if j == i:
            continue
        sr, t, k = _ray_polyline(tip, d, o.xy, p.join_distance_m)
        if not -p.join_behind_share * p.join_distance_m <= sr <= p.join_distance_m:  # nan too
            continue
        if abs(sr) < abs(best_s):
            best_s, best_j, best_t, best_k = sr, j, t, k
    heads_to_pole = abs(d[0]) > p.toward_pole_min_cos
    to_pole = (pole_x - tip[0]) / d[0] if heads_to_pole else math.inf
    near_pole = s.kind != "vertical" and abs(tip[0] - pole_x) <= p.pole_extension_m
    # A diagonal or curved pipe that meets another before the pole ends there (a diamond's
    # diagonal on its rail), unless at the pole itself (diagonals from the corners); rails run
    # from pole to pole through their junctions.
    meets_first = (
        s.kind != "horizontal"
        and best_j >= 0
        and best_s < to_pole - p.join_distance_m * p.join_slack
    )
    if near_pole and math.isfinite(to_pole) and not meets_first:
        # §4.3: close to a pole: extended to the pole.
        _set_end(s, end, tip + to_pole * d, p)
        return
    if best_j < 0:
        return
    # §4.3: close ends are extended to their intersection.
    point = tip + best_s * d
    _set_end(s, end, point, p)
    o = skels[best_j]
    if best_k == 0 and best_t < 0:
        _set_end(o, 0, point, p)
    elif best_k == len(o.xy) - 2 and best_t > 1:
        _set_end(o, -1, point, p)


def _ray_polyline(
    e: np.ndarray, d: np.ndarray, xy: np.ndarray, ext: float
) -> tuple[float, float, int]:
    """Intersection of the line ``e + s d`` with the polyline ``xy`` (K, 2), its end segments
    extended by ``ext`` metres.

    Returns (s, t, k): the ray parameter, the segment parameter and segment index of the
    intersection closest to ``e`` (|s| smallest), or (nan, nan, -1).
    """
    a, b = xy[:-1], xy[1:]
    ab = b - a
    seg_len = np.maximum(np.linalg.norm(ab, axis=1), TINY)
    den = d[0] * ab[:, 1] - d[1] * ab[:, 0]
    w = a - e
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (w[:, 0] * ab[:, 1] - w[:, 1] * ab[:, 0]) / den
        t = (w[:, 0] * d[1] - w[:, 1] * d[0]) / den
    tlo = np.zeros(len(ab))
    thi = np.ones(len(ab))
    tlo[0] = -ext / seg_len[0]
    thi[-1] = 1.0 + ext / seg_len[-1]
    ok = np.isfinite(s) & (np.abs(den) > _PARALLEL) & (t >= tlo) & (t <= thi)
    if not ok.any():
        return math.nan, math.nan, -1
    k = int(np.argmin(np.where(ok, np.abs(s), np.inf)))
    return float(s[k]), float(t[k]), k


def _set_end(s: Skeleton, end: int, point: np.ndarray, p: PipeParams) -> None:
    """Move the first (``end`` 0) or last (-1) vertex of ``s`` to ``point`` (2,); a curve that
    is extended grows a vertex instead."""
    xy = s.xy
    if s.kind == "curved":
        tip = xy[end]
        direction = end_direction(xy, p, end=end == -1)
        if (point - tip) @ direction > 0:  # extension: add the point
            s.xy = np.vstack([xy, point]) if end == -1 else np.vstack([point, xy])
            return
    xy = xy.copy()
    xy[end] = point
    s.xy = xy
