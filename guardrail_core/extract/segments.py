"""Segments (§3.1): the lattice wireframe, its connected components, and what a segment is.

Lattice neighbours closer than a distance threshold are joined by an edge; small fragments join
the component they touch. :mod:`guardrail_core.extract.slices` cuts the components into 0.5 m
slices, the segments (:class:`Segments`); each kept point ends in exactly one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from scipy.spatial import cKDTree

from guardrail_core.extract.lattice import Lattice, neighbour_at
from guardrail_core.params import StageParams, param


@dataclass(frozen=True)
class SegmentParams(StageParams):
    """Thresholds of the wireframe and the slicing."""

    link_distance_m: float = param(
        0.3, unit="m", gt=0, le=10, doc="lattice neighbours closer than this are joined"
    )
    along_reach: int = param(
        3,
        ge=1,
        le=100,
        doc="along a scan line, the next this many pulses are neighbours (bridges dropped returns)",
    )
    rotation_reach: int = param(
        2,
        ge=0,
        le=100,
        doc="the next this many scan lines hold neighbours (bridges a scan line that missed)",
    )
    phase_reach: int = param(
        4,
        ge=0,
        le=1000,
        doc="on those scan lines, pulses up to this many phases either side are neighbours, so "
        "a thin pipe or a beam edge whose hit drifts with the vehicle's vibration stays "
        "connected",
    )
    fragment_points: int = param(
        10,
        ge=1,
        le=1_000_000,
        doc="components of fewer points are fragments: the scattered hits of a thin pipe, a "
        "pole's far side or a diagonal that the scan lines cross only here and there",
    )
    fragment_reach_m: float = param(
        0.3,
        unit="m",
        ge=0,
        le=10,
        doc="a fragment joins the larger component that comes closest to it within this reach "
        "(0: fragments stay apart, as in the paper)",
    )
    ground_fragment_points: int = param(
        30,
        ge=0,
        le=1_000_000,
        doc="a component of fewer points that lies wholly below ground_fragment_top_m is a "
        "fragment too: where road removal takes the band of a far post just above the "
        "sidewalk, the post's foot and the sidewalk around it form a component of their own "
        "(5-20 points, half of them sidewalk), cut off from the post. Joined to the post it "
        "belongs to; alone it is a segment the classifier calls guardrail, a false alarm or "
        "not by a point or two. 0: only fragment_points counts",
    )
    ground_fragment_top_m: float = param(
        0.25,
        unit="m",
        ge=0,
        le=10,
        doc="metres above the road under which a component's highest point lies for "
        "ground_fragment_points (RoadParams.height_tolerance_m: the band where road removal "
        "judges points as ground). A bottom rail 0.15-0.2 m high has its few hits there too; "
        "they join its posts or balusters, as a thin pipe's fragments do",
    )
    slice_length_m: float = param(
        0.5,
        unit="m",
        gt=0,
        le=100,
        doc="section planes perpendicular to the trajectory cut components every this many "
        "metres (the paper's 0.5 m)",
    )
    max_width_m: float = param(
        1.0,
        unit="m",
        ge=0,
        le=100,
        doc="a slice wider than this across the trajectory holds things side by side that "
        "something joins (a median's two rails and the hedge between them; a rail against a "
        "bush): it is cut where its points thin out across the trajectory (see valley_share); "
        "0 turns this off. A guardrail's slice, posts included, is at most about 0.5 m wide",
    )
    width_bin_m: float = param(
        0.1,
        unit="m",
        gt=0,
        le=10,
        doc="bins of the lateral offset in which a wide slice's density is measured",
    )
    valley_share: float = param(
        0.1,
        ge=0,
        le=1,
        doc="a bin holding at most this share of the fullest bin's points is a valley bin",
    )
    min_valley_m: float = param(
        0.3,
        unit="m",
        ge=0,
        le=100,
        doc="a wide slice is cut on both sides of every run of valley bins at least this wide "
        "(each such run is a piece of its own); narrower thin stretches (a post behind its "
        "rail, the dip between a beam's ridges) do not cut",
    )
    gap_width_m: float = param(
        0.6,
        unit="m",
        ge=0,
        le=100,
        doc="a slice wider than this across the trajectory is also cut at every empty gap of "
        "min_gap_m or more beside a piece of gap_piece_m: a hedge or a bush just behind a rail, "
        "which a link of link_distance_m joins to it, with no wide valley between them; 0 turns "
        "this off. A guardrail's slice (a beam and its posts) is narrower",
    )
    min_gap_m: float = param(
        0.1,
        unit="m",
        gt=0,
        le=100,
        doc="an empty stretch across the trajectory at least this wide cuts a slice wider than "
        "gap_width_m, where the points on one side of it span gap_piece_m or more",
    )
    gap_piece_m: float = param(
        0.4,
        unit="m",
        ge=0,
        le=100,
        doc="a gap cuts only beside a piece at least this wide across (a hedge, a bush): a post "
        "0.1-0.3 m behind its beam, or the scattered hits of a sparse scan's post, stay with it",
    )
    front_layer_m: float = param(
        0.08,
        unit="m",
        ge=0,
        le=100,
        doc="a slice (or piece) is also cut this far behind its front (the side nearest the "
        "trajectory) where what lies behind is a mass of its own: it spans "
        "front_behind_min_width_m across and front_behind_min_length_m along the slice, and "
        "holds front_behind_ratio times the front's points. A hedge or a bush that touches the "
        "back of a rail, or stands just behind it: seen from across the road, only its face, "
        "0.1-0.4 m deep, and the rail make the slice. The part behind becomes a component of "
        "its own (the wireframe joined two objects); 0 turns this off",
    )
    front_behind_min_width_m: float = param(
        0.1,
        unit="m",
        ge=0,
        le=100,
        doc="a slice is cut behind its front (front_layer_m) only where what lies behind spans "
        "at least this much across: the face of a hedge seen from across the road spans "
        "0.1-0.4 m",
    )
    front_behind_min_length_m: float = param(
        0.25,
        unit="m",
        ge=0,
        le=100,
        doc="a slice is cut behind its front (front_layer_m) only where what lies behind spans "
        "at least this much along the trajectory (from a tenth to nine tenths of its points, "
        "so a stray point does not stretch it): a hedge fills the 0.5 m slice, while a pole "
        "or a beam's post behind the rail's face is at most 0.15 m thick",
    )
    front_min_height_m: float = param(
        0.25,
        unit="m",
        ge=0,
        le=100,
        doc="a slice is cut behind its front (front_layer_m) only where the front spans at least "
        "this much in height: a rail's face does (a W-beam is 0.31 m tall, a pipe rail's pipes "
        "and posts more), the bulge of a hedge or a car's flank nearest the road is a thinner "
        "band",
    )
    front_min_points: int = param(
        20,
        ge=1,
        le=1_000_000,
        doc="a slice is cut behind its front (front_layer_m) only where the front holds at "
        "least this many points: a sparse scan's few hits on the near side of a bush are too "
        "little shape to judge apart from the rest",
    )
    front_behind_ratio: float = param(
        1.5,
        gt=0,
        le=1000,
        doc="a slice is cut behind its front (front_layer_m) only where what lies behind holds "
        "at least this many times the points of the front: a hedge is bigger than the rail it "
        "backs, while a deep beam's back half and its post hold fewer points than its face",
    )
    curb_gap_m: float = param(
        0.15,
        unit="m",
        ge=0,
        le=10,
        doc="a component's 0.5 m slice holds a curb under an empty band at least this tall "
        "across it where what lies below is a curb's: no higher than curb_top_m, in front of "
        "all that stands above the band, spanning curb_min_length_m along the slice and holding "
        "curb_min_points, curb-shaped (curb_max_width_m, curb_max_rise_m). A rail set just "
        "behind a curb is joined to it by its posts, and where no post is in the slice the "
        "rail and the curb are one segment of two objects with nothing between them (a "
        "W-beam's plate starts 0.4 m above the curb). That curb, and the rest of it "
        "(curb_front_m), are linked apart from the rest of the component "
        "(guardrail_core/extract/curbs.py). 0 turns this off. A pipe guardrail's bottom rail "
        "lies under its top rail, not in front of it",
    )
    curb_top_m: float = param(
        0.3,
        unit="m",
        ge=0,
        le=10,
        doc="what curb_gap_m cuts off lies wholly at most this far above the road (a curb is "
        "0.1-0.2 m tall)",
    )
    curb_min_length_m: float = param(
        0.25,
        unit="m",
        ge=0,
        le=100,
        doc="what curb_gap_m cuts off spans at least this much along the trajectory (from a "
        "tenth to nine tenths of its points): a curb runs through the slice",
    )
    curb_max_width_m: float = param(
        0.3,
        unit="m",
        ge=0,
        le=10,
        doc="what curb_gap_m and curb_front_m take as curb spans at most this much across the "
        "trajectory in its slice (from a tenth to nine tenths of its points): a curb's face and "
        "top do, 0.1-0.25 m with the road's edge before it; grass and the ground before a "
        "fence spread wider (a fence cut from them looked like a rail to the classifier)",
    )
    curb_max_rise_m: float = param(
        0.25,
        unit="m",
        ge=0,
        le=10,
        doc="what curb_gap_m and curb_front_m take as curb rises at most this much in its slice "
        "(from a tenth to nine tenths of its points): a curb's face is 0.1-0.2 m tall; the "
        "ground before a fence on an embankment's slope or a ditch's rises more",
    )
    curb_front_m: float = param(
        0.03,
        unit="m",
        ge=0,
        le=10,
        doc="in the slices of a component with a curb cut by curb_gap_m, what lies no higher "
        "than curb_top_m and at least this much in front of nine tenths of what stands higher "
        "is curb too: the curb where a post fills the band (the post's foot stands behind the "
        "rail's face, a pipe rail's bottom rail in its plane), and the curb between two rails",
    )
    curb_min_points: int = param(
        5,
        ge=1,
        le=1_000_000,
        doc="what curb_gap_m cuts off holds at least this many points",
    )
    chain_gap_m: float = param(
        0.1,
        unit="m",
        ge=0,
        le=10,
        doc="a segment's chain features (its length along the road, slices, heights and lateral "
        "course) are taken over its chain: the pieces of its component in consecutive slices "
        "whose ranges across the trajectory come within this much of each other "
        "(guardrail_core/extract/classify/piece_chains.py). Over the whole component, a rail "
        "and the hedge grown into it, cut apart in every slice, shared one 1.8 m high, 0.4 m wide "
        "description, and a model that had not seen the rail's design took it for hedge: with "
        "chains, designs left out of training went from guardrail F 0.922 to 0.951 "
        "(beam_thrie), 0.919 to 0.951 (beam_w) and 0.880 to 0.915 (pipe_ladder; README, leave "
        "one design out). A pipe rail's pipes, stacked in one range, stay one chain. Models "
        "trained before chains (the shipped default model among them) read the same features "
        "over whole components, which are computed for them",
    )


@dataclass(frozen=True)
class Segments:
    """Points grouped into sliced segments, with a per-segment summary.

    Segment ids run from 0 to S - 1, ordered along the trajectory (by slice, then component).

    Attributes
    ----------
    point_segment : (N,) int32, segment of every input point, -1 for points not kept
    point_component : (N,) int32, connected component of every point, -1 for points not kept;
        what was cut from behind a front (``SegmentParams.front_layer_m``) is a component of its
        own, numbered C + c for component c of the C that the wireframe made
    component : (S,) int32, the component each segment was cut from (as ``point_component``)
    slice_index : (S,) int64, station slice: the segment lies in
        [slice_index * slice_length_m, (slice_index + 1) * slice_length_m) along the trajectory
    n_points : (S,) int64
    order : (K,) int64, indices of the kept points sorted by segment
    starts : (S + 1,) int64, segment s owns ``order[starts[s]:starts[s + 1]]``
    """

    point_segment: np.ndarray
    point_component: np.ndarray
    component: np.ndarray
    slice_index: np.ndarray
    n_points: np.ndarray
    order: np.ndarray
    starts: np.ndarray

    def __len__(self) -> int:
        return int(len(self.n_points))

    def members(self, segment: int) -> np.ndarray:
        """Point indices (n,) int64 of one segment."""
        return self.order[self.starts[segment] : self.starts[segment + 1]]


def wireframe_components(
    xyz: np.ndarray, kept: np.ndarray, lattice: Lattice, params: SegmentParams = SegmentParams()
) -> np.ndarray:
    """Connected components of the lattice wireframe over the kept points.

    Parameters
    ----------
    xyz : (N, 3) float64, metres
    kept : (N,) bool, the points to connect (road removed)
    lattice : the scan lattice of all N points
    params : link distance and the lattice window of neighbours

    Returns
    -------
    (N,) int32 component of every point, numbered 0.. in order of first point; -1 where not kept.

    References
    ----------
    Matsumoto et al. 2019, §3.1 (wireframe model on the 2D lattice, connected components).
    """
    xyz = np.asarray(xyz, np.float64)
    kept = np.asarray(kept, bool)
    max_sq = params.link_distance_m**2
    # Each undirected edge once: forward along the scan line, and nearby pulses of later lines.
    offsets = [(0, d) for d in range(1, params.along_reach + 1)] + [
        (r, d)
        for r in range(1, params.rotation_reach + 1)
        for d in range(-params.phase_reach, params.phase_reach + 1)
    ]
    phases = lattice.phases
    step = np.array([d_rotation * phases + d_phase for d_rotation, d_phase in offsets], np.int64)
    root = _link(xyz, kept, lattice.cell, lattice.grid.ravel(), step, max_sq)
    return _renumber(root, kept)


# Compiled: a union-find over the wireframe's edges as the lattice gives them, in one pass per
# point, instead of an edge list per lattice offset and a sparse graph (the same components:
# :func:`_renumber` numbers them by first point, whatever the roots).
@numba.njit(cache=True, nogil=True)
def _link(
    xyz: np.ndarray,
    kept: np.ndarray,
    cell: np.ndarray,
    grid: np.ndarray,
    step: np.ndarray,
    max_sq: float,
) -> np.ndarray:  # pragma: no cover - compiled
    """(N,) int64: a root point of every kept point's component (each point its own root where
    not kept). ``step`` (K,): the flat lattice offsets of the edges each point links forward."""
    n = len(kept)
    parent = np.arange(n)
    for a in range(n):
        if not kept[a]:
            continue
        for k in range(len(step)):
            b = neighbour_at(cell[a], step[k], grid)
            if b < 0 or not kept[b]:
                continue
            d0 = xyz[a, 0] - xyz[b, 0]
            d1 = xyz[a, 1] - xyz[b, 1]
            d2 = xyz[a, 2] - xyz[b, 2]
            if d0 * d0 + d1 * d1 + d2 * d2 >= max_sq:
                continue
            # Union by pointing the larger root at the smaller, halving paths on the way.
            ra = a
            while parent[ra] != ra:
                parent[ra] = parent[parent[ra]]
                ra = parent[ra]
            rb = b
            while parent[rb] != rb:
                parent[rb] = parent[parent[rb]]
                rb = parent[rb]
            if ra < rb:
                parent[rb] = ra
            elif rb < ra:
                parent[ra] = rb
    for a in range(n):
        r = a
        while parent[r] != r:
            r = parent[r]
        parent[a] = r
    return parent


def _renumber(labels: np.ndarray, kept: np.ndarray) -> np.ndarray:
    """(N,) int32: the labels of kept points renumbered 0.. in order of first point, else -1."""
    component = np.full(len(labels), -1, np.int32)
    _, first, inverse = np.unique(labels[kept], return_index=True, return_inverse=True)
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    component[kept] = rank[inverse]
    return component


def absorb_fragments(
    xyz: np.ndarray,
    component: np.ndarray,
    params: SegmentParams = SegmentParams(),
    height: np.ndarray | None = None,
) -> np.ndarray:
    """Join each small component to the nearest larger one within reach.

    The wireframe leaves a thin pipe's sparse hits as many components of a few points each; as
    their own 0.5 m segments they are too small to crop and classify, though they lie beside the
    rail they belong to. A fragment (fewer than ``fragment_points`` points, or with ``height``
    fewer than ``ground_fragment_points`` all below ``ground_fragment_top_m``: a far post's
    foot cut off from it with the sidewalk around it) joins the component that is no fragment
    and comes closest to any of its points, if within ``fragment_reach_m``; otherwise it stays
    as it is.

    Parameters
    ----------
    xyz : (N, 3) float64, metres
    component : (N,) int, component of every point from :func:`wireframe_components`, -1 for
        points not kept
    height : (N,) float64, metres above the road, or None (no ground fragments)

    Returns
    -------
    (N,) int32 components, renumbered densely in order of first point; -1 where not kept.
    """
    component = np.asarray(component, np.int64)
    kept = component >= 0
    if params.fragment_reach_m <= 0 or not kept.any():
        return component.astype(np.int32)
    size = np.bincount(component[kept])
    is_fragment = size < params.fragment_points
    if height is not None:
        top = np.full(len(size), -np.inf)
        np.maximum.at(top, component[kept], np.asarray(height, np.float64)[kept])
        is_fragment |= (size < params.ground_fragment_points) & (top < params.ground_fragment_top_m)
    small = kept & is_fragment[np.maximum(component, 0)]
    large = np.flatnonzero(kept & ~small)
    fragment = np.flatnonzero(small)
    merged = component.copy()
    if len(large) and len(fragment):
        distance, nearest = cKDTree(xyz[large]).query(
            xyz[fragment], distance_upper_bound=params.fragment_reach_m
        )
        reached = np.isfinite(distance)
        owner = component[fragment]
        closest = np.full(len(size), np.inf)
        np.minimum.at(closest, owner[reached], distance[reached])
        # The point of the fragment that comes closest decides where the whole fragment goes.
        decides = reached & (distance == closest[owner])
        target = np.full(len(size), -1, np.int64)
        target[owner[decides]] = component[large[nearest[decides]]]
        moves = target[owner] >= 0
        merged[fragment[moves]] = target[owner[moves]]
    return _renumber(merged, kept)


@dataclass(frozen=True)
class SegmentSummary:
    """Where every segment lies and when it was scanned.

    Attributes
    ----------
    centroid : (S, 3) float64, metres, local frame
    bbox_min, bbox_max : (S, 3) float64, metres, axis-aligned bounds in the local frame
    lateral : (S, 2) float64, metres, smallest and largest offset left of the trajectory
    height : (S, 2) float64, metres, lowest and highest point above the road
    time : (S, 2) float64, seconds, GPS time of the first and last point
    """

    centroid: np.ndarray
    bbox_min: np.ndarray
    bbox_max: np.ndarray
    lateral: np.ndarray
    height: np.ndarray
    time: np.ndarray


def summarise_segments(
    xyz: np.ndarray,
    gps_time: np.ndarray,
    lateral: np.ndarray,
    height: np.ndarray,
    segments: Segments,
) -> SegmentSummary:
    """Per-segment extents from per-point (N,) coordinates, by sorted reductions (no loops)."""
    if len(segments) == 0:
        z3, z2 = np.zeros((0, 3)), np.zeros((0, 2))
        return SegmentSummary(z3, z3, z3, z2, z2, z2)
    starts = segments.starts[:-1]
    p = np.asarray(xyz, np.float64)[segments.order]

    def bounds(values: np.ndarray) -> np.ndarray:
        v = np.asarray(values, np.float64)[segments.order]
        return np.stack([np.minimum.reduceat(v, starts), np.maximum.reduceat(v, starts)], axis=1)

    return SegmentSummary(
        centroid=np.add.reduceat(p, starts, axis=0) / segments.n_points[:, None],
        bbox_min=np.minimum.reduceat(p, starts, axis=0),
        bbox_max=np.maximum.reduceat(p, starts, axis=0),
        lateral=bounds(lateral),
        height=bounds(height),
        time=bounds(gps_time),
    )
