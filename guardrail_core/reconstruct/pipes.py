"""Skeletons and radii of the pipes of a unit shape (Matsumoto et al. 2019, §4.3).

Input: the superimposed points of many units of one run, in unit coordinates
(:mod:`guardrail_core.reconstruct.unit_frame`: x along the unit from its first pole's axis,
y above the ground line, z toward the road; metres). Output: one :class:`Pipe` per pipe of the
unit shape, its axis polyline in the same coordinates.

The steps follow §4.3:

1. points within the poles (x near 0 and ``length``) are dropped;
2. vertical pipes: a histogram of x; contiguous regions above a threshold are candidate vertical
   pipes; the diameter is the width holding a share of their points, the skeleton sits at the
   centre of that width and spans the points' height (Fig. 14, 15). Straight pipes are then
   found by a line search; short vertical pipes between two others (an arch's king post), which
   barely rise above the rails in the histogram, are found in the histogram of the points off
   the straight pipes, and kept where pipes run across both their ends;
3. their points are removed; the rest is cut into 30 mm slices along x, each slice triangulated
   (2-D Delaunay on (x, y)), edges longer than a cut length removed, and the centre of each
   connected component taken (Fig. 16 a-c; the components are those of the points closer than
   the cut length, which a k-d tree finds faster than a triangulation);
4. centres of consecutive slices are joined into polylines (Fig. 16 d), predicting along the
   current direction so that crossing pipes continue straight through the crossing; where one
   still bounced off the other (an X linked as a Λ and two halves), they are re-linked;
5. polylines are smoothed by Taubin's low-pass filter, fitted by a straight line when nearly
   straight, snapped to horizontal when nearly horizontal;
6. a chain's end that runs on along a rail past their junction is cut and given back to the
   rail (the part left shaped again, straight or curved); what still runs along a rail is its
   duplicate and goes; ends near a pole are extended to the pole axis; ends near another pipe
   are extended to their intersection;
7. the radius and the axis depth z of each pipe are measured from its points, per 0.1 m
   stretch along it (the median over the stretches: a junction sways a few of them).

Geometry of the points on a pipe (used in 2 and 7): the scanner sees the +z face. Rays sample a
pipe about uniformly in the offset across it, so the signed in-plane offsets of its points from the
axis (x for a vertical pipe, the normal offset in (x, y) for the others) are close to uniform on
[-r, r] (slightly squeezed on the far side when the scanner looks down on the pipe). The central
``radius_share`` of the offsets then spans about ``2 * radius_share * r``: the radius is that
half-width divided by the share, and the axis is the midpoint of the two quantiles (not the mean,
which the look-down angle biases toward the scanner by a few mm). A point at offset ``o`` lies
``sqrt(r**2 - o**2)`` in front of the axis, which gives the axis depth z.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from guardrail_core.errors import ReconstructionError
from guardrail_core.reconstruct.model import PIPE_KINDS, Pipe
from guardrail_core.reconstruct.smoothing import check_taubin_params, taubin_smooth

_FORBIDDEN = 1e9  # assignment cost of a centre out of a polyline's reach

__all__ = [
    "PipeHistogram",
    "PipeParams",
    "PipeReconstruction",
    "reconstruct_pipes",
    "check_unit_points",
]


@dataclass(frozen=True)
class PipeParams:
    """Thresholds of the pipe reconstruction (§4.3). Lengths in metres, angles in degrees.

    Attributes
    ----------
    pole_margin : float, m
        Points with x within ``pole_radius + pole_margin`` of a pole axis (x = 0, x = length) are
        dropped as pole points (and points beyond the poles with them).
    histogram_bin : float, m
        Bin width of the x histogram of vertical-pipe detection (Fig. 14).
    histogram_factor : float
        The histogram threshold is ``histogram_factor`` times the median bin count (the level the
        horizontal pipes give everywhere), and at least ``histogram_min_count``. An arch's 0.15 m
        king post peaks at 2.4x; 2.3 adds no other vertical pipe on the units-sweep street or
        on two random streets (2.5 missed the king post).
    histogram_min_count : float, points per bin
        Floor of the histogram threshold (sparse clouds have a median of 0 or 1).
    radius_share : float in (0, 1)
        The paper's "certain percentage": the share of a pipe's points that its diameter holds.
        The central ``radius_share`` of the signed offsets spans the diameter ``2 r``; for offsets
        uniform on [-r, r] its half-width is ``radius_share * r``, so ``r = half_width / share``.
    vertical_min_length : float, m
        A vertical pipe's points must cover at least this height without a gap.
    vertical_gap : float, m
        The largest gap in y within the points of one vertical pipe.
    vertical_sparse_gap : float, m
        The largest gap where ``vertical_gap`` finds no vertical pipe: a thin pipe gets one
        streak of points per scan line, and when every unit of a run was scanned at the same
        heights (the pole spacing a multiple of the vehicle's advance per scanner turn, 0.1 m
        at 10 m/s) the superimposition does not fill the gaps between the streaks.
    vertical_angle : float, deg
        A histogram peak whose points lean more than this from the vertical is no vertical pipe
        (the steep foot of an arch); a straight skeleton within it of the vertical is vertical.
    slice_interval : float, m
        Width of the slices along x (§4.3: 30 mm).
    max_edge : float, m
        Edges of a slice's Delaunay wireframe longer than this are cut before its connected
        components are taken.
    link_distance : float, m
        A centre joins a polyline when it lies within this distance (across the polyline's
        direction) of the position predicted along the polyline.
    link_gap : float, m
        Polylines bridge runs of empty slices up to this length in x (sparse clouds).
    link_max_slope : float, dy/dx
        Steepest direction a polyline of one centre may continue in.
    link_same_angle : float, deg
        Two polylines that want the same centre are one pipe (a duplicate) when their directions
        differ by less than this; else they cross and share it.
    direction_window : float, m
        The direction of a polyline is fitted to its centres within this x span of its end.
    taubin_lambda, taubin_mu : float
        Taubin's filter factors (lambda > 0, mu < -lambda).
    taubin_iterations : int
        Taubin's filter iterations.
    straight_tolerance : float, m
        A polyline is a straight line when ``straight_share`` of its smoothed centres lie within
        this distance of their fitted line.
    straight_share : float in (0, 1]
        See ``straight_tolerance`` (below 1: the bumps where other pipes join do not count).
    horizontal_angle : float, deg
        A straight line within this angle of the horizontal is a horizontal pipe.
    pole_extension : float, m
        Ends within this x distance of a pole axis are extended to it (a rail always; a
        diagonal or curved pipe only if it meets no other pipe on the way). An arch's foot
        takes the last ~0.4 m of its rail's points, which the rail then has to bridge.
    join_distance : float, m
        Ends within this distance of another pipe (or of its extension) are extended or trimmed
        to the intersection.
    merge_gap : float, m
        Largest gap (in x, and end to start) between two pieces of one pipe that are joined.
    merge_angle : float, deg
        Largest turn between a piece's end direction, the step across a gap and the next piece's
        start direction for the two to be joined.
    min_points : int
        Fewest points a pipe must hold.
    min_length : float, m
        Shortest skeleton (before extension) kept as a pipe.
    assign_margin : float, m
        Points within ``r + assign_margin`` of an axis (in x, y) belong to the pipe.
    measure_step : float, m
        Spacing of the skeleton samples that point offsets are measured against.
    measure_stretch : float, m
        A pipe's radius and axis are measured per stretch of this length along it, and the
        median over the stretches taken, so that the points of a pipe joining it, which crowd
        one side near the junction, sway a few stretches and not the measure.
    measure_stretch_points : int
        Fewest points for a stretch to be measured; with fewer than three such stretches the
        pipe is measured on all its points at once.
    short_window : float, m
        Short vertical pipes (an arch's king post, see ``_short_verticals``): the width their
        histogram is summed over, the least half-width of their window, and the gap beyond
        their radius where the pipes crossing their ends are looked for.
    short_drift : float, m
        The most a short vertical pipe's points may drift in x over its height (a linear fit;
        units registered to a few mm leave ~1 cm on a 0.15 m pipe, a fixed angle would not do).
    line_band : float, m
        Straight pipes (``_straight_pipes``): half-width of a line hypothesis's band of points.
    line_min_length : float, m
        Shortest gap-free run of a straight pipe.
    line_chunk : float, m
        Length of the pieces a run is cut into to check it is populated and straight.
    line_straightness : float, m
        A piece's median offset may differ from the run's by this much, or by three standard
        errors of that median where more (a sparse pipe's few points scatter); on more than a
        fifth of the pieces it does not, and the run is curved. A rail superimposed from 8-12
        units bows by up to 6 mm (3 mm either side of its median); an arch's crown deviates by
        1-3 cm, the stretch of a wave (amplitude 0.15 m) between its crests by 4-8 mm.
    line_occupancy : float in (0, 1]
        Share of pieces holding two points or more.
    line_hypotheses : int
        Line hypotheses (pairs of points) drawn per search.
    """

    pole_margin: float = 0.015
    histogram_bin: float = 0.005
    histogram_factor: float = 2.3
    histogram_min_count: float = 4.0
    radius_share: float = 0.94
    vertical_min_length: float = 0.1
    vertical_gap: float = 0.06
    vertical_sparse_gap: float = 0.12
    vertical_angle: float = 4.0
    slice_interval: float = 0.03
    max_edge: float = 0.03
    link_distance: float = 0.04
    link_gap: float = 0.15
    link_max_slope: float = 3.0
    link_same_angle: float = 10.0
    direction_window: float = 0.15
    taubin_lambda: float = 0.5
    taubin_mu: float = -0.53
    taubin_iterations: int = 10
    straight_tolerance: float = 0.01
    straight_share: float = 0.75
    horizontal_angle: float = 3.0
    pole_extension: float = 0.45
    join_distance: float = 0.25
    merge_gap: float = 0.3
    merge_angle: float = 50.0
    min_points: int = 15
    min_length: float = 0.1
    assign_margin: float = 0.01
    measure_step: float = 0.005
    measure_stretch: float = 0.1
    measure_stretch_points: int = 20
    short_window: float = 0.015
    short_drift: float = 0.015
    line_band: float = 0.03
    line_min_length: float = 0.3
    line_chunk: float = 0.1
    line_straightness: float = 0.005
    line_occupancy: float = 0.7
    line_hypotheses: int = 300

    def __post_init__(self) -> None:
        positive = (
            "histogram_bin",
            "histogram_factor",
            "vertical_min_length",
            "vertical_gap",
            "vertical_sparse_gap",
            "slice_interval",
            "max_edge",
            "link_distance",
            "link_gap",
            "link_max_slope",
            "direction_window",
            "straight_tolerance",
            "min_length",
            "short_window",
            "short_drift",
            "merge_gap",
            "measure_step",
        )
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ReconstructionError(f"PipeParams.{name} must be > 0, got {value}")
        non_negative = (
            "pole_margin",
            "histogram_min_count",
            "pole_extension",
            "join_distance",
            "assign_margin",
        )
        for name in non_negative:
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ReconstructionError(f"PipeParams.{name} must be >= 0, got {value}")
        if not 0.0 < self.straight_share <= 1.0:
            raise ReconstructionError(
                f"PipeParams.straight_share must be in (0, 1], got {self.straight_share}"
            )
        if not 0.0 < self.radius_share < 1.0:
            raise ReconstructionError(
                f"PipeParams.radius_share must be in (0, 1), got {self.radius_share}"
            )
        for name in ("vertical_angle", "horizontal_angle", "link_same_angle", "merge_angle"):
            value = getattr(self, name)
            if not 0.0 <= value < 90.0:
                raise ReconstructionError(
                    f"PipeParams.{name} must be in [0, 90) degrees, got {value}"
                )
        check_taubin_params(
            "PipeParams", self.taubin_lambda, self.taubin_mu, self.taubin_iterations
        )
        if self.min_points < 1:
            raise ReconstructionError(f"PipeParams.min_points must be >= 1, got {self.min_points}")


@dataclass(frozen=True)
class PipeHistogram:
    """The x histogram of vertical-pipe detection (§4.3, Fig. 14).

    Attributes
    ----------
    edges : (B + 1,) float64, metres, unit x
    counts : (B,) int64, points per bin (pole points excluded)
    threshold : float, points per bin: regions above it are vertical-pipe candidates
    """

    edges: np.ndarray
    counts: np.ndarray
    threshold: float


@dataclass(frozen=True)
class PipeReconstruction:
    """What :func:`reconstruct_pipes` returns.

    Attributes
    ----------
    pipes : the reconstructed pipes, axes in unit coordinates
    histogram : the x histogram and its threshold
    notes : what could not be reconstructed, in words
    """

    pipes: tuple[Pipe, ...]
    histogram: PipeHistogram
    notes: tuple[str, ...] = ()


@dataclass
class _Skel:
    """A pipe under construction: a 2-D skeleton in (x, y) and its points."""

    xy: np.ndarray  # (K, 2)
    kind: str
    idx: np.ndarray  # indices into the non-pole points
    radius: float = 0.0
    z: float = 0.0
    n_points: int = 0
    extras: dict = field(default_factory=dict)


def check_unit_points(points: np.ndarray, name: str = "points") -> np.ndarray:
    """Validate an (N, 3) array of finite unit coordinates; return it as float64."""
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ReconstructionError(f"{name} must be an (N, 3) array of numbers: {exc}") from exc
    if p.ndim != 2 or p.shape[1] != 3:
        raise ReconstructionError(f"{name} must have shape (N, 3) (unit x, y, z), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ReconstructionError(f"{name} holds NaN or infinite coordinates")
    return p


def _check_scalar(value: float, name: str, *, positive: bool) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise ReconstructionError(f"{name} must be a number, got {value!r}") from exc
    if not math.isfinite(v) or (v <= 0 if positive else v < 0):
        raise ReconstructionError(f"{name} must be {'> 0' if positive else '>= 0'}, got {value!r}")
    return v


def reconstruct_pipes(
    points: np.ndarray,
    length: float,
    pole_radius: float,
    params: PipeParams = PipeParams(),
) -> PipeReconstruction:
    """Reconstruct the pipes of a unit shape from superimposed unit points.

    Parameters
    ----------
    points : (N, 3) float64, unit coordinates, metres
        Superimposed points of many units of one run; pole points may be included (they are
        dropped by x).
    length : float, metres
        Unit length (the second pole's axis is at x = length).
    pole_radius : float, metres
        Radius of the poles.
    params : PipeParams
        Thresholds.

    Returns
    -------
    PipeReconstruction
        ``pipes`` with axis polylines (K, 3) in unit coordinates (z: the axis depth), radii,
        kinds (:data:`PIPE_KINDS`) and point counts; the x ``histogram``; ``notes``.

    Raises
    ------
    ReconstructionError
        If points are not (N, 3) finite, or length / pole_radius are out of range.

    References
    ----------
    Matsumoto, Mori, Masuda (2019). Extraction and shape reconstruction of guardrails using
    mobile mapping data. ISPRS Archives XLII-2/W13, §4.3, Fig. 14-16.
    Taubin, G. (1995). A signal processing approach to fair surface design. SIGGRAPH '95.
    """
    pts = check_unit_points(points)
    length = _check_scalar(length, "length", positive=True)
    pole_radius = _check_scalar(pole_radius, "pole_radius", positive=False)
    p = params
    notes: list[str] = []

    # §4.3: points within the poles are eliminated.
    x0 = pole_radius + p.pole_margin
    x1 = length - x0
    if x1 <= x0:
        raise ReconstructionError(
            f"the unit (length {length} m) is shorter than its two poles and margins ({2 * x0} m)"
        )
    pts = pts[(pts[:, 0] > x0) & (pts[:, 0] < x1)]

    # §4.3, Fig. 14: histogram of points along x.
    n_bins = max(1, int(math.ceil((x1 - x0) / p.histogram_bin)))
    edges = x0 + p.histogram_bin * np.arange(n_bins + 1)
    counts = np.bincount(
        np.minimum(((pts[:, 0] - x0) / p.histogram_bin).astype(np.int64), n_bins - 1),
        minlength=n_bins,
    ).astype(np.int64)
    threshold = max(p.histogram_factor * float(np.median(counts)), p.histogram_min_count)
    histogram = PipeHistogram(edges, counts, float(threshold))
    if len(pts) == 0:
        notes.append("no points between the poles: no pipe reconstructed")
        return PipeReconstruction((), histogram, tuple(notes))

    # §4.3, Fig. 15: vertical pipes at the histogram peaks.
    verticals, vertical_mask = _vertical_pipes(pts, edges, counts, threshold, p)

    # §4.3, Fig. 16(a): the points of the vertical pipes are removed.
    rest_idx = np.flatnonzero(~vertical_mask)
    lines, line_mask = _straight_pipes(pts, rest_idx, p)
    rest_idx = rest_idx[~line_mask]
    # Short vertical pipes between two others (an arch's king post) stand out only once the
    # rails' points are out of the histogram.
    short, short_mask = _short_verticals(pts, rest_idx, lines, edges, p)
    verticals += short
    rest_idx = rest_idx[~short_mask]
    others = _non_vertical_pipes(pts, rest_idx, x0, p, notes)

    rails = lines + [s for s in others if s.kind == "horizontal" and not _runs_along(s, lines, p)]
    others = [s for s in others if s.kind != "horizontal"]
    for s in others:
        if _trim_along(s, rails, length, p) and s.kind == "curved":
            _reshape_cut(s, pts, p)
    # A chain is a rail's duplicate when it still runs along one once its ends along rails are
    # cut: a diagonal that took over a rail's points past its junction is not.
    others = [s for s in others if not _runs_along(s, lines, p)]
    skels = verticals + rails + others
    # §4.3: ends extended to the poles, and to the intersection of close ends.
    _extend_and_join(skels, length, p)
    # Radius and depth of each pipe from its points.
    pipes = []
    _measure_all(pts, skels, p)
    for s in skels:
        if s.n_points < p.min_points:
            notes.append(
                f"a {s.kind} pipe near x={s.xy[:, 0].mean():.2f} m, y={s.xy[:, 1].mean():.2f} m "
                f"kept only {s.n_points} points: dropped"
            )
            continue
        axis = np.column_stack([s.xy, np.full(len(s.xy), s.z)])
        kind = s.kind if s.kind in PIPE_KINDS else "curved"
        pipes.append(Pipe(axis=axis, radius=float(s.radius), kind=kind, n_points=int(s.n_points)))
    if not pipes:
        notes.append(f"no pipe found among {len(pts)} points between the poles")
    pipes.sort(
        key=lambda q: (PIPE_KINDS.index(q.kind), -float(q.axis[:, 1].mean()), float(q.axis[0, 0]))
    )
    return PipeReconstruction(tuple(pipes), histogram, tuple(notes))


# ----------------------------------------------------------------------------------------------
# Vertical pipes
# ----------------------------------------------------------------------------------------------


def _central_quantiles(values: np.ndarray, share: float) -> tuple[float, float]:
    lo, hi = np.quantile(values, [(1.0 - share) / 2.0, (1.0 + share) / 2.0])
    return float(lo), float(hi)


def _longest_chain(y: np.ndarray, gap: float) -> tuple[float, float]:
    """The y extent of the longest run of sorted ``y`` without a gap above ``gap``."""
    ys = np.sort(y)
    breaks = np.flatnonzero(np.diff(ys) > gap)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [len(ys) - 1]])
    k = int(np.argmax(ys[ends] - ys[starts]))
    return float(ys[starts[k]]), float(ys[ends[k]])


def _regions_above(counts: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """First bins (starts) and bins one past the last (stops) of the runs above ``threshold``."""
    above = np.concatenate([[False], counts > threshold, [False]])
    return np.flatnonzero(~above[:-1] & above[1:]), np.flatnonzero(above[:-1] & ~above[1:])


def _vertical_pipes(
    pts: np.ndarray, edges: np.ndarray, counts: np.ndarray, threshold: float, p: PipeParams
) -> tuple[list[_Skel], np.ndarray]:
    """Vertical pipes from the contiguous regions of the x histogram above ``threshold``."""
    starts, stops = _regions_above(counts, threshold)
    removed = np.zeros(len(pts), dtype=bool)
    skels: list[_Skel] = []
    tan_tol = math.tan(math.radians(p.vertical_angle))
    x, y = pts[:, 0], pts[:, 1]
    for a, b in zip(starts, stops, strict=True):
        lo, hi = edges[a], edges[b]
        found = None
        # A thin pipe is hit once per scan line: where every unit of a run was scanned at the
        # same heights its points stand in streaks vertical_sparse_gap apart. That wider gap is
        # tried only where the usual one finds nothing (its inner points, a gap in from either
        # end, leave none on a 0.15 m king post); a found pipe's extent is taken with it.
        for gap in (p.vertical_gap, p.vertical_sparse_gap):
            centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo) + p.histogram_bin
            for _ in range(2):  # the window follows the estimated pipe width
                found = None
                sel = (np.abs(x - centre) <= half) & ~removed  # a pipe split in two regions
                if sel.sum() < p.min_points:
                    break
                y0, y1 = _longest_chain(y[sel], gap)
                if y1 - y0 < p.vertical_min_length:
                    break
                inner = sel & (y > y0 + gap) & (y < y1 - gap)
                inner &= ~_horizontal_bands(y, inner, p)
                if inner.sum() < p.min_points:
                    break
                # A vertical pipe stands straight: x does not drift with y.
                slope = np.polyfit(y[inner], x[inner], 1)[0]
                if abs(slope) > tan_tol:
                    break
                qlo, qhi = _central_quantiles(x[inner], p.radius_share)
                centre = 0.5 * (qlo + qhi)
                radius = 0.5 * (qhi - qlo) / p.radius_share
                half = radius + p.assign_margin
                found = (sel, centre, radius)
            if found is not None:
                break
        if found is None:
            continue
        sel, centre, radius = found
        y0, y1 = _longest_chain(y[sel], p.vertical_sparse_gap)
        # A short one ends on pipes running across; the steep foot of an arch goes on aside.
        if y1 - y0 < 2 * p.vertical_min_length and not all(
            _crossed(pts, centre, end, radius, p) for end in (y0, y1)
        ):
            continue
        band = sel & (y >= y0) & (y <= y1)
        removed |= band
        xy = np.array([[centre, y0], [centre, y1]])
        skels.append(_Skel(xy=xy, kind="vertical", idx=np.flatnonzero(band)))
    return skels, removed


def _short_verticals(
    pts: np.ndarray, rest_idx: np.ndarray, lines: list[_Skel], edges: np.ndarray, p: PipeParams
) -> tuple[list[_Skel], np.ndarray]:
    """Short vertical pipes between two pipes that run across them (an arch's king post).

    In the x histogram of all points a 0.15 m vertical barely rises above the rails; here the
    histogram holds only the points off the straight pipes, summed over ``short_window`` (the
    points are few), with the threshold ``histogram_factor`` times its median over the filled
    bins (the level of the curved pipes). A peak is a short vertical when its points stand
    within ``short_drift`` of one x over at least ``vertical_min_length`` and both its ends meet
    points on both sides (a pipe running across). The foot of an arch, as steep, fails that:
    at its top the arch goes on to one side only.

    Returns the vertical skeletons and a mask over ``rest_idx`` of their points.
    """
    mask = np.zeros(len(rest_idx), dtype=bool)
    on_line = np.zeros(len(pts), dtype=bool)
    for line in lines:
        on_line[line.idx] = True
    keep = ~on_line[rest_idx]
    off = rest_idx[keep]
    if len(off) < p.min_points:
        return [], mask
    n_bins = len(edges) - 1
    b = np.minimum(((pts[off, 0] - edges[0]) / p.histogram_bin).astype(np.int64), n_bins - 1)
    width = max(1, int(round(p.short_window / p.histogram_bin)))
    counts = np.convolve(np.bincount(b, minlength=n_bins), np.ones(width), mode="same")
    threshold = max(
        p.histogram_factor * float(np.median(counts[counts > 0])), p.histogram_min_count
    )
    starts, stops = _regions_above(counts, threshold)
    x, y = pts[off, 0], pts[off, 1]
    skels: list[_Skel] = []
    taken = np.zeros(len(off), dtype=bool)
    for a, b_ in zip(starts, stops, strict=True):
        centre = 0.5 * (edges[a] + edges[b_])
        half = max(0.5 * (edges[b_] - edges[a]), p.short_window)
        found = None
        for _ in range(2):  # the window follows the estimated pipe width
            sel = (np.abs(x - centre) <= half) & ~taken
            if sel.sum() < p.min_points:
                break
            y0, y1 = _longest_chain(y[sel], p.vertical_gap)
            inner = sel & (y > y0 + p.slice_interval) & (y < y1 - p.slice_interval)
            if y1 - y0 < p.vertical_min_length or inner.sum() < p.min_points:
                break
            slope = np.polyfit(y[inner], x[inner], 1)[0]
            qlo, qhi = _central_quantiles(x[inner], p.radius_share)
            centre, radius = 0.5 * (qlo + qhi), 0.5 * (qhi - qlo) / p.radius_share
            half = radius + p.assign_margin
            found = (y0, y1, radius, abs(slope) * (y1 - y0))
        if found is None:
            continue
        y0, y1, radius, drift = found
        if drift > p.short_drift or not all(
            _crossed(pts, centre, end, radius, p) for end in (y0, y1)
        ):
            continue
        band = (np.abs(x - centre) <= half) & (y >= y0) & (y <= y1) & ~taken
        taken |= band
        xy = np.array([[centre, y0], [centre, y1]])
        skels.append(_Skel(xy=xy, kind="vertical", idx=off[band]))
    mask[np.flatnonzero(keep)[taken]] = True
    return skels, mask


def _crossed(pts: np.ndarray, x: float, y: float, radius: float, p: PipeParams) -> bool:
    """Whether points lie on both sides of (x, y) just beyond a vertical pipe of ``radius``
    (within ``slice_interval`` in y, ``short_window`` to ``3 short_window`` out in x): a pipe
    runs across the vertical's end there."""
    near = np.abs(pts[:, 1] - y) <= p.slice_interval
    dx = pts[near, 0] - x
    lo, hi = radius + p.short_window, radius + 3 * p.short_window
    left = int(((dx <= -lo) & (dx >= -hi)).sum())
    right = int(((dx >= lo) & (dx <= hi)).sum())
    return min(left, right) >= 3


def _horizontal_bands(y: np.ndarray, sel: np.ndarray, p: PipeParams) -> np.ndarray:
    """Points of ``sel`` in y bands much denser than the median (horizontal pipes crossing)."""
    ys = y[sel]
    out = np.zeros(len(y), dtype=bool)
    if len(ys) == 0:
        return out
    b = np.floor((y - ys.min()) / p.slice_interval).astype(np.int64)
    cnt = np.bincount(b[sel])
    dense = cnt > p.histogram_factor * max(np.median(cnt[cnt > 0]), 1.0)
    out[sel] = dense[b[sel]]
    return out


# ----------------------------------------------------------------------------------------------
# Straight pipes: sequential line search
# ----------------------------------------------------------------------------------------------


def _line_run(
    t: np.ndarray, off: np.ndarray, p: PipeParams, *, straight: bool = True
) -> tuple[float, float, np.ndarray] | None:
    """The longest gap-free run of projections ``t`` (N,) and whether it is a straight pipe
    (with ``straight``: its pieces' offsets ``off`` (N,) agree; else only its length and
    occupancy are checked)."""
    if len(t) < p.min_points:
        return None
    order = np.argsort(t)
    ts = t[order]
    breaks = np.flatnonzero(np.diff(ts) > p.link_gap)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [len(ts) - 1]])
    k = int(np.argmax(ends - starts))
    t0, t1 = float(ts[starts[k]]), float(ts[ends[k]])
    if t1 - t0 < p.line_min_length or ends[k] - starts[k] + 1 < p.min_points:
        return None
    sel = (t >= t0) & (t <= t1)
    n_chunks = max(2, int(round((t1 - t0) / p.line_chunk)))
    chunk = np.minimum(((t[sel] - t0) / (t1 - t0) * n_chunks).astype(np.int64), n_chunks - 1)
    cnt = np.bincount(chunk, minlength=n_chunks)
    if np.mean(cnt >= 2) < p.line_occupancy:
        return None
    if not straight:
        return t0, t1, sel
    o = off[sel]
    med = float(np.median(o))
    full = cnt >= 4
    # A piece's median is off when it is off by more than line_straightness and by more than
    # three of its standard errors (1.25 sd / sqrt n): a sparse rail's few points scatter.
    by_piece = np.lexsort((o, chunk))
    first = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    sorted_o = o[by_piece]
    last = len(o) - 1  # empty pieces index anywhere; only full pieces are read
    lower = np.clip(first + (cnt - 1) // 2, 0, last)
    upper = np.clip(first + cnt // 2, 0, last)
    piece_median = 0.5 * (sorted_o[lower] + sorted_o[upper])
    mean = np.bincount(chunk, o, n_chunks) / np.maximum(cnt, 1)
    var = np.bincount(chunk, o * o, n_chunks) / np.maximum(cnt, 1) - mean**2
    se = 1.25 * np.sqrt(np.maximum(var, 0.0) / np.maximum(cnt, 1))
    off_line = np.abs(piece_median - med) > np.maximum(p.line_straightness, 3.0 * se)
    if (off_line & full).sum() > 0.2 * full.sum():
        return None
    return t0, t1, sel


def _straight_pipes(
    pts: np.ndarray, rest_idx: np.ndarray, p: PipeParams
) -> tuple[list[_Skel], np.ndarray]:
    """Straight non-vertical pipes found one after another (most points first).

    Line hypotheses through pairs of points are scored by the points within ``line_band``; the
    best is refitted, cut to its longest gap-free run and kept when that run is at least
    ``line_min_length`` long, populated along ``line_occupancy`` of its length and straight
    (the median offset of every ``line_chunk`` piece within ``line_straightness`` of the
    whole's, see :func:`_line_run`: a curved pipe fails this). The kept line's points are
    removed from the search.
    """
    removed = np.zeros(len(rest_idx), dtype=bool)
    hidden = np.zeros(len(rest_idx), dtype=bool)
    skels: list[_Skel] = []
    if len(rest_idx) < p.min_points:
        return skels, hidden
    xy = pts[rest_idx, :2]
    rng = np.random.default_rng(0)
    failed: list[tuple[np.ndarray, np.ndarray]] = []
    for _ in range(16):
        live = np.flatnonzero(~removed)
        if len(live) < p.min_points:
            break
        sub = live if len(live) <= 3000 else rng.choice(live, 3000, replace=False)
        a = xy[rng.choice(sub, p.line_hypotheses)]
        b = xy[rng.choice(sub, p.line_hypotheses)]
        d = b - a
        n = np.linalg.norm(d, axis=1)
        ok = (n >= p.line_chunk) & (np.abs(d[:, 0]) > 1e-6)
        if not ok.any():
            break
        a, d = a[ok], d[ok] / n[ok, None]
        normal = np.column_stack([-d[:, 1], d[:, 0]])
        off = np.abs(
            (xy[sub, 0][None, :] - a[:, :1]) * normal[:, :1]
            + (xy[sub, 1][None, :] - a[:, 1:]) * normal[:, 1:]
        )
        score = (off <= p.line_band).sum(axis=1)
        accepted = False
        for h in np.argsort(-score)[:8]:
            if score[h] < p.min_points:
                break
            c, u = a[h], d[h]
            if any(
                abs(u[0] * fu[1] - u[1] * fu[0]) < 0.05
                and abs((c - fc) @ [-fu[1], fu[0]]) < p.line_band
                for fc, fu in failed
            ):
                continue
            res = _refine_line(xy, live, c, u, p)
            if res is None:
                failed.append((c, u))
                continue
            c, u, t0, t1, half = res
            nrm = np.array([-u[1], u[0]])
            rel = xy - c
            t_all, o_all = rel @ u, rel @ nrm
            angle = math.degrees(math.atan2(abs(u[1]), abs(u[0])))
            kind = "horizontal" if angle <= p.horizontal_angle else "diagonal"
            band = (np.abs(o_all) <= half) & (t_all >= t0 - half) & (t_all <= t1 + half)
            idx = rest_idx[band & ~removed]
            removed |= band
            # The core of a horizontal rail stays for the chains that touch it tangentially.
            hidden |= band if kind == "diagonal" else band & (np.abs(o_all) > 0.6 * half)
            end = c + np.outer([t0, t1], u)
            if end[0, 0] > end[1, 0]:
                end = end[::-1]
            if kind == "horizontal":
                end[:, 1] = end[:, 1].mean()
            extras = {"centres": end.copy(), "shared": np.zeros(2, bool), "own": idx}
            skels.append(_Skel(xy=end, kind=kind, idx=idx, extras=extras))
            accepted = True
            break
        if not accepted:
            break
    return skels, hidden


def _runs_along(s: _Skel, lines: list[_Skel], p: PipeParams) -> bool:
    """Whether a chained skeleton mostly follows one of the straight pipes (a duplicate)."""
    probe = _resample(s.xy, p.slice_interval)
    for line in lines:
        dist, _ = _distance_to_polyline(probe, line.xy)
        if np.mean(dist <= p.link_distance) >= 0.5:
            return True
    return False


def _trim_along(s: _Skel, lines: list[_Skel], length: float, p: PipeParams) -> bool:
    """Cut the ends of a chained skeleton that run along a rail (a straight pipe, taken from
    pole to pole), within ``line_band`` of it for ``join_distance / 5`` or more: past a junction
    the chain took over the rail's points (an arch's foot running on along its rail). The rail
    runs on through them: its end is moved out to the last of them. The cut end is joined to the
    rail again by :func:`_extend_and_join`. Returns whether it was cut."""
    if not lines or len(s.xy) < 3:
        return False
    near = np.full(len(s.xy), -1)
    best = np.full(len(s.xy), np.inf)
    for j, line in enumerate(lines):
        a, b = line.xy[0], line.xy[-1]
        u = (b - a) / max(float(np.linalg.norm(b - a)), 1e-12)
        if abs(u[0]) < 0.1:
            continue
        reach = np.vstack([a + (0.0 - a[0]) / u[0] * u, a + (length - a[0]) / u[0] * u])
        dist = _distance_to_polyline(s.xy, reach)[0]
        closer = (dist <= p.line_band) & (dist < best)
        near[closer], best[closer] = j, dist[closer]
    along = near >= 0
    if along.all() or not along.any():
        return False
    step = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(s.xy, axis=0), axis=1))])
    first, last = int(np.argmin(along)), len(along) - 1 - int(np.argmin(along[::-1]))
    cut_head = step[first] >= p.join_distance / 5
    cut_tail = step[-1] - step[last] >= p.join_distance / 5
    if (cut_head or cut_tail) and (last if cut_tail else len(along) - 1) > (
        first if cut_head else 0
    ):
        for tip, cut in ((0, cut_head), (-1, cut_tail)):
            if cut:
                _run_on(lines[int(near[tip])], s.xy[tip])
        s.xy = s.xy[(first if cut_head else 0) : (last + 1 if cut_tail else len(along))]
        return True
    return False


def _reshape_cut(s: _Skel, pts: np.ndarray, p: PipeParams) -> None:
    """A curved chain cut down to its own part is shaped again from that part and its points
    near it: a diagonal that ran on along a rail is straight once the rail's part is cut."""
    own = s.idx[_distance_to_polyline(pts[s.idx, :2], s.xy)[0] <= p.link_distance]
    if len(own) >= 2:
        s.xy, s.kind = _straight_or_curved(s.xy, np.zeros(len(s.xy), bool), own, s.idx, pts, p)


def _run_on(line: _Skel, point: np.ndarray) -> None:
    """Move the nearer end of a straight skeleton out to ``point`` projected on it, if beyond."""
    a, b = line.xy[0], line.xy[-1]
    u = (b - a) / max(float(np.linalg.norm(b - a)), 1e-12)
    t = float((point - a) @ u)
    if t > float((b - a) @ u):
        line.xy = np.vstack([line.xy[:-1], a + t * u])
    elif t < 0:
        line.xy = np.vstack([a + t * u, line.xy[1:]])


def _refine_line(
    xy: np.ndarray, live: np.ndarray, c: np.ndarray, u: np.ndarray, p: PipeParams
) -> tuple[np.ndarray, np.ndarray, float, float, float] | None:
    """Refit a line hypothesis to its band's points; its run, or None when no straight pipe.

    Straightness is judged on the refitted line only: a hypothesis through two points a few
    centimetres apart leans by several degrees, and its band's offsets drift along it."""
    for _ in range(3):
        nrm = np.array([-u[1], u[0]])
        rel = xy[live] - c
        o = rel @ nrm
        inb = np.abs(o) <= p.line_band
        if inb.sum() < p.min_points:
            return None
        run = _line_run(rel[inb] @ u, o[inb], p, straight=False)
        if run is None:
            return None
        q = xy[live][inb][run[2]]
        c, u = _fit_line(q)
    nrm = np.array([-u[1], u[0]])
    rel = xy[live] - c
    o = rel @ nrm
    inb = np.abs(o) <= p.line_band
    run = _line_run(rel[inb] @ u, o[inb], p)
    if run is None:
        return None
    t0, t1, sel = run
    oo = o[inb][sel]
    lo, hi = _central_quantiles(oo, p.radius_share)
    half = min(max(0.5 * (hi - lo) / p.radius_share, 0.005) + p.assign_margin, 2 * p.line_band)
    c = c + 0.5 * (lo + hi) * nrm
    return c, u, t0, t1, half


# ----------------------------------------------------------------------------------------------
# Non-vertical pipes: slices, components, centres, polylines
# ----------------------------------------------------------------------------------------------


def _slice_components(xy: np.ndarray, x0: float, p: PipeParams) -> tuple[np.ndarray, np.ndarray]:
    """Connected components of each slice's Delaunay wireframe (§4.3, Fig. 16 b, c).

    Returns the slice index (N,) of each point and its component label (N,). The components of
    a Delaunay wireframe cut at ``max_edge`` are the single-linkage clusters at ``max_edge`` (the
    Delaunay graph holds the minimum spanning tree), so they are taken from the pairs of points
    closer than ``max_edge`` (a k-d tree), with the slices pulled apart along x by more than
    ``max_edge`` so that no pair crosses a slice boundary. The same components, 2-5x faster
    than triangulating: the superimposed rails are dense.
    """
    n = len(xy)
    s = np.floor((xy[:, 0] - x0) / p.slice_interval).astype(np.int64)
    spread = xy.copy()
    spread[:, 0] += s * (p.slice_interval + 4.0 * p.max_edge)
    pairs = cKDTree(spread).query_pairs(p.max_edge, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    return s, labels


class _Track:
    """A polyline being linked across slices: one centre per slice it has data in."""

    def __init__(self, slice_index: int, x: float, y: float, comp: int, w: float) -> None:
        self.s = [slice_index]
        self.x = [x]
        self.y = [y]
        self.w = [w]
        self.comps = [[comp]]
        self.shared = [False]
        self.last_own_x = x  # x of the last centre not shared with another polyline

    def predict(self, x: float, p: PipeParams) -> tuple[float, float, float]:
        """Predicted y at ``x``, the allowed |dy| and the slope (nan while unknown).

        The direction is a weighted least-squares fit to the polyline's own centres (not shared
        at a crossing) within ``direction_window`` of its last own centre; it is trusted once they
        span half the window, before that the polyline may turn up to ``link_max_slope``.
        """
        own = self._steering(p)
        if own is not None:
            xs = np.array([self.x[k] for k in own])
            ys = np.array([self.y[k] for k in own])
            ws = np.array([self.w[k] for k in own])
            mx, my = np.average(xs, weights=ws), np.average(ys, weights=ws)
            sxx = float(np.sum(ws * (xs - mx) ** 2))
            slope = float(np.sum(ws * (xs - mx) * (ys - my))) / sxx if sxx > 0 else 0.0
            slope = min(max(slope, -p.link_max_slope), p.link_max_slope)
            return my + slope * (x - mx), p.link_distance * math.sqrt(1.0 + slope * slope), slope
        return self.y[-1], p.link_distance + p.link_max_slope * abs(x - self.x[-1]), math.nan

    def _steering(self, p: PipeParams) -> list[int] | None:
        """Indices of the own centres within ``direction_window`` of the last one when they
        span half the window (the direction is known), else None."""
        start = self.last_own_x - p.direction_window
        own = [k for k in range(len(self.x)) if not self.shared[k] and self.x[k] >= start]
        if len(own) >= 2 and self.x[own[-1]] - self.x[own[0]] >= 0.5 * p.direction_window:
            return own
        return None

    def steered(self, p: PipeParams) -> bool:
        """Whether the polyline's direction is known (see predict): only then may it bridge
        empty slices."""
        return self._steering(p) is not None

    def add(self, slice_index: int, x: float, y: float, comp: int, w: float, shared: bool) -> None:
        self.s.append(slice_index)
        self.x.append(x)
        self.y.append(y)
        self.w.append(w)
        self.comps.append([comp])
        self.shared.append(shared)
        if not shared:
            self.last_own_x = x


def _link_centres(
    cs: np.ndarray, cx: np.ndarray, cy: np.ndarray, cw: np.ndarray, p: PipeParams
) -> list[_Track]:
    """Join component centres of consecutive slices into polylines (§4.3, Fig. 16 d).

    Slice by slice, every active polyline takes the centre nearest to its prediction within its
    tolerance; a centre taken by two polylines (a crossing, or a pipe meeting another) is shared
    and does not steer them. A polyline stops after ``link_gap`` without an own centre (so one
    that runs into another pipe does not ride along it); centres nobody took start polylines.
    """
    tracks: list[_Track] = []
    order = np.lexsort((cy, cs))
    bounds = np.flatnonzero(np.diff(cs[order])) + 1
    reach = p.link_gap + p.slice_interval
    step = 1.5 * p.slice_interval  # the next slice
    same_direction = math.tan(math.radians(p.link_same_angle))
    for group in np.split(order, bounds):
        if len(group) == 0:
            continue
        si = int(cs[group[0]])
        xc = float(cx[group].mean())
        gy = cy[group]
        active = [
            t
            for t in tracks
            if xc - t.last_own_x <= reach and xc - t.x[-1] <= (reach if t.steered(p) else step)
        ]
        taken: dict[int, list[tuple[_Track, float]]] = {}
        if active:
            preds = np.array([t.predict(xc, p) for t in active])
            cost = np.abs(gy[None, :] - preds[:, :1]) / preds[:, 1:2]
            rows, cols = linear_sum_assignment(np.where(cost <= 1.0, cost, _FORBIDDEN))
            assigned = np.zeros(len(active), dtype=bool)
            for r, c in zip(rows, cols, strict=True):
                if cost[r, c] <= 1.0:
                    taken.setdefault(int(c), []).append((active[r], preds[r, 2]))
                    assigned[r] = True
            # A polyline left without a centre shares its nearest one: two pipes crossing or
            # meeting fall into one component there. With the same direction it is a duplicate.
            for r in np.flatnonzero(~assigned):
                c = int(np.argmin(cost[r]))
                if cost[r, c] > 1.0:
                    continue
                owner = taken.get(c)
                if owner and math.isfinite(preds[r, 2]) and math.isfinite(owner[0][1]):
                    if abs(preds[r, 2] - owner[0][1]) <= same_direction:
                        continue
                elif owner and len(active[r].x) < len(owner[0][0].x):
                    continue
                taken.setdefault(c, []).append((active[r], preds[r, 2]))
        for j, g in enumerate(group):
            claim = taken.get(j)
            if claim:
                for t, _ in claim:
                    t.add(si, float(cx[g]), float(cy[g]), int(g), float(cw[g]), len(claim) > 1)
            else:
                tracks.append(_Track(si, float(cx[g]), float(cy[g]), int(g), float(cw[g])))
    for t in tracks:  # trailing centres shared with another polyline are that one's
        while len(t.x) > 1 and t.shared[-1]:
            for lst in (t.s, t.x, t.y, t.w, t.comps, t.shared):
                lst.pop()
    return tracks


def _polyline_length(xy: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()) if len(xy) > 1 else 0.0


def _fit_line(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total least squares line: (centroid (2,), unit direction (2,) with x >= 0)."""
    c = xy.mean(axis=0)
    _, _, vt = np.linalg.svd(xy - c, full_matrices=False)
    d = vt[0]
    if d[0] < 0 or (d[0] == 0 and d[1] < 0):
        d = -d
    return c, d


def _non_vertical_pipes(
    pts: np.ndarray, rest_idx: np.ndarray, x0: float, p: PipeParams, notes: list[str]
) -> list[_Skel]:
    if len(rest_idx) == 0:
        return []
    xy = pts[rest_idx, :2]
    # §4.3, Fig. 16(b, c): 30 mm slices along x, Delaunay wireframes, connected components.
    s, labels = _slice_components(xy, x0, p)
    n_comp = int(labels.max()) + 1
    cw = np.bincount(labels, minlength=n_comp).astype(np.float64)
    cx = np.bincount(labels, xy[:, 0], n_comp) / cw
    cy = np.bincount(labels, xy[:, 1], n_comp) / cw
    cs = np.zeros(n_comp, dtype=np.int64)
    cs[labels] = s
    # §4.3, Fig. 16(d): neighbouring centres joined into polylines.
    tracks = _link_centres(cs, cx, cy, cw, p)
    tracks = _uncross(_merge_tracks(tracks, p), p)
    members = np.argsort(labels, kind="stable")
    comp_start = np.concatenate([[0], np.cumsum(cw.astype(np.int64))])

    skels: list[_Skel] = []
    n_short = 0
    for t in tracks:
        comps = np.array([c for cc in t.comps for c in cc], dtype=np.int64)
        n_pts = int(cw[comps].sum())
        centres = np.column_stack([t.x, t.y])
        if len(centres) < 2 or n_pts < p.min_points or _polyline_length(centres) < p.min_length:
            n_short += 1
            continue
        idx = rest_idx[np.concatenate([members[comp_start[c] : comp_start[c + 1]] for c in comps])]
        own_comps = [c for cc, sh in zip(t.comps, t.shared, strict=True) if not sh for c in cc]
        own = np.concatenate(
            [members[comp_start[c] : comp_start[c + 1]] for c in own_comps]
            or [np.zeros(0, np.int64)]
        )
        skels.append(_shape_polyline(centres, np.asarray(t.shared), rest_idx[own], idx, pts, p))
    skels = _merge_fragments(_merge_duplicates(skels, pts, p), pts, p)
    if n_short:
        notes.append(f"{n_short} short or sparse point chains were not taken as pipes")
    return skels


def _merge_tracks(tracks: list[_Track], p: PipeParams) -> list[_Track]:
    """Join polylines broken by a gap or a sharp bend: one's end close to the other's start."""
    merged = True
    while merged:
        merged = False
        tracks.sort(key=lambda t: t.x[0])
        for i, a in enumerate(tracks):
            for j, b in enumerate(tracks):
                if i == j or b.x[0] <= a.x[-1]:
                    continue
                gap = math.hypot(b.x[0] - a.x[-1], b.y[0] - a.y[-1])
                if gap > p.join_distance or b.x[0] - a.x[-1] > p.link_gap + p.slice_interval:
                    continue
                # the joining step must continue both directions (no side branches)
                da = _end_direction(np.column_stack([a.x, a.y]), p, end=True)
                db = _end_direction(np.column_stack([b.x, b.y]), p, end=False)
                step = np.array([b.x[0] - a.x[-1], b.y[0] - a.y[-1]]) / max(gap, 1e-9)
                if da @ step < 0.7 or -db @ step < 0.7:
                    continue
                _append(a, b)
                tracks.pop(j)
                merged = True
                break
            if merged:
                break
    return tracks


def _side_angle(t: _Track, x0: float, x1: float) -> float:
    """Direction (radians from +x) of a track's own centres with x0 <= x <= x1; nan if < 3."""
    k = [i for i in range(len(t.x)) if x0 <= t.x[i] <= x1 and not t.shared[i]]
    if len(k) < 3:
        return math.nan
    xs, ys = np.array([t.x[i] for i in k]), np.array([t.y[i] for i in k])
    return math.atan(float(np.polyfit(xs, ys, 1)[0]))


_TRACK_FIELDS = ("s", "x", "y", "w", "comps", "shared")  # a _Track's per-centre lists


def _append(a: _Track, b: _Track, start: int = 0) -> None:
    """Append b's centres from ``start`` on to a."""
    for name in _TRACK_FIELDS:
        getattr(a, name).extend(getattr(b, name)[start:])


def _uncross(tracks: list[_Track], p: PipeParams) -> list[_Track]:
    """Repair crossings where a polyline bounced off the other pipe instead of crossing it.

    The linking predicts straight on through a crossing, but where one side is thin there a
    polyline can turn into the other pipe's far half: an X becomes a Λ (or V) and two halves,
    one ending and one starting near the Λ's apex. Where the halves continue the Λ's two arms
    straighter than the Λ turns (by ``link_same_angle`` at least, directions fitted within
    ``direction_window`` either side), they are joined to them instead.
    """
    margin = p.link_distance + p.slice_interval
    w = p.direction_window
    repaired = True
    while repaired:
        repaired = False
        for t in tracks:
            if len(t.x) < 3:
                continue
            for k in range(1, len(t.x) - 1):  # per centre: is it the apex of a bounce?
                x, y = t.x[k], t.y[k]
                head = _side_angle(t, x - margin - w, x - margin)
                tail = _side_angle(t, x + margin, x + margin + w)
                if not (np.isfinite(head) and np.isfinite(tail)):
                    continue
                turn = abs(head - tail)
                if turn < 2 * math.radians(p.link_same_angle):
                    continue
                ends = [
                    u for u in tracks
                    if u is not t and u.x[-1] < x
                    and math.hypot(u.x[-1] - x, u.y[-1] - y) <= p.join_distance
                ]  # fmt: skip
                starts = [
                    v for v in tracks
                    if v is not t and v.x[0] > x
                    and math.hypot(v.x[0] - x, v.y[0] - y) <= p.join_distance
                ]  # fmt: skip
                best = None
                for u in ends:
                    u_dir = _side_angle(u, u.x[-1] - w, u.x[-1])
                    for v in starts:
                        if v is u:
                            continue
                        v_dir = _side_angle(v, v.x[0], v.x[0] + w)
                        bent = abs(u_dir - tail) + abs(head - v_dir)
                        if np.isfinite(bent) and bent <= turn - math.radians(p.link_same_angle):
                            if best is None or bent < best[0]:
                                best = (bent, u, v)
                if best is None:
                    continue
                _, u, v = best
                # The apex: the highest centre near here of a Λ, the lowest of a V.
                near = [i for i in range(len(t.x)) if abs(t.x[i] - x) <= margin]
                sign = 1.0 if head > tail else -1.0
                k = max(near, key=lambda i: sign * t.y[i])
                _append(u, t, k + 1)  # the ending half runs on into the Λ's second arm
                for name in _TRACK_FIELDS:
                    setattr(t, name, getattr(t, name)[: k + 1])
                _append(t, v)  # the Λ's first arm runs on into the starting half
                tracks.remove(v)
                repaired = True
                break
            if repaired:
                break
    return tracks


def _end_direction(xy: np.ndarray, p: PipeParams, *, end: bool) -> np.ndarray:
    """Unit direction leaving the polyline at its last (end=True) or first vertex."""
    q = xy if end else xy[::-1]
    if len(q) < 2:
        return np.array([1.0, 0.0]) if end else np.array([-1.0, 0.0])
    tip = q[-1]
    d = np.linalg.norm(q - tip, axis=1)
    k = np.flatnonzero(d >= min(p.direction_window / 2.0, d.max()))
    base = q[k[-1]] if len(k) else q[0]
    v = tip - base
    nv = np.linalg.norm(v)
    return v / nv if nv > 0 else (np.array([1.0, 0.0]) if end else np.array([-1.0, 0.0]))


def _shape_polyline(
    centres: np.ndarray,
    shared: np.ndarray,
    own_idx: np.ndarray,
    idx: np.ndarray,
    pts: np.ndarray,
    p: PipeParams,
) -> _Skel:
    """§4.3: Taubin smoothing, straight-line fit, horizontal snap of one polyline."""
    smooth = taubin_smooth(
        centres, lam=p.taubin_lambda, mu=p.taubin_mu, iterations=p.taubin_iterations
    )
    extras = {"centres": centres, "shared": shared, "own": own_idx}
    xy, kind = _straight_or_curved(smooth, shared, own_idx, idx, pts, p)
    return _Skel(xy=xy, kind=kind, idx=idx, extras=extras)


def _straight_or_curved(
    smooth: np.ndarray,
    shared: np.ndarray,
    own_idx: np.ndarray,
    idx: np.ndarray,
    pts: np.ndarray,
    p: PipeParams,
) -> tuple[np.ndarray, str]:
    """A smoothed polyline (K, 2) kept as it is ("curved"), or, when straight, the line fitted
    to its own points (``own_idx``, else ``idx``) snapped horizontal or vertical when nearly so:
    (xy (K, 2) or (2, 2), kind)."""
    fit_on = smooth[~shared] if (~shared).sum() >= 2 else smooth
    c, d = _fit_line(fit_on)
    normal = np.array([-d[1], d[0]])
    dev = np.abs((smooth - c) @ normal)
    if np.quantile(dev, p.straight_share) > p.straight_tolerance:
        return smooth, "curved"
    # Straight: fit the line to the pipe's own points (components not shared at crossings).
    pxy = pts[own_idx if len(own_idx) >= 2 else idx, :2]
    c2, d2 = _fit_line(pxy)
    off = (pxy - c2) @ np.array([-d2[1], d2[0]])
    keep = np.abs(off) <= np.quantile(np.abs(off), 0.9) + p.link_distance * 0.25
    if keep.sum() >= 2:
        c2, d2 = _fit_line(pxy[keep])
    angle = math.degrees(math.atan2(abs(d2[1]), abs(d2[0])))
    t = (smooth - c2) @ d2
    if angle <= p.horizontal_angle:
        kind = "horizontal"
        d2 = np.array([1.0, 0.0])
        t = smooth[:, 0] - c2[0]
    elif angle >= 90.0 - p.vertical_angle:
        kind = "vertical"
        d2 = np.array([0.0, 1.0])
        t = smooth[:, 1] - c2[1]
    else:
        kind = "diagonal"
    return c2 + np.outer([t.min(), t.max()], d2), kind


def _distance_to_polyline(q: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance (M,) of points q (M, 2) to the polyline xy (K, 2), and the signed offset (left +)."""
    a, b = xy[:-1], xy[1:]
    ab = b - a
    L2 = np.maximum((ab**2).sum(1), 1e-18)
    t = np.clip(((q[:, None, :] - a[None]) * ab[None]).sum(-1) / L2[None], 0.0, 1.0)
    foot = a[None] + t[..., None] * ab[None]
    diff = q[:, None, :] - foot
    d2 = (diff**2).sum(-1)
    k = np.argmin(d2, axis=1)
    rows = np.arange(len(q))
    dist = np.sqrt(d2[rows, k])
    cross = ab[k, 0] * diff[rows, k, 1] - ab[k, 1] * diff[rows, k, 0]
    return dist, np.where(cross >= 0, dist, -dist)


def _merge_duplicates(skels: list[_Skel], pts: np.ndarray, p: PipeParams) -> list[_Skel]:
    """Merge a skeleton that runs along a bigger one (two chains that followed one pipe)."""
    skels = sorted(skels, key=lambda s: -len(s.idx))
    kept: list[_Skel] = []
    for s in skels:
        probe = _resample(s.xy, p.slice_interval)
        for i, k in enumerate(kept):
            dist, _ = _distance_to_polyline(probe, k.xy)
            if np.mean(dist <= p.link_distance) >= 0.5:
                kept[i] = _union(k, s, pts, p)
                break
        else:
            kept.append(s)
    return kept


def _union(a: _Skel, b: _Skel, pts: np.ndarray, p: PipeParams) -> _Skel:
    """One skeleton from the centres and points of two pieces of a pipe."""
    cen = np.vstack([a.extras["centres"], b.extras["centres"]])
    sh = np.concatenate([a.extras["shared"], b.extras["shared"]])
    order = np.argsort(cen[:, 0], kind="stable")
    own = np.union1d(a.extras["own"], b.extras["own"])
    return _shape_polyline(cen[order], sh[order], own, np.union1d(a.idx, b.idx), pts, p)


def _merge_fragments(skels: list[_Skel], pts: np.ndarray, p: PipeParams) -> list[_Skel]:
    """Join pieces of one pipe that the linking left apart (gaps, crossings, junctions).

    Two straight pieces merge when they lie on one line (directions within ``horizontal_angle``,
    ends within ``link_distance`` of the other's line) with at most ``merge_gap`` between them;
    two pieces merge end to start when the gap is at most ``merge_gap`` and the step from one
    to the other continues both directions (within ``merge_angle``).
    """
    cos_turn = math.cos(math.radians(p.merge_angle))
    sin_line = math.sin(math.radians(max(p.horizontal_angle, 1e-3)))
    changed = True
    while changed:
        changed = False
        skels.sort(key=lambda k: float(k.xy[:, 0].min()))
        for i in range(len(skels)):
            a = skels[i]
            for j in range(i + 1, len(skels)):
                b = skels[j]
                if _can_merge(a, b, p, cos_turn, sin_line):
                    skels[i] = _union(a, b, pts, p)
                    skels.pop(j)
                    changed = True
                    break
            if changed:
                break
    return skels


def _can_merge(a: _Skel, b: _Skel, p: PipeParams, cos_turn: float, sin_line: float) -> bool:
    a_end, b_start = a.xy[-1], b.xy[0]
    gap = b_start[0] - a_end[0]
    if gap > p.merge_gap:
        return False
    if a.kind != "curved" and b.kind != "curved":  # straight pieces may overlap
        da = (a.xy[-1] - a.xy[0]) / max(np.linalg.norm(a.xy[-1] - a.xy[0]), 1e-12)
        db = (b.xy[-1] - b.xy[0]) / max(np.linalg.norm(b.xy[-1] - b.xy[0]), 1e-12)
        if abs(da[0] * db[1] - da[1] * db[0]) > sin_line:
            return False
        na = np.array([-da[1], da[0]])
        return bool(np.all(np.abs((b.xy - a.xy[0]) @ na) <= p.link_distance))
    if gap < -p.link_distance:
        return False
    step = b_start - a_end
    n = float(np.linalg.norm(step))
    if n > p.merge_gap:
        return False
    ea = _end_direction(a.xy, p, end=True)
    sb = -_end_direction(b.xy, p, end=False)
    if n < 1e-9:
        return bool(ea @ sb >= cos_turn)
    step = step / n
    return bool(ea @ step >= cos_turn and sb @ step >= cos_turn)


def _resample(xy: np.ndarray, step: float) -> np.ndarray:
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    if cum[-1] <= 0:
        return xy[:1].copy()
    u = np.linspace(0.0, cum[-1], max(2, int(math.ceil(cum[-1] / step)) + 1))
    return np.column_stack([np.interp(u, cum, xy[:, 0]), np.interp(u, cum, xy[:, 1])])


# ----------------------------------------------------------------------------------------------
# Extension to poles and intersections
# ----------------------------------------------------------------------------------------------


def _ray_polyline(
    e: np.ndarray, d: np.ndarray, xy: np.ndarray, ext: float
) -> tuple[float, float, int]:
    """Intersection of the line e + s d with the polyline xy, its end segments extended by ``ext``.

    Returns (s, t, k): the ray parameter, the segment parameter and segment index of the
    intersection closest to e (|s| smallest), or (nan, nan, -1).
    """
    a, b = xy[:-1], xy[1:]
    ab = b - a
    seg_len = np.maximum(np.linalg.norm(ab, axis=1), 1e-12)
    den = d[0] * ab[:, 1] - d[1] * ab[:, 0]
    w = a - e
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (w[:, 0] * ab[:, 1] - w[:, 1] * ab[:, 0]) / den
        t = (w[:, 0] * d[1] - w[:, 1] * d[0]) / den
    tlo = np.zeros(len(ab))
    thi = np.ones(len(ab))
    tlo[0] = -ext / seg_len[0]
    thi[-1] = 1.0 + ext / seg_len[-1]
    ok = np.isfinite(s) & (np.abs(den) > 1e-9) & (t >= tlo) & (t <= thi)
    if not ok.any():
        return math.nan, math.nan, -1
    k = int(np.argmin(np.where(ok, np.abs(s), np.inf)))
    return float(s[k]), float(t[k]), k


def _set_end(s: _Skel, end: int, point: np.ndarray, p: PipeParams) -> None:
    """Move the first (end=0) or last (end=-1) vertex to ``point``; a curve grows a vertex."""
    xy = s.xy
    if s.kind == "curved":
        tip = xy[end]
        direction = _end_direction(xy, p, end=end == -1)
        if (point - tip) @ direction > 0:  # extension: add the point
            s.xy = np.vstack([xy, point]) if end == -1 else np.vstack([point, xy])
            return
    xy = xy.copy()
    xy[end] = point
    s.xy = xy


def _extend_and_join(skels: list[_Skel], length: float, p: PipeParams) -> None:
    """§4.3: extend ends close to a pole to its axis, and close ends to their intersection.

    An end within ``pole_extension`` (in x) of a pole axis, heading toward it, goes to the axis,
    unless it meets another skeleton on the way. Any other end is moved along its direction to
    the nearest crossing with another skeleton (or
    with the extension of that skeleton's end, which is then extended too) within
    ``join_distance`` ahead, or within half of it behind (a trim: the points of a vertical pipe
    reach beyond the axis of the rail it stands on).
    """
    for i, s in enumerate(skels):
        for end in (0, -1):
            tip = s.xy[end]
            d = _end_direction(s.xy, p, end=end == -1)
            pole_x = 0.0 if d[0] < 0 else length
            best_s, best_j, best_t, best_k = math.inf, -1, 0.0, 0
            for j, o in enumerate(skels):
                if j == i:
                    continue
                sr, t, k = _ray_polyline(tip, d, o.xy, p.join_distance)
                if not -0.5 * p.join_distance <= sr <= p.join_distance:  # nan fails too
                    continue
                if abs(sr) < abs(best_s):
                    best_s, best_j, best_t, best_k = sr, j, t, k
            to_pole = (pole_x - tip[0]) / d[0] if abs(d[0]) > 0.1 else math.inf
            near_pole = s.kind != "vertical" and abs(tip[0] - pole_x) <= p.pole_extension
            # A diagonal or curved pipe that meets another before the pole ends there (a
            # diamond's diagonal on its rail), unless at the pole itself (diagonals from the
            # corners); rails run from pole to pole through their junctions.
            meets_first = (
                s.kind != "horizontal" and best_j >= 0 and best_s < to_pole - p.join_distance / 5
            )
            if near_pole and math.isfinite(to_pole) and not meets_first:
                # §4.3: close to a pole: extended to the pole.
                _set_end(s, end, tip + to_pole * d, p)
                continue
            if best_j < 0:
                continue
            # §4.3: close ends are extended to their intersection.
            point = tip + best_s * d
            _set_end(s, end, point, p)
            o = skels[best_j]
            if best_k == 0 and best_t < 0:
                _set_end(o, 0, point, p)
            elif best_k == len(o.xy) - 2 and best_t > 1:
                _set_end(o, -1, point, p)


# ----------------------------------------------------------------------------------------------
# Radius and depth
# ----------------------------------------------------------------------------------------------


def _dense(xy: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertices every ``step`` along a polyline and their left unit normals."""
    v = _resample(xy, step)
    if len(v) < 2:
        return v, np.tile([0.0, 1.0], (len(v), 1))
    tang = np.gradient(v, axis=0)
    tang /= np.maximum(np.linalg.norm(tang, axis=1, keepdims=True), 1e-12)
    return v, np.column_stack([-tang[:, 1], tang[:, 0]])


def _offsets(
    q: np.ndarray, xy: np.ndarray, p: PipeParams
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance (M,) of points q (M, 2) to a skeleton, their signed offset across it (left +)
    and their station along it (M,), metres from its first vertex.

    Points whose nearest skeleton place is an end vertex beyond which they lie get an infinite
    distance (they are not beside the pipe).
    """
    v, nrm = _dense(xy, p.measure_step)
    dist, k = cKDTree(v).query(q, k=1)
    off = np.einsum("ij,ij->i", q - v[k], nrm[k])
    along = np.abs(np.einsum("ij,ij->i", q - v[k], nrm[k][:, ::-1] * [1.0, -1.0]))
    dist = np.where(along > p.measure_step, np.inf, dist)
    return dist, off, k * p.measure_step


def _width_and_centre(off: np.ndarray, station: np.ndarray, p: PipeParams) -> tuple[float, float]:
    """Half-width (the radius) and centre (metres) of a pipe's signed offsets: the central
    ``radius_share`` of each ``measure_stretch`` along it, medians over the stretches (all the
    offsets at once where fewer than three stretches hold ``measure_stretch_points``)."""
    stretch = np.floor(station / p.measure_stretch).astype(np.int64)
    order = np.argsort(stretch, kind="stable")
    cuts = np.flatnonzero(np.diff(stretch[order])) + 1
    widths, centres = [], []
    for group in np.split(order, cuts):  # per stretch (~20 per pipe)
        if len(group) >= p.measure_stretch_points:
            lo, hi = _central_quantiles(off[group], p.radius_share)
            widths.append(0.5 * (hi - lo) / p.radius_share)
            centres.append(0.5 * (lo + hi))
    if len(widths) < 3:
        lo, hi = _central_quantiles(off, p.radius_share)
        return 0.5 * (hi - lo) / p.radius_share, 0.5 * (lo + hi)
    return float(np.median(widths)), float(np.median(centres))


def _measure_all(pts: np.ndarray, skels: list[_Skel], p: PipeParams) -> None:
    """Radius, axis correction and depth of every pipe from the offsets of its points.

    A pipe's points are those within ``r + assign_margin`` of its skeleton and not within
    ``r + assign_margin`` of another pipe's (junctions and crossings count for neither). The
    central ``radius_share`` of their signed offsets gives the radius (half-width / share) and
    the axis (the midpoint: the skeleton is moved across by it), per stretch along the pipe and
    the median over the stretches; each point then gives the axis depth
    ``z - sqrt(r**2 - o**2)``, and the median of these is taken (see the module notes).
    """
    if not skels:
        return
    xy = pts[:, :2]
    # First guess: the points the chain was built from.
    radius = np.zeros(len(skels))
    for i, s in enumerate(skels):
        if len(s.idx) >= 3:
            _, off, station = _offsets(xy[s.idx], s.xy, p)
            radius[i] = _width_and_centre(off, station, p)[0]
        else:
            radius[i] = p.assign_margin
    for _ in range(2):
        dist = np.full((len(skels), len(pts)), np.inf)
        offs = np.zeros((len(skels), len(pts)))
        stations = np.zeros((len(skels), len(pts)))
        for i, s in enumerate(skels):
            lo = s.xy.min(axis=0) - radius[i] - p.assign_margin - p.measure_step
            hi = s.xy.max(axis=0) + radius[i] + p.assign_margin + p.measure_step
            cand = np.flatnonzero(np.all((xy >= lo) & (xy <= hi), axis=1))
            if len(cand):
                dist[i, cand], offs[i, cand], stations[i, cand] = _offsets(xy[cand], s.xy, p)
        inside = dist <= (radius + p.assign_margin)[:, None]
        exclusive = inside & (inside.sum(axis=0) == 1)[None, :]
        for i, s in enumerate(skels):
            sel = exclusive[i]
            if sel.sum() < 3:
                continue
            radius[i], centre = _width_and_centre(offs[i, sel], stations[i, sel], p)
            _shift_polyline(s, centre)
    for i, s in enumerate(skels):
        sel = exclusive[i]
        s.n_points = int(sel.sum())
        s.radius = float(radius[i])
        if s.n_points == 0:
            continue
        _, o, _ = _offsets(xy[sel], s.xy, p)
        depth = pts[sel, 2] - np.sqrt(np.clip(s.radius**2 - o**2, 0.0, None))
        s.z = float(np.median(depth))


def _shift_polyline(s: _Skel, shift: float) -> None:
    """Move the polyline by ``shift`` along its left normal (vertex normals)."""
    xy = s.xy
    if len(xy) < 2 or shift == 0.0:
        return
    tang = np.gradient(xy, axis=0)
    tang /= np.maximum(np.linalg.norm(tang, axis=1, keepdims=True), 1e-12)
    normal = np.column_stack([-tang[:, 1], tang[:, 0]])
    s.xy = xy + shift * normal
