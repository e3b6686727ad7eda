"""Where sliced segments lie, which of them touch, and how many slices their runs and wireframe
components span: what label correction (§3.3) and the neighbour features count with.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from guardrail_core.extract.classify.label_correction_params import CorrectionParams


@dataclass(frozen=True)
class SegmentExtents:
    """Where each segment lies in track coordinates (see :mod:`guardrail_core.sensors.track`).

    Attributes
    ----------
    slice_index : (S,) int64, station slice of the segment
    lateral : (S, 2) float64, metres, smallest and largest lateral offset of its points (signed:
        the path is at 0)
    height : (S, 2) float64, metres, lowest and highest point above the road
    component : (S,) int64, the wireframe component (§3.2: one object) the segment was cut from
    n_points : (S,) int64, how many points it holds
    """

    slice_index: np.ndarray
    lateral: np.ndarray
    height: np.ndarray
    component: np.ndarray
    n_points: np.ndarray


def neighbour_pairs(
    extents: SegmentExtents, params: CorrectionParams = CorrectionParams()
) -> np.ndarray:
    """Pairs (E, 2) int64 of neighbouring segments, each pair once, first in the lower slice.

    Two segments are neighbours when their slices are equal or adjacent and both their lateral
    and height intervals come within ``touch_distance_m``.
    """
    slice_index = np.asarray(extents.slice_index, np.int64)
    if len(slice_index) == 0:
        return np.zeros((0, 2), np.int64)
    order = np.argsort(slice_index, kind="stable")
    bounds = np.searchsorted(slice_index[order], np.unique(slice_index))
    groups = dict(zip(np.unique(slice_index).tolist(), np.split(order, bounds[1:]), strict=True))
    gap = params.touch_distance_m
    pairs = []
    for k, here in groups.items():
        for other in (here, groups.get(k + 1)):
            if other is None:
                continue
            a = np.repeat(here, len(other))
            b = np.tile(other, len(here))
            touch = (
                (extents.lateral[a, 0] <= extents.lateral[b, 1] + gap)
                & (extents.lateral[b, 0] <= extents.lateral[a, 1] + gap)
                & (extents.height[a, 0] <= extents.height[b, 1] + gap)
                & (extents.height[b, 0] <= extents.height[a, 1] + gap)
            )
            if other is here:
                touch &= a < b
            pairs.append(np.stack([a[touch], b[touch]], axis=1))
    return np.concatenate(pairs).astype(np.int64)


def run_span(labels: np.ndarray, pairs: np.ndarray, slice_index: np.ndarray) -> np.ndarray:
    """(S,) int64: how many slices the run of neighbouring guardrail segments of each guardrail
    segment spans (meaningless for other segments)."""
    n = len(labels)
    run_pairs = pairs[labels[pairs[:, 0]] & labels[pairs[:, 1]]]
    graph = coo_matrix(
        (np.ones(len(run_pairs), np.int8), (run_pairs[:, 0], run_pairs[:, 1])), shape=(n, n)
    )
    _, run = connected_components(graph, directed=False)
    guardrail = np.flatnonzero(labels)
    first = np.full(n, np.iinfo(np.int64).max)
    last = np.full(n, np.iinfo(np.int64).min)
    np.minimum.at(first, run[guardrail], slice_index[guardrail])
    np.maximum.at(last, run[guardrail], slice_index[guardrail])
    return last[run] - first[run] + 1


def component_spans(extents: SegmentExtents) -> np.ndarray:
    """(S,) int64: how many slices each segment's wireframe component spans (first to last)."""
    _, component = np.unique(np.asarray(extents.component), return_inverse=True)
    slice_index = np.asarray(extents.slice_index, np.int64)
    k = int(component.max()) + 1
    first = np.full(k, np.iinfo(np.int64).max)
    last = np.full(k, np.iinfo(np.int64).min)
    np.minimum.at(first, component, slice_index)
    np.maximum.at(last, component, slice_index)
    return (last - first + 1)[component]


def expand_ranges(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every position of the ranges ``[lo[k], hi[k])`` (K,) int: (P,) the range each belongs to
    and (P,) the position itself, ranges in order."""
    count = hi - lo
    owner = np.repeat(np.arange(len(lo)), count)
    return owner, np.arange(count.sum()) - np.repeat(np.cumsum(count) - count - lo, count)


def pairs_in_a_slice(
    slice_index: np.ndarray, piece: np.ndarray, host: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Every pair of a ``piece`` segment and a ``host`` segment of the same slice.

    Parameters
    ----------
    slice_index : (S,) int64, each segment's slice
    piece, host : (S,) bool, the segments on either side of a pair

    Returns
    -------
    (P,) int64 piece indices and (P,) int64 host indices, pieces in order
    """
    hosts = np.flatnonzero(host)
    hosts = hosts[np.argsort(slice_index[hosts], kind="stable")]
    pieces = np.flatnonzero(piece)
    lo = np.searchsorted(slice_index[hosts], slice_index[pieces], side="left")
    hi = np.searchsorted(slice_index[hosts], slice_index[pieces], side="right")
    owner, position = expand_ranges(lo, hi)
    return pieces[owner], hosts[position]
