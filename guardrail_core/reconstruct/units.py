"""Subdivision of a guardrail run into unit shapes (§4.1): one unit between consecutive poles.

The poles are ordered along the run so that the road lies on the +z side of every unit frame
(:mod:`guardrail_core.reconstruct.unit_frame`: z = x × up). Each unit has its own chord frame,
so a curved run is followed unit by unit.

Missing poles: where the gap between two consecutive detected poles is about k times the run's
pole spacing (k >= 2; the gap most gaps are whole multiples of, :func:`run_spacing`), k - 1
virtual poles are inserted evenly on the chord, so every unit has the design length and
superimposes with the others (§4.2); the split reports them (``virtual``) and says so in
``notes``. An end pole whose gap is no whole multiple of the spacing is dropped (no post). The
spacing is only known with at least two gaps; a run of two poles is one unit.

Sparse real scans (a spinning multi-beam scanner's single frame) need two more things:

- poles are seen only near the scanner while the rail goes on: virtual poles are placed at the
  spacing along the rail beyond the end poles (``extrapolated``); their units take the model
  but do not shape it, since their x is only extrapolated;
- the ground beside real posts is uneven (a verge, a kerb): where the rail's height above the
  measured ground differs between poles by more than a tolerance, the poles' ground follows
  the rail, so all units superimpose.

References
----------
Matsumoto, Mori, Masuda (2019), "Extraction and shape reconstruction of guardrails using mobile
mapping data", ISPRS Archives, §4.1, Fig. 10(d).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from guardrail_core.errors import ReconstructionError
from guardrail_core.params import StageParams, param
from guardrail_core.reconstruct.model import Pole
from guardrail_core.reconstruct.runs import check_points
from guardrail_core.reconstruct.unit_frame import UP, UnitFrame


@dataclass(frozen=True)
class UnitParams(StageParams):
    """How a run is split into units, and where its missing poles are placed."""

    end_margin_m: float = param(
        0.3,
        unit="m",
        ge=0,
        le=10.0,
        doc="Points up to this far beyond the first or last pole (along the end unit's x) still "
        "belong to the end unit; farther ones to none.",
    )
    max_offset_m: float = param(
        1.0,
        unit="m",
        gt=0,
        le=10.0,
        doc="Points farther than this from a unit's pole plane (|z|) belong to no unit.",
    )
    max_behind_m: float = param(
        0.15,
        unit="m",
        ge=0,
        le=10.0,
        doc="Points farther than this behind a unit's pole plane (z below minus this) belong to "
        "no unit: rails and beams are bolted to the posts' road side or run through them, so "
        "what stands behind the posts (a hedge the classifier called guardrail, some 0.3 m "
        "back) is no part of the unit. It leaves room for the posts' back and for a rail "
        "bowing behind the chord of a bend (4 m units on a 15 m radius: 0.13 m).",
    )
    ground_clearance_m: float = param(
        0.05,
        unit="m",
        ge=-1.0,
        le=2.0,
        doc="Points lower than this above a unit's ground line are ground the classifier took for "
        "guardrail (no rail runs that low), not the unit shape (negative: points below the "
        "ground line are kept down to this).",
    )
    max_hole_m: float = param(
        0.4,
        unit="m",
        gt=0,
        doc="A unit whose points leave a stretch of x this long empty between its poles (a "
        "slice called other cut it, or something hid it) takes the model but does not shape "
        "it, unless no unit is whole: what made the slice look other, a shrub against the "
        "rails, leaves its strays in the unit.",
    )
    missing_pole_ratio: float = param(
        1.6,
        gt=1,
        doc="A gap longer than this many times the run's spacing (see ``spacing_tolerance``) "
        "has missing poles: round(gap / spacing) - 1 virtual poles are inserted in it.",
    )
    min_spacing_m: float = param(
        1.5,
        unit="m",
        ge=0,
        le=10.0,
        doc="A run's spacing is at least this: posts stand 2 m or 4 m apart (real railings 1.5 m "
        "and more), so a shorter gap is a false pole's, never the spacing. Two stems of a hedge "
        "behind a W-beam that pass for posts some 1 m apart made 1 m the spacing, every 2 m "
        "gap between real posts then took a virtual pole in its middle, and one run carried "
        "ten poles that were not there. A run whose gaps are all shorter has no spacing: no "
        "pole is inserted, dropped or added beyond its ends.",
    )
    spacing_tolerance: float = param(
        0.08,
        gt=0,
        lt=0.5,
        doc="Share of a spacing. The run's spacing is the gap between consecutive poles that "
        "the most gaps are whole multiples of, within this share of it (the shortest such gap "
        "on a tie: a missed pole lengthens a gap, it does not shorten one). With three poles "
        "or more, an end pole whose gap is no whole multiple of the spacing is no post (a "
        "delineator or a sign post beside the rail's end) and the run ends at its neighbour: "
        "the spacing of a real W-beam's posts was read as 6.0 m from the gaps 4.2 and 7.9 m, "
        "and the unit came out a pipe.",
    )
    rail_level_tolerance_m: float = param(
        0.03,
        unit="m",
        ge=0,
        le=1.0,
        doc="In one design the rail's top (the ``rail_top_percentile`` of z within "
        "``rail_top_radius_m`` of a pole) stands at one height above every pole's ground. "
        "Where these heights spread (max - min) wider than this, the ground under the poles "
        "is uneven (a verge, a kerb; on a real motorway scan they spread 0.71-0.79 m) and "
        "each pole's ground is set to the rail top near it less the median height, so the "
        "units follow the rail. A rail top off the (Theil-Sen) line of the others by more "
        "than this is a rail unseen near that pole: that pole keeps its measured ground. 0 "
        "turns this off.",
    )
    rail_top_radius_m: float = param(
        1.0,
        unit="m",
        gt=0,
        le=10.0,
        doc="Rail points within this horizontal distance of a pole give the rail top there.",
    )
    rail_top_percentile: float = param(
        95.0,
        ge=0,
        le=100,
        doc="Percent. The rail's top is this percentile of the heights of the rail points near a "
        "pole (not the highest: a stray point above the rail would be).",
    )
    rail_top_min_points: int = param(
        3, ge=1, doc="Points. Fewer rail points near a pole give no rail top there."
    )
    min_extension_points: int = param(
        10,
        ge=0,
        doc="Points. Where at least this many rail points lie more than "
        "``extension_beyond_share`` of a spacing beyond an end pole (within a spacing of it), "
        "the rail goes on where no pole was seen (a sparse scan sees poles only near the "
        "scanner): a virtual pole is added a spacing further along the rail, and again while "
        "the rail goes on. 0 turns this off.",
    )
    extension_beyond_share: float = param(
        0.5,
        ge=0,
        le=1,
        doc="Share of a spacing beyond an end pole that the rail points of "
        "``min_extension_points`` must lie past (nearer ones are the end unit's own rail "
        "ends).",
    )
    max_turn_deg: float = param(
        30.0,
        unit="deg",
        gt=0,
        le=90,
        doc="The largest turn from one placed pole to the next beyond the end poles: where the "
        "rail points ahead turn more, they are not the rail going on (clutter across it, or "
        "the run's end turning away).",
    )


@dataclass(frozen=True)
class UnitSplit:
    """A run split into units.

    Attributes
    ----------
    frames : (U,) unit frames, in order along the run
    unit_of_point : (N,) int32, unit of each run point, -1 outside every unit
    poles : (U + 1,) the poles the frames stand on, detected and virtual, in order
    virtual : (U + 1,) bool, poles inserted where one was missing
    notes : what was done about missing poles, in words
    extrapolated : (U + 1,) bool, virtual poles added beyond the detected end poles
    """

    frames: list[UnitFrame]
    unit_of_point: np.ndarray
    poles: list[Pole] = field(default_factory=list)
    virtual: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    notes: tuple[str, ...] = ()
    extrapolated: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    @property
    def anchored(self) -> np.ndarray:
        """(U,) bool: units between poles that were detected or interpolated between detected
        ones (their x is known to the poles' accuracy; an extrapolated pole's is not)."""
        return ~(self.extrapolated[:-1] | self.extrapolated[1:])


def order_poles(poles: list[Pole], toward_road: np.ndarray) -> list[Pole]:
    """Poles in order along the run with the road on the +z side of every unit frame.

    Parameters
    ----------
    poles : the poles of one run (any order)
    toward_road : (3,) float64: horizontal direction from the run to the road or trajectory

    Returns
    -------
    The poles sorted along the run's principal direction, reversed if needed so that the unit
    normals (x × up) point toward the road (by the sum over units of normal · toward_road).

    References
    ----------
    Matsumoto et al. 2019, §4.2, Fig. 13 (the z axis of a unit is the plane normal).
    """
    toward = np.asarray(toward_road, np.float64).reshape(-1)
    if toward.shape != (3,) or not np.isfinite(toward).all():
        raise ReconstructionError(f"toward_road must be a finite (3,) vector, got {toward_road!r}")
    horizontal = toward * np.array([1.0, 1.0, 0.0])
    if np.linalg.norm(horizontal) == 0:
        raise ReconstructionError("toward_road must have a horizontal component")
    if len(poles) < 2:
        return list(poles)
    xy = np.array([p.position[:2] for p in poles], np.float64)
    centred = xy - xy.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    ordered = [poles[i] for i in np.argsort(centred @ vt[0], kind="stable")]
    pos = np.array([p.position for p in ordered])
    along = np.diff(pos, axis=0) * np.array([1.0, 1.0, 0.0])
    normals = np.cross(along, UP)
    if float((normals @ horizontal).sum()) < 0:
        ordered.reverse()
    return ordered


def _gaps(poles: list[Pole]) -> np.ndarray:
    """(P - 1,) horizontal distances (m) between consecutive poles."""
    pos = np.array([p.position for p in poles], np.float64).reshape(-1, 3)
    return np.linalg.norm(np.diff(pos[:, :2], axis=0), axis=1)


def _whole_multiples(gaps: np.ndarray, spacing: float, tolerance: float) -> np.ndarray:
    """(G,) bool: gaps within ``tolerance`` x ``spacing`` of k x ``spacing``, k >= 1."""
    k = np.maximum(np.round(gaps / spacing), 1.0)
    return np.abs(gaps - k * spacing) <= tolerance * spacing


def run_spacing(gaps: np.ndarray, tolerance: float, min_spacing: float = 0.0) -> float:
    """The spacing (m) of a run's poles from the gaps (G,) between consecutive ones, G >= 1: the
    gap of at least ``min_spacing`` (m) that the most gaps are whole multiples of (within
    ``tolerance`` of it), the shortest of those on a tie; 0.0 when no gap is that long. A
    missed pole makes a gap of two spacings and a false one two odd gaps, so the median, which
    most gaps being single spacings made right, fails with few gaps."""
    gaps = np.asarray(gaps, np.float64)
    candidates = np.sort(gaps[(gaps > 0) & (gaps >= min_spacing)])
    if len(candidates) == 0:
        return 0.0
    support = [int(_whole_multiples(gaps, c, tolerance).sum()) for c in candidates]
    return float(candidates[int(np.argmax(support))])  # argmax: the first, shortest, of the best


def _drop_off_grid_ends(poles: list[Pole], params: UnitParams) -> tuple[list[Pole], list[str]]:
    """The run without end poles whose gap to their neighbour is no whole multiple of the
    run's spacing (three poles or more; two always stay)."""
    if len(poles) < 3:
        return list(poles), []
    gaps = _gaps(poles)
    spacing = run_spacing(gaps, params.spacing_tolerance, params.min_spacing_m)
    if spacing <= 0:
        return list(poles), []
    fits = _whole_multiples(gaps, spacing, params.spacing_tolerance)
    first = 0 if fits[0] else 1
    last = len(poles) - (0 if fits[-1] else 1)
    if last - first < 2:
        return list(poles), []
    notes = [
        f"pole {i} stands {gaps[min(i, len(gaps) - 1)]:.2f} m from its neighbour, no whole "
        f"multiple of the run's spacing {spacing:.2f} m: no post, the run ends before it"
        for i in (*range(first), *range(last, len(poles)))
    ]
    return list(poles[first:last]), notes


def _fill_missing(
    poles: list[Pole], params: UnitParams
) -> tuple[list[Pole], np.ndarray, list[str]]:
    """Insert virtual poles in gaps of about k x the run's spacing (k >= 2)."""
    if len(poles) < 3:
        return list(poles), np.zeros(len(poles), bool), []
    pos = np.array([p.position for p in poles])
    gap = _gaps(poles)
    spacing = run_spacing(gap, params.spacing_tolerance, params.min_spacing_m)
    if spacing <= 0:
        return list(poles), np.zeros(len(poles), bool), []
    out: list[Pole] = [poles[0]]
    virtual = [False]
    notes = []
    for i, g in enumerate(gap):
        k = int(round(g / spacing)) if g > params.missing_pole_ratio * spacing else 1
        for j in range(1, k):
            t = j / k
            out.append(
                Pole(
                    position=(1 - t) * pos[i] + t * pos[i + 1],
                    radius=float(np.median([p.radius for p in poles])),
                    height=float(np.median([p.height for p in poles])),
                    n_points=0,
                )
            )
            virtual.append(True)
        if k > 1:
            notes.append(
                f"gap of {g:.2f} m between poles {i} and {i + 1} (spacing {spacing:.2f} m): "
                f"{k - 1} missing pole(s) inserted"
            )
        out.append(poles[i + 1])
        virtual.append(False)
    return out, np.array(virtual), notes


def _level_to_rail(
    poles: list[Pole], rails: np.ndarray, params: UnitParams
) -> tuple[list[Pole], list[str]]:
    """Poles whose ground follows the rail where the measured ground is uneven (see
    ``rail_level_tolerance_m``); each pole keeps its top (its height changes with its ground)."""
    if params.rail_level_tolerance_m <= 0 or len(poles) < 2 or len(rails) == 0:
        return list(poles), []
    pos = np.array([p.position for p in poles], np.float64)
    # The run's grade (a line through the measured grounds), so an end pole, which has rails
    # on one side only, does not read the grade as rail height.
    chord = np.linalg.norm(np.diff(pos[:, :2], axis=0), axis=1)
    grade = np.polyfit(np.concatenate([[0.0], np.cumsum(chord)]), pos[:, 2], 1)[0]
    tangent = np.gradient(pos[:, :2], axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    near = cKDTree(rails[:, :2]).query_ball_point(pos[:, :2], params.rail_top_radius_m)
    top = np.full(len(poles), np.nan)
    for k, i in enumerate(near):  # per pole
        if len(i) >= params.rail_top_min_points:
            along = (rails[i, :2] - pos[k, :2]) @ tangent[k]
            top[k] = np.percentile(rails[i, 2] - grade * along, params.rail_top_percentile)
    known = np.isfinite(top)
    if known.sum() < 2:
        return list(poles), []
    # A rail top off the line of the others is a rail unseen near that pole, not its ground.
    station = np.concatenate([[0.0], np.cumsum(chord)])
    slope, intercept = _theil_sen(station[known], top[known])
    off_line = np.abs(top - (intercept + slope * station))
    top[known & (off_line > params.rail_level_tolerance_m)] = np.nan
    known = np.isfinite(top)
    above = top - pos[:, 2]
    if known.sum() < 2:
        return list(poles), []
    low, high = np.nanmin(above), np.nanmax(above)
    if high - low <= params.rail_level_tolerance_m:
        return list(poles), []
    level = float(np.nanmedian(above))
    out = []
    for p, t in zip(poles, top, strict=True):  # per pole
        if not np.isfinite(t):
            out.append(p)
            continue
        ground = t - level
        position = np.array([p.position[0], p.position[1], ground])
        height = p.height + float(p.position[2]) - ground
        out.append(Pole(position=position, radius=p.radius, height=height, n_points=p.n_points))
    note = (
        f"the rail's top stands {low:.2f}-{high:.2f} m above the ground measured at the poles "
        f"(uneven ground): the poles' ground follows the rail, {level:.2f} m below its top"
    )
    return out, [note]


def _theil_sen(x: np.ndarray, z: np.ndarray) -> tuple[float, float]:
    """(slope, intercept) of the Theil-Sen line of heights ``z`` (K,) over stations ``x`` (K,):
    the median slope of all pairs, through the median intercept (from four heights on, one
    wrong height does not tilt it)."""
    i, j = np.triu_indices(len(x), 1)
    ok = np.abs(x[j] - x[i]) > 1e-9
    slope = float(np.median((z[j] - z[i])[ok] / (x[j] - x[i])[ok])) if ok.any() else 0.0
    return slope, float(np.median(z - slope * x))


#: Share of a spacing either side of the end pole, and of where the next pole goes, whose rail
#: points give the rail's offset there.
_HEADING_WINDOW = 0.25


def _heading(t: np.ndarray, offset: np.ndarray, spacing: float) -> np.ndarray:
    """(2,) unit vector, (along, across), from an end pole to where the rail is a ``spacing``
    further on: the change of the rail points' median ``offset`` across the current heading
    (K,) from around the pole (station ``t`` (K,) within ``_HEADING_WINDOW`` spacings of 0) to
    around the next pole (of ``spacing``); (1, 0), the heading kept, where either holds fewer
    than three points. A chord, so a curve is followed; medians, so a post or a delineator
    standing in front of the rail moves nothing (it turned the points' principal direction,
    and a real one put an extrapolated post 0.4 m off the rail)."""
    window = _HEADING_WINDOW * spacing
    here, there = np.abs(t) <= window, np.abs(t - spacing) <= window
    if here.sum() < 3 or there.sum() < 3:
        return np.array([1.0, 0.0])
    rise = float(np.median(offset[there]) - np.median(offset[here]))
    return np.array([spacing, rise]) / np.hypot(spacing, rise)


def _extend_ends(
    poles: list[Pole], rails: np.ndarray, params: UnitParams
) -> tuple[list[Pole], int, int]:
    """Virtual poles beyond both end poles where the rail goes on (see ``min_extension_points``).

    Each new pole stands a spacing (:func:`run_spacing`) from the current end pole, along the
    heading of the rail points within a spacing of it (:func:`_heading`; a curve is followed), its
    ground raised or lowered as the rail's top (``rail_top_percentile`` of z) rises or falls from the
    previous stretch to the next. Returns the poles and how many were added before and after.
    """
    if params.min_extension_points <= 0 or len(poles) < 2 or len(rails) == 0:
        return list(poles), 0, 0
    pos = np.array([p.position for p in poles], np.float64)
    spacing = run_spacing(_gaps(poles), params.spacing_tolerance, params.min_spacing_m)
    if spacing <= 0:
        return list(poles), 0, 0
    radius = float(np.median([p.radius for p in poles]))
    height = float(np.median([p.height for p in poles]))
    limit = int(np.ptp(rails[:, :2], axis=0).max() / spacing) + 1
    max_turn_cos = float(np.cos(np.radians(params.max_turn_deg)))
    added: list[list[Pole]] = []
    for end, prev in ((pos[-1], pos[-2]), (pos[0], pos[1])):
        new: list[Pole] = []
        cur, direction = end.copy(), (end - prev)[:2] / np.linalg.norm((end - prev)[:2])
        top_before = None
        for _ in range(limit):  # per added pole
            d = rails[:, :2] - cur[:2]
            t = d @ direction
            across = np.abs(d @ np.array([-direction[1], direction[0]]))
            near = across <= params.max_offset_m
            ahead = near & (t > 0) & (t <= spacing)
            beyond = t > params.extension_beyond_share * spacing
            if (ahead & beyond).sum() < params.min_extension_points:
                break
            if top_before is None:
                behind = near & (t <= 0) & (t > -spacing)
                if behind.sum() < params.min_extension_points:
                    break
                top_before = float(np.percentile(rails[behind, 2], params.rail_top_percentile))
            xy = rails[ahead, :2]
            _, _, vt = np.linalg.svd(xy - xy.mean(axis=0), full_matrices=False)
            if abs(vt[0] @ direction) < max_turn_cos:
                break  # not a rail going on: clutter across it, or the run's end turning away
            around = near & (t >= -_HEADING_WINDOW * spacing)
            around &= t <= (1 + _HEADING_WINDOW) * spacing
            across_dir = np.array([-direction[1], direction[0]])
            heading = _heading(t[around], (d @ across_dir)[around], spacing)
            direction = heading[0] * direction + heading[1] * across_dir
            top = float(np.percentile(rails[ahead, 2], params.rail_top_percentile))
            cur = np.array([*(cur[:2] + spacing * direction), cur[2] + top - top_before])
            top_before = top
            new.append(Pole(position=cur.copy(), radius=radius, height=height, n_points=0))
        added.append(new)
    after, before = added
    return before[::-1] + list(poles) + after, len(before), len(after)


def split_units(xyz: np.ndarray, poles: list[Pole], params: UnitParams = UnitParams()) -> UnitSplit:
    """Units of one run: a frame between each pair of consecutive poles, and each point's unit.

    Parameters
    ----------
    xyz : (N, 3) float64, metres, world: the points of the run
    poles : the run's poles in order (see :func:`order_poles`)
    params : margins and the missing-pole rule

    Returns
    -------
    UnitSplit: a point belongs to the unit whose [0, length] x-range holds it; where two
    units' ranges hold it (the outside of a bend) the one it lies nearest the pole plane of,
    where none does (the inside of a bend, or past the end poles) the nearest within
    ``end_margin_m``; points farther than ``max_offset_m`` from the pole plane, or than
    ``max_behind_m`` behind it, get -1.

    References
    ----------
    Matsumoto et al. 2019, §4.1, Fig. 10(d) (each unit shape includes two poles).
    """
    xyz = check_points(xyz)
    n = len(xyz)
    if len(poles) < 2:
        note = f"{len(poles)} pole(s): no unit"
        none = np.zeros(len(poles), bool)
        return UnitSplit([], np.full(n, -1, np.int32), list(poles), none, (note,), none)
    kept, dropped = _drop_off_grid_ends(list(poles), params)
    all_poles, virtual, notes = _fill_missing(kept, params)
    notes[:0] = dropped
    all_poles, level_notes = _level_to_rail(all_poles, xyz, params)
    notes.extend(level_notes)
    all_poles, n_before, n_after = _extend_ends(all_poles, xyz, params)
    virtual = np.concatenate([np.ones(n_before, bool), virtual, np.ones(n_after, bool)])
    extrapolated = np.zeros(len(all_poles), bool)
    extrapolated[:n_before] = True
    extrapolated[len(all_poles) - n_after :] = True
    if n_before or n_after:
        notes.append(
            f"the rail goes on beyond the end poles: {n_before + n_after} pole(s) placed at the "
            "spacing along it (not seen); those units take the model but do not shape it"
        )
    pos = np.array([p.position for p in all_poles], np.float64)
    frames = [UnitFrame.between(pos[i], pos[i + 1]) for i in range(len(pos) - 1)]
    n_units = len(frames)
    unit = np.full(n, -1, np.int32)
    if n == 0:
        return UnitSplit(frames, unit, all_poles, virtual, tuple(notes), extrapolated)
    # Candidates: the two units meeting at the nearest pole.
    _, nearest = cKDTree(pos[:, :2]).query(xyz[:, :2])
    cand = np.stack([np.clip(nearest - 1, 0, n_units - 1), np.clip(nearest, 0, n_units - 1)], 1)
    origin = np.array([f.origin for f in frames])
    along = np.array([f.along for f in frames])
    normal = np.array([f.normal for f in frames])
    length = np.array([f.length for f in frames])
    outside = np.empty((n, 2))
    toward_road = np.empty((n, 2))
    for c in range(2):  # the two candidates, vectorised over points
        d = xyz - origin[cand[:, c]]
        x = np.einsum("ij,ij->i", d, along[cand[:, c]])
        outside[:, c] = np.maximum(0.0, np.maximum(-x, x - length[cand[:, c]]))
        toward_road[:, c] = np.einsum("ij,ij->i", d, normal[cand[:, c]])
    offset = np.abs(toward_road)
    # Inside a range first, then nearer the pole plane.
    key = outside * 1e3 + offset
    pick = np.argmin(key, axis=1)
    rows = np.arange(n)
    ok = (
        (outside[rows, pick] <= params.end_margin_m)
        & (offset[rows, pick] <= params.max_offset_m)
        & (toward_road[rows, pick] >= -params.max_behind_m)
    )
    unit[ok] = cand[rows[ok], pick[ok]]
    return UnitSplit(frames, unit, all_poles, virtual, tuple(notes), extrapolated)


def unit_points(xyz: np.ndarray, split: UnitSplit) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Each unit's points in its own unit coordinates, and their indices into ``xyz``.

    Parameters
    ----------
    xyz : (N, 3) float64, metres, world: the run points given to :func:`split_units`
    split : the split

    Returns
    -------
    points : (U,) list of (Ni, 3) float64 unit coordinates (x along, y up, z toward the road)
    index : (U,) list of (Ni,) int64 indices into ``xyz``

    References
    ----------
    Matsumoto et al. 2019, §4.2, Fig. 13.
    """
    xyz = check_points(xyz)
    if len(split.unit_of_point) != len(xyz):
        raise ReconstructionError(
            f"the split has {len(split.unit_of_point)} points, xyz has {len(xyz)}"
        )
    order = np.argsort(split.unit_of_point, kind="stable")
    bounds = np.searchsorted(split.unit_of_point[order], np.arange(len(split.frames) + 1))
    index = [order[bounds[u] : bounds[u + 1]] for u in range(len(split.frames))]
    return [f.to_unit(xyz[i]) for f, i in zip(split.frames, index, strict=True)], index
