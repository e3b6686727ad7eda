"""The 0.5 m slices of §3.1: each wireframe component cut by planes perpendicular to the
trajectory every ``slice_length_m``, then, where a slice is wider than a rail can be, cut again
across the trajectory where its points thin out, and what stands behind a low front (a curb, a
hedge behind a railing) cut from it.
"""

from __future__ import annotations

import numpy as np

from guardrail_core.extract.segments import SegmentParams, Segments

#: Sums of bin widths that should equal a length differ from it by rounding only.
ROUNDING_M = 1e-9


def slice_components(
    component: np.ndarray,
    station: np.ndarray,
    params: SegmentParams = SegmentParams(),
    lateral: np.ndarray | None = None,
    height: np.ndarray | None = None,
) -> Segments:
    """Cut components into segments by planes perpendicular to the trajectory.

    Parameters
    ----------
    component : (N,) int, component of every point, -1 for points not kept
    station : (N,) float64, metres along the trajectory (see :mod:`guardrail_core.sensors.track`)
    params : slice length, and how wide slices are cut across
    lateral : (N,) float64, metres left of the trajectory; with it, slices wider than
        ``params.max_width_m`` are cut where their points thin out across the trajectory
    height : (N,) float64, metres above the road; with it and ``lateral``, what lies behind
        a wide slice's front is cut from it (``params.front_layer_m``)

    References
    ----------
    Matsumoto et al. 2019, §3.1 (0.5 m slices along the trajectory, Fig. 6). The cut across is
    ours: on a sparse real scan a median's hedge joins its two rails into one component.
    """
    component = np.asarray(component, np.int64)
    kept = np.flatnonzero(component >= 0)
    n = len(component)
    point_segment = np.full(n, -1, np.int32)
    if len(kept) == 0:
        empty = np.zeros(0, np.int64)
        return Segments(
            point_segment,
            component.astype(np.int32),
            empty.astype(np.int32),
            empty,
            empty,
            empty,
            np.zeros(1, np.int64),
        )
    slices = np.floor(station[kept] / params.slice_length_m).astype(np.int64)
    first_slice = int(slices.min())
    n_components = int(component[kept].max()) + 1
    key = (slices - first_slice) * n_components + component[kept]
    unique_keys, segment_of_kept = np.unique(key, return_inverse=True)
    across = None if lateral is None else np.asarray(lateral, np.float64)[kept]
    if across is not None and (params.max_width_m > 0 or params.gap_width_m > 0):
        bounds = _lateral_bounds(segment_of_kept, across)
        piece = _lateral_pieces(segment_of_kept, across, bounds, params)
        gaps = _gap_pieces(segment_of_kept, across, bounds, params)
        piece = piece * (int(gaps.max(initial=0)) + 1) + gaps
        if piece.any():
            # Pieces of one slice keep its key; they are told apart by a second key.
            n_pieces = int(piece.max()) + 1
            pairs, segment_of_kept = np.unique(
                segment_of_kept * n_pieces + piece, return_inverse=True
            )
            unique_keys = unique_keys[pairs // n_pieces]
    segment_component = unique_keys % n_components
    point_component = component.astype(np.int32)
    if height is not None and across is not None and params.front_layer_m > 0:
        up = np.asarray(height, np.float64)[kept]
        behind = _behind_front(segment_of_kept, across, up, station[kept], params)
        if behind.any():
            # What lies behind a front is another object: a component of its own (one for each
            # component it was cut from), so label correction tells the two apart.
            pairs, segment_of_kept = np.unique(segment_of_kept * 2 + behind, return_inverse=True)
            unique_keys = unique_keys[pairs // 2]
            segment_component = unique_keys % n_components + n_components * (pairs % 2)
            point_component[kept[behind]] += n_components
    point_segment[kept] = segment_of_kept
    order_in_kept = np.argsort(segment_of_kept, kind="stable")
    n_points = np.bincount(segment_of_kept, minlength=len(unique_keys)).astype(np.int64)
    return Segments(
        point_segment=point_segment,
        point_component=point_component,
        component=segment_component.astype(np.int32),
        slice_index=unique_keys // n_components + first_slice,
        n_points=n_points,
        order=kept[order_in_kept],
        starts=np.concatenate([[0], np.cumsum(n_points)]),
    )


def _lateral_pieces(
    segment: np.ndarray,
    lateral: np.ndarray,
    bounds: tuple[np.ndarray, np.ndarray],
    params: SegmentParams,
) -> np.ndarray:
    """(K,) int64: the piece of its slice each point falls in (0 for slices left whole).

    A slice wider than ``max_width_m`` is binned across (``width_bin_m``); bins with at most
    ``valley_share`` of the fullest bin's points are valleys; each run of valley bins at least
    ``min_valley_m`` wide is a piece, and so is each stretch between such runs.
    """
    piece = np.zeros(len(segment), np.int64)
    low, high = bounds
    wide = np.flatnonzero(high - low > params.max_width_m)
    if params.max_width_m <= 0 or len(wide) == 0:
        return piece
    bins = _bins_across(segment, lateral, bounds, wide, params.width_bin_m)
    n_bins, first_bin, members, cell, counts, owner = bins
    total = len(counts)
    fullest = np.maximum.reduceat(counts, first_bin[wide])
    valley = counts <= params.valley_share * np.repeat(fullest, n_bins[wide])
    opens = np.ones(total, bool)  # a slice's first bin opens its first piece
    opens[1:] = owner[1:] != owner[:-1]

    def runs(flag: np.ndarray) -> np.ndarray:
        """Run number of each bin: a run ends where ``flag`` changes or a slice ends."""
        start = opens.copy()
        start[1:] |= flag[1:] != flag[:-1]
        return np.cumsum(start) - 1

    run = runs(valley)
    valley &= np.bincount(run)[run] * params.width_bin_m >= params.min_valley_m - ROUNDING_M
    run = runs(valley)
    piece[members] = (run - run[first_bin[owner]])[cell]
    return piece


def _bins_across(
    segment: np.ndarray,
    across: np.ndarray,
    bounds: tuple[np.ndarray, np.ndarray],
    wide: np.ndarray,
    bin_m: float,
) -> tuple[np.ndarray, ...]:
    """The slices ``wide`` (W,) binned across (``bin_m``), their bins laid end to end.

    Returns ``n_bins`` and ``first_bin`` (S,) (0 bins for the other slices), ``members`` (M,)
    the points of those slices, ``cell`` (M,) the bin of each (its slice's first bin + its
    bin), ``counts`` (B,) the points of every bin and ``owner`` (B,) its slice.
    """
    low, high = bounds
    n_bins = np.zeros(len(low), np.int64)
    n_bins[wide] = ((high[wide] - low[wide]) / bin_m).astype(np.int64) + 1
    first_bin = np.concatenate([[0], np.cumsum(n_bins)[:-1]])
    members = np.flatnonzero(n_bins[segment] > 0)
    s = segment[members]
    cell = first_bin[s] + ((across[members] - low[s]) / bin_m).astype(np.int64)
    counts = np.bincount(cell, minlength=int(n_bins.sum()))
    owner = np.repeat(np.arange(len(low)), n_bins)
    return n_bins, first_bin, members, cell, counts, owner


def _gap_pieces(
    segment: np.ndarray,
    lateral: np.ndarray,
    bounds: tuple[np.ndarray, np.ndarray],
    params: SegmentParams,
) -> np.ndarray:
    """(K,) int64: the piece of its slice each point falls in (0 for slices left whole).

    A slice wider than ``gap_width_m`` is cut at every empty stretch across it at least
    ``min_gap_m`` wide that has, on one side or the other, a run of points spanning at least
    ``gap_piece_m`` before the next such stretch: its points sorted across, each such step
    between neighbours starts the next piece.
    """
    piece = np.zeros(len(segment), np.int64)
    if params.gap_width_m <= 0 or len(segment) == 0:
        return piece
    low, high = bounds
    # Only the points of wide slices are sorted: most slices are narrower.
    members = np.flatnonzero((high - low > params.gap_width_m)[segment])
    if len(members) == 0:
        return piece
    order = members[np.lexsort((lateral[members], segment[members]))]
    s, across = segment[order], lateral[order]
    first = np.concatenate([[True], s[1:] != s[:-1]])
    step = np.zeros(len(order), bool)
    step[1:] = ~first[1:] & (np.diff(across) >= params.min_gap_m)
    # Runs between gaps (and slice ends), contiguous in this order, and how wide each spans.
    starts = np.flatnonzero(step | first)
    ends = np.append(starts[1:], len(order)) - 1
    wide = across[ends] - across[starts] >= params.gap_piece_m - ROUNDING_M
    run = np.cumsum(step | first) - 1
    # A gap starts run r: it cuts when run r or run r - 1 is wide.
    cut = step.copy()
    at = np.flatnonzero(step)
    cut[at] = wide[run[at]] | wide[run[at] - 1]
    count = np.cumsum(cut)
    piece[order] = count - np.maximum.accumulate(np.where(first, count, 0))
    return piece


def _behind_front(
    segment: np.ndarray,
    lateral: np.ndarray,
    height: np.ndarray,
    station: np.ndarray,
    params: SegmentParams,
) -> np.ndarray:
    """(K,) bool: the points of slices that lie ``front_layer_m`` or more behind their slice's
    front, where those points span ``front_behind_min_width_m`` or more across and
    ``front_behind_min_length_m`` or more along the trajectory and hold ``front_behind_ratio``
    times the points in front of them or more, and where the points in front, at least
    ``front_min_points`` of them, span ``front_min_height_m`` or more in height.

    ``segment``, ``lateral``, ``height``, ``station``: (K,) per kept point (metres). A slice's
    front lies in its bin (``width_bin_m``) nearest the trajectory (on the slice's side) of
    those that hold more than ``valley_share`` of the fullest bin's points, at the point
    ``valley_share`` of the way into that bin's points by depth: a sparse scan's clutter in
    front of a rail does not move it.
    """
    behind = np.zeros(len(segment), bool)
    if len(segment) == 0:
        return behind
    n_seg = int(segment.max()) + 1
    depth = depth_from_path(segment, lateral, n_seg)
    low, high = _lateral_bounds(segment, depth)
    # Only slices deep enough to hold a front layer and a mass behind it are binned.
    deep_m = params.front_layer_m + params.front_behind_min_width_m
    deep = np.flatnonzero(high - low >= deep_m - ROUNDING_M)
    if len(deep) == 0:
        return behind
    _, _, members, cell, counts, owner = _bins_across(
        segment, depth, (low, high), deep, params.width_bin_m
    )
    s, d = segment[members], depth[members]
    fullest = np.zeros(n_seg, np.int64)
    np.maximum.at(fullest, owner, counts)
    dense = counts > params.valley_share * fullest[owner]
    # The nearest dense bin of each slice, and the point valley_share of the way into it.
    nearest = np.full(n_seg, np.iinfo(np.int64).max)
    np.minimum.at(nearest, s[dense[cell]], cell[dense[cell]])
    mine = np.flatnonzero(cell == nearest[s])
    (front,) = group_shares(s[mine], d[mine], (params.valley_share,), n_seg, np.inf)
    back = d - front[s] >= params.front_layer_m
    # The nearest point behind each slice's front layer, and how many lie behind and before.
    back_low = np.full(n_seg, np.inf)
    np.minimum.at(back_low, s[back], d[back])
    n_back = np.bincount(s[back], minlength=n_seg)
    n_front = np.bincount(s[~back], minlength=n_seg)
    top = np.full(n_seg, -np.inf)
    bottom = np.full(n_seg, np.inf)
    front_height = height[members][~back]
    np.maximum.at(top, s[~back], front_height)
    np.minimum.at(bottom, s[~back], front_height)
    cut = (
        (high - back_low >= params.front_behind_min_width_m - ROUNDING_M)
        & (n_back >= params.front_behind_ratio * n_front)
        & (n_front >= params.front_min_points)
        & (top - bottom >= params.front_min_height_m)
    )
    # How far what lies behind spans along the trajectory, its tails left out (a stray point
    # does not stretch it).
    first, last = group_shares(
        s[back], station[members][back], (SPAN_TAIL, 1 - SPAN_TAIL), n_seg, 0.0
    )
    cut &= last - first >= params.front_behind_min_length_m - ROUNDING_M
    behind[members] = back & cut[s]
    return behind


#: Share of the points behind a slice's front left out at either end of their span along the
#: trajectory.
SPAN_TAIL = 0.1


def depth_from_path(segment: np.ndarray, lateral: np.ndarray, n_seg: int) -> np.ndarray:
    """(K,) metres from the trajectory on each slice's side: ``lateral`` (K,) (metres left of
    the trajectory) negated in the slices ``segment`` (K,) of ``n_seg`` whose points lie right
    of it on the whole."""
    side = np.where(np.bincount(segment, weights=lateral, minlength=n_seg) < 0, -1.0, 1.0)
    return lateral * side[segment]


def group_shares(
    group: np.ndarray,
    value: np.ndarray,
    shares: tuple[float, ...],
    n_groups: int,
    empty: float,
) -> np.ndarray:
    """(len(shares), n_groups): for each share, the value that share of the way into each
    group's values sorted (the floor of ``share * (size - 1)``); ``empty`` for a group with
    none. ``group`` (M,) int in [0, n_groups), ``value`` (M,) float."""
    out = np.full((len(shares), n_groups), empty, np.float64)
    if len(group) == 0:
        return out
    order = np.lexsort((value, group))
    g, v = group[order], value[order]
    starts = np.flatnonzero(np.concatenate([[True], g[1:] != g[:-1]]))
    size = np.diff(np.append(starts, len(g)))
    for row, share in enumerate(shares):  # one or two shares
        out[row, g[starts]] = v[starts + (share * (size - 1)).astype(np.int64)]
    return out


def _lateral_bounds(segment: np.ndarray, lateral: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Smallest and largest lateral offset (S,) of each slice."""
    n_seg = int(segment.max()) + 1 if len(segment) else 0
    low = np.full(n_seg, np.inf)
    high = np.full(n_seg, -np.inf)
    np.minimum.at(low, segment, lateral)
    np.maximum.at(high, segment, lateral)
    return low, high
