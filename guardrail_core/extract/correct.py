"""Label correction (§3.3): labels of sliced segments are made to agree with their neighbours.

An isolated guardrail segment becomes "other"; an "other" segment inside a run of guardrail
segments becomes "guardrail" when it lies within their cross-section or is one of the run's
posts. Neighbours are segments of the same or the next slice along the trajectory whose extents
beside and above the road touch.

Beyond the paper: a guardrail segment that stands behind a run of guardrail of another object, in
the same slice and on the same side of the path, becomes other. A hedge, a fence or a bicycle
rack just behind a rail is cut into slices like the rail, and its crop shows the rail in front of
it; the paper's streets had nothing behind their rails. And a short wireframe component whose
crops say other is other, whatever its shape: a far mesh fence's wire rows come apart into short
pieces that look like a pipe rail, and the crops of them show the mesh. The wireframe's objects
speak too: a few slices of a long object called other are part of it (a fence, a wall, a strip
of grass), and so is a short piece lying within the outline of a thin one (a fence's wire row).
A hedge grown into a rail's back is of the rail's component; cut from the rail's slices, what
stands behind the rail and is wider than any of its own parts is other too. And a short piece
lying wholly inside a rail's slice is of the railing: the arches and stays between its rails,
thin pipes whose sparse hits the wireframe leaves apart from them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from guardrail_core.errors import InvalidOptionError
from guardrail_core.params import StageParams, param


@dataclass(frozen=True)
class CorrectionParams(StageParams):
    """Rules of label correction."""

    touch_distance_m: float = param(
        0.3,
        unit="m",
        ge=0,
        le=10,
        doc="segments whose lateral and height extents come within this of each other, in the "
        "same or adjacent slices, are neighbours",
    )
    fill_margin_m: float = param(
        0.05,
        unit="m",
        ge=0,
        le=10,
        doc="an other segment inside a run becomes guardrail only if it lies within the lateral "
        "and height extent of its guardrail neighbours, widened by this (so a curb or a "
        "sidewalk beside a guardrail stays other)",
    )
    post_width_m: float = param(
        0.15,
        unit="m",
        ge=0,
        le=10,
        doc="an other segment inside a run that stands on the ground (post_foot_m), reaches at "
        "least post_min_reach of the way up its guardrail neighbours but no higher than their "
        "top (widened by fill_margin_m), and lies within this of them beside the road is a post "
        "and becomes guardrail: a post stands below the rails and behind them (they are bolted "
        "to its face). The classifier misses far posts' slices most often, and a missed post "
        "cuts the run there",
    )
    post_foot_m: float = param(
        0.3,
        unit="m",
        ge=0,
        le=10,
        doc="a post's segment reaches this close to the road surface (the road takes a far "
        "post's lowest 0.15 m); a bicycle rack's bars behind a guardrail do not",
    )
    post_min_reach: float = param(
        0.5,
        ge=0,
        le=1,
        doc="share of the way from the bottom of a post's guardrail neighbours to their top "
        "that the post's top reaches at least; a curb beside or under the rails does not",
    )
    post_stub_gap_m: float = param(
        0.12,
        unit="m",
        ge=0,
        le=10,
        doc="an other segment inside a run that stands on the ground (post_foot_m), within "
        "post_width_m of its guardrail neighbours beside the road, and whose top comes within "
        "this of their bottom is the stub of a post under a low rail and becomes guardrail: "
        "the rest of the post is of the rail's segment, and the stub stops 5-10 cm under the "
        "rail, short of post_min_reach. 0 turns the rule off",
    )
    post_stub_min_top_m: float = param(
        0.25,
        unit="m",
        ge=0,
        le=10,
        doc="a post's stub reaches at least this high above the road: a curb does not",
    )
    max_hole_slices: int = param(
        2,
        choices=(1, 2),
        doc="other segments inside a run are filled in holes of up to this many consecutive "
        "slices (each segment of a hole of two fitting the guardrail segments on its side)",
    )
    fill_min_probability: float = param(
        0.1,
        ge=0,
        le=1,
        doc="an other segment is filled only if the classifier gave it at least this P(guardrail) "
        "(one without an answer can be filled): one it is sure of stays other. On four simulated "
        "development streets 64 of the 67 fills of segments under 0.1 were wrong (hedges and "
        "fences behind the rails); 0 fills by position alone, as the paper does",
    )
    min_run_slices: int = param(
        2,
        ge=1,
        le=1000,
        doc="a group of neighbouring guardrail segments spanning fewer slices than this is "
        "isolated and becomes other (the paper: an isolated segment)",
    )
    behind_gap_m: float = param(
        0.1,
        unit="m",
        ge=0,
        finite=False,
        doc="a guardrail segment whose nearest point lies more than this (and at most "
        "behind_max_m) farther from the path than the guardrail segments of another wireframe "
        "component in its slice and on its side (in a run of at least behind_front_min_slices) "
        "becomes other: what stands just behind a rail is a hedge, a fence or a bicycle rack, "
        "and its crop shows the rail. A rail's own posts and back rail are of its component. "
        "inf turns the rule off",
    )
    behind_max_m: float = param(
        1.0,
        unit="m",
        gt=0,
        finite=False,
        doc="what stands farther than this behind a rail may be a barrier of its own: the real "
        "KITTI motorway's median has a rail for each carriageway, the far one 1.1-1.8 m behind "
        "the near one with a hedge between",
    )
    behind_wide_m: float = param(
        0.1,
        unit="m",
        gt=0,
        finite=False,
        doc="a guardrail segment spanning at least this much across the path stands behind a "
        "run of another component with no gap at all: a hedge or a bush that touches the back "
        "of a rail, or the face of one just behind it seen from across the road "
        "(SegmentParams.front_layer_m cuts it from the rail as a component of its own when it "
        "spans front_behind_min_width_m, 0.1 m, or more). A rail's posts and back rail are of "
        "its own component; inf asks every segment for behind_gap_m",
    )
    behind_own_wide_m: float = param(
        0.3,
        unit="m",
        gt=0,
        finite=False,
        doc="a guardrail segment spanning at least this much across the path that stands more "
        "than behind_gap_m and at most behind_max_m behind a front of its own component in its "
        "slice becomes other: a hedge grown into a rail's back is one wireframe component with "
        "it, and the cut of a slice behind the rail's front parts its face from the rail, as "
        "its own segment. Wider than a rail, a post with its blockouts or the back rail of a "
        "double-sided barrier (each at most 0.2 m across, the last as its own segment only "
        "between posts); inf turns the rule off",
    )
    behind_front_min_slices: int = param(
        4,
        ge=1,
        le=1000,
        doc="the run in front spans at least this many slices (2 m in 0.5 m slices): a short "
        "false alarm in front of a rail does not take the rail with it",
    )
    behind_front_min_points: int = param(
        5,
        ge=1,
        le=1_000_000,
        doc="the segment in front holds at least this many points: a multi-beam scanner cuts a "
        "rail into fragments of a point or two, and one a few centimetres nearer the path "
        "than the rest is not something the rest stands behind",
    )

    crop_veto_max_slices: int = param(
        20,
        ge=0,
        le=1000,
        doc="every segment of a wireframe component spanning at most this many slices (10 m in "
        "0.5 m slices) whose crops say other (crop_veto_min_crops of them at least, "
        "crop_veto_share of them under 0.5: all by default) is other, whatever the segment "
        "head made of its shape: a short piece says little by its shape, and the top pipe and "
        "wire rows of a mesh fence 4-8 m off come apart into pieces of a few slices that the "
        "head takes for a pipe rail. Only crops the head weighed count (those whose segment's "
        "shape left the label open). At most the tile margin in slices (20 with the default "
        "10 m), so that a tile sees such a component whole; 0 turns the rule off",
    )
    crop_veto_min_crops: int = param(
        2,
        ge=1,
        le=1000,
        doc="a short component's crops overrule its shape only if it has at least this many: one "
        "crop of a far slice of 30-40 px is too often wrong",
    )
    crop_veto_share: float = param(
        1.0,
        gt=0,
        le=1,
        doc="share of a short component's crops that must say other (P(guardrail) under 0.5) "
        "for them to overrule its shape: every one of them by default, since a component can "
        "hold a rail and the hedge pressed against it, and the rail's crops are of a design "
        "the CNN may not know (0.75 cost a street of a design its model never saw 17 "
        "guardrail segments of such rails)",
    )

    crop_veto_rest_share: float = param(
        0.5,
        gt=0,
        finite=False,
        doc="a short component the crops say other is spared when at least this share of its "
        "segments are thin (infill_host_max_width_m) and rest on a guardrail segment of "
        "another component in their slice: within its lateral extent (widened by "
        "fill_margin_m) and touch_distance_m of it in height, the host's component spanning "
        "at least behind_front_min_slices and not vetoed itself. A railing's top rail, 1 m up, "
        "that the wireframe keeps apart from the rest of the railing is seen by the side "
        "camera as a thin strip, and its crops say other; a fence's wire row sits on no rail. "
        "Above 1 (inf): none is spared",
    )

    object_window_slices: int = param(
        20,
        ge=0,
        le=1000,
        doc="a guardrail segment is other when its wireframe component (one object, §3.2), "
        "within this many slices on either side of it (10 m in 0.5 m slices), holds at least "
        "object_min_other segments called other reaching up to its mid-height and "
        "object_max_share or less of its segments there are called guardrail: a few slices of "
        "a long fence, hedge or strip of grass that the classifier took for a rail are part of "
        "that object, not a rail of their own. At most the tile margin in slices (20 with the "
        "default 10 m), so that a tile sees the window whole; 0 turns the rule off",
    )
    object_min_other: int = param(
        15,
        ge=1,
        le=10000,
        doc="the component holds at least this many segments called other within "
        "object_window_slices of the segment (7.5 m of slices in all with the default)",
    )
    object_max_share: float = param(
        0.25,
        ge=0,
        lt=0.5,
        doc="and at most this share of its segments there are called guardrail",
    )

    inside_max_slices: int = param(
        6,
        ge=0,
        le=1000,
        doc="a guardrail segment of a wireframe component spanning at most this many slices "
        "(3 m in 0.5 m slices) that lies within the lateral and height extent (widened by "
        "fill_margin_m) of a segment in its slice whose component spans at least "
        "inside_host_min_slices, which is at most inside_host_max_width_m thick and whose "
        "P(guardrail) is under inside_host_max_probability is other: the wire rows of a mesh "
        "fence come apart from its frame in a far scan, and lie within the fence's outline. 0 "
        "turns the rule off",
    )
    inside_host_min_slices: int = param(
        10,
        ge=1,
        le=1000,
        doc="the segment it lies within is of a component spanning at least this many slices "
        "(5 m in 0.5 m slices); at most the tile margin in slices, so a tile sees that much",
    )
    inside_host_max_width_m: float = param(
        0.2,
        unit="m",
        ge=0,
        finite=False,
        doc="and that segment spans at most this much across the path: a fence or a wall, "
        "thin, whose outline holds nothing but itself, not a hedge or a bush, whose outline "
        "may hold a rail pressed into it; inf: any width",
    )
    inside_host_max_probability: float = param(
        0.1,
        ge=0,
        le=1,
        doc="and the classifier is this sure that segment is other (P(guardrail) under this)",
    )

    infill_max_slices: int = param(
        6,
        ge=0,
        le=1000,
        doc="an other segment of a wireframe component spanning at most this many slices (3 m "
        "in 0.5 m slices) that lies within the lateral and height extent (widened by "
        "fill_margin_m) of a thin guardrail segment (infill_host_max_width_m) of another "
        "component in its slice, in a run spanning at least behind_front_min_slices, becomes "
        "guardrail, whatever the classifier said: the arches, stays and diagonals between a "
        "railing's rails, thin pipes whose sparse hits the wireframe does not link to the "
        "rails, are pieces of a few slices the classifier judges alone, and one that never saw "
        "the design calls them other. Little else lies wholly inside a rail's slice: a hedge "
        "or a shrub reaches behind, in front of or above it. At most the tile margin in "
        "slices, so that a tile sees the component whole; 0 turns the rule off",
    )
    infill_host_max_width_m: float = param(
        0.2,
        unit="m",
        ge=0,
        finite=False,
        doc="the guardrail segment a piece lies within spans at most this much across the path: "
        "a pipe railing's infill lies in the plane of its rails, and its slice, rails and "
        "posts, is thin; a beam's slice with its posts and blockouts is wider and holds no "
        "infill, and what lies within it is a bicycle rack's bar behind the beam or a point "
        "of the sidewalk under it; inf: any width",
    )

    def check_relations(self) -> None:
        if np.isfinite(self.behind_gap_m) and self.behind_gap_m >= self.behind_max_m:
            self.fail(
                f"behind_gap_m ({self.behind_gap_m}) must be under behind_max_m "
                f"({self.behind_max_m}), or inf to turn the rule off"
            )


@dataclass(frozen=True)
class SegmentExtents:
    """Where each segment lies in track coordinates (see :mod:`guardrail_core.sensors.track`).

    Attributes
    ----------
    slice_index : (S,) int64, station slice of the segment
    lateral : (S, 2) float64, metres, smallest and largest lateral offset of its points (signed:
        the path is at 0)
    height : (S, 2) float64, metres, lowest and highest point above the road
    component : (S,) int64, the wireframe component (§3.2: one object) the segment was cut from
    n_points : (S,) int64, how many points it holds
    """

    slice_index: np.ndarray
    lateral: np.ndarray
    height: np.ndarray
    component: np.ndarray
    n_points: np.ndarray


def correction_reach_slices(params: CorrectionParams = CorrectionParams()) -> int:
    """How many slices away a raw label can change a corrected label, at most.

    A segment's corrected label depends only on the raw labels of segments within this many
    slices of its own (so a processing tile asks the CNN only for crops that close to the
    slices it owns). Counted step by step through :func:`correct_labels`, ``m`` being
    ``min_run_slices`` and ``f`` ``behind_front_min_slices``: the one-slice fill looks one slice
    away, at neighbours standing behind no run in front, which is settled within ``f`` slices;
    whether a run spans ``m`` slices is settled within ``m`` slices (a run that leaves them
    already spans more); the two-slice fill looks a further run test and two slices beyond; the
    isolation test of the filled labels ``m`` more; the infill (:func:`_infill`), whether its
    host's run spans ``f`` slices, ``f`` more; whether a run in front spans ``f`` slices ``f``
    more; the second isolation test ``m`` more: ``3 m + 3 f + 3`` in all. The crop veto
    (:func:`_crops_say_other`) makes a raw label depend on the crops of its component within
    ``crop_veto_max_slices`` slices (whether the component spans more is settled that far),
    and, as it may be spared for resting on a rail (:func:`_resting_on_rails`), on the
    rail's raw labels and crops ``crop_veto_max_slices`` further (twice that in all); the rule
    of a long object's few slices (:func:`_pieces_of_other_objects`) on the raw labels of its
    component within ``object_window_slices``: the larger of the two more. A
    short piece within a fence's outline (:func:`_inside_other_objects`) depends on the labels
    of its own slice alone.
    """
    rules = 3 * params.min_run_slices + 3 * params.behind_front_min_slices + 3
    veto = params.crop_veto_max_slices * (2 if params.crop_veto_rest_share <= 1 else 1)
    return rules + max(veto, params.object_window_slices)


def neighbour_pairs(
    extents: SegmentExtents, params: CorrectionParams = CorrectionParams()
) -> np.ndarray:
    """Pairs (E, 2) int64 of neighbouring segments, each pair once, first in the lower slice.

    Two segments are neighbours when their slices are equal or adjacent and both their lateral
    and height intervals come within ``touch_distance_m``.
    """
    slice_index = np.asarray(extents.slice_index, np.int64)
    if len(slice_index) == 0:
        return np.zeros((0, 2), np.int64)
    order = np.argsort(slice_index, kind="stable")
    bounds = np.searchsorted(slice_index[order], np.unique(slice_index))
    groups = dict(zip(np.unique(slice_index).tolist(), np.split(order, bounds[1:]), strict=True))
    gap = params.touch_distance_m
    pairs = []
    for k, here in groups.items():
        for other in (here, groups.get(k + 1)):
            if other is None:
                continue
            a = np.repeat(here, len(other))
            b = np.tile(other, len(here))
            touch = (
                (extents.lateral[a, 0] <= extents.lateral[b, 1] + gap)
                & (extents.lateral[b, 0] <= extents.lateral[a, 1] + gap)
                & (extents.height[a, 0] <= extents.height[b, 1] + gap)
                & (extents.height[b, 0] <= extents.height[a, 1] + gap)
            )
            if other is here:
                touch &= a < b
            pairs.append(np.stack([a[touch], b[touch]], axis=1))
    return np.concatenate(pairs).astype(np.int64)


def _guardrail_sides(
    labels: np.ndarray,
    pairs: np.ndarray,
    slice_index: np.ndarray,
    lateral: np.ndarray,
    height: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where each segment's guardrail neighbours are.

    Returns ``before`` and ``after`` (S,) bool: it has a guardrail neighbour in an earlier or a
    later slice; ``low`` and ``high`` (S, 2): the lowest and highest lateral offset and height
    of its guardrail neighbours (metres; +inf and -inf where it has none).
    """
    n = len(labels)
    before = np.zeros(n, bool)
    after = np.zeros(n, bool)
    low = np.full((n, 2), np.inf)
    high = np.full((n, 2), -np.inf)
    for a, b in ((pairs[:, 0], pairs[:, 1]), (pairs[:, 1], pairs[:, 0])):
        from_guardrail = labels[b]
        a, b = a[from_guardrail], b[from_guardrail]
        before[a[slice_index[b] < slice_index[a]]] = True
        after[a[slice_index[b] > slice_index[a]]] = True
        np.minimum.at(low, a, np.stack([lateral[b, 0], height[b, 0]], axis=1))
        np.maximum.at(high, a, np.stack([lateral[b, 1], height[b, 1]], axis=1))
    return before, after, low, high


def _run_span(labels: np.ndarray, pairs: np.ndarray, slice_index: np.ndarray) -> np.ndarray:
    """(S,) int64: how many slices the run of neighbouring guardrail segments of each guardrail
    segment spans (meaningless for other segments)."""
    n = len(labels)
    run_pairs = pairs[labels[pairs[:, 0]] & labels[pairs[:, 1]]]
    graph = coo_matrix(
        (np.ones(len(run_pairs), np.int8), (run_pairs[:, 0], run_pairs[:, 1])), shape=(n, n)
    )
    _, run = connected_components(graph, directed=False)
    guardrail = np.flatnonzero(labels)
    first = np.full(n, np.iinfo(np.int64).max)
    last = np.full(n, np.iinfo(np.int64).min)
    np.minimum.at(first, run[guardrail], slice_index[guardrail])
    np.maximum.at(last, run[guardrail], slice_index[guardrail])
    return last[run] - first[run] + 1


def _fits_between(
    lateral: np.ndarray,
    height: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    params: CorrectionParams,
) -> np.ndarray:
    """(S,) bool: segments that lie within the cross-section of their guardrail neighbours or
    are one of their posts.

    ``lateral`` and ``height`` (S, 2) are each segment's extents; ``low`` and ``high`` (S, 2)
    the lowest and highest lateral offset and height of its guardrail neighbours (infinite where
    it has none: then it does not fit).
    """
    out = np.zeros(len(lateral), bool)
    near = np.isfinite(low[:, 0])
    lateral, height, low, high = lateral[near], height[near], low[near], high[near]
    margin, post, reach = params.fill_margin_m, params.post_width_m, params.post_min_reach
    below_top = height[:, 1] <= high[:, 1] + margin
    within = (
        (lateral[:, 0] >= low[:, 0] - margin)
        & (lateral[:, 1] <= high[:, 0] + margin)
        & (height[:, 0] >= low[:, 1] - margin)
        & below_top
    )
    is_post = (
        (height[:, 0] <= params.post_foot_m)
        & (lateral[:, 0] >= low[:, 0] - post)
        & (lateral[:, 1] <= high[:, 0] + post)
        & (height[:, 1] >= (1 - reach) * low[:, 1] + reach * high[:, 1])
        & below_top
    )
    # The stub of a post under a low rail (the rest of the post is of the rail's segment).
    is_stub = (
        (height[:, 0] <= params.post_foot_m)
        & (lateral[:, 0] >= low[:, 0] - post)
        & (lateral[:, 1] <= high[:, 0] + post)
        & (height[:, 1] >= low[:, 1] - params.post_stub_gap_m)
        & (height[:, 1] >= params.post_stub_min_top_m)
        & below_top
        & (params.post_stub_gap_m > 0)
    )
    out[near] = within | is_post | is_stub
    return out


def _expand_ranges(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every position of the ranges ``[lo[k], hi[k])`` (K,) int: (P,) the range each belongs to
    and (P,) the position itself, ranges in order."""
    count = hi - lo
    owner = np.repeat(np.arange(len(lo)), count)
    return owner, np.arange(count.sum()) - np.repeat(np.cumsum(count) - count - lo, count)


def _fronts(
    labels: np.ndarray,
    pairs: np.ndarray,
    extents: SegmentExtents,
    params: CorrectionParams,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each segment's side of the path (S,) int (1 right, -1 left, 0 straddling it), its
    nearest and farthest reach from the path (S,) metres, and whether it is a front (S,) bool:
    a guardrail segment wholly on one side, of at least ``behind_front_min_points`` points, in a
    run spanning at least ``behind_front_min_slices`` slices."""
    lateral = np.asarray(extents.lateral, np.float64)
    side = np.where(lateral[:, 0] > 0, 1, np.where(lateral[:, 1] < 0, -1, 0))
    nearest = np.where(side > 0, lateral[:, 0], -lateral[:, 1])
    farthest = np.where(side > 0, lateral[:, 1], -lateral[:, 0])
    front = labels & (side != 0) & (np.asarray(extents.n_points) >= params.behind_front_min_points)
    slice_index = np.asarray(extents.slice_index, np.int64)
    front &= _run_span(labels, pairs, slice_index) >= params.behind_front_min_slices
    return side, nearest, farthest, front


def _behind_a_run(
    labels: np.ndarray,
    pairs: np.ndarray,
    extents: SegmentExtents,
    params: CorrectionParams,
) -> np.ndarray:
    """(S,) bool: guardrail segments that stand behind a run of guardrail of another component.

    A front is a guardrail segment wholly on one side of the path, of at least
    ``behind_front_min_points`` points, in a run spanning at least ``behind_front_min_slices``
    slices. Guardrail segment ``i``, wholly on one side, stands behind when for some other
    wireframe component than its own, the fronts of that component in its slice and on its
    side reach at most to ``i``'s nearest point less ``behind_gap_m`` (less nothing when ``i``
    spans ``behind_wide_m`` or more across), and at least to it less ``behind_max_m`` (metres
    from the path): it stands behind that object's slice as a whole.
    """
    out = np.zeros(len(labels), bool)
    if not np.isfinite(params.behind_gap_m):
        return out
    slice_index = np.asarray(extents.slice_index, np.int64)
    component = np.asarray(extents.component, np.int64)
    side, nearest, farthest, front = _fronts(labels, pairs, extents, params)
    # The farthest reach of the fronts of each (slice, side, component); then each candidate
    # against those of its slice and side, of another component than its own.
    candidates = np.flatnonzero(labels & (side != 0))
    fronts = np.flatnonzero(front)
    if len(candidates) == 0 or len(fronts) == 0:
        return out
    fronts = fronts[np.lexsort((component[fronts], side[fronts], slice_index[fronts]))]
    key = np.stack([slice_index[fronts], side[fronts], component[fronts]], axis=1)
    starts = np.flatnonzero(np.r_[True, (np.diff(key, axis=0) != 0).any(axis=1)])
    group_far = np.maximum.reduceat(farthest[fronts], starts)
    group_place = key[starts, 0] * 2 + (key[starts, 1] > 0)  # (slice, side) as one sorted key
    place = slice_index[candidates] * 2 + (side[candidates] > 0)
    lo = np.searchsorted(group_place, place, side="left")
    hi = np.searchsorted(group_place, place, side="right")
    owner, group = _expand_ranges(lo, hi)
    who = candidates[owner]
    behind = nearest[who] - group_far[group]
    wide = farthest - nearest >= params.behind_wide_m
    gap = (behind > params.behind_gap_m) | (wide[who] & (behind >= 0.0))
    hit = (key[starts, 2][group] != component[who]) & gap & (behind <= params.behind_max_m)
    out[who[hit]] = True
    return out


def _behind_its_own_rail(
    labels: np.ndarray,
    pairs: np.ndarray,
    extents: SegmentExtents,
    params: CorrectionParams,
) -> np.ndarray:
    """(S,) bool: guardrail segments spanning ``behind_own_wide_m`` or more across that stand
    more than ``behind_gap_m`` and at most ``behind_max_m`` behind a front (as for
    :func:`_behind_a_run`) of their own component in their slice."""
    n = len(labels)
    out = np.zeros(n, bool)
    if not (np.isfinite(params.behind_gap_m) and np.isfinite(params.behind_own_wide_m)):
        return out
    slice_index = np.asarray(extents.slice_index, np.int64)
    _, component = np.unique(np.asarray(extents.component), return_inverse=True)
    side, nearest, farthest, front = _fronts(labels, pairs, extents, params)
    wide = labels & (side != 0) & (farthest - nearest >= params.behind_own_wide_m)
    if not wide.any() or not front.any():
        return out
    # Pairs (a, b): a wide segment and a front of the same (slice, side, component).
    members = np.flatnonzero(wide | front)
    key = (slice_index[members] - slice_index.min()) * 2 + (side[members] > 0)
    key = key * (int(component.max()) + 1) + component[members]
    order = np.argsort(key, kind="stable")
    members, key = members[order], key[order]
    candidates = np.flatnonzero(wide[members])
    lo = np.searchsorted(key, key[candidates], side="left")
    hi = np.searchsorted(key, key[candidates], side="right")
    owner, position = _expand_ranges(lo, hi)
    a, b = members[candidates[owner]], members[position]
    behind = nearest[a] - farthest[b]
    hit = front[b] & (behind > params.behind_gap_m) & (behind <= params.behind_max_m)
    out[a[hit]] = True
    return out


def _pieces_of_other_objects(
    labels: np.ndarray, extents: SegmentExtents, params: CorrectionParams
) -> np.ndarray:
    """(S,) bool: guardrail segments whose wireframe component, within
    ``object_window_slices`` slices on either side, holds at least ``object_min_other`` other
    segments reaching across the segment's mid-height and at most ``object_max_share``
    guardrail ones (the segment itself counted) among those and its guardrail segments there.

    The other segments must reach across the segment's height: a rail joined through its posts
    to a long curb or strip of verge is one component with them, but it stands above them."""
    n = len(labels)
    window = params.object_window_slices
    if window == 0 or n == 0:
        return np.zeros(n, bool)
    _, component = np.unique(np.asarray(extents.component), return_inverse=True)
    slice_index = np.asarray(extents.slice_index, np.int64)
    height = np.asarray(extents.height, np.float64)
    # Pairs (a, b) of segments of one component within the window of a: the segments of each
    # component in order of their slices, a's window a run of them.
    stride = int(slice_index.max() - slice_index.min()) + 2 * window + 2
    key = component.astype(np.int64) * stride + (slice_index - slice_index.min() + window)
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    candidates = np.flatnonzero(labels)
    lo = np.searchsorted(sorted_key, key[candidates] - window, side="left")
    hi = np.searchsorted(sorted_key, key[candidates] + window, side="right")
    owner, position = _expand_ranges(lo, hi)
    a, b = candidates[owner], order[position]
    middle = height[a].mean(axis=1)
    across = ~labels[b] & (middle <= height[b, 1])
    n_other = np.bincount(a, weights=across, minlength=n)
    n_guardrail = np.bincount(a, weights=labels[b], minlength=n)
    return (
        labels
        & (n_other >= params.object_min_other)
        & (n_guardrail <= params.object_max_share * (n_guardrail + n_other))
    )


def _component_spans(extents: SegmentExtents) -> np.ndarray:
    """(S,) int64: how many slices each segment's wireframe component spans (first to last)."""
    _, component = np.unique(np.asarray(extents.component), return_inverse=True)
    slice_index = np.asarray(extents.slice_index, np.int64)
    k = int(component.max()) + 1
    first = np.full(k, np.iinfo(np.int64).max)
    last = np.full(k, np.iinfo(np.int64).min)
    np.minimum.at(first, component, slice_index)
    np.maximum.at(last, component, slice_index)
    return (last - first + 1)[component]


def _inside_other_objects(
    labels: np.ndarray,
    extents: SegmentExtents,
    probability: np.ndarray,
    params: CorrectionParams,
) -> np.ndarray:
    """(S,) bool: guardrail segments of short components (``inside_max_slices``) lying within
    the extent, widened by ``fill_margin_m``, of a segment in their slice of another component
    spanning ``inside_host_min_slices`` or more, P(guardrail) under
    ``inside_host_max_probability``."""
    n = len(labels)
    if params.inside_max_slices == 0 or n == 0:
        return np.zeros(n, bool)
    span = _component_spans(extents)
    piece = labels & (span <= params.inside_max_slices)
    width = np.diff(np.asarray(extents.lateral, np.float64), axis=1)[:, 0]
    host = (
        ~labels
        & (span >= params.inside_host_min_slices)
        & (width <= params.inside_host_max_width_m)
        & (probability < params.inside_host_max_probability)
    )
    return _within_in_slice(piece, host, extents, params.fill_margin_m)


def _within_in_slice(
    piece: np.ndarray, host: np.ndarray, extents: SegmentExtents, margin: float
) -> np.ndarray:
    """(S,) bool: the ``piece`` segments (S,) bool lying within the lateral and height extent,
    widened by ``margin`` (metres), of a ``host`` segment (S,) bool of another wireframe
    component in their slice."""
    out = np.zeros(len(piece), bool)
    if not piece.any() or not host.any():
        return out
    slice_index = np.asarray(extents.slice_index, np.int64)
    component = np.asarray(extents.component)
    lateral = np.asarray(extents.lateral, np.float64)
    height = np.asarray(extents.height, np.float64)
    hosts = np.flatnonzero(host)
    hosts = hosts[np.argsort(slice_index[hosts], kind="stable")]
    pieces = np.flatnonzero(piece)
    lo = np.searchsorted(slice_index[hosts], slice_index[pieces], side="left")
    hi = np.searchsorted(slice_index[hosts], slice_index[pieces], side="right")
    owner, position = _expand_ranges(lo, hi)
    a, b = pieces[owner], hosts[position]
    within = (
        (component[a] != component[b])
        & (lateral[a, 0] >= lateral[b, 0] - margin)
        & (lateral[a, 1] <= lateral[b, 1] + margin)
        & (height[a, 0] >= height[b, 0] - margin)
        & (height[a, 1] <= height[b, 1] + margin)
    )
    out[a[within]] = True
    return out


def _infill(
    labels: np.ndarray, span: np.ndarray, extents: SegmentExtents, params: CorrectionParams
) -> np.ndarray:
    """(S,) bool: other segments of short components (``infill_max_slices``) lying within the
    extent, widened by ``fill_margin_m``, of a guardrail segment of another component in their
    slice, at most ``infill_host_max_width_m`` across, in a run spanning
    ``behind_front_min_slices`` or more (``span`` (S,): each guardrail segment's run, from
    :func:`_run_span`)."""
    if params.infill_max_slices == 0 or len(labels) == 0:
        return np.zeros(len(labels), bool)
    piece = ~labels & (_component_spans(extents) <= params.infill_max_slices)
    width = np.diff(np.asarray(extents.lateral, np.float64), axis=1)[:, 0]
    host = (
        labels
        & (width <= params.infill_host_max_width_m)
        & (span >= params.behind_front_min_slices)
    )
    return _within_in_slice(piece, host, extents, params.fill_margin_m)


def _crops_say_other(
    extents: SegmentExtents, crop_probability: np.ndarray, params: CorrectionParams
) -> np.ndarray:
    """(S,) bool: segments of a wireframe component spanning at most ``crop_veto_max_slices``
    slices of which at least ``crop_veto_min_crops`` have a crop probability (finite) and at
    least ``crop_veto_share`` of those are under 0.5."""
    n = len(crop_probability)
    if params.crop_veto_max_slices == 0 or n == 0:
        return np.zeros(n, bool)
    _, component = np.unique(np.asarray(extents.component), return_inverse=True)
    has_crop = np.isfinite(crop_probability)
    crops = np.bincount(component, weights=has_crop)[component]
    other = np.bincount(component, weights=has_crop & (crop_probability < 0.5))[component]
    return (
        (_component_spans(extents) <= params.crop_veto_max_slices)
        & (crops >= params.crop_veto_min_crops)
        & (other >= params.crop_veto_share * crops)
    )


def _resting_on_rails(
    labels: np.ndarray, veto: np.ndarray, extents: SegmentExtents, params: CorrectionParams
) -> np.ndarray:
    """(S,) bool: the ``veto`` segments (S,) bool of components of which at least
    ``crop_veto_rest_share`` of the segments are at most ``infill_host_max_width_m`` across and
    lie within the lateral extent, widened by ``fill_margin_m``, and ``touch_distance_m`` in
    height of a guardrail segment (``labels`` (S,) bool), not vetoed, of another component
    spanning ``behind_front_min_slices`` or more in their slice."""
    n = len(labels)
    if not np.isfinite(params.crop_veto_rest_share) or not veto.any():
        return np.zeros(n, bool)
    lateral = np.asarray(extents.lateral, np.float64)
    height = np.asarray(extents.height, np.float64)
    piece = veto & (lateral[:, 1] - lateral[:, 0] <= params.infill_host_max_width_m)
    host = labels & ~veto & (_component_spans(extents) >= params.behind_front_min_slices)
    if not piece.any() or not host.any():
        return np.zeros(n, bool)
    slice_index = np.asarray(extents.slice_index, np.int64)
    _, component = np.unique(np.asarray(extents.component), return_inverse=True)
    hosts = np.flatnonzero(host)
    hosts = hosts[np.argsort(slice_index[hosts], kind="stable")]
    pieces = np.flatnonzero(piece)
    lo = np.searchsorted(slice_index[hosts], slice_index[pieces], side="left")
    hi = np.searchsorted(slice_index[hosts], slice_index[pieces], side="right")
    owner, position = _expand_ranges(lo, hi)
    a, b = pieces[owner], hosts[position]
    margin = params.fill_margin_m
    gap = np.maximum(height[a, 0] - height[b, 1], height[b, 0] - height[a, 1])
    rests = (
        (component[a] != component[b])
        & (lateral[a, 0] >= lateral[b, 0] - margin)
        & (lateral[a, 1] <= lateral[b, 1] + margin)
        & (gap <= params.touch_distance_m)
    )
    resting = np.zeros(n, bool)
    resting[a[rests]] = True
    total = np.bincount(component)
    share = np.bincount(component, weights=resting, minlength=len(total)) / total
    return veto & (share[component] >= params.crop_veto_rest_share)


def correct_labels(
    labels: np.ndarray,
    extents: SegmentExtents,
    params: CorrectionParams = CorrectionParams(),
    probability: np.ndarray | None = None,
    crop_probability: np.ndarray | None = None,
) -> np.ndarray:
    """Correct raw segment labels by their neighbours.

    Parameters
    ----------
    labels : (S,) bool, raw labels (True: guardrail)
    extents : where the segments lie
    params : the rules
    probability : (S,) float, the classifier's P(guardrail) of each segment (NaN: no answer), or
        None (none known: every other segment may be filled); segments under
        ``params.fill_min_probability`` are not filled
    crop_probability : (S,) float, the crop classifier's P(guardrail) of each crop the segment
        head weighed (NaN: none, or the shape decided alone;
        :func:`~guardrail_core.extract.segment_scores.weighed_crop_probability`), or None (the
        crop veto is not applied): every segment of a short component whose crops say other
        becomes other and is not filled (``crop_veto_max_slices``)

    Returns
    -------
    (S,) bool, corrected labels.

    References
    ----------
    Matsumoto et al. 2019, §3.3 (an isolated guardrail segment is regarded as other; other
    segments among consecutive guardrail segments are regarded as guardrail).
    """
    labels = np.asarray(labels, bool).copy()
    n = len(labels)
    for name, array in (
        ("slice_index", extents.slice_index),
        ("lateral", extents.lateral),
        ("height", extents.height),
        ("component", extents.component),
        ("n_points", extents.n_points),
    ):
        if len(array) != n:
            raise InvalidOptionError(f"correct_labels: {n} labels but {len(array)} rows of {name}")
    for name, values in (("probabilities", probability), ("crop probabilities", crop_probability)):
        if values is not None and np.shape(values) != (n,):
            raise InvalidOptionError(
                f"correct_labels: {n} labels but {name} of shape {np.shape(values)}"
            )
    if n == 0:
        return labels
    fillable = np.ones(n, bool)
    if probability is not None:
        fillable = ~(np.asarray(probability, np.float64) < params.fill_min_probability)  # NaN: yes

    # Beyond the paper: a short component whose crops say other is other, however its shape
    # looks; nothing of it is filled either. One resting on another component's rail is a
    # railing's rail the wireframe kept apart, whose thin strip the crops misread.
    if crop_probability is not None:
        say_other = _crops_say_other(extents, np.asarray(crop_probability, np.float64), params)
        say_other &= ~_resting_on_rails(labels, say_other, extents, params)
        labels &= ~say_other
        fillable &= ~say_other
    # Beyond the paper: a few slices of a long object called other are part of that object,
    # and so is a short piece lying within the outline of one.
    piece = _pieces_of_other_objects(labels, extents, params)
    if probability is not None:
        piece |= _inside_other_objects(labels, extents, np.asarray(probability, np.float64), params)
    labels &= ~piece
    fillable &= ~piece
    slice_index = np.asarray(extents.slice_index, np.int64)
    pairs = neighbour_pairs(extents, params)

    # §3.3: an other segment inside a run becomes guardrail: it has guardrail neighbours in the
    # slices before and after it and lies within their cross-section (or is a post).
    lateral = np.asarray(extents.lateral, np.float64)
    height = np.asarray(extents.height, np.float64)
    # What stands behind a run of another component does not widen the cross-section a
    # hole is filled within (it becomes other below).
    standing = labels & ~_behind_a_run(labels, pairs, extents, params)
    before, after, _, _ = _guardrail_sides(labels, pairs, slice_index, lateral, height)
    _, _, low, high = _guardrail_sides(standing, pairs, slice_index, lateral, height)
    fits = _fits_between(lateral, height, low, high, params) & fillable
    fill = ~labels & before & after & fits
    if params.max_hole_slices == 2:
        # Two other segments in consecutive slices, each fitting the guardrail on its side,
        # where that guardrail is a run of its own (holes of one filled): two isolated segments
        # three slices apart do not make a run.
        filled = labels | fill
        in_run = filled & (_run_span(filled, pairs, slice_index) >= params.min_run_slices)
        run_before, run_after, _, _ = _guardrail_sides(in_run, pairs, slice_index, lateral, height)
        a, b = pairs[:, 0], pairs[:, 1]  # a in the lower slice
        two = (slice_index[b] == slice_index[a] + 1) & ~labels[a] & ~labels[b]
        two &= run_before[a] & fits[a] & run_after[b] & fits[b]
        fill[a[two]] = True
        fill[b[two]] = True
    labels |= fill

    # §3.3: an isolated guardrail segment becomes other. Holes are filled first, so that a
    # misclassified segment next to a run's end does not leave the end segment isolated.
    span = _run_span(labels, pairs, slice_index)
    labels[labels & (span < params.min_run_slices)] = False
    # Beyond the paper: a short piece wholly inside a rail's slice is the railing's infill (the
    # runs left keep their spans: what the isolation test took were runs of their own).
    labels |= _infill(labels, span, extents, params)

    # What stands behind a run of another object is not guardrail, nor what stands behind its
    # own rail wider than any of a rail's parts; what it leaves of a run too short is isolated.
    behind = _behind_a_run(labels, pairs, extents, params)
    behind |= _behind_its_own_rail(labels, pairs, extents, params)
    if behind.any():
        labels[behind] = False
        span = _run_span(labels, pairs, slice_index)
        labels[labels & (span < params.min_run_slices)] = False
    return labels
