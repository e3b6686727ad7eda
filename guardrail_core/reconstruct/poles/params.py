"""The thresholds of pole detection (§4.1), each with its unit and allowed range."""

from __future__ import annotations

from dataclasses import dataclass

from guardrail_core.params import StageParams, param


@dataclass(frozen=True)
class PoleParams(StageParams):
    """Thresholds of pole detection (Matsumoto et al. 2019, §4.1; Fukano & Masuda 2015)."""

    section_step_m: float = param(
        0.05,
        unit="m",
        gt=0,
        le=0.5,
        doc="Height step of the horizontal section planes (Fukano & Masuda cut at a fixed step; "
        "the paper gives no value). Sections are contiguous: thickness = step.",
    )
    cluster_gap_m: float = param(
        0.05,
        unit="m",
        gt=0,
        le=0.5,
        doc="Within a section, points closer than this (horizontally) are one cluster. Below the "
        "83 mm gap between a pole and the nearest baluster (125 mm spacing) and above the "
        "point spacing on a sparse pole.",
    )
    max_cluster_width_m: float = param(
        0.17,
        unit="m",
        gt=0,
        le=2.0,
        doc="A cluster wider than this (xy bounding-box diagonal) is a rail or a beam, not a pole "
        "section: the widest pole (phi 139.8 mm) plus noise.",
    )
    min_circle_points: int = param(
        4,
        ge=3,
        doc="Points. A section cluster with fewer points keeps its centroid but gets no circle "
        "fit (a circle needs three).",
    )
    flat_radius_factor: float = param(
        2.0,
        ge=1,
        doc="A section cluster whose circle is more than this many times ``max_radius_m`` is a "
        "flat piece (a cap seen from above, a beam end), not a pole's section.",
    )
    stack_radius_m: float = param(
        0.08,
        unit="m",
        gt=0,
        le=1.0,
        doc="Compact clusters whose centres lie within this of each other support each other as "
        "sections of one pole, and a stack takes the clusters within this of its median "
        "centre: the widest pole's clusters (phi 139.8 mm, cut by sparse scan lines) lie "
        "within it, the nearest baluster (125 mm from a pole's axis) does not.",
    )
    max_section_gap: int = param(
        2,
        ge=0,
        doc="Sections. A stack's sections may skip at most this many sections (where a rail "
        "through the pole makes the section's cluster long); farther sections belong to "
        "another run of sections (the fragments of a sparse rail line up under the same "
        "rail's fragments above).",
    )
    min_sections: int = param(
        4,
        ge=1,
        doc="Sections. A pole has compact clusters, within ``stack_radius_m`` of each other, in "
        "at least this many nearly consecutive sections (a thrie-beam post shows 5 below the "
        "beam).",
    )
    base_section_gap: int = param(
        1,
        ge=0,
        doc="Sections. A pole's base is the bottom of its lowest section holding inliers that is "
        "followed by another such section after at most this many empty ones (sparse poles "
        "skip a section now and then): a stray point below (a ground point under a baluster "
        "that happens to lie on its circle, 0.15 m below the baluster's end) is not the base.",
    )
    min_points: int = param(
        8, ge=1, doc="Points. A pole has at least this many points in its stack."
    )
    min_extent_share: float = param(
        0.2,
        ge=0,
        le=1,
        doc="Share of the pole height (ground to top) that the stack's compact sections must "
        "span; beam posts are seen only below the beam (0.25 m of 0.82 m for a thrie beam).",
    )
    max_base_height_m: float = param(
        0.1,
        unit="m",
        ge=0,
        le=2.0,
        doc="The lowest stack point must be at most this far above the ground: poles reach the "
        "ground, balusters and stays stop at the lowest rail, 0.15-0.25 m above it.",
    )
    foot_gap_m: float = param(
        0.1,
        unit="m",
        ge=0,
        le=1.0,
        doc="Road points on a stack's footprint continue it downward while each lies at most this "
        "far below the one above: seen from across the road, a pole's lowest 0.15 m is taken "
        "for road (its normals tilt up), yet it still reaches the ground. The scan lines cross "
        "a pole on the verge some 0.07-0.09 m apart, and the step from the road-labelled foot "
        "up to the stack is one of them. A baluster's stack ends on the lowest rail, its "
        "underside 0.12 m or more above the ground points under it.",
    )
    min_radius_m: float = param(
        0.02,
        unit="m",
        gt=0,
        le=0.5,
        doc="Smallest accepted pole radius (data: 30.5 mm; balusters are 11-14 mm).",
    )
    max_radius_m: float = param(
        0.09, unit="m", gt=0, le=0.5, doc="Largest accepted pole radius (data: 70 mm)."
    )
    min_height_m: float = param(
        0.45,
        unit="m",
        ge=0,
        le=10.0,
        doc="A pole stands at least this tall above the ground (the lowest guardrail, a W-beam's "
        "post, stands 0.6 m, and a post reaches up to the rails it carries); shorter stacks are "
        "clutter at the run's foot: the stems of a hedge under a W-beam, 0.30-0.36 m tall where "
        "the beam hides the rest, passed 0.3 m as posts (12 of the 13 poles under 0.45 m "
        "detected on the fourteen development streets stood where no pole was).",
    )
    max_height_m: float = param(
        1.6,
        unit="m",
        gt=0,
        le=10.0,
        doc="Taller stacks are sign or lamp posts, not guardrail poles (data: 0.78-1.1 m).",
    )
    ransac_trials: int = param(
        256,
        ge=1,
        doc="Random point triples tried for a stack's circle (seeded: results are reproducible).",
    )
    ransac_tolerance_m: float = param(
        0.01,
        unit="m",
        gt=0,
        le=0.1,
        doc="Points within this of a circle are its inliers (2x the ~5 mm range noise).",
    )
    base_fit_height_m: float = param(
        0.3,
        unit="m",
        ge=0,
        le=5.0,
        doc="The RANSAC circle of a stack is drawn from its points up to this height above its "
        "lowest point (a thrie-beam post shows 0.3 m below the beam); the fit then takes the "
        "points near that circle at every height.",
    )
    in_line_m: float = param(
        0.04,
        unit="m",
        ge=0,
        le=1.0,
        doc="A stack's RANSAC circles are judged by the points of its sections whose cluster "
        "centroid lies within this of the median centroid of its lowest sections (those "
        "within ``base_fit_height_m``): a pole's sections stand in line above its foot, a "
        "beam's fragments in front of a post and rail ends beside a pole do not. Judged by "
        "the lowest 0.3 m alone (some 25 points where the road took a pole's lowest 0.15 m), "
        "circles 12 mm too big and 14 mm off the axes won on a whole run.",
    )
    merge_distance_m: float = param(
        0.15,
        unit="m",
        ge=0,
        le=2.0,
        doc="Two accepted axes closer than this are the same pole (the one with fewer points "
        "goes); poles stand 2 m or 4 m apart. Rail ends stacked beside a pole, 0.10-0.12 m "
        "from its axis and reaching the ground through a stray ground point, fit a pole's "
        "circle too.",
    )
    min_spacing_m: float = param(
        1.0,
        unit="m",
        ge=0,
        le=4.0,
        doc="A guardrail's posts stand 2 m or 4 m apart (real railings 1.5 m and more): of two "
        "accepted axes closer than this, the one with fewer points on its circle is no post, "
        "and the axes left so give the run's line (``max_offset_deviation_m``). The stems of "
        "a hedge behind the rails that the classifier called guardrail, some 0.2 m apart, fit "
        "a pole's circle too.",
    )
    shared_radius: bool = param(
        True,
        doc="Poles of one run share a design: after a first pass, every pole is refitted with the "
        "radius that fits all the run's poles together (only its axis is fitted), and that is "
        "its radius (see :func:`guardrail_core.reconstruct.poles.circles.fit_shared_radius`).",
    )
    shared_radius_tolerance: float = param(
        0.15,
        ge=0,
        lt=1,
        doc="Relative. In the refit, RANSAC hypotheses must be within this share of the shared "
        "radius.",
    )
    shared_radius_step_m: float = param(
        0.001,
        unit="m",
        gt=0,
        le=0.01,
        doc="The shared radius is the best of radii this far apart from ``min_radius_m`` to "
        "``max_radius_m``, refined by a parabola through its neighbours.",
    )
    circle_iterations: int = param(4, ge=0, doc="Rounds of outlier rejection of the circle fits.")
    circle_outlier_k: float = param(
        2.5,
        gt=0,
        doc="A point farther than this many RMS residuals from the fitted circle is an outlier.",
    )
    circle_noise_floor_m: float = param(
        0.004,
        unit="m",
        ge=0,
        le=0.1,
        doc="The RMS used for outlier rejection is at least this (the range noise, ~5 mm), so a "
        "near-perfect fit does not reject good points.",
    )
    member_margin_m: float = param(
        0.015,
        unit="m",
        ge=0,
        le=0.5,
        doc="Points within radius + this of the axis belong to the pole (``point_is_pole``, "
        "height); beam points, 0.09 m in front of a 70 mm post's axis, stay out.",
    )
    ground_radius_m: float = param(
        0.5,
        unit="m",
        gt=0,
        le=10.0,
        doc="Ground points within this horizontal distance of the axis give the ground height.",
    )
    ground_k: int = param(
        16,
        ge=1,
        doc="Points. The ground height is the median z of the nearest this-many ground points.",
    )
    max_offset_deviation_m: float = param(
        0.1,
        unit="m",
        ge=0,
        le=10.0,
        doc="The poles of a run stand at one offset from its rails (one design): with at least "
        "``offset_min_poles`` poles, one whose offset from the rail points near it differs "
        "from the median offset of the poles ``min_spacing_m`` apart by more than this is not "
        "one of them (a delineator post before a beam), as long as most of those lie within "
        "this of their median; with no such majority no pole is rejected.",
    )
    offset_window_m: float = param(
        1.5,
        unit="m",
        gt=0,
        le=20.0,
        doc="The rail points within this horizontal distance of a pole's axis give its offset "
        "from the rails (their median distance across the local run direction).",
    )
    offset_min_points: int = param(
        10,
        ge=2,
        doc="Points. A pole's offset is measured only with at least this many rail points within "
        "``offset_window_m`` (a direction needs two), and the offset test runs only on a run "
        "with this many rail points.",
    )
    offset_min_poles: int = param(
        3,
        ge=2,
        doc="Poles. The offset test needs at least this many accepted poles, and as many with a "
        "measured offset (of two, neither can be told off the line).",
    )
    no_ground_window_m: float = param(
        2.5,
        unit="m",
        ge=0,
        le=20.0,
        doc="Without ground points, a stack's base is tested against the lowest run point within "
        "this horizontal distance of the axis: it covers the nearest pole (poles stand at "
        "most 4 m apart), whose base is then the ground of a baluster or of a beam's "
        "fragments (on a grade that reference is low by up to grade x window). The pole's "
        "ground point is then its own lowest point.",
    )
    direction_points: int = param(
        5000,
        ge=2,
        doc="Points. The run's principal direction (the poles' order, the sides of their offsets) "
        "is taken from about this many of its points, every k-th (speed: the direction of "
        "thousands of points does not change).",
    )

    def check_relations(self) -> None:
        if self.min_radius_m > self.max_radius_m:
            self.fail(
                f"min_radius_m ({self.min_radius_m} m) must not exceed max_radius_m "
                f"({self.max_radius_m} m)"
            )
        if self.min_height_m > self.max_height_m:
            self.fail(
                f"min_height_m ({self.min_height_m} m) must not exceed max_height_m "
                f"({self.max_height_m} m)"
            )
