"""Crossings where a polyline bounced off the other pipe instead of crossing it (§4.3).

The linking predicts straight on through a crossing, but where one side is thin there a
polyline can turn into the other pipe's far half: an X becomes a Λ (or V) and two halves, one
ending and one starting near the Λ's apex. Where the halves continue the Λ's two arms straighter
than the Λ turns, they are joined to them instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from guardrail_core.reconstruct.pipes.params import PipeParams
from guardrail_core.reconstruct.pipes.tracking import Track


@dataclass(frozen=True)
class _Bounce:
    """A Λ (or V) polyline ``track`` with its apex at centre ``apex``; ``ending`` is the half
    that continues its second arm (it ends near the apex), ``starting`` the half that continues
    its first arm."""

    track: Track
    apex: int
    ending: Track
    starting: Track


def uncross(tracks: list[Track], p: PipeParams) -> list[Track]:
    """Repair every bounce: the ending half runs on into the Λ's second arm, the Λ's first arm
    runs on into the starting half. The first bounce found is repaired, then the search starts
    again (a repair changes the polylines around it)."""
    while (bounce := _first_bounce(tracks, p)) is not None:
        t, k = bounce.track, bounce.apex
        bounce.ending.extend(t, k + 1)
        t.keep_first(k + 1)
        t.extend(bounce.starting)
        tracks.remove(bounce.starting)
    return tracks


def _first_bounce(tracks: list[Track], p: PipeParams) -> _Bounce | None:
    """The first centre, polyline by polyline, that is the apex of a bounce.

    A centre is one where the polyline's own directions, fitted within ``direction_window_m``
    either side beyond a margin (``link_distance_m`` + a slice), turn by at least
    ``bounce_turn_factor`` times ``link_same_angle_deg``, and where a polyline ending and one
    starting within ``join_distance_m`` of it continue the two arms straighter, by
    ``link_same_angle_deg`` at least.
    """
    margin = p.link_distance_m + p.slice_interval_m
    w = p.direction_window_m
    same = math.radians(p.link_same_angle_deg)
    for t in tracks:
        for centre in t.centres[1:-1]:
            x, y = centre.x, centre.y
            head = _side_angle(t, x - margin - w, x - margin, p)
            tail = _side_angle(t, x + margin, x + margin + w, p)
            if not (np.isfinite(head) and np.isfinite(tail)):
                continue
            turn = abs(head - tail)
            if turn < p.bounce_turn_factor * same:
                continue
            ends = [
                u for u in tracks
                if u is not t and u.last.x < x
                and math.hypot(u.last.x - x, u.last.y - y) <= p.join_distance_m
            ]  # fmt: skip
            starts = [
                v for v in tracks
                if v is not t and v.first.x > x
                and math.hypot(v.first.x - x, v.first.y - y) <= p.join_distance_m
            ]  # fmt: skip
            best = None
            for u in ends:
                u_dir = _side_angle(u, u.last.x - w, u.last.x, p)
                for v in starts:
                    if v is u:
                        continue
                    v_dir = _side_angle(v, v.first.x, v.first.x + w, p)
                    bent = abs(u_dir - tail) + abs(head - v_dir)
                    if np.isfinite(bent) and bent <= turn - same:
                        if best is None or bent < best[0]:
                            best = (bent, u, v)
            if best is None:
                continue
            # The apex: the highest centre near here of a Λ, the lowest of a V.
            near = [i for i, c in enumerate(t.centres) if abs(c.x - x) <= margin]
            sign = 1.0 if head > tail else -1.0
            apex = max(near, key=lambda i: sign * t.centres[i].y)
            return _Bounce(track=t, apex=apex, ending=best[1], starting=best[2])
    return None


def _side_angle(t: Track, x0: float, x1: float, p: PipeParams) -> float:
    """Direction (radians from +x) of a polyline's own centres with x0 <= x <= x1 (metres);
    nan with fewer than ``bounce_side_centres``."""
    own = [c for c in t.centres if x0 <= c.x <= x1 and not c.shared]
    if len(own) < p.bounce_side_centres:
        return math.nan
    xs, ys = np.array([c.x for c in own]), np.array([c.y for c in own])
    return math.atan(float(np.polyfit(xs, ys, 1)[0]))
