"""Beyond the paper (§3.3): a short wireframe component whose crops say other is other.

A far mesh fence's wire rows come apart into short pieces that look like a pipe rail by their
shape, and the crops of them show the mesh. A railing's top rail that the wireframe keeps apart
from the rest of the railing is spared: its thin strip rests on another component's rail.
"""

from __future__ import annotations

import numpy as np

from guardrail_core.extract.classify.label_correction_params import CorrectionParams
from guardrail_core.extract.classify.segment_extents import (
    SegmentExtents,
    component_spans,
    pairs_in_a_slice,
)


def crops_say_other(
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
        (component_spans(extents) <= params.crop_veto_max_slices)
        & (crops >= params.crop_veto_min_crops)
        & (other >= params.crop_veto_share * crops)
    )


def resting_on_rails(
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
    host = labels & ~veto & (component_spans(extents) >= params.behind_front_min_slices)
    if not piece.any() or not host.any():
        return np.zeros(n, bool)
    slice_index = np.asarray(extents.slice_index, np.int64)
    _, component = np.unique(np.asarray(extents.component), return_inverse=True)
    a, b = pairs_in_a_slice(slice_index, piece, host)
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
