"""The thresholds of the pipe reconstruction (Matsumoto et al. 2019, §4.3), each with its unit.

Lengths are in metres (``_m``), angles in degrees (``_deg``); counts, shares and factors have no
suffix. A factor multiplies the length named in its description, so that the thresholds that
follow a length move with it when it is tuned.
"""

from __future__ import annotations

from dataclasses import dataclass

from guardrail_core.params import Slider, StageParams, param


@dataclass(frozen=True)
class PipeParams(StageParams):
    """Thresholds of the pipe reconstruction (§4.3); see each field's ``doc`` (``specs()``)."""

    # -- poles and the x histogram (§4.3, Fig. 14) ------------------------------------------------
    pole_margin_m: float = param(
        0.015,
        unit="m",
        ge=0,
        doc="Points with x within pole radius + this of a pole axis (x = 0, x = length) are "
        "dropped as pole points (and points beyond the poles with them).",
    )
    histogram_bin_m: float = param(
        0.005, unit="m", gt=0, doc="Bin width of the x histogram of vertical-pipe detection."
    )
    histogram_factor: float = param(
        2.3,
        gt=0,
        slider=Slider("histogram threshold (x median)", 1.0, 6.0, 0.1),
        doc="The histogram threshold is this times the median bin count (the level the "
        "horizontal pipes give everywhere), and at least histogram_min_count. An arch's 0.15 m "
        "king post peaks at 2.4x; 2.3 adds no other vertical pipe on the units-sweep street or "
        "on two random streets (2.5 missed the king post). Also the density, over the median, "
        "of the y bands taken as horizontal pipes crossing a vertical one.",
    )
    histogram_min_count: float = param(
        4.0,
        ge=0,
        doc="Floor of the histogram threshold, points per bin (sparse clouds have a median of "
        "0 or 1).",
    )
    radius_share: float = param(
        0.94,
        gt=0,
        lt=1,
        slider=Slider("share of points for the radius", 0.5, 0.99, 0.01),
        doc="The paper's 'certain percentage': the share of a pipe's points that its diameter "
        "holds. For offsets uniform on [-r, r] the central share spans 2 * share * r, so "
        "r = half-width / share; a pipe looked down on is measured from this span and the "
        "median's distance from its middle (pipes/measure.py).",
    )

    # -- points another unit confirms (§4.2) -----------------------------------------------------
    confirm_cell_m: float = param(
        0.02,
        unit="m",
        gt=0,
        doc="Another unit confirms a superimposed point where one of its points lies in the "
        "point's cube of this size or in one of the 26 around it (see confirm_behind_m): what "
        "one unit alone holds behind the rails (a shrub against them, a hedge's face) is not "
        "the unit shape.",
    )
    confirm_behind_m: float = param(
        0.03,
        unit="m",
        ge=0,
        doc="Points more than this behind the median depth of the unit's points are left out "
        "unless another unit confirms them; those in front need no confirming: a pipe that "
        "one unit alone shows (a scan line along a diagonal) stands in the unit's plane.",
    )
    confirm_min_units: int = param(
        3,
        ge=2,
        doc="Runs of fewer superimposed units keep all their points (with two, a pipe one unit "
        "hides would go with the strays).",
    )

    # -- vertical pipes (§4.3, Fig. 15) -----------------------------------------------------------
    vertical_min_length_m: float = param(
        0.1, unit="m", gt=0, doc="A vertical pipe's points cover at least this height, gap-free."
    )
    vertical_gap_m: float = param(
        0.06, unit="m", gt=0, doc="The largest gap in y within the points of one vertical pipe."
    )
    vertical_sparse_gap_m: float = param(
        0.12,
        unit="m",
        gt=0,
        doc="The largest gap where vertical_gap_m finds no vertical pipe: a thin pipe gets one "
        "streak of points per scan line, and when every unit of a run was scanned at the same "
        "heights (the pole spacing a multiple of the vehicle's advance per scanner turn, 0.1 m "
        "at 10 m/s) the superimposition does not fill the gaps between the streaks. Also how "
        "far beside a short vertical's end (beyond its radius) the streaks of a pipe across "
        "it are looked for.",
    )
    vertical_angle_deg: float = param(
        4.0,
        unit="deg",
        ge=0,
        lt=90,
        doc="A histogram peak whose points lean more than this from the vertical is no vertical "
        "pipe (the steep foot of an arch); a straight skeleton within it of the vertical is "
        "vertical.",
    )
    window_passes: int = param(
        2,
        ge=1,
        doc="Passes of a vertical pipe's x window: each one centres it on the pipe and narrows "
        "it to the estimated radius + assign_margin_m.",
    )
    short_vertical_factor: float = param(
        2.0,
        gt=0,
        doc="A vertical pipe shorter than this times vertical_min_length_m is kept only where "
        "pipes run across both its ends (the steep foot of an arch goes on aside).",
    )
    crossing_reach: float = param(
        3.0,
        gt=1,
        doc="Points of a pipe running across a vertical's end are looked for from short_window_m "
        "to this times short_window_m beyond its radius (in x, within slice_interval_m in y).",
    )
    crossing_min_points: int = param(
        3, ge=1, doc="Fewest such points on either side for a pipe to run across a vertical's end."
    )
    short_window_m: float = param(
        0.015,
        unit="m",
        gt=0,
        doc="Short vertical pipes (an arch's king post): the width their histogram is summed "
        "over, the least half-width of their window, and the gap beyond their radius where the "
        "pipes crossing their ends are looked for.",
    )
    short_min_inner_points: int = param(
        8,
        ge=3,
        doc="Fewest points a short vertical candidate must hold a slice interval in from both "
        "its ends, where the pipes across them do not reach (its drift is measured on them), "
        "and fewest it must keep once those pipes took theirs (min_points for every other "
        "pipe). A king post of a far or short run holds 9-13 there.",
    )
    short_drift_m: float = param(
        0.015,
        unit="m",
        gt=0,
        doc="The most a short vertical pipe's points may drift in x from the lowest third of "
        "them to the highest (their medians; units registered to a few mm leave ~1 cm on a "
        "0.15 m pipe, a fixed angle would not do). An arch's foot drifts 1.7 cm (outer arch) "
        "to 2.7 cm (inner) over the 0.1 m above the rail.",
    )

    # -- straight pipes: the line search ----------------------------------------------------------
    line_band_m: float = param(
        0.03, unit="m", gt=0, doc="Half-width of a line hypothesis's band of points."
    )
    line_min_length_m: float = param(
        0.3, unit="m", gt=0, doc="Shortest gap-free run of a straight pipe."
    )
    line_chunk_m: float = param(
        0.1,
        unit="m",
        gt=0,
        doc="Length of the pieces a run is cut into to check it is populated and straight; also "
        "the shortest pair of points a line hypothesis is drawn through.",
    )
    line_straightness_m: float = param(
        0.005,
        unit="m",
        gt=0,
        doc="A piece's median offset may differ from the run's by this much, or by "
        "line_straightness_se of its standard errors where more (a sparse pipe's few points "
        "scatter); where more than line_bent_share of the pieces do not, the run is curved. A "
        "rail superimposed from 8-12 units bows by up to 6 mm (3 mm either side of its "
        "median); an arch's crown deviates by 1-3 cm, the stretch of a wave (amplitude 0.15 m) "
        "between its crests by 4-8 mm.",
    )
    line_straightness_se: float = param(
        3.0, gt=0, doc="See line_straightness_m: standard errors of a piece's median."
    )
    line_bent_share: float = param(
        0.2,
        ge=0,
        le=1,
        doc="Largest share of a run's full pieces whose median is off the line, for the run to "
        "be straight.",
    )
    line_piece_min_points: int = param(
        2, ge=1, doc="Points a piece holds to count as populated (see line_occupancy)."
    )
    line_piece_full_points: int = param(
        4, ge=1, doc="Points a piece holds for its median to be judged for straightness."
    )
    line_occupancy: float = param(
        0.7, gt=0, le=1, doc="Share of a run's pieces holding line_piece_min_points or more."
    )
    line_hypotheses: int = param(
        300, ge=1, doc="Line hypotheses (pairs of points) drawn per search."
    )
    line_searches: int = param(
        16, ge=0, doc="Most searches, each finding at most one straight pipe (most points first)."
    )
    line_sample: int = param(
        3000,
        ge=2,
        doc="Most points a search draws its hypotheses from and scores them on (a random "
        "sample of the points not yet taken).",
    )
    line_candidates: int = param(
        8, ge=1, doc="Best-scored hypotheses of a search refined before it gives up."
    )
    line_same_sin: float = param(
        0.05,
        ge=0,
        le=1,
        doc="A hypothesis whose direction is within this sine of a failed one's, and whose "
        "centre lies within line_band_m of that line, is not refined again.",
    )
    line_refits: int = param(
        3, ge=1, doc="Refits of a hypothesis to its band's points before it is judged."
    )
    line_min_radius_m: float = param(
        0.005,
        unit="m",
        ge=0,
        doc="Least radius a straight pipe's band of points is taken with (its half-width is "
        "radius + assign_margin_m).",
    )
    line_band_growth: float = param(
        2.0, gt=0, doc="A straight pipe's band is at most this times line_band_m wide."
    )
    rail_core_share: float = param(
        0.6,
        ge=0,
        le=1,
        doc="The central share of a horizontal straight pipe's band stays in the points chained "
        "by slices (the chains that touch a rail tangentially need it); a diagonal's band goes.",
    )

    # -- slices, components and their chains (§4.3, Fig. 16) --------------------------------------
    slice_interval_m: float = param(
        0.03,
        unit="m",
        ge=0.005,
        le=1.0,
        slider=Slider("pipe slice interval (m)", 0.01, 0.1, 0.005),
        doc="Width of the slices along x (§4.3: 30 mm); below 5 mm a unit's slices hold too few "
        "points to fit, and the work grows without bound (1e-5 m took minutes and 4 GB).",
    )
    max_edge_m: float = param(
        0.03,
        unit="m",
        gt=0,
        doc="Edges of a slice's Delaunay wireframe longer than this are cut before its connected "
        "components are taken.",
    )
    slice_spread: float = param(
        4.0,
        gt=1,
        doc="Slices are pulled apart along x by this times max_edge_m before the pairs within "
        "max_edge_m are taken, so that no pair crosses a slice boundary (any value above 1 "
        "gives the same components).",
    )
    link_distance_m: float = param(
        0.04,
        unit="m",
        gt=0,
        doc="A centre joins a polyline when it lies within this distance (across the "
        "polyline's direction) of the position predicted along the polyline.",
    )
    link_gap_m: float = param(
        0.15, unit="m", gt=0, doc="Polylines bridge runs of empty slices up to this length in x."
    )
    link_max_slope: float = param(
        3.0, gt=0, doc="Steepest direction (dy/dx) a polyline of one centre may continue in."
    )
    link_same_angle_deg: float = param(
        10.0,
        unit="deg",
        ge=0,
        lt=90,
        doc="Two polylines that want the same centre are one pipe (a duplicate) when their "
        "directions differ by less than this; else they cross and share it.",
    )
    direction_window_m: float = param(
        0.15,
        unit="m",
        gt=0,
        doc="The direction of a polyline is fitted to its centres within this x span of its end.",
    )
    direction_trust_share: float = param(
        0.5,
        gt=0,
        le=1,
        doc="A polyline's fitted direction steers it once its own centres span this share of "
        "direction_window_m.",
    )
    end_direction_share: float = param(
        0.5,
        gt=0,
        le=1,
        doc="The direction leaving a polyline's end is the step from its last vertex this share "
        "of direction_window_m back.",
    )
    track_join_cos: float = param(
        0.7,
        ge=-1,
        le=1,
        doc="Two polylines broken by a gap or a bend are joined when the step across continues "
        "both their directions: cosines of at least this.",
    )
    bounce_turn_factor: float = param(
        2.0,
        gt=0,
        doc="A polyline bounced off a crossing pipe (an X linked as a Λ) turns by at least this "
        "times link_same_angle_deg at the apex.",
    )
    bounce_side_centres: int = param(
        3,
        ge=2,
        doc="Fewest own centres the direction of either side of a bounce's apex (and of the "
        "halves that continue it) is fitted to.",
    )

    # -- smoothing and shaping (§4.3) -------------------------------------------------------------
    taubin_lambda: float = param(0.5, gt=0, lt=1, doc="Taubin's shrinking factor.")
    taubin_mu: float = param(-0.53, lt=0, doc="Taubin's inflating factor, below -taubin_lambda.")
    taubin_iterations: int = param(
        10,
        ge=0,
        doc="Taubin's filter iterations.",
        slider=Slider("smoothing passes (Taubin)", 0, 40, 1),
    )
    straight_tolerance_m: float = param(
        0.01,
        unit="m",
        gt=0,
        doc="A polyline is a straight line when straight_share of its smoothed centres lie "
        "within this distance of their fitted line.",
    )
    straight_share: float = param(
        0.75,
        gt=0,
        le=1,
        doc="See straight_tolerance_m (below 1: the bumps where other pipes join do not count).",
    )
    straight_fit_quantile: float = param(
        0.9,
        ge=0,
        le=1,
        doc="A straight pipe's line is refitted to its points within this quantile of their "
        "offsets from the first fit, plus straight_fit_margin times link_distance_m.",
    )
    straight_fit_margin: float = param(
        0.25, ge=0, doc="See straight_fit_quantile: a share of link_distance_m."
    )
    horizontal_angle_deg: float = param(
        3.0,
        unit="deg",
        ge=0,
        lt=90,
        doc="A straight line within this angle of the horizontal is a horizontal pipe; two "
        "straight pieces within it of each other lie on one line.",
    )

    # -- merging, rails, joining (§4.3) -----------------------------------------------------------
    duplicate_share: float = param(
        0.5,
        gt=0,
        le=1,
        doc="A chain with this share of its length within link_distance_m of a bigger chain or "
        "of a straight pipe is that one's duplicate.",
    )
    merge_gap_m: float = param(
        0.3,
        unit="m",
        gt=0,
        doc="Largest gap (in x, and end to start) between two pieces of one pipe that are joined.",
    )
    stretch_turn_deg: float = param(
        70.0,
        unit="deg",
        ge=0,
        le=180,
        doc="A diagonal straight pipe with a curved chain's end within link_gap_m of one of its "
        "ends, turning from the chain's direction by at most this, is a straight stretch of "
        "the curve (a wave's flank, 45° between crests and troughs where the chain's ends "
        "level out: 43-69° on the development streets' waves); its points are chained again "
        "with the curve's. Where two straight pipes of a lattice meet, they turn by 90°.",
    )
    merge_angle_deg: float = param(
        50.0,
        unit="deg",
        ge=0,
        lt=90,
        doc="Largest turn between a piece's end direction, the step across a gap and the next "
        "piece's start direction for the two to be joined.",
    )
    pole_extension_m: float = param(
        0.45,
        unit="m",
        ge=0,
        doc="Ends within this x distance of a pole axis are extended to it (a rail always; a "
        "diagonal or curved pipe only if it meets no other pipe on the way). An arch's foot "
        "takes the last ~0.4 m of its rail's points, which the rail then has to bridge.",
    )
    toward_pole_min_cos: float = param(
        0.1,
        ge=0,
        le=1,
        doc="A direction whose x component is below this runs toward no pole: such an end is "
        "not extended to a pole axis, such a straight pipe is no rail to cut chains back along.",
    )
    join_distance_m: float = param(
        0.25,
        unit="m",
        ge=0,
        doc="Ends within this distance of another pipe (or of its extension) are extended or "
        "trimmed to the intersection.",
    )
    join_behind_share: float = param(
        0.5,
        ge=0,
        doc="An end is trimmed back to a crossing up to this share of join_distance_m behind "
        "it (the points of a vertical pipe reach beyond the axis of the rail it stands on).",
    )
    join_slack: float = param(
        0.2,
        ge=0,
        doc="A share of join_distance_m: the least length of a chain's end along a rail for it "
        "to be cut back, and how far before a pole another pipe must be met for a diagonal or "
        "curved pipe to end there.",
    )

    # -- pipes kept and measured (§4.3) -----------------------------------------------------------
    min_points: int = param(15, ge=1, doc="Fewest points a pipe must hold.")
    min_length_m: float = param(
        0.1, unit="m", gt=0, doc="Shortest skeleton (before extension) kept as a pipe."
    )
    assign_margin_m: float = param(
        0.01,
        unit="m",
        ge=0,
        doc="Points within r + this of an axis (in x, y) belong to the pipe.",
    )
    measure_step_m: float = param(
        0.005,
        unit="m",
        gt=0,
        doc="Spacing of the skeleton samples that point offsets are measured against.",
    )
    measure_stretch_m: float = param(
        0.1,
        unit="m",
        gt=0,
        doc="A pipe's radius and axis are measured per stretch of this length along it, and the "
        "median over the stretches taken, so that the points of a pipe joining it, which crowd "
        "one side near the junction, sway a few stretches and not the measure.",
    )
    measure_stretch_points: int = param(20, ge=1, doc="Fewest points for a stretch to be measured.")
    measure_min_stretches: int = param(
        3,
        ge=1,
        doc="With fewer measured stretches the pipe is measured on all its points at once.",
    )
    measure_min_points: int = param(
        3, ge=1, doc="Fewest points a pipe is measured on (else its first guess stays)."
    )
    measure_passes: int = param(
        2,
        ge=1,
        doc="Passes of assigning points to the pipes and measuring them (each moves the axes).",
    )

    def check_relations(self) -> None:
        if not self.taubin_mu < -self.taubin_lambda:
            self.fail(
                f"taubin_mu must be below -taubin_lambda = {-self.taubin_lambda} (Taubin's filter "
                f"shrinks otherwise), got {self.taubin_mu}"
            )
