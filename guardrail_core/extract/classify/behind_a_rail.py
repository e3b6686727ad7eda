"""Beyond the paper (§3.3): what stands behind a rail is other.

A hedge, a fence or a bicycle rack just behind a rail is cut into slices like the rail, and its
crop shows the rail in front of it; the paper's streets had nothing behind their rails. A hedge
grown into a rail's back is of the rail's wireframe component: cut from the rail's slices, what
stands behind the rail and is wider than any of its own parts is other too.
"""

from __future__ import annotations

import numpy as np

from guardrail_core.extract.classify.label_correction_params import CorrectionParams
from guardrail_core.extract.classify.segment_extents import SegmentExtents, expand_ranges, run_span


def rail_fronts(
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
    front &= run_span(labels, pairs, slice_index) >= params.behind_front_min_slices
    return side, nearest, farthest, front


def behind_a_run(
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
    side, nearest, farthest, front = rail_fronts(labels, pairs, extents, params)
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
    owner, group = expand_ranges(lo, hi)
    who = candidates[owner]
    behind = nearest[who] - group_far[group]
    wide = farthest - nearest >= params.behind_wide_m
    gap = (behind > params.behind_gap_m) | (wide[who] & (behind >= 0.0))
    hit = (key[starts, 2][group] != component[who]) & gap & (behind <= params.behind_max_m)
    out[who[hit]] = True
    return out


def behind_its_own_rail(
    labels: np.ndarray,
    pairs: np.ndarray,
    extents: SegmentExtents,
    params: CorrectionParams,
) -> np.ndarray:
    """(S,) bool: guardrail segments spanning ``behind_own_wide_m`` or more across that stand
    more than ``behind_gap_m`` and at most ``behind_max_m`` behind a front (as for
    :func:`behind_a_run`) of their own component in their slice."""
    n = len(labels)
    out = np.zeros(n, bool)
    if not (np.isfinite(params.behind_gap_m) and np.isfinite(params.behind_own_wide_m)):
        return out
    slice_index = np.asarray(extents.slice_index, np.int64)
    _, component = np.unique(np.asarray(extents.component), return_inverse=True)
    side, nearest, farthest, front = rail_fronts(labels, pairs, extents, params)
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
    owner, position = expand_ranges(lo, hi)
    a, b = members[candidates[owner]], members[position]
    behind = nearest[a] - farthest[b]
    hit = front[b] & (behind > params.behind_gap_m) & (behind <= params.behind_max_m)
    out[a[hit]] = True
    return out
