"""Chains of pieces: a component's segments followed from slice to slice, side by side.

The wireframe joins what touches: a rail and the hedge grown into it are one connected component.
Slicing parts them where a slice's points thin out across the road, so each slice holds a rail
piece and a hedge piece, but the component stays one, and features taken over a whole component
describe both (a 25 m rail 1.8 m high, spread 0.4 m across). A chain links a component's pieces in
consecutive slices whose lateral ranges come within a gap of each other: the rail's pieces form
one chain, the hedge's another, and a clean rail's chain is its whole component. Pieces side by
side where rail and hedge touch within a slice still join both.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


def piece_chains(
    component: np.ndarray,
    slice_index: np.ndarray,
    lateral_min: np.ndarray,
    lateral_max: np.ndarray,
    gap_m: float,
) -> np.ndarray:
    """The chain of every segment.

    Parameters
    ----------
    component : (S,) int, the component each segment was cut from
    slice_index : (S,) int, each segment's slice along the trajectory
    lateral_min, lateral_max : (S,) float64, metres, each segment's range across the trajectory
    gap_m : metres; segments of one component in consecutive slices whose ranges come within
        this of each other (or overlap) are linked

    Returns
    -------
    (S,) int64 chain of every segment, 0 to C - 1; linked segments share a chain, and segments of
    different components never do.
    """
    n = len(component)
    if n == 0:
        return np.zeros(0, np.int64)
    component = np.asarray(component, np.int64)
    slice_index = np.asarray(slice_index, np.int64)
    order = np.lexsort((slice_index, component))
    comp, slices = component[order], slice_index[order]
    # Groups: the segments of one component in one slice, consecutive in `order`.
    new = np.r_[True, (comp[1:] != comp[:-1]) | (slices[1:] != slices[:-1])]
    start = np.flatnonzero(new)
    size = np.diff(np.r_[start, n])
    # A group followed by its component's next slice: every pair across the two is a candidate.
    g = np.flatnonzero(
        (comp[start[1:]] == comp[start[:-1]]) & (slices[start[1:]] == slices[start[:-1]] + 1)
    )
    n_a, n_b = size[g], size[g + 1]
    n_pairs = n_a * n_b
    block = np.repeat(np.arange(len(g)), n_pairs)
    within = np.arange(int(n_pairs.sum())) - np.repeat(np.cumsum(n_pairs) - n_pairs, n_pairs)
    a = order[start[g][block] + within // n_b[block]]
    b = order[start[g + 1][block] + within % n_b[block]]
    lo = np.asarray(lateral_min, np.float64)
    hi = np.asarray(lateral_max, np.float64)
    close = (lo[b] <= hi[a] + gap_m) & (lo[a] <= hi[b] + gap_m)
    a, b = a[close], b[close]
    graph = coo_matrix((np.ones(len(a), np.int8), (a, b)), shape=(n, n))
    _, chain = connected_components(graph, directed=False)
    return chain.astype(np.int64)
