"""Slice centres joined into polylines across the slices (§4.3, Fig. 16 d).

Slice by slice, every active polyline takes the centre nearest to the position predicted along
its direction, so that crossing pipes continue straight through the crossing; a centre taken by
two polylines (a crossing, or a pipe meeting another) is shared and does not steer them.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from guardrail_core.reconstruct.pipes.params import PipeParams
from guardrail_core.reconstruct.pipes.polylines import end_direction
from guardrail_core.reconstruct.pipes.slices import SliceComponents

#: Assignment cost of a centre out of a polyline's reach (reachable costs are at most 1).
_FORBIDDEN = 1e9
#: An x step below this many slice intervals reaches the next slice and no farther.
_NEXT_SLICE = 1.5
#: Gaps (metres) below this are zero: guards a division.
_TINY_GAP = 1e-9


@dataclass(frozen=True, slots=True)
class Centre:
    """The centre of one slice component on a polyline.

    Attributes
    ----------
    x, y : float, unit coordinates, metres
    weight : float, the component's points
    component : int, the component's index (:class:`SliceComponents`)
    shared : bool, taken by another polyline too: it does not steer this one
    """

    x: float
    y: float
    weight: float
    component: int
    shared: bool = False


@dataclass(eq=False)
class Track:
    """A polyline being linked across slices: one centre per slice it has data in, in x order.

    Attributes
    ----------
    centres : its centres
    last_own_x : float, metres: x of its last centre not shared with another polyline
    """

    centres: list[Centre]
    last_own_x: float = field(init=False)

    def __post_init__(self) -> None:
        self._update_last_own()

    def __len__(self) -> int:
        return len(self.centres)

    @property
    def first(self) -> Centre:
        return self.centres[0]

    @property
    def last(self) -> Centre:
        return self.centres[-1]

    def xy(self) -> np.ndarray:
        """(K, 2) float64, the centres' (x, y), metres."""
        return np.array([[c.x, c.y] for c in self.centres], dtype=np.float64).reshape(-1, 2)

    def add(self, centre: Centre) -> None:
        self.centres.append(centre)
        if not centre.shared:
            self.last_own_x = centre.x

    def extend(self, other: Track, start: int = 0) -> None:
        """Append ``other``'s centres from ``start`` on."""
        self.centres.extend(other.centres[start:])
        self._update_last_own()

    def keep_first(self, n: int) -> None:
        """Keep the first ``n`` centres only."""
        del self.centres[n:]
        self._update_last_own()

    def drop_shared_tail(self) -> None:
        """Drop the trailing centres shared with another polyline (they are that one's)."""
        while len(self.centres) > 1 and self.centres[-1].shared:
            self.centres.pop()

    def predict(self, x: float, p: PipeParams) -> tuple[float, float, float]:
        """Predicted y at ``x`` (metres), the allowed |dy| and the slope (nan while unknown).

        The direction is a weighted least-squares fit to the polyline's own centres (not shared
        at a crossing) within ``direction_window_m`` of its last own centre; it is trusted once
        they span ``direction_trust_share`` of the window, before that the polyline may turn up
        to ``link_max_slope``.
        """
        own = self._steering(p)
        if own is None:
            tolerance = p.link_distance_m + p.link_max_slope * abs(x - self.last.x)
            return self.last.y, tolerance, math.nan
        xs = np.array([c.x for c in own])
        ys = np.array([c.y for c in own])
        ws = np.array([c.weight for c in own])
        mx, my = np.average(xs, weights=ws), np.average(ys, weights=ws)
        sxx = float(np.sum(ws * (xs - mx) ** 2))
        slope = float(np.sum(ws * (xs - mx) * (ys - my))) / sxx if sxx > 0 else 0.0
        slope = min(max(slope, -p.link_max_slope), p.link_max_slope)
        return my + slope * (x - mx), p.link_distance_m * math.sqrt(1.0 + slope * slope), slope

    def steered(self, p: PipeParams) -> bool:
        """Whether the polyline's direction is known (see :meth:`predict`): only then may it
        bridge empty slices."""
        return self._steering(p) is not None

    def _steering(self, p: PipeParams) -> list[Centre] | None:
        """The own centres within ``direction_window_m`` of the last one when they span
        ``direction_trust_share`` of the window (the direction is known), else None."""
        start = self.last_own_x - p.direction_window_m
        own = [c for c in self.centres if not c.shared and c.x >= start]
        if len(own) >= 2 and own[-1].x - own[0].x >= p.direction_trust_share * p.direction_window_m:
            return own
        return None

    def _update_last_own(self) -> None:
        own = [c.x for c in self.centres if not c.shared]
        self.last_own_x = own[-1] if own else self.centres[0].x


def link_centres(components: SliceComponents, p: PipeParams) -> list[Track]:
    """Join the component centres of consecutive slices into polylines (§4.3, Fig. 16 d).

    A polyline stops after ``link_gap_m`` without an own centre (so one that runs into another
    pipe does not ride along it), and bridges empty slices only once its direction is known;
    centres nobody took start polylines.
    """
    cs = components.slice_of
    cx, cy = components.centres[:, 0], components.centres[:, 1]
    cw = components.weights
    tracks: list[Track] = []
    order = np.lexsort((cy, cs))
    bounds = np.flatnonzero(np.diff(cs[order])) + 1
    reach = p.link_gap_m + p.slice_interval_m
    step = _NEXT_SLICE * p.slice_interval_m
    for group in np.split(order, bounds):
        if len(group) == 0:
            continue
        xc = float(cx[group].mean())
        active = [
            t
            for t in tracks
            if xc - t.last_own_x <= reach and xc - t.last.x <= (reach if t.steered(p) else step)
        ]
        claims = _claims(active, xc, cy[group], p) if active else {}
        for j, g in enumerate(group):
            claim = claims.get(j)
            centre = Centre(float(cx[g]), float(cy[g]), float(cw[g]), int(g))
            if claim:
                shared = Centre(centre.x, centre.y, centre.weight, centre.component, True)
                for t in claim:
                    t.add(shared if len(claim) > 1 else centre)
            else:
                tracks.append(Track([centre]))
    for t in tracks:
        t.drop_shared_tail()
    return tracks


def _claims(active: list[Track], x: float, ys: np.ndarray, p: PipeParams) -> dict[int, list[Track]]:
    """Which of one slice's centres (at ``x``, heights ``ys`` (G,) metres) each ``active``
    polyline takes: centre index -> the polylines taking it.

    The nearest centre within a polyline's tolerance, one polyline per centre (an optimal
    assignment). A polyline left without a centre shares its nearest one: two pipes crossing or
    meeting fall into one component there. With the same direction (within
    ``link_same_angle_deg``) as the centre's owner, or while its direction is unknown and it is
    the shorter, it is a duplicate and takes none.
    """
    same_direction = math.tan(math.radians(p.link_same_angle_deg))
    preds = np.array([t.predict(x, p) for t in active])
    cost = np.abs(ys[None, :] - preds[:, :1]) / preds[:, 1:2]
    rows, cols = linear_sum_assignment(np.where(cost <= 1.0, cost, _FORBIDDEN))
    taken: dict[int, list[tuple[Track, float]]] = {}
    assigned = np.zeros(len(active), dtype=bool)
    for r, c in zip(rows, cols, strict=True):
        if cost[r, c] <= 1.0:
            taken.setdefault(int(c), []).append((active[r], preds[r, 2]))
            assigned[r] = True
    for r in np.flatnonzero(~assigned):
        c = int(np.argmin(cost[r]))
        if cost[r, c] > 1.0:
            continue
        owner = taken.get(c)
        if owner and math.isfinite(preds[r, 2]) and math.isfinite(owner[0][1]):
            if abs(preds[r, 2] - owner[0][1]) <= same_direction:
                continue
        elif owner and len(active[r]) < len(owner[0][0]):
            continue
        taken.setdefault(c, []).append((active[r], preds[r, 2]))
    return {c: [t for t, _ in claim] for c, claim in taken.items()}


def join_broken_tracks(tracks: list[Track], p: PipeParams) -> list[Track]:
    """Join polylines broken by a gap or a sharp bend: one's end within ``join_distance_m``
    (and ``link_gap_m`` + a slice in x) of the other's start, the step across continuing both
    directions (cosines of ``track_join_cos`` at least: no side branches). A polyline of one
    centre has no direction to continue and is joined to none: taken as level, it let an
    arch's chain step from its crown to a lone centre 0.17 m on and 0.12 m up, and from there
    onto the top rail. The first such pair in x order is joined, then the search starts
    again."""
    while True:
        tracks.sort(key=lambda t: t.first.x)
        pair = _first_broken_pair(tracks, p)
        if pair is None:
            return tracks
        i, j = pair
        head, tail = tracks[i], tracks.pop(j)
        head.extend(tail)


def _first_broken_pair(tracks: list[Track], p: PipeParams) -> tuple[int, int] | None:
    """The first pair (i, j) that :func:`join_broken_tracks` joins, of ``tracks`` sorted by the
    x of their first centre: in (i, j) order, as a double loop over all pairs would find it,
    looking at each track only among those that start just after its end (a bisection), with
    each end's direction worked out once."""
    firsts = [t.first.x for t in tracks]
    reach_x = p.link_gap_m + p.slice_interval_m
    directions: dict[tuple[int, bool], np.ndarray] = {}

    def direction(k: int, end: bool) -> np.ndarray:
        key = (k, end)
        if key not in directions:
            directions[key] = end_direction(tracks[k].xy(), p, end=end)
        return directions[key]

    for i, a in enumerate(tracks):
        # The tests below decide; the bisection (with a nanometre to spare on either side of
        # the rounding) only skips tracks that cannot pass them.
        lo = bisect.bisect_left(firsts, a.last.x - 1e-9)
        hi = bisect.bisect_right(firsts, a.last.x + reach_x + 1e-9)
        for j in range(lo, hi):
            b = tracks[j]
            if i == j or b.first.x <= a.last.x or len(a) < 2 or len(b) < 2:
                continue
            dx, dy = b.first.x - a.last.x, b.first.y - a.last.y
            gap = math.hypot(dx, dy)
            if gap > p.join_distance_m or dx > reach_x:
                continue
            step = np.array([dx, dy]) / max(gap, _TINY_GAP)
            if direction(i, True) @ step < p.track_join_cos:
                continue
            if -direction(j, False) @ step < p.track_join_cos:
                continue
            return i, j
    return None
