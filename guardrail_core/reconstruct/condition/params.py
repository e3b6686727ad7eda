"""The parameters of the condition assessment: post lean, missing posts and rail-top height."""

from __future__ import annotations

from dataclasses import dataclass

from guardrail_core.params import StageParams, param


@dataclass(frozen=True)
class ConditionParams(StageParams):
    """How a reconstructed run's condition is measured, and the limits a standard leaves open."""

    segment_length_m: float = param(
        10.0,
        unit="m",
        gt=0,
        le=1000.0,
        doc="The rail-top height is reported per segment of this length along the run (vendors "
        "check safety-fence height per 10 m).",
    )
    height_bin_m: float = param(
        0.5,
        unit="m",
        gt=0,
        le=100.0,
        doc="Within a segment the rail top and the road are measured per bin of this length "
        "along the run; the segment's min, median and max are over its bins.",
    )
    rail_max_offset_m: float = param(
        1.0,
        unit="m",
        gt=0,
        le=10.0,
        doc="Guardrail points farther than this across the line of the poles are no part of the "
        "rail.",
    )
    rail_top_percentile: float = param(
        99.0,
        ge=50,
        le=100,
        doc="Percent. A bin's rail top is this percentile of its rail points' heights (not the "
        "highest: a stray point above the rail would be).",
    )
    pole_margin_m: float = param(
        0.03,
        unit="m",
        ge=0,
        le=1.0,
        doc="Points within a pole's radius plus this of its axis are the pole's, not the rail's "
        "(a post standing above the rail is no rail top).",
    )
    road_reach_m: float = param(
        3.0,
        unit="m",
        gt=0,
        le=50.0,
        doc="Road points up to this far from the line of the poles, on the road side, give the "
        "road's height beside the run.",
    )
    min_points: int = param(
        10,
        ge=1,
        doc="Points. A bin needs this many rail points for a rail top, a segment this many road "
        "points for the road's height (fewer: the poles' ground is used, and the output says "
        "so).",
    )
    lean_reach_m: float = param(
        0.06,
        unit="m",
        gt=0,
        le=1.0,
        doc="In the first fit, points within the post's radius plus this of its vertical axis "
        "are the post's (a lean of a few degrees moves its top a few centimetres).",
    )
    lean_surface_margin_m: float = param(
        0.015,
        unit="m",
        gt=0,
        le=1.0,
        doc="After the first fit, points within this of the post's surface about the fitted "
        "axis are the post's (the scanner's noise; a blockout on it stands farther out, a rail "
        "running through it farther in).",
    )
    lean_base_m: float = param(
        0.1,
        unit="m",
        ge=0,
        le=2.0,
        doc="Post points lower than this above its ground are left out (grass, the ground).",
    )
    lean_min_points: int = param(
        20, ge=4, doc="Points. A post with fewer points on its surface gets no lean."
    )
    lean_min_span_m: float = param(
        0.2,
        unit="m",
        gt=0,
        le=5.0,
        doc="A post whose points span less height than this gets no lean (a stump, a post seen "
        "only at its foot).",
    )
    max_lean_deg: float = param(
        5.0,
        unit="deg",
        ge=0,
        lt=90,
        doc="A post leaning more than this from vertical is flagged, where the standard states "
        "no limit (a project default, from no standard).",
    )
    spacing_tolerance: float = param(
        0.08,
        gt=0,
        lt=0.5,
        doc="Share of a spacing. A gap within this of k spacings is k spacings; the run's "
        "spacing must lie within this share of the standard's where the standard states no "
        "tolerance.",
    )
    min_spacing_m: float = param(
        1.5,
        unit="m",
        ge=0,
        le=10.0,
        doc="The run's own spacing is at least this (as ``units.min_spacing_m``: a false post "
        "a metre from a real one is no spacing); a run whose seen gaps are all shorter is "
        "checked at the standard's spacing.",
    )
    missing_post_ratio: float = param(
        1.6,
        gt=1,
        doc="A gap between seen posts longer than this many spacings has round(gap / spacing) "
        "- 1 missing posts (as the reconstruction's units insert them).",
    )
