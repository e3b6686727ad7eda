"""Curbs cut from the rails their posts join (beyond the paper).

A rail set just behind a curb stands on posts whose feet the wireframe links to the curb, and
the curb runs on from one rail to the next: every guardrail along it, and the curb, become one
component some hundred metres long, and each 0.5 m slice without a post holds a rail and a curb
with nothing between them. Such a component is unlike any guardrail's (the classifier called
most of a far W-beam behind a curb other), and its slices are two objects each. The curb is
found where a slice shows it apart from the rail (under an empty band, in front of the rail),
and the wireframe is linked again without it: the rails are components of their own again, and
so is the curb.
"""

from __future__ import annotations

import numpy as np

from guardrail_core.extract.lattice import Lattice
from guardrail_core.extract.segments import SegmentParams, wireframe_components
from guardrail_core.extract.slices import ROUNDING_M, SPAN_TAIL, depth_from_path, group_shares


def curb_points(
    component: np.ndarray,
    station: np.ndarray,
    lateral: np.ndarray,
    height: np.ndarray,
    params: SegmentParams = SegmentParams(),
) -> np.ndarray:
    """(N,) bool: the points of a curb under a rail, and the rest of that curb.

    Each component is cut into slices (``params.slice_length_m``). Under a rail: a slice's
    points under an empty band across the slice at least ``curb_gap_m`` tall, where those
    points lie wholly at most ``curb_top_m`` above the road, in front of what stands above the
    band (nine tenths of them nearer the trajectory than nine tenths of it), span
    ``curb_min_length_m`` or more along the trajectory and at most ``curb_max_width_m`` across
    it, rise at most ``curb_max_rise_m``, and number ``curb_min_points`` or more;
    of several such bands in a slice the highest cuts. The rest of the curb: in every slice of
    a component with such a cut, the points at most ``curb_top_m`` above the road that lie
    ``curb_front_m`` or more in front of nine tenths of the points above that (all of them,
    where nothing is above: the curb between two rails, which would join them again; where a
    post fills the band, the curb before its foot), where they span at most
    ``curb_max_width_m`` across and rise at most ``curb_max_rise_m``. ``curb_gap_m`` 0 finds none.

    Parameters
    ----------
    component : (N,) int, component of every point, -1 for points not kept
    station, lateral : (N,) float64, metres along and left of the trajectory
    height : (N,) float64, metres above the road
    params : the slice length and the ``curb_*`` thresholds
    """
    component = np.asarray(component, np.int64)
    curb = np.zeros(len(component), bool)
    kept = np.flatnonzero(component >= 0)
    if params.curb_gap_m <= 0 or len(kept) == 0:
        return curb
    slices = np.floor(np.asarray(station, np.float64)[kept] / params.slice_length_m)
    slices = slices.astype(np.int64) - int(slices.min())
    n_components = int(component[kept].max()) + 1
    keys, segment = np.unique(slices * n_components + component[kept], return_inverse=True)
    up = np.asarray(height, np.float64)[kept]
    across = np.asarray(lateral, np.float64)[kept]
    below = _under_a_band(segment, across, up, np.asarray(station)[kept], params)
    if not below.any():
        return curb
    n_seg = len(keys)
    with_curb = np.isin(keys % n_components, np.unique(component[kept[below]]))[segment]
    # In those components' slices, what lies low in front of all above it: the curb where a
    # post fills the band (the post's foot stands behind the rail's face), and the curb alone
    # between two rails (nothing above it).
    depth = depth_from_path(segment, across, n_seg)
    high = up > params.curb_top_m
    (front,) = group_shares(segment[high], depth[high], (SPAN_TAIL,), n_seg, np.inf)
    rest = with_curb & ~high & (depth <= front[segment] - params.curb_front_m)
    shaped = _curb_shaped(segment, depth, up, rest, n_seg, params)
    curb[kept] = below | (rest & shaped[segment])
    return curb


def separate_curbs(
    xyz: np.ndarray,
    component: np.ndarray,
    lattice: Lattice,
    station: np.ndarray,
    lateral: np.ndarray,
    height: np.ndarray,
    params: SegmentParams = SegmentParams(),
) -> np.ndarray:
    """(N,) int32 components with the curbs of :func:`curb_points` linked apart.

    The wireframe (:func:`~guardrail_core.extract.segments.wireframe_components`) is linked
    again twice, once over the kept points but the curbs' and once over the curbs' alone; the
    second's components are numbered after the first's. Where there is no curb the components
    are returned as they are.

    Parameters
    ----------
    xyz : (N, 3) float64, metres
    component : (N,) int, component of every point, -1 for points not kept
    lattice : the scan lattice of all N points
    station, lateral, height : (N,) float64, track coordinates (metres)
    params : the wireframe's and the curbs' thresholds
    """
    component = np.asarray(component, np.int32)
    curb = curb_points(component, station, lateral, height, params)
    if not curb.any():
        return component
    kept = component >= 0
    rest = wireframe_components(xyz, kept & ~curb, lattice, params)
    curbs = wireframe_components(xyz, curb, lattice, params)
    return np.where(curb, curbs + int(rest.max()) + 1, rest).astype(np.int32)


def _curb_shaped(
    segment: np.ndarray,
    depth: np.ndarray,
    height: np.ndarray,
    points: np.ndarray,
    n_seg: int,
    params: SegmentParams,
) -> np.ndarray:
    """(S,) bool: the slices whose ``points`` (K,) bool span at most ``curb_max_width_m``
    across the trajectory and rise at most ``curb_max_rise_m``, each from a tenth to nine
    tenths of them: a curb's face and top do; the grass and the ground before a fence, on an
    embankment's slope or a ditch's, spread wider or rise higher."""
    spans = []
    for value in (depth, height):
        low, high = group_shares(
            segment[points], value[points], (SPAN_TAIL, 1 - SPAN_TAIL), n_seg, 0.0
        )
        spans.append(high - low)
    width, rise = spans
    return (width <= params.curb_max_width_m + ROUNDING_M) & (
        rise <= params.curb_max_rise_m + ROUNDING_M
    )


def _under_a_band(
    segment: np.ndarray,
    lateral: np.ndarray,
    height: np.ndarray,
    station: np.ndarray,
    params: SegmentParams,
) -> np.ndarray:
    """(K,) bool: the points of each slice under its highest band of ``curb_gap_m`` whose
    points below are a curb's (see :func:`curb_points`).

    ``segment`` (K,) the slice of every kept point, ``lateral``, ``height``, ``station`` (K,)
    per kept point (metres).
    """
    below = np.zeros(len(segment), bool)
    n_seg = int(segment.max()) + 1
    order = np.lexsort((height, segment))
    s, h = segment[order], height[order]
    first = np.concatenate([[True], s[1:] != s[:-1]])
    # A band opens above point i - 1 of a slice sorted by height, under point i.
    opens = np.zeros(len(order), bool)
    opens[1:] = ~first[1:] & (np.diff(h) >= params.curb_gap_m) & (h[:-1] <= params.curb_top_m)
    position = np.arange(len(order))
    cut_at = np.full(n_seg, -1, np.int64)
    np.maximum.at(cut_at, s[opens], position[opens])
    low = position < cut_at[s]
    if not low.any():
        return below
    depth = depth_from_path(segment, lateral, n_seg)[order]
    (low_back,) = group_shares(s[low], depth[low], (1 - SPAN_TAIL,), n_seg, np.inf)
    (high_front,) = group_shares(s[~low], depth[~low], (SPAN_TAIL,), n_seg, -np.inf)
    start, end = group_shares(s[low], station[order][low], (SPAN_TAIL, 1 - SPAN_TAIL), n_seg, 0.0)
    cut = (
        (low_back <= high_front)
        & (end - start >= params.curb_min_length_m - ROUNDING_M)
        & (np.bincount(s[low], minlength=n_seg) >= params.curb_min_points)
        & _curb_shaped(s, depth, h, low, n_seg, params)
    )
    below[order] = low & cut[s]
    return below
