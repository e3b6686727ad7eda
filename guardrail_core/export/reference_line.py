"""A road's reference line and elevation, fitted to the vehicle's trajectory (for OpenDRIVE).

OpenDRIVE places everything along a road's reference line: a chain of plan-view geometry
records, each with its start point, heading and length, and s the distance along the chain. The
chain here is made of lines and arcs only, the two records every reader evaluates in closed
form: a ``paramPoly3``'s parameter is not its arc length, and readers map between the two
differently, so an object's s would land in different places.

The fit is a G1 biarc spline (Bolton 1975; Meek & Walton 1992). Knots are trajectory points
with the trajectory's tangent there (a quadratic fitted to the points within
:data:`TANGENT_WINDOW_M`); between two knots a biarc, two arcs meeting with a common tangent,
runs through both knots along their tangents. An interval whose trajectory points stray more
than the tolerance from its biarc is split at its middle, until every point is within it. The
chain is continuous in position and heading, passes through every knot, and its worst
deviation from the trajectory is at most the tolerance. Beyond its ends the line is taken to
go on straight (:meth:`ReferenceLine.extended` writes that out, so objects past the trajectory's
ends have an s on the road).

The elevation is a natural cubic spline through the road's height at knots every
:data:`ELEVATION_STEP_M` along s, continued linearly past the first and last knot: OpenDRIVE's
``<elevation>`` records, one per cubic piece.

Coordinates are the frame of the points given (the drive's local frame, metres); headings are
radians counter-clockwise from +x; curvature is 1/m, positive turning left; t is the lateral
offset from the line, positive to its left.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial import cKDTree

from guardrail_core.errors import ExportError

#: Metres. The reference line's largest deviation from the trajectory: well inside a lane's
#: tolerance for placing the road, and each object's position is exact whatever it is (its s, t
#: are measured on the fitted line).
FIT_TOLERANCE_M = 0.05
#: Metres each side of a knot whose trajectory points give its tangent: wide enough to average
#: out a few centimetres of position noise, narrow enough for a 20 m radius.
TANGENT_WINDOW_M = 2.0
#: Metres. A trajectory point this close to the previous one kept is dropped (a vehicle
#: standing still), so the path has no repeated points.
MIN_STEP_M = 0.05
#: Metres. An arc that leaves its chord by less than this is written as the chord (a line):
#: the heading jump it leaves at its ends is below 1e-5 rad for any record over 1 m.
STRAIGHT_SAGITTA_M = 1e-6
#: Metres between the knots of the elevation spline.
ELEVATION_STEP_M = 10.0
#: Metres between the points that find the records near a point (:meth:`ReferenceLine.project`).
_SAMPLE_M = 1.0
#: Nearest samples whose records (and their neighbours) are tried for each projected point.
_NEAREST_SAMPLES = 4


@dataclass(frozen=True)
class Projection:
    """Points located on a :class:`ReferenceLine`; (N,) float64 each.

    Attributes
    ----------
    s : metres along the line; below 0 or past its length for a point beyond an end (on the
        line's straight continuation)
    t : metres, lateral offset, positive to the left of the line
    distance : metres, horizontal distance to the line (|t| where the point lies abreast of it)
    """

    s: np.ndarray
    t: np.ndarray
    distance: np.ndarray


@dataclass(frozen=True)
class ReferenceLine:
    """A chain of G line and arc records, (G,) float64 arrays.

    Attributes
    ----------
    s : each record's start along the line, metres (``s[0] == 0``)
    x, y : its start point, metres
    hdg : its heading at the start, radians counter-clockwise from +x
    length : its length, metres (> 0)
    curvature : 1/m, positive turning left; 0 for a line
    """

    s: np.ndarray
    x: np.ndarray
    y: np.ndarray
    hdg: np.ndarray
    length: np.ndarray
    curvature: np.ndarray

    @property
    def total_length(self) -> float:
        """Metres from the first record's start to the last one's end."""
        return float(self.s[-1] + self.length[-1])

    def evaluate(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 2) points and (N,) headings (radians) at (N,) s, metres; an s beyond an end is on
        the line's straight continuation."""
        s = np.asarray(s, np.float64)
        g = np.clip(np.searchsorted(self.s, s, side="right") - 1, 0, len(self.s) - 1)
        ds = s - self.s[g]
        inside = np.clip(ds, 0.0, self.length[g])
        u, v = _local_point(inside, self.curvature[g])
        heading = self.hdg[g] + self.curvature[g] * inside
        u = u + (ds - inside) * np.cos(self.curvature[g] * inside)
        v = v + (ds - inside) * np.sin(self.curvature[g] * inside)
        cos, sin = np.cos(self.hdg[g]), np.sin(self.hdg[g])
        xy = np.stack([self.x[g] + u * cos - v * sin, self.y[g] + u * sin + v * cos], axis=-1)
        return xy, heading

    def to_xy(self, s: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(N, 2) points at (N,) s along the line and t to its left, metres."""
        xy, heading = self.evaluate(s)
        return xy + np.asarray(t, np.float64)[:, None] * np.stack(
            [-np.sin(heading), np.cos(heading)], axis=-1
        )

    def project(self, xy: np.ndarray) -> Projection:
        """The nearest point of the line (or of its straight continuation beyond an end) to each
        of (N, 2) points.

        The candidates of a point are the records of its nearest samples of the line and their
        neighbours; each is solved in closed form.
        """
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        samples, record = self._samples()
        k = min(_NEAREST_SAMPLES, len(samples))
        _, nearest = cKDTree(samples).query(xy, k=k)
        nearest = np.asarray(nearest).reshape(len(xy), k)
        # Index -1 is the straight continuation before the start, G the one after the end.
        candidates = (record[nearest][:, :, None] + np.arange(-1, 2)).reshape(len(xy), 3 * k)
        params = self._with_continuations()
        x0, y0, hdg, curvature, lo, hi, s0 = (p[candidates + 1] for p in params)
        ds, t, distance = _project_local(xy[:, None, :], x0, y0, hdg, curvature, lo, hi)
        best = np.argmin(distance, axis=1)[:, None]
        s, t, distance = (np.take_along_axis(a, best, axis=1)[:, 0] for a in (s0 + ds, t, distance))
        return Projection(s=s, t=t, distance=distance)

    def extended(self, before: float, after: float) -> ReferenceLine:
        """The line with straight records of ``before`` metres ahead of its start and ``after``
        metres past its end (none where 0), the continuation :meth:`project` measures on; s
        starts again at 0 at the new start."""
        x, y = self.x, self.y
        hdg, length, curvature = self.hdg, self.length, self.curvature
        if before > 0:
            x = np.r_[x[0] - before * np.cos(hdg[0]), x]
            y = np.r_[y[0] - before * np.sin(hdg[0]), y]
            hdg, length, curvature = (
                np.r_[hdg[0], hdg],
                np.r_[before, length],
                np.r_[0.0, curvature],
            )
        if after > 0:
            (end_x, end_y), end_hdg = (a[0] for a in self.evaluate(np.array([self.total_length])))
            x, y = np.r_[x, end_x], np.r_[y, end_y]
            hdg, length, curvature = (
                np.r_[hdg, end_hdg],
                np.r_[length, after],
                np.r_[curvature, 0.0],
            )
        return _chain(x, y, hdg, length, curvature)

    def _samples(self) -> tuple[np.ndarray, np.ndarray]:
        """(M, 2) points along the line, at most :data:`_SAMPLE_M` apart and at least two per
        record, and (M,) the record of each."""
        counts = np.maximum(np.ceil(self.length / _SAMPLE_M).astype(np.int64), 1) + 1
        record = np.repeat(np.arange(len(self.s)), counts)
        fraction = np.concatenate([np.linspace(0.0, 1.0, n) for n in counts])
        xy, _ = self.evaluate(self.s[record] + fraction * self.length[record])
        return xy, record

    def _with_continuations(self) -> tuple[np.ndarray, ...]:
        """x0, y0, hdg, curvature, lo, hi, s0 of the records, with the straight continuation
        before the start first and the one past the end last ((G + 2,) each): a point is
        ``lo <= ds <= hi`` metres along a record that starts at ``s0`` on the line."""
        (end_x, end_y), end_hdg = (a[0] for a in self.evaluate(np.array([self.total_length])))
        n = len(self.s)
        return (
            np.r_[self.x[0], self.x, end_x],
            np.r_[self.y[0], self.y, end_y],
            np.r_[self.hdg[0], self.hdg, end_hdg],
            np.r_[0.0, self.curvature, 0.0],
            np.r_[-np.inf, np.zeros(n), 0.0],
            np.r_[0.0, self.length, np.inf],
            np.r_[0.0, self.s, self.total_length],
        )


def fit_reference_line(xy: np.ndarray, tolerance: float = FIT_TOLERANCE_M) -> ReferenceLine:
    """Lines and arcs through (N, 2) trajectory points, in driving order, within ``tolerance``
    metres of every point (see the module docstring).

    Raises
    ------
    ExportError
        The trajectory does not move (fewer than two points :data:`MIN_STEP_M` apart).
    """
    path = _moving(np.asarray(xy, np.float64).reshape(-1, 2))
    if len(path) < 2:
        raise ExportError(
            f"the trajectory never moves {MIN_STEP_M} m: there is no road to fit a reference "
            "line to"
        )
    along = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))]
    tangents: dict[int, np.ndarray] = {}

    def tangent(i: int) -> np.ndarray:
        if i not in tangents:
            tangents[i] = _tangent(path, along, i)
        return tangents[i]

    pieces: list[np.ndarray] = []
    stack = [(0, len(path) - 1)]
    while stack:
        i, j = stack.pop()
        biarc = _biarc(path[i], tangent(i), path[j], tangent(j))
        if j - i > 1 and (biarc is None or _deviation(biarc, path[i + 1 : j]).max() > tolerance):
            middle = int(np.searchsorted(along, (along[i] + along[j]) / 2))
            middle = min(max(middle, i + 1), j - 1)
            stack += [(middle, j), (i, middle)]  # the first half is popped first
            continue
        # Two neighbouring points whose tangents no biarc joins (a jump of the trajectory):
        # the chord between them.
        pieces += list(biarc) if biarc is not None else [_piece(path[i], path[j] - path[i])]
    x, y, hdg, length, curvature = np.array(pieces).T
    return _chain(x, y, hdg, length, curvature)


def worst_deviation(line: ReferenceLine, xy: np.ndarray) -> float:
    """Metres: the largest horizontal distance of (N, 2) points from the line."""
    return float(line.project(xy).distance.max(initial=0.0))


@dataclass(frozen=True)
class Elevation:
    """A road's height along its reference line: cubic pieces, OpenDRIVE's ``<elevation>``.

    Attributes
    ----------
    s : (K,) float64, metres, each piece's start along the line (``s[0] == 0``, ascending)
    a, b, c, d : (K,) float64, the height ``a + b ds + c ds² + d ds³`` metres, ds metres from
        the piece's start
    """

    s: np.ndarray
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray

    def __call__(self, s: np.ndarray) -> np.ndarray:
        """(N,) heights, metres, at (N,) s, metres."""
        s = np.asarray(s, np.float64)
        k = np.clip(np.searchsorted(self.s, s, side="right") - 1, 0, len(self.s) - 1)
        ds = s - self.s[k]
        return self.a[k] + ds * (self.b[k] + ds * (self.c[k] + ds * self.d[k]))


def fit_elevation(
    s: np.ndarray, height: np.ndarray, length: float, step: float = ELEVATION_STEP_M
) -> Elevation:
    """The road's height along a line of ``length`` metres from (N,) heights, metres, at (N,)
    s, metres: a natural cubic spline through the heights interpolated at knots ``step`` metres
    apart over the range of s, straight beyond it."""
    s = np.clip(np.asarray(s, np.float64), 0.0, length)
    height = np.asarray(height, np.float64)
    order = np.argsort(s, kind="stable")
    s, height = s[order], height[order]
    lo, hi = float(s[0]), float(s[-1])
    if hi - lo < MIN_STEP_M:  # the vehicle stood still: a level road
        level = float(np.median(height))
        return Elevation(*(np.array([v]) for v in (0.0, level, 0.0, 0.0, 0.0)))
    knots = np.linspace(lo, hi, max(2, int(np.ceil((hi - lo) / step)) + 1))
    spline = CubicSpline(knots, np.interp(knots, s, height), bc_type="natural")
    starts, coefficients = list(knots[:-1]), list(spline.c[::-1].T)  # a, b, c, d per piece
    if lo > 0:
        slope = float(spline(lo, 1))
        starts.insert(0, 0.0)
        coefficients.insert(0, np.array([float(spline(lo)) - slope * lo, slope, 0.0, 0.0]))
    if hi < length:
        starts.append(hi)
        coefficients.append(np.array([float(spline(hi)), float(spline(hi, 1)), 0.0, 0.0]))
    a, b, c, d = np.array(coefficients).T
    return Elevation(np.array(starts), a, b, c, d)


# ------------------------------------------------------------------------------------ helpers


def _chain(
    x: np.ndarray, y: np.ndarray, hdg: np.ndarray, length: np.ndarray, curvature: np.ndarray
) -> ReferenceLine:
    s = np.r_[0.0, np.cumsum(length)[:-1]]
    return ReferenceLine(s=s, x=x, y=y, hdg=hdg, length=length, curvature=curvature)


def _moving(xy: np.ndarray) -> np.ndarray:
    """The points at least :data:`MIN_STEP_M` from the previous point kept, in order."""
    kept = [0] if len(xy) else []
    for i in range(1, len(xy)):
        if np.hypot(*(xy[i] - xy[kept[-1]])) >= MIN_STEP_M:
            kept.append(i)
    return xy[kept]


def _tangent(path: np.ndarray, along: np.ndarray, i: int) -> np.ndarray:
    """(2,) unit tangent of the path at point i: the derivative of a quadratic in arc length
    fitted to the points within :data:`TANGENT_WINDOW_M` (at least its neighbours)."""
    lo = min(int(np.searchsorted(along, along[i] - TANGENT_WINDOW_M)), max(i - 1, 0))
    hi = max(int(np.searchsorted(along, along[i] + TANGENT_WINDOW_M, side="right")), i + 2)
    lo, hi = max(lo, 0), min(hi, len(path))
    degree = min(2, hi - lo - 1)
    coefficients = np.polyfit(along[lo:hi] - along[i], path[lo:hi], degree)
    derivative = coefficients[-2]
    return derivative / np.linalg.norm(derivative)


def _piece(start: np.ndarray, chord: np.ndarray, tangent: np.ndarray | None = None) -> np.ndarray:
    """(5,) x, y, hdg, length, curvature of the arc from ``start`` along unit ``tangent`` to
    ``start + chord``; without a tangent, or for an arc within :data:`STRAIGHT_SAGITTA_M` of
    its chord, the line along the chord."""
    span = float(np.hypot(*chord))
    line = np.array([start[0], start[1], np.arctan2(chord[1], chord[0]), span, 0.0])
    if tangent is None:
        return line
    # The chord's angle from the tangent is half the arc's turn.
    half = np.arctan2(tangent[0] * chord[1] - tangent[1] * chord[0], tangent @ chord)
    curvature = 2 * np.sin(half) / span
    length = span / np.sinc(half / np.pi)
    if abs(curvature) * length**2 / 8 < STRAIGHT_SAGITTA_M:
        return line
    return np.array([start[0], start[1], np.arctan2(tangent[1], tangent[0]), length, curvature])


def _biarc(
    p0: np.ndarray, t0: np.ndarray, p1: np.ndarray, t1: np.ndarray
) -> list[np.ndarray] | None:
    """The records (one or two) of the biarc from ``p0`` along unit ``t0`` to ``p1`` along
    unit ``t1``, with equal tangent lengths (Ryan Juckett, *Biarc interpolation*); None where
    no such biarc turns less than a half circle per arc (the tangents disagree with the chord).
    """
    v = p1 - p0
    vv, vt = v @ v, v @ (t0 + t1)
    # d solves 2 (1 - t0.t1) d² + 2 (v.(t0 + t1)) d - v.v = 0, written without cancellation.
    root = vt + np.sqrt(vt**2 + 2 * (1 - t0 @ t1) * vv)
    if root <= 1e-12 * np.sqrt(vv):
        return None
    d = vv / root
    c0, c1 = p0 + d * t0, p1 - d * t1
    joint = (c0 + c1) / 2
    across = c1 - c0
    tangent = across / np.linalg.norm(across) if np.linalg.norm(across) > 1e-12 else t0
    pieces = []
    for start, direction, end in ((p0, t0, joint), (joint, tangent, p1)):
        chord = end - start
        if np.hypot(*chord) < 1e-9:
            continue
        if direction @ chord <= 0:  # the arc would turn half a circle or more
            return None
        pieces.append(_piece(start, chord, direction))
    return pieces


def _deviation(pieces: list[np.ndarray], points: np.ndarray) -> np.ndarray:
    """(N,) metres from each of (N, 2) points to the nearest of the records (each (5,))."""
    x0, y0, hdg, length, curvature = np.array(pieces).T
    _, _, distance = _project_local(points[:, None, :], x0, y0, hdg, curvature, 0.0, length)
    return distance.min(axis=1, initial=np.inf)


def _local_point(ds: np.ndarray, curvature: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """u (along the start heading) and v (to its left), metres, of the point ds metres along
    a record of the given curvature; exact for a line (curvature 0) and near one."""
    turn = curvature * ds
    u = ds * np.sinc(turn / np.pi)  # sin(turn) / curvature
    v = turn * ds / 2 * np.sinc(turn / (2 * np.pi)) ** 2  # (1 - cos(turn)) / curvature
    return u, v


def _project_local(
    q: np.ndarray,
    x0: np.ndarray,
    y0: np.ndarray,
    hdg: np.ndarray,
    curvature: np.ndarray,
    lo: np.ndarray | float,
    hi: np.ndarray | float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points ``q`` (..., 2) on records (broadcast arrays) that start at (x0, y0) with heading
    hdg and hold from ``lo`` to ``hi`` metres: ds along the record (clamped to that range), t
    to its left (the signed distance where clamped), and the distance, metres."""
    dx, dy = q[..., 0] - x0, q[..., 1] - y0
    cos, sin = np.cos(hdg), np.sin(hdg)
    u, v = dx * cos + dy * sin, dy * cos - dx * sin
    k = curvature
    # Around the arc's centre: the angle turned to the point and its distance, scaled by k,
    # written so that k -> 0 gives the line's u and v.
    along = np.where(k == 0, u, np.arctan2(k * u, 1 - k * v) / np.where(k == 0, 1.0, k))
    radial = np.hypot(k * u, 1 - k * v)
    t = (2 * v - k * (u**2 + v**2)) / (1 + radial)
    ds = np.clip(along, lo, hi)
    pu, pv = _local_point(ds, k)
    distance = np.hypot(u - pu, v - pv)
    clamped = ds != along
    return ds, np.where(clamped, np.copysign(distance, t), t), distance
