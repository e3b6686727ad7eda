"""Section curve of guardrails consisting of beams (Matsumoto et al. 2019, §4.4), and the
thresholds of both beam stages.

Input: superimposed points of units in unit coordinates (:mod:`guardrail_core.reconstruct.unit_frame`:
x along the unit from its first pole's axis, y above the ground line, z toward the road; metres).

Whether a unit is a beam at all is :func:`guardrail_core.reconstruct.unit_type.unit_type`. The
section curve of a beam is the centre of its points in 10 mm horizontal slices, joined into a
polyline and smoothed by Taubin's low-pass filter (:func:`reconstruct_beam`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from guardrail_core.errors import ReconstructionError
from guardrail_core.params import Slider, StageParams, param
from guardrail_core.reconstruct.pipes import check_unit_points
from guardrail_core.reconstruct.smoothing import taubin_smooth

__all__ = ["BeamParams", "BeamReconstruction", "check_unit_length", "reconstruct_beam"]


@dataclass(frozen=True)
class BeamParams(StageParams):
    """Thresholds of beam detection and section extraction (§4.4)."""

    # -- unit type: beams fill a relatively large rectangle (§4.4) --------------------------------
    cell_m: float = param(
        0.02,
        unit="m",
        gt=0,
        le=0.5,
        doc="Cell size of the occupancy grid of :func:`unit_type` (x and y).",
    )
    band_m: float = param(
        0.06,
        unit="m",
        gt=0,
        le=1.0,
        doc="Height of the band of rows whose points count for a row's occupancy: single-unit "
        "scans of a beam are slanted stripes ~0.1 m apart, a band of rows spreads them over "
        "x, while the balusters of a pipe fence stay at fixed x.",
    )
    row_share: float = param(
        0.4,
        gt=0,
        le=1,
        doc="A row is occupied when this share of its x cells holds points (within its band).",
    )
    filled_share: float = param(
        0.5,
        gt=0,
        le=1,
        doc='A region of occupied rows is "filled by points" when the mean occupancy of its rows '
        "reaches this share.",
    )
    min_height_m: float = param(
        0.2,
        unit="m",
        gt=0,
        le=2.0,
        doc='Least height of a filled region for the unit to be a beam ("relatively large").',
    )
    max_gap_m: float = param(
        0.08,
        unit="m",
        ge=0,
        le=1.0,
        doc="Rows below ``row_share`` over at most this height (shadowed corrugation valleys) do "
        "not break a region.",
    )
    type_margin_m: float = param(
        0.2,
        unit="m",
        ge=0,
        le=2.0,
        doc=":func:`unit_type` ignores points within this x distance of the poles (it knows no "
        "pole radius; beam posts are ~0.07 m in radius).",
    )
    max_open_share: float = param(
        0.1,
        ge=0,
        lt=1,
        doc="A beam covers every x between its posts: when more than this share of the ``cell_m / "
        "2`` wide x bins between the margins hold no point (in the middle "
        "``open_height_share`` of the heights), the unit is a pipe fence (vertical pipes at "
        "fixed x, however dense the superimposed points make its rows look).",
    )
    open_height_share: float = param(
        0.5,
        gt=0,
        le=1,
        doc="The share of the unit's heights, around their median, whose points tell an open "
        "fence from a beam (rails above and below would cover every x).",
    )
    gap_column_m: float = param(
        0.1,
        unit="m",
        gt=0,
        le=1.0,
        doc="Width of the x columns of the gap test of :func:`unit_type`.",
    )
    max_column_gap_m: float = param(
        0.11,
        unit="m",
        gt=0,
        le=2.0,
        doc="A beam's plate leaves no gap in height taller than a shadowed corrugation valley "
        "(under 0.1 m) in any x column; pipes leave gaps between them in every column, "
        "however densely superimposition fills the rows where they cross (a wave, diagonals, "
        "a diamond lattice). When the tallest gap of the median column exceeds this, the unit "
        "is a pipe fence.",
    )
    gap_height_share: float = param(
        0.9,
        gt=0,
        le=1,
        doc="The gap test spans this share of the points' heights around their median (the "
        "ends count as the edges of a gap).",
    )
    gap_depth_m: float = param(
        0.1,
        unit="m",
        gt=0,
        le=1.0,
        doc="The gap test counts only points within this depth (z) of the points' median depth: "
        "a beam's plate is under 0.1 m deep, while a hedge seen through a pipe fence would "
        "fill its gaps.",
    )
    gap_column_points: int = param(
        10,
        ge=1,
        doc="Points. Columns with fewer points take no part in the gap test.",
    )
    # -- the section curve: 10 mm slices, smoothed (§4.4) ----------------------------------------
    pole_margin_m: float = param(
        0.05,
        unit="m",
        ge=0,
        le=1.0,
        doc=":func:`reconstruct_beam` drops points within ``pole_radius + pole_margin_m`` in x of "
        "a pole.",
    )
    post_gap_m: float = param(
        0.03,
        unit="m",
        ge=0,
        le=1.0,
        doc="Points more than this behind (lower z than) the beam's rear-most slice centre are "
        "post or blockout points and are dropped.",
    )
    slice_interval_m: float = param(
        0.01,
        unit="m",
        gt=0,
        le=0.2,
        doc="Height of the horizontal slices (§4.4: 10 mm).",
        slider=Slider("beam slice interval (m)", 0.005, 0.05, 0.005),
    )
    min_points: int = param(3, ge=1, doc="Points. Fewest points for a slice to give a centre.")
    shadow_gap_m: float = param(
        0.02,
        unit="m",
        ge=0,
        le=1.0,
        doc="A step in y between consecutive section vertices above this is a shadowed stretch.",
    )
    sparse_share: float = param(
        0.05,
        ge=0,
        lt=1,
        doc="Slices with fewer points than this share of the median slice are left out (grazing "
        "views at the edge of a shadow, whose centres are biased).",
    )
    min_x_spread: float = param(
        0.2,
        ge=0,
        lt=1,
        doc="A beam runs the whole unit: slices whose points span (``x_spread_percentile`` to its "
        "complement of x) less than this share of the length between the posts are a "
        "blockout, a post top or clutter, and are left out.",
    )
    x_spread_percentile: float = param(
        10.0,
        ge=0,
        lt=50,
        doc="Percent. A slice's x span runs from this percentile of its points' x to 100 less it "
        "(a stray point does not stretch it).",
    )
    max_band_gap_m: float = param(
        0.1,
        unit="m",
        ge=0,
        le=2.0,
        doc="The beam is one band of heights: slices separated from the band holding the most "
        "points by a gap in y above this are left out (clutter at the foot, on a sparse "
        "scan).",
    )
    # -- shadowed flanks ---------------------------------------------------------------------------
    fill_shadowed: bool = param(
        True,
        doc="Fill the shadowed downward-facing flank below a ridge (the scanner looks down on the "
        "beam and cannot see it) with the mirror image of the ridge's upper flank about its "
        "crest; also below the lowest vertex when the section stops near a crest. Assumes the "
        "symmetric ridges of standard W and thrie beams; False bridges gaps straight.",
    )
    crest_depth_m: float = param(
        0.015,
        unit="m",
        ge=0,
        le=0.5,
        doc="The height of a crest, the mirror's axis, is fitted to the slice centres of its "
        "ridge within this depth (z) of the highest: the ridge's rounded top.",
    )
    crest_side_vertices: int = param(
        2,
        ge=1,
        doc="Vertices. The parabola of a crest is its height only with at least this many of the "
        "ridge's top vertices on each side of its vertex (an extrapolated top is no "
        "measurement); else the highest vertex is.",
    )
    valley_rise_m: float = param(
        0.005,
        unit="m",
        ge=0,
        le=0.1,
        doc="Past a crest, the flank's valley is where z has risen this much above its lowest; "
        "climbing to a crest, a fall of this much below the highest z so far ends the climb "
        "(the slices' noise does not).",
    )
    # -- Taubin's low-pass filter ------------------------------------------------------------------
    taubin_lambda: float = param(0.5, gt=0, lt=1, doc="Taubin's shrinking factor.")
    taubin_mu: float = param(-0.53, lt=0, doc="Taubin's inflating factor, below -taubin_lambda.")
    taubin_iterations: int = param(5, ge=0, doc="Taubin's filter iterations.")

    def check_relations(self) -> None:
        if not self.taubin_mu < -self.taubin_lambda:
            self.fail(
                f"taubin_mu must be below -taubin_lambda = {-self.taubin_lambda} (Taubin's filter "
                f"shrinks otherwise), got {self.taubin_mu}"
            )


@dataclass(frozen=True)
class BeamReconstruction:
    """What :func:`reconstruct_beam` returns.

    Attributes
    ----------
    section : (M, 2) float64, (z, y) metres: the section curve from bottom to top (M = 0 when
        nothing could be reconstructed)
    n_points : int, beam points used
    notes : what could not be reconstructed, in words
    """

    section: np.ndarray
    n_points: int
    notes: tuple[str, ...] = ()


def check_unit_length(length: float) -> float:
    """``length`` (m) as a float, checked finite and positive (:class:`ReconstructionError`)."""
    try:
        v = float(length)
    except (TypeError, ValueError) as exc:
        raise ReconstructionError(f"length must be a number, got {length!r}") from exc
    if not (math.isfinite(v) and v > 0):
        raise ReconstructionError(f"length must be > 0, got {length!r}")
    return v


def reconstruct_beam(
    points: np.ndarray,
    length: float,
    pole_radius: float,
    params: BeamParams = BeamParams(),
) -> BeamReconstruction:
    """The section curve of a beam unit from superimposed unit points.

    Parameters
    ----------
    points : (N, 3) float64, unit coordinates, metres
        Superimposed points of the units of one run; pole points may be included.
    length : float, metres
        Unit length.
    pole_radius : float, metres
        Radius of the posts.
    params : BeamParams

    Returns
    -------
    BeamReconstruction
        ``section`` (M, 2) (z, y) metres from bottom to top: the centre of the scanned face in
        each 10 mm horizontal slice, smoothed. It is the front face, ``thickness / 2``
        (1.2-1.6 mm) in front of the plate's mid-surface, which is left uncorrected.

    Raises
    ------
    ReconstructionError
        If points are not (N, 3) finite, or length / pole_radius are out of range.

    References
    ----------
    Matsumoto, Mori, Masuda (2019). Extraction and shape reconstruction of guardrails using
    mobile mapping data. ISPRS Archives XLII-2/W13, §4.4, Fig. 18, 19.
    Taubin, G. (1995). A signal processing approach to fair surface design. SIGGRAPH '95.
    """
    pts = check_unit_points(points)
    length = check_unit_length(length)
    try:
        pole_radius = float(pole_radius)
    except (TypeError, ValueError) as exc:
        raise ReconstructionError(f"pole_radius must be a number, got {pole_radius!r}") from exc
    if not (math.isfinite(pole_radius) and pole_radius >= 0):
        raise ReconstructionError(f"pole_radius must be >= 0, got {pole_radius!r}")
    p = params
    empty = np.zeros((0, 2))
    # §4.4: points on poles are eliminated.
    x0 = pole_radius + p.pole_margin_m
    pts = pts[(pts[:, 0] > x0) & (pts[:, 0] < length - x0)]
    if len(pts) == 0:
        return BeamReconstruction(empty, 0, ("no points between the posts: no beam section",))
    # §4.4: 10 mm horizontal slices, the centre of each.
    span = length - 2 * x0
    section, used = _slice_centres(pts, span, p)
    if len(section) >= 2:
        # Posts and blockouts stand behind the beam: drop points behind its rear-most centre.
        front = pts[:, 2] >= section[:, 0].min() - p.post_gap_m
        if not front.all():
            pts = pts[front]
            section, used = _slice_centres(pts, span, p)
    notes: list[str] = []
    if len(section) < 2:
        notes.append(
            f"only {len(section)} horizontal slices hold {p.min_points}+ points: no beam section"
        )
        return BeamReconstruction(empty, int(used), tuple(notes))
    gaps = np.flatnonzero(np.diff(section[:, 1]) > p.shadow_gap_m)
    if len(gaps):
        spans = ", ".join(f"{section[g, 1]:.2f}-{section[g + 1, 1]:.2f} m" for g in gaps)
        how = "mirrored from the ridges' upper flanks" if p.fill_shadowed else "bridged straight"
        notes.append(f"no points at heights {spans} (shadowed flanks): {how}")
    if p.fill_shadowed:
        section = _fill_shadowed(section, p)
    # §4.4: the polyline is smoothed by the low-pass filter.
    section = taubin_smooth(
        section, lam=p.taubin_lambda, mu=p.taubin_mu, iterations=p.taubin_iterations
    )
    return BeamReconstruction(section, int(used), tuple(notes))


def _slice_centres(pts: np.ndarray, span: float, p: BeamParams) -> tuple[np.ndarray, int]:
    """(z median, y mean) of each 10 mm slice in y that is part of the beam, bottom to top.

    A slice is part of the beam when it holds ``min_points`` points and ``sparse_share`` of the
    median slice, its points span ``min_x_spread`` of ``span`` (metres between the posts), and
    it lies in the band of such slices, joined across gaps up to ``max_band_gap_m``, that holds the
    most points.
    """
    y0 = float(pts[:, 1].min())
    s = ((pts[:, 1] - y0) / p.slice_interval_m).astype(np.int64)
    order = np.argsort(s, kind="stable")
    s_sorted = s[order]
    bounds = np.flatnonzero(np.diff(s_sorted)) + 1
    groups = np.split(order, bounds)
    counts = np.array([len(g) for g in groups])
    # Slices with few points are the edge of a shadow (a grazing view): left out.
    ok = counts >= max(p.min_points, p.sparse_share * float(np.median(counts)))
    q = [p.x_spread_percentile, 100 - p.x_spread_percentile]
    spread = np.array([np.ptp(np.percentile(pts[g, 0], q)) for g in groups])
    ok &= spread >= p.min_x_spread * span
    if not ok.any():
        return np.zeros((0, 2)), 0
    kept = np.flatnonzero(ok)
    level = s_sorted[bounds - 1] if len(bounds) else np.zeros(0, np.int64)
    level = np.concatenate([level, [s_sorted[-1]]])[kept]
    band = np.concatenate([[0], np.cumsum(np.diff(level) * p.slice_interval_m > p.max_band_gap_m)])
    main = int(np.argmax(np.bincount(band, weights=counts[kept])))
    kept = kept[band == main]
    z = np.array([np.median(pts[groups[k], 2]) for k in kept])
    y = np.array([pts[groups[k], 1].mean() for k in kept])
    return np.column_stack([z, y]), int(counts[kept].sum())


def _fill_shadowed(section: np.ndarray, p: BeamParams) -> np.ndarray:
    """Fill shadowed lower flanks of ridges by mirroring the upper flank about the crest.

    section : (M, 2) (z, y) from bottom to top. A gap (a step in y above ``shadow_gap_m``) whose
    upper side climbs to a crest (a local maximum of z) is filled with the crest's upper flank
    mirrored about the crest height; so is the stretch below the lowest vertex when that vertex
    lies in the upper half of the section's depth (the plate cannot end at a ridge). Crest
    heights come from :func:`_crest_height`, not from the highest vertex: a mirror axis off by
    d moves the filled flank by 2 d.
    """
    z, y = section[:, 0], section[:, 1]
    z_mid = 0.5 * (z.min() + z.max())
    pieces = [section]

    def mirrored(axis: float, lo: float, hi: float) -> np.ndarray:
        up = section[y >= axis]
        m = np.column_stack([up[:, 0], 2.0 * axis - up[:, 1]])
        # lo is inclusive: below the lowest vertex it is the mirror of the valley that ends the
        # upper flank, the plate's edge.
        return m[(m[:, 1] >= lo) & (m[:, 1] < hi)]

    for g in np.flatnonzero(np.diff(y) > p.shadow_gap_m):
        c = _crest_above(z, int(g) + 1, p)
        if c > g + 1 or z[g + 1] > z_mid:
            pieces.append(mirrored(_crest_height(section, c, p), y[g], y[g + 1]))
    if z[0] > z_mid:
        c = _crest_above(z, 0, p)
        axis = _crest_height(section, c, p)
        half_pitch = _half_pitch(section, c, axis, p)
        if half_pitch is None:
            # one ridge: mirror down to the next valley above the crest (where the upper flank
            # ends), the deepest vertex before z rises again by more than the slices' noise
            k = j = c
            while j + 1 < len(z) and z[j + 1] <= z[k] + p.valley_rise_m:
                j += 1
                k = j if z[j] < z[k] else k
            pieces.append(mirrored(axis, 2.0 * axis - y[k], y[0]))
        else:
            # standard beams repeat one ridge: the plate's edge lies half a pitch below the
            # crest, at the depth of the valleys (the flank above may stop short of its valley,
            # in the shadow of the next ridge)
            edge = axis - half_pitch
            # the mirrored valley is the upper flank's end, sliced at a grazing view where the
            # next ridge's shadow begins (biased outward): the edge vertex replaces its last
            fill = mirrored(axis, edge + 0.5 * p.slice_interval_m, y[0])
            pieces.append(np.vstack([fill, [[float(z.min()), edge]]]))
    out = np.vstack(pieces)
    return out[np.argsort(out[:, 1], kind="stable")]


def _crest_above(z: np.ndarray, i: int, p: BeamParams) -> int:
    """Index of the crest reached by climbing from vertex ``i``: the highest z before z falls
    more than ``valley_rise_m`` below it (noise does not stop the climb)."""
    best = j = i
    while j + 1 < len(z) and z[j + 1] >= z[best] - p.valley_rise_m:
        j += 1
        best = j if z[j] > z[best] else best
    return best


def _crest_height(section: np.ndarray, c: int, p: BeamParams) -> float:
    """Height y (m) of the crest at vertex ``c``: the vertex of a parabola z(y) fitted to the
    ridge's top, the vertices within ``crest_depth_m`` of its highest z along the stretch around
    ``c`` that stays above mid-depth without a shadowed gap.

    The highest vertex alone is off by several mm on a sparse scan (the ridge is flat there,
    and a grazing slice at a shadow's edge can top it); the fit stays within 1-2 mm. Falls
    back to the highest vertex unless the fit has a maximum with ``crest_side_vertices`` on each
    side.
    """
    z, y = section[:, 0], section[:, 1]
    z_mid = 0.5 * (z.min() + z.max())
    lo = hi = c
    while lo > 0 and z[lo - 1] > z_mid and y[lo] - y[lo - 1] <= p.shadow_gap_m:
        lo -= 1
    while hi + 1 < len(z) and z[hi + 1] > z_mid and y[hi + 1] - y[hi] <= p.shadow_gap_m:
        hi += 1
    ridge = np.arange(lo, hi + 1)
    top = ridge[z[ridge] >= z[ridge].max() - p.crest_depth_m]
    highest = float(y[ridge[np.argmax(z[ridge])]])
    if len(top) < 2 * p.crest_side_vertices:
        return highest
    a, b, _ = np.polyfit(y[top] - y[c], z[top], 2)
    if a >= 0:
        return highest
    vertex = y[c] - b / (2.0 * a)
    # an extrapolated top is no measurement: the fit must have vertices on both sides
    below = int((y[top] < vertex).sum())
    return float(vertex) if min(below, len(top) - below) >= p.crest_side_vertices else highest


def _half_pitch(section: np.ndarray, c: int, axis: float, p: BeamParams) -> float | None:
    """Half the distance (m) from the crest at ``axis`` (vertex ``c``) to the next crest above,
    or None when no crest lies above (a single ridge)."""
    z = section[:, 0]
    z_mid = 0.5 * (z.min() + z.max())
    j = c + 1
    while j < len(z) and z[j] > z_mid:  # down the upper flank to the valley
        j += 1
    while j < len(z) and z[j] <= z_mid:
        j += 1
    if j >= len(z):
        return None
    k = _crest_above(z, j, p)
    if k == len(z) - 1:
        return None  # the section stops on the way up: no whole crest
    return 0.5 * (_crest_height(section, k, p) - axis)
