"""The rules of label correction (§3.3) and their parameters: what the paper's rules and ours
beyond it (:mod:`~guardrail_core.extract.classify.label_correction`) measure with."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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
