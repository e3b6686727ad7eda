"""Beyond the paper (§3.3): the wireframe's objects speak for their pieces.

A few slices of a long object called other are part of it (a fence, a wall, a strip of grass),
and so is a short piece lying within the outline of a thin one (a fence's wire row). And a short
piece lying wholly inside a rail's slice is of the railing: the arches and stays between its
rails, thin pipes whose sparse hits the wireframe leaves apart from them.
"""

from __future__ import annotations

import numpy as np

from guardrail_core.extract.classify.label_correction_params import CorrectionParams
from guardrail_core.extract.classify.segment_extents import (
    SegmentExtents,
    component_spans,
    expand_ranges,
    pairs_in_a_slice,
)


def pieces_of_other_objects(
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
    owner, position = expand_ranges(lo, hi)
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


def inside_other_objects(
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
    span = component_spans(extents)
    piece = labels & (span <= params.inside_max_slices)
    width = np.diff(np.asarray(extents.lateral, np.float64), axis=1)[:, 0]
    host = (
        ~labels
        & (span >= params.inside_host_min_slices)
        & (width <= params.inside_host_max_width_m)
        & (probability < params.inside_host_max_probability)
    )
    return within_in_slice(piece, host, extents, params.fill_margin_m)


def within_in_slice(
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
    a, b = pairs_in_a_slice(slice_index, piece, host)
    within = (
        (component[a] != component[b])
        & (lateral[a, 0] >= lateral[b, 0] - margin)
        & (lateral[a, 1] <= lateral[b, 1] + margin)
        & (height[a, 0] >= height[b, 0] - margin)
        & (height[a, 1] <= height[b, 1] + margin)
    )
    out[a[within]] = True
    return out


def railing_infill(
    labels: np.ndarray, span: np.ndarray, extents: SegmentExtents, params: CorrectionParams
) -> np.ndarray:
    """(S,) bool: other segments of short components (``infill_max_slices``) lying within the
    extent, widened by ``fill_margin_m``, of a guardrail segment of another component in their
    slice, at most ``infill_host_max_width_m`` across, in a run spanning
    ``behind_front_min_slices`` or more (``span`` (S,): each guardrail segment's run, from
    :func:`~guardrail_core.extract.classify.segment_extents.run_span`)."""
    if params.infill_max_slices == 0 or len(labels) == 0:
        return np.zeros(len(labels), bool)
    piece = ~labels & (component_spans(extents) <= params.infill_max_slices)
    width = np.diff(np.asarray(extents.lateral, np.float64), axis=1)[:, 0]
    host = (
        labels
        & (width <= params.infill_host_max_width_m)
        & (span >= params.behind_front_min_slices)
    )
    return within_in_slice(piece, host, extents, params.fill_margin_m)
