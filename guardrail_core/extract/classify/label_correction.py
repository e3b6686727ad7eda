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

This module holds the paper's two rules and :func:`correct_labels`, which applies every rule in
order; the rules beyond the paper are :mod:`~guardrail_core.extract.classify.behind_a_rail`,
:mod:`~guardrail_core.extract.classify.wireframe_objects` and
:mod:`~guardrail_core.extract.classify.crop_veto`.
"""

from __future__ import annotations

import numpy as np

from guardrail_core.errors import InvalidOptionError
from guardrail_core.extract.classify.behind_a_rail import behind_a_run, behind_its_own_rail
from guardrail_core.extract.classify.crop_veto import crops_say_other, resting_on_rails
from guardrail_core.extract.classify.label_correction_params import CorrectionParams
from guardrail_core.extract.classify.segment_extents import (
    SegmentExtents,
    neighbour_pairs,
    run_span,
)
from guardrail_core.extract.classify.wireframe_objects import (
    inside_other_objects,
    pieces_of_other_objects,
    railing_infill,
)


def correction_reach_slices(params: CorrectionParams = CorrectionParams()) -> int:
    """How many slices away a raw label can change a corrected label, at most.

    A segment's corrected label depends only on the raw labels of segments within this many
    slices of its own (so a processing tile asks the CNN only for crops that close to the
    slices it owns). Counted step by step through :func:`correct_labels`, ``m`` being
    ``min_run_slices`` and ``f`` ``behind_front_min_slices``: the one-slice fill looks one slice
    away, at neighbours standing behind no run in front, which is settled within ``f`` slices;
    whether a run spans ``m`` slices is settled within ``m`` slices (a run that leaves them
    already spans more); the two-slice fill looks a further run test and two slices beyond; the
    isolation test of the filled labels ``m`` more; the infill (:func:`.railing_infill`),
    whether its host's run spans ``f`` slices, ``f`` more; whether a run in front spans ``f``
    slices ``f`` more; the second isolation test ``m`` more: ``3 m + 3 f + 3`` in all. The crop
    veto (:func:`.crops_say_other`) makes a raw label depend on the crops of its component
    within ``crop_veto_max_slices`` slices (whether the component spans more is settled that
    far), and, as it may be spared for resting on a rail (:func:`.resting_on_rails`), on the
    rail's raw labels and crops ``crop_veto_max_slices`` further (twice that in all); the rule
    of a long object's few slices (:func:`.pieces_of_other_objects`) on the raw labels of its
    component within ``object_window_slices``: the larger of the two more. A short piece within
    a fence's outline (:func:`.inside_other_objects`) depends on the labels of its own slice
    alone.
    """
    rules = 3 * params.min_run_slices + 3 * params.behind_front_min_slices + 3
    veto = params.crop_veto_max_slices * (2 if params.crop_veto_rest_share <= 1 else 1)
    return rules + max(veto, params.object_window_slices)


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
        :func:`~guardrail_core.extract.classify.segment_scores.weighed_crop_probability`), or
        None (the crop veto is not applied): every segment of a short component whose crops say
        other becomes other and is not filled (``crop_veto_max_slices``)

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
        say_other = crops_say_other(extents, np.asarray(crop_probability, np.float64), params)
        say_other &= ~resting_on_rails(labels, say_other, extents, params)
        labels &= ~say_other
        fillable &= ~say_other
    # Beyond the paper: a few slices of a long object called other are part of that object,
    # and so is a short piece lying within the outline of one.
    piece = pieces_of_other_objects(labels, extents, params)
    if probability is not None:
        piece |= inside_other_objects(labels, extents, np.asarray(probability, np.float64), params)
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
    standing = labels & ~behind_a_run(labels, pairs, extents, params)
    before, after, _, _ = _guardrail_sides(labels, pairs, slice_index, lateral, height)
    _, _, low, high = _guardrail_sides(standing, pairs, slice_index, lateral, height)
    fits = _fits_between(lateral, height, low, high, params) & fillable
    fill = ~labels & before & after & fits
    if params.max_hole_slices == 2:
        # Two other segments in consecutive slices, each fitting the guardrail on its side,
        # where that guardrail is a run of its own (holes of one filled): two isolated segments
        # three slices apart do not make a run.
        filled = labels | fill
        in_run = filled & (run_span(filled, pairs, slice_index) >= params.min_run_slices)
        run_before, run_after, _, _ = _guardrail_sides(in_run, pairs, slice_index, lateral, height)
        a, b = pairs[:, 0], pairs[:, 1]  # a in the lower slice
        two = (slice_index[b] == slice_index[a] + 1) & ~labels[a] & ~labels[b]
        two &= run_before[a] & fits[a] & run_after[b] & fits[b]
        fill[a[two]] = True
        fill[b[two]] = True
    labels |= fill

    # §3.3: an isolated guardrail segment becomes other. Holes are filled first, so that a
    # misclassified segment next to a run's end does not leave the end segment isolated.
    span = run_span(labels, pairs, slice_index)
    labels[labels & (span < params.min_run_slices)] = False
    # Beyond the paper: a short piece wholly inside a rail's slice is the railing's infill (the
    # runs left keep their spans: what the isolation test took were runs of their own).
    labels |= railing_infill(labels, span, extents, params)

    # What stands behind a run of another object is not guardrail, nor what stands behind its
    # own rail wider than any of a rail's parts; what it leaves of a run too short is isolated.
    behind = behind_a_run(labels, pairs, extents, params)
    behind |= behind_its_own_rail(labels, pairs, extents, params)
    if behind.any():
        labels[behind] = False
        span = run_span(labels, pairs, slice_index)
        labels[labels & (span < params.min_run_slices)] = False
    return labels
