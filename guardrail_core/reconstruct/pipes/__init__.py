"""Skeletons and radii of the pipes of a unit shape (Matsumoto et al. 2019, §4.3).

Input: the superimposed points of many units of one run, in unit coordinates
(:mod:`guardrail_core.reconstruct.unit_frame`: x along the unit from its first pole's axis,
y above the ground line, z toward the road; metres). Output: one :class:`Pipe` per pipe of the
unit shape, its axis polyline in the same coordinates.

The steps follow §4.3, one module each:

1. points within the poles (x near 0 and ``length``) are dropped, and, in runs of several
   units, the points behind the unit's plane that no other unit confirms (:mod:`.consensus`:
   a shrub against one unit's rails);
2. vertical pipes (:mod:`.verticals`): a histogram of x (:mod:`.histogram`); contiguous regions
   above a threshold are candidate vertical pipes; the diameter is the width holding a share of
   their points, the skeleton sits at the centre of that width and spans the points' height
   (Fig. 14, 15). Straight pipes are then found by a random line search (:mod:`.line_search`);
   short vertical pipes between two others (an arch's king post, :mod:`.short_verticals`),
   which barely rise above the rails in the histogram, are found in the histogram of the points
   off the straight pipes, and kept where pipes run across both their ends;
3. their points are removed; the rest is cut into 30 mm slices along x (:mod:`.slices`), each
   slice triangulated (2-D Delaunay on (x, y)), edges longer than a cut length removed, and the
   centre of each connected component taken (Fig. 16 a-c; the components are those of the points
   closer than the cut length, which a k-d tree finds faster than a triangulation);
4. centres of consecutive slices are joined into polylines (Fig. 16 d, :mod:`.tracking`),
   predicting along the current direction so that crossing pipes continue straight through the
   crossing; where one still bounced off the other (an X linked as a Λ and two halves), they are
   re-linked (:mod:`.crossings`); :mod:`.chains` runs 3 and 4; a diagonal line that a curved
   chain levels into (a wave's flank, which the line search took as straight) is given back
   and the curve chained again, kept when the curve then runs along it and past both its ends
   (:mod:`.curve_pieces`);
5. polylines are smoothed by Taubin's low-pass filter, fitted by a straight line when nearly
   straight, snapped to horizontal when nearly horizontal (:mod:`.shaping`); pieces of one pipe
   are merged (:mod:`.merging`);
6. a chain's end that runs on along a rail past their junction is cut and given back to the
   rail (the part left shaped again, straight or curved); what still runs along a rail is its
   duplicate and goes (:mod:`.rails`); ends near a pole are extended to the pole axis; ends near
   another pipe are extended to their intersection (:mod:`.joining`); pieces of a curve whose
   ends were joined end to start, where they run on smoothly, are one pipe (:mod:`.merging`: an
   arch broken at its crown);
7. the radius and the axis depth z of each pipe are measured from its points, per 0.1 m
   stretch along it (the median over the stretches: a junction sways a few of them;
   :mod:`.measure`).

The thresholds are the fields of :class:`PipeParams` (:mod:`.params`), each with its unit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from guardrail_core.errors import ReconstructionError
from guardrail_core.reconstruct.model import PIPE_KINDS, Pipe
from guardrail_core.reconstruct.pipes.chains import chained_pipes
from guardrail_core.reconstruct.pipes.consensus import strays_behind
from guardrail_core.reconstruct.pipes.curve_pieces import curve_stretches, runs_along_a_curve
from guardrail_core.reconstruct.pipes.histogram import PipeHistogram, x_histogram
from guardrail_core.reconstruct.pipes.inputs import check_length, check_unit_points
from guardrail_core.reconstruct.pipes.joining import extend_and_join
from guardrail_core.reconstruct.pipes.line_search import straight_pipes
from guardrail_core.reconstruct.pipes.measure import measure_pipes
from guardrail_core.reconstruct.pipes.merging import merge_meetings
from guardrail_core.reconstruct.pipes.params import PipeParams
from guardrail_core.reconstruct.pipes.rails import cut_back, runs_along
from guardrail_core.reconstruct.pipes.short_verticals import short_verticals
from guardrail_core.reconstruct.pipes.skeleton import Skeleton
from guardrail_core.reconstruct.pipes.verticals import vertical_pipes

__all__ = [
    "PipeHistogram",
    "PipeParams",
    "PipeReconstruction",
    "reconstruct_pipes",
    "check_unit_points",
]


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


def reconstruct_pipes(
    points: np.ndarray,
    length: float,
    pole_radius: float,
    params: PipeParams = PipeParams(),
    *,
    rng: np.random.Generator | int | None = 0,
    unit_of_point: np.ndarray | None = None,
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
    rng : numpy Generator, int seed or None
        The randomness of the line search (:mod:`.line_search`). The default seed 0 gives the
        same pipes on every call; None draws fresh entropy; a Generator is used as it is (and
        advanced).
    unit_of_point : (N,) int or None
        The unit each point came from. Given, the points behind the unit's plane that no
        other unit confirms are dropped first (:func:`.consensus.strays_behind`).

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
    length = check_length(length, "length", positive=True)
    pole_radius = check_length(pole_radius, "pole_radius", positive=False)
    p = params
    generator = np.random.default_rng(rng)
    notes: list[str] = []

    # §4.3: points within the poles are eliminated.
    x0 = pole_radius + p.pole_margin_m
    x1 = length - x0
    if x1 <= x0:
        raise ReconstructionError(
            f"the unit (length {length} m) is shorter than its two poles and margins ({2 * x0} m)"
        )
    between = (pts[:, 0] > x0) & (pts[:, 0] < x1)
    pts = pts[between]
    if unit_of_point is not None:
        units = np.asarray(unit_of_point).reshape(-1)
        if len(units) != len(between):
            raise ReconstructionError(
                f"{len(between)} points but {len(units)} units of points: one unit per point"
            )
        stray = strays_behind(pts, units[between], p)
        if stray.any():
            notes.append(
                f"{int(stray.sum())} of {len(pts)} points behind the unit's plane, which no "
                "other unit confirms, were left out"
            )
            pts = pts[~stray]

    # §4.3, Fig. 14: histogram of points along x.
    histogram = x_histogram(pts[:, 0], x0, x1, p)
    if len(pts) == 0:
        notes.append("no points between the poles: no pipe reconstructed")
        return PipeReconstruction((), histogram, tuple(notes))

    # §4.3, Fig. 15: vertical pipes at the histogram peaks.
    verticals, vertical_mask = vertical_pipes(pts, histogram, p)

    # §4.3, Fig. 16(a): the points of the vertical pipes are removed.
    rest_idx = np.flatnonzero(~vertical_mask)
    lines, line_mask = straight_pipes(pts, rest_idx, p, generator)
    rest_idx = rest_idx[~line_mask]
    # Short vertical pipes between two others (an arch's king post) stand out only once the
    # rails' points are out of the histogram.
    short, short_mask = short_verticals(pts, rest_idx, lines, histogram.edges, p)
    verticals += short
    rest_idx = rest_idx[~short_mask]
    rails, others, n_short = _chained_and_cut_back(pts, rest_idx, lines, x0, length, p)
    # A diagonal line that a curved chain continues may be a straight stretch of that curve (a
    # wave's flank): its points go back, and it was one when the curve, chained again, runs
    # along it.
    for stretch in [lines[i] for i in curve_stretches(lines, others, p)]:
        trial_lines = [line for line in lines if line is not stretch]
        trial_rest = np.union1d(rest_idx, stretch.idx)
        trial_rails, trial_others, trial_short = _chained_and_cut_back(
            pts, trial_rest, trial_lines, x0, length, p
        )
        if runs_along_a_curve(stretch, trial_others, (x0, x1), p):
            lines, rest_idx = trial_lines, trial_rest
            rails, others, n_short = trial_rails, trial_others, trial_short
    if n_short:
        notes.append(f"{n_short} short or sparse point chains were not taken as pipes")
    skels = verticals + rails + others
    # §4.3: ends extended to the poles, and to the intersection of close ends.
    extend_and_join(skels, length, p)
    skels = merge_meetings(skels, p)
    # Radius and depth of each pipe from its points.
    pipes = []
    # A short vertical shares its ends' points with the pipes across them: what it keeps is
    # what it held between them.
    short_ids = {id(s) for s in short}
    for s, m in zip(skels, measure_pipes(pts, skels, p), strict=True):
        if m.n_points < (p.short_min_inner_points if id(s) in short_ids else p.min_points):
            notes.append(
                f"a {s.kind} pipe near x={m.xy[:, 0].mean():.2f} m, y={m.xy[:, 1].mean():.2f} m "
                f"kept only {m.n_points} points: dropped"
            )
            continue
        axis = np.column_stack([m.xy, np.full(len(m.xy), m.z)])
        pipes.append(Pipe(axis=axis, radius=m.radius, kind=s.kind, n_points=m.n_points))
    if not pipes:
        notes.append(f"no pipe found among {len(pts)} points between the poles")
    pipes.sort(
        key=lambda q: (PIPE_KINDS.index(q.kind), -float(q.axis[:, 1].mean()), float(q.axis[0, 0]))
    )
    return PipeReconstruction(tuple(pipes), histogram, tuple(notes))


def _chained_and_cut_back(
    pts: np.ndarray,
    rest_idx: np.ndarray,
    lines: list[Skeleton],
    x0: float,
    length: float,
    p: PipeParams,
) -> tuple[list[Skeleton], list[Skeleton], int]:
    """The straight pipes with the horizontal chains that are rails of their own, the other
    chains (their ends along a rail cut back, a rail's duplicates gone), and how many chains
    were too short or sparse (see :func:`chained_pipes`)."""
    others, n_short = chained_pipes(pts, rest_idx, x0, p)
    rails = lines + [s for s in others if s.kind == "horizontal" and not runs_along(s, lines, p)]
    others = [s for s in others if s.kind != "horizontal"]
    for s in others:
        cut_back(s, rails, length, pts, p)
    # A chain is a rail's duplicate when it still runs along one once its ends along rails are
    # cut: a diagonal that took over a rail's points past its junction is not.
    others = [s for s in others if not runs_along(s, lines, p)]
    return rails, others, n_short
